"""The bounds of the paper's barrier functions H1 (28) and H2 (29) and of their condition,
keys of the pipeline's ``[safety]`` table that the paper's package adds to it (the framework
knows only the safe sets). The NN weight bounds (Z̃) are in the weights' own units, which
mix those of their inputs."""

from __future__ import annotations

from ..declared import Safety, extend_safety
from ..schema import PositiveFloat, Section


class BarrierBounds(Section):
    """``[safety]``'s keys for the paper's barriers (:func:`barrier_bounds` reads them)."""

    # bound ε_max of the observer-error sets (16), ‖x̃1‖ ≤ ε_max in rad and ‖x̃2‖ ≤ ε_max in
    # rad/s; in H1 of (28) and the observer_error_norm check, rad and rad/s
    observer_error_bound: PositiveFloat = 1.0
    # bound Z̃_Wo on the observer's weight error ‖W̃o‖, the set (17) that H1 uses, mixed units
    z_wo_tilde: PositiveFloat = 20.0
    # bound Z̃_Wc on the controller's output-weight error ‖W̃c‖ of (18), in H2, mixed units
    z_wc_tilde: PositiveFloat = 50.0
    # bound Z̃_Vc on the controller's hidden-weight error ‖Ṽc‖ of (18), in H2, mixed units
    z_vc_tilde: PositiveFloat = 50.0
    # rate α of the barrier condition Ḣ + α·H ≥ 0 (class-K, linear), 1/s
    barrier_alpha: PositiveFloat = 1.0


extend_safety(BarrierBounds)


def barrier_bounds(safety: Safety) -> BarrierBounds:
    """The barrier bounds of a run's ``[safety]``: its values, or the defaults where the
    section was built without the paper's keys."""
    return BarrierBounds.model_validate(
        {name: getattr(safety, name) for name in BarrierBounds.model_fields
         if hasattr(safety, name)})
