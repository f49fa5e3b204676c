"""Evaluation of a run: safety checks, series and metrics, computed once.

The evaluation is made of evaluators (:mod:`.parts`), each declaring the signals and block
constants it reads; a run is evaluated by those whose inputs it has, and its summary says
why each other one did not run. The framework's own (:mod:`.sets`) read the plant's ports
and the declared interface (:mod:`cosim.interface`); others register like a user's plugin.
The :class:`Evaluator` fills each check's and series' values as rows complete (so a
recording can stream them), and :meth:`Evaluator.result` gives the :class:`Evaluation`
that summary.json, the recording and the figures all read.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..schema import PipelineError
from ..signals import Trace
from . import sets  # noqa: F401  (the framework's own evaluators register on import)
from .checks import Check, Declaration, Kind, is_safe, kept, left_sets, safety_entries
from .parts import (
    EVALUATORS,
    Part,
    evaluated_signals,
    register_evaluator,
    select,
    series_names,
    units_said,
)
from .safety import SafeSet, torque_reversals

__all__ = ["EVALUATORS", "Check", "Declaration", "Evaluation", "Evaluator", "Kind", "Part",
           "SafeSet", "evaluated_signals", "is_safe", "kept", "left_sets",
           "register_evaluator", "series_names", "torque_reversals"]


@dataclass
class Evaluation:
    """A run's completed rows evaluated: every check (values per row, bounds, reference),
    the evaluators' series per row (barrier functions, their conditions), what summary.json
    says of them, per evaluator whether it ran (or why not), and the lines to print."""

    checks: dict[str, Check]
    barriers: dict[str, np.ndarray]  # the evaluators' series per row, by name
    metrics: dict
    safety: dict
    evaluators: dict[str, str] = field(default_factory=dict)
    # what `cosim run` prints: headlines of their own, then lines beside each other
    headlines: list[str] = field(default_factory=list)
    lines: list[str] = field(default_factory=list)
    metric_units: dict[str, str] = field(default_factory=dict)  # Part.metric_units, merged


@dataclass
class Evaluator:
    """Evaluates a run's trace chunk by chunk, as the master completes rows, with the
    evaluators its signals and ``constants`` (what the run's blocks publish) allow.

    Built once the blocks are reset: R of Theorem 1 depends on the whole reference, so every
    chunk is evaluated against the same bounds.
    """

    trace: Trace
    safe: SafeSet
    constants: Mapping[str, Any]
    # Trace signals that hold no values (plant outputs the plant does not map: NaN).
    unmapped: frozenset[str] = frozenset()
    upto: int = 0
    values: dict[str, np.ndarray] = field(default_factory=dict)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    # check -> (its declaration, its joint or None for the norm)
    declared: dict[str, tuple[Declaration, int | None]] = field(default_factory=dict)
    # check -> the set's centre where value + centre is what a limit bounds (Check.centre)
    centres: dict[str, float | None] = field(default_factory=dict)
    barrier_values: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        chosen, self.skipped = select(self.trace, self.constants, self.unmapped, self.safe)
        available = frozenset(self.trace.arrays) - self.unmapped
        self.parts: list[Part] = [cls(self.trace, self.safe, self.constants, available)
                                  for cls in chosen]
        _refuse_shared(self.parts)

    def update(self, upto: int) -> tuple[int, dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Evaluate rows [previous ``upto``, ``upto``). Returns (first row, check values,
        barrier values) of those rows."""
        start = self.upto
        rows = {name: array[start:upto] for name, array in self.trace.arrays.items()}
        total = self.trace.steps + 1
        checks, series = {}, {}
        for part in self.parts:
            made = part.checks(rows)
            for name, check in made.items():
                if name not in self.values and check.declared not in part.declarations:
                    raise PipelineError(f"evaluator {part.name!r}: check {name!r} is not made by "
                                    "one of its declarations (list each Declaration in the "
                                    "evaluator's `declarations` and make its checks with "
                                    "Declaration.joints_and_norm or Declaration.norm)")
            checks.update(made)
            series.update(part.series(rows))
        for name, check in checks.items():
            if name not in self.values:
                self.values[name] = np.full(total, np.nan)
                self.bounds[name] = (check.lower, check.upper)
                self.declared[name] = (check.declared, check.joint)
                self.centres[name] = check.centre
            self.values[name][start:upto] = check.value
        for name, value in series.items():
            if name not in self.barrier_values:
                self.barrier_values[name] = np.full(total, np.nan)
            self.barrier_values[name][start:upto] = value
        self.upto = upto
        return start, {n: c.value for n, c in checks.items()}, series

    def result(self) -> Evaluation:
        """The evaluation of the completed rows (``trace.rows_done``)."""
        k = self.trace.rows_done
        if self.upto < k or (self.parts and not self.values and not self.barrier_values):
            self.update(k)
        done = self.trace.completed()
        references = {}
        for part in self.parts:
            references.update(part.references(done))
        checks = {name: Check(self.values[name][:k], upper, lower, references.get(name),
                              *self.declared[name], self.centres[name])
                  for name, (lower, upper) in self.bounds.items()}
        h = {name: value[:k] for name, value in self.barrier_values.items()}
        metrics = {}
        if k:  # a run stopped at its first row (a block raised there): nothing to sum up
            for part in self.parts:
                metrics.update(part.metrics(done, h))
            for part in self.parts:
                metrics.update(part.conclude(done, checks))
        headlines, lines = [], []
        for part in self.parts:
            headline, more = part.report(metrics) if k else (None, [])
            headlines += [headline] if headline else []
            lines += more
        ran = {part.name for part in self.parts}
        notes = {part.name: part.note for part in self.parts if part.note}
        said = {name: ("ran" + (f" ({notes[name]})" if name in notes else "")) if name in ran
                else f"not run: {self.skipped[name]}"
                for name in EVALUATORS if name in ran or name in self.skipped}
        units = {name: unit for part in self.parts for name, unit in part.metric_units.items()}
        units.update(units_said(metrics, units))
        return Evaluation(checks, h, metrics, safety_entries(checks, self.trace.dt), said,
                          headlines, lines, units)


def _refuse_shared(parts: list[Part]) -> None:
    """Two evaluators may not declare the same family of checks, nor give the same series:
    one would silently replace the other's values (a plugin's check passing for a built-in
    one)."""
    owner: dict[str, str] = {}
    for part in parts:
        for name in [d.family for d in part.declarations] + list(part.series_meanings):
            if name in owner and owner[name] != part.name:
                raise PipelineError(f"evaluators {owner[name]!r} and {part.name!r} both declare "
                                f"{name!r}: give one of them another name")
            owner[name] = part.name
