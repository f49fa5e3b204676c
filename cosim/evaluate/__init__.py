"""Evaluation of a run: safety checks, barrier values and metrics, computed once.

The :class:`Evaluator` fills each check's and barrier's values as rows complete (so a
recording can stream them), and :meth:`Evaluator.result` gives the :class:`Evaluation`
that summary.json, the recording and the figures all read.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..signals import Trace
from .safety import (
    EVALUATION_INPUTS,
    Check,
    Gains,
    SafeSet,
    barrier_condition,
    barriers,
    check_references,
    check_signals,
    summarise,
    theorem1,
    torque_reversals,
)

BARRIERS = ("H1", "H2", "H")

__all__ = ["BARRIERS", "EVALUATION_INPUTS", "Check", "Evaluation", "Evaluator", "Gains",
           "SafeSet", "barriers", "check_signals", "gains", "theorem1", "torque_reversals"]


def gains(run, links: int) -> Gains:
    """The gains the barriers need, from a run's tables (``pipeline.runs[name]``)."""
    controller = run.controller
    lam = np.broadcast_to(np.asarray(controller.lam, float), (links,)).copy()
    velocity = controller.velocity
    if velocity == "auto":
        velocity = "observer" if controller.variant == "proposed" else "plant"
    return Gains(lam, controller.f, controller.g, run.observer.fo, velocity == "observer")


@dataclass
class Evaluation:
    """A run's completed rows evaluated: every check (values per row, bounds, reference),
    the barriers per row, and what summary.json says of them."""

    checks: dict[str, Check]
    barriers: dict[str, np.ndarray]
    metrics: dict
    safety: dict


@dataclass
class Evaluator:
    """Evaluates a run's trace chunk by chunk, as the master completes rows.

    R of Theorem 1 depends on the whole reference, which is known once the blocks are reset,
    so every chunk is evaluated against the same bounds.
    """

    trace: Trace
    safe: SafeSet
    gains: Gains
    upto: int = 0
    values: dict[str, np.ndarray] = field(default_factory=dict)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    barrier_values: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.r_bound = theorem1(self.trace, self.safe, self.gains.Lambda)["R"]
        rows = self.trace.steps + 1
        self.barrier_values = {name: np.full(rows, np.nan) for name in (*BARRIERS, "condition")}

    def update(self, upto: int) -> tuple[int, dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Evaluate rows [previous ``upto``, ``upto``). Returns (first row, check values,
        barrier values) of those rows."""
        start = self.upto
        rows = {name: array[start:upto] for name, array in self.trace.arrays.items()}
        checks = check_signals(rows, self.safe, self.gains, self.r_bound)
        if not self.values:
            total = self.trace.steps + 1
            self.values = {name: np.full(total, np.nan) for name in checks}
            self.bounds = {name: (c.lower, c.upper) for name, c in checks.items()}
        for name, check in checks.items():
            self.values[name][start:upto] = check.value
        h = barriers(rows, self.safe, self.gains, self.r_bound)
        previous = self.barrier_values["H"][start - 1] if start else np.nan
        h["condition"] = barrier_condition(h["H"], previous, self.trace.dt,
                                           self.safe.barrier_alpha)
        for name, value in h.items():
            self.barrier_values[name][start:upto] = value
        self.upto = upto
        return start, {n: c.value for n, c in checks.items()}, h

    def result(self) -> Evaluation:
        """The evaluation of the completed rows (``trace.rows_done``)."""
        k = self.trace.rows_done
        if self.upto < k or not self.values:
            self.update(k)
        done = self.trace.completed()
        references = check_references(done, self.safe, self.gains)
        checks = {name: Check(self.values[name][:k], upper, lower, references.get(name))
                  for name, (lower, upper) in self.bounds.items()}
        h = {name: value[:k] for name, value in self.barrier_values.items()}
        metrics, safety = summarise(done, checks, h, self.safe, self.gains)
        return Evaluation(checks, h, metrics, safety)
