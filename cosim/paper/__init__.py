"""The paper's study, plugged in like a user's plugin: its evaluators (Theorem 1's bound on
‖r̂‖, the observer's error, the barriers H1, H2 and their condition, the effective gain) and
the safety filter's guarantee, registered through :func:`cosim.evaluate.register_evaluator`
when this package is imported (the ``cosim.blocks`` entry point ``paper`` imports it, as it
would a user's package)."""

from . import evaluators, guarantee  # noqa: F401  (they register on import)
from .theorem import BARRIERS, Gains, barriers, theorem1

__all__ = ["BARRIERS", "Gains", "barriers", "theorem1"]
