"""The pipeline sections that blocks read through their :class:`~cosim.blocks.BlockContext`
(one typed interface, no other block's table): the safe set and the declared uncertainty.
They import nothing of the blocks, so blocks may import them. SI units, radians."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from .schema import FiniteFloat, NonNegativeFloat, PositiveFloat, Section


class Safety(Section):
    """The safe sets every run is checked against, and the bounds of the paper's barriers.
    The NN weight bounds (Z̃) are in the weights' own units, which mix those of their inputs.
    """

    # radius α_max of the position set ‖x1 − q_s‖ ≤ α_max, per joint and as a norm, rad
    position_bound: PositiveFloat = 20.0
    # radius α_max of the velocity set ‖q̇ − q̇_s‖ ≤ α_max, per joint and as a norm, rad/s
    velocity_bound: PositiveFloat = 13.5
    error_bound: PositiveFloat = 1.0  # bound E1 of the tracking-error set ‖e‖ ≤ E1, rad
    error_rate_bound: PositiveFloat = 5.0  # bound E2 of the error-rate set ‖ė‖ ≤ E2, rad/s
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


class Uncertainty(Section):
    """What the safety filter's guarantee assumes, declared: its margins are computed from
    these, and the evaluation checks every run against them (a run outside them is
    classified as such, never counted as a failure of the filter).

    - ``payload``: the range [low, high] of mass added at the last link's centre of mass
      (its tip on the paper's arm), kg: the plant's m[n] lies in nominal + [low, high].
    - ``noise_bound``: bound on the sensor's error |q_meas − q| per joint, rad (Gaussian
      noise: take ~6σ).
    - ``initial_velocity_error``: bound on the observer's initial velocity error
      |q̇(0) − x̂2(0)| per joint, rad/s.
    - ``disturbance``: bound on the error of the disturbance model |τ_d − τ_d,model| per
      joint, N·m.
    - ``observer_residual_rate``: a bound J̄ on the rate of the observer's unmodelled
      acceleration, rad/s³, which the observer's bound ε(t) once rested on. No longer used
      by it: ε(t) is certified from the quantities above, the applied torque and the
      nominal chain (cosim/paper/observer.py; docs/safety.md, "How the margins follow from
      them"), since the closed loop broke any declared J̄. Kept so that pipelines that set
      it still load.
    """

    payload: Annotated[list[FiniteFloat], Field(min_length=2, max_length=2)] = [0.0, 0.0]
    noise_bound: NonNegativeFloat = 0.0
    initial_velocity_error: NonNegativeFloat = 0.0
    disturbance: NonNegativeFloat = 0.0
    observer_residual_rate: NonNegativeFloat = 4.0e4

    @model_validator(mode="after")
    def _ordered(self) -> Uncertainty:
        low, high = self.payload
        if low > high:
            raise ValueError(f"uncertainty.payload = [{low:g}, {high:g}]: give [low, high] "
                             "with low ≤ high, kg")
        return self


__all__ = ["PositiveFloat", "Safety", "Uncertainty"]
