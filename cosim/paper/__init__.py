"""The paper's study, plugged in like a user's package: its blocks (the reference, the
paper's sinusoids or a user's waypoints or CSV trajectory, and its safe centres, the
sensor, the nominal inertia model, the FLNN observer, the NN controller, the CBF-QP safety
filter, the PD + gravity compensation reference) and its evaluators (Theorem 1's bound on
‖r̂‖, the observer's error, the barriers H1, H2 and their condition, the effective gain,
the filter's activity and guarantee), registered through
:func:`cosim.blocks.register_block` and :func:`cosim.evaluate.register_evaluator` when this
package is imported: the ``cosim.blocks`` entry point ``paper`` imports it, as it would a
user's package. It sets the chain a pipeline that names none steps."""

from ..blocks import set_default_chain
from . import (  # noqa: F401  (they register on import)
    barrier_bounds,
    cbf_filter,
    controller,
    evaluators,
    guarantee,
    inertia,
    observer_block,
    pd_controller,
    reference,
    sensor,
    sweep_report,
)
from .theorem import BARRIERS, Gains, barriers, theorem1

set_default_chain(["reference", "sensor", "inertia_model", "observer", "controller"])

__all__ = ["BARRIERS", "Gains", "barriers", "theorem1"]
