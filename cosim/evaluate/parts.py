"""The evaluators: each part of a run's evaluation declares the signals and the block
constants it reads, and runs only when the run has them (a run whose chain has no observer
is evaluated without the observer's checks, and its summary says why). Like a block, a new
evaluator is one class plus :func:`register_evaluator`.

A part may give, per chunk of rows, safety checks (:class:`Check`, made by the
:class:`Declaration` s it lists) and series (per-row values such as barrier functions), at
the end of the run metrics from the completed rows and from its checks, and the lines
`cosim run` prints of them. SI units, radians. Ground truth (the true q̇) is read by
evaluators for evaluation only, never for control.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from .checks import Check, Declaration
from .safety import SafeSet, Signals


class Part:
    """One evaluator. ``inputs``: the trace signals it reads; ``constants``: the constants
    (published by blocks, :attr:`cosim.blocks.Block.publishes`) it needs. Built once the
    blocks are reset (the reference, so every bound, is known)."""

    name: ClassVar[str]
    meaning: ClassVar[str]  # what it evaluates, for the summary
    inputs: ClassVar[tuple[str, ...]]
    constants: ClassVar[tuple[str, ...]] = ()
    # The checks it may make: each family declared once (name, quantity, unit, kind,
    # figure); the evaluation refuses a check made by a declaration not listed here.
    declarations: ClassVar[tuple[Declaration, ...]] = ()
    # The series it gives, each with its meaning and unit; ``conditions``: those that must
    # stay ≥ 0 (drawn apart, their failing rows marked).
    series_meanings: ClassVar[Mapping[str, str]] = {}
    conditions: ClassVar[tuple[str, ...]] = ()
    # The figure its series are drawn in, per run: a PNG of this name in the run folder ("",
    # none), the series on the left and its conditions on the right (the paper's barriers:
    # "fig5_barriers")
    series_figure: ClassVar[str] = ""
    # The unit of each number its metrics give, by dotted name (a per-joint list's entries
    # share their list's; a name not listed takes its nearest listed parent's): what
    # summary.json's ``metric_units`` and `cosim compare` say. "1" for a fraction.
    metric_units: ClassVar[Mapping[str, str]] = {}

    def __init__(self, trace: Signals, safe: SafeSet, constants: Mapping[str, Any],
                 available: frozenset[str] = frozenset()):
        self.safe = safe
        self.given = constants
        self.available = available  # the run's signals that hold values
        self.note: str | None = None  # what summary.json adds to "ran" (a part left out)

    @classmethod
    def undeclared(cls, safe: SafeSet) -> str | None:
        """Why this evaluator has nothing to judge under these declarations (it then does not
        run, and says so), or None."""
        return None

    def checks(self, rows: Signals) -> dict[str, Check]:
        """Safety checks of these rows (each joint and the norm against their bounds), each
        made by a :class:`Declaration` (:meth:`Declaration.joints_and_norm`)."""
        return {}

    def references(self, trace: Signals) -> dict[str, np.ndarray]:
        """The reference trajectory's own value of the checks that have one."""
        return {}

    def series(self, rows: Signals) -> dict[str, np.ndarray]:
        """Other per-row values of these rows (the barriers)."""
        return {}

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        """What summary.json's ``metrics`` gets from the completed rows."""
        return {}

    def conclude(self, trace: Signals, checks: Mapping[str, Check]) -> dict:
        """What summary.json's ``metrics`` gets from the run's evaluated checks."""
        return {}

    def report(self, metrics: Mapping[str, Any]) -> tuple[str | None, list[str]]:
        """What `cosim run` prints of this part under the run's name: a headline of its own
        (or None) and lines beside the other parts' (SI units)."""
        return None, []


EVALUATORS: dict[str, type[Part]] = {}


def register_evaluator(cls: type[Part]) -> type[Part]:
    """Class decorator: evaluate every run with ``cls`` where its inputs exist."""
    if cls.name in EVALUATORS and EVALUATORS[cls.name] is not cls:
        raise ValueError(f"an evaluator named {cls.name!r} is registered already")
    EVALUATORS[cls.name] = cls
    return cls


# The units of the metrics the loop itself adds to every run's (the evaluators declare theirs).
LOOP_METRIC_UNITS = {"wall_time_s": "s", "steps_per_second": "1/s", "simulated_time_s": "s",
                     "recording_handoff_s": "s"}


def declared_metric_units() -> dict[str, str]:
    """Every registered evaluator's metric units, and the loop's."""
    return {**{name: unit for cls in EVALUATORS.values()
               for name, unit in cls.metric_units.items()}, **LOOP_METRIC_UNITS}


def metric_unit(units: Mapping[str, str], metric: str) -> str | None:
    """A metric's unit: its own dotted name's in ``units``, else its nearest listed
    parent's; a per-joint entry (``rms_error[2]`` in a summary, ``rms_error.2`` in a sweep's
    row) takes its list's. None where nothing declares one (an evaluator that declares no
    units, a folder of an older cosim)."""
    name = re.sub(r"(\[\d+\]|\.\d+)$", "", metric)
    while name:
        if name in units:
            return units[name]
        name = name.rpartition(".")[0]
    return None


def units_said(metrics: Mapping, declared: Mapping[str, str], prefix: str = "") -> dict[str, str]:
    """The units a run's metrics state themselves, for the numbers ``declared`` gives none:
    a table holding a text ``unit`` gives it to them (a hard set's first exit: its value and
    bound are in that set's unit, rad or rad/s, known only once the run says which set it
    left; its time is declared, s)."""
    out: dict[str, str] = {}
    unit = metrics.get("unit")
    for key, value in metrics.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(units_said(value, declared, f"{name}."))
        elif isinstance(unit, str) and isinstance(value, int | float) \
                and not isinstance(value, bool) and metric_unit(declared, name) is None:
            out[name] = unit
    return out


def series_names() -> frozenset[str]:
    """Every series some evaluator gives."""
    return frozenset(s for cls in EVALUATORS.values() for s in cls.series_meanings)


def evaluated_signals() -> frozenset[str]:
    """Every signal some evaluator reads (an output only they read is not unused)."""
    return frozenset(s for cls in EVALUATORS.values() for s in cls.inputs)


def select(trace: Signals, constants: Mapping[str, Any],
           unmapped: frozenset[str] = frozenset(), safe: SafeSet | None = None
           ) -> tuple[list[type[Part]], dict[str, str]]:
    """(the evaluators whose inputs this run has, why each other one does not run);
    ``unmapped``: plant outputs in the trace that the plant does not map (NaN, absent);
    ``safe``, given: an evaluator with nothing declared to judge does not run either."""
    chosen, skipped = [], {}
    for name, cls in EVALUATORS.items():
        reason = cls.undeclared(safe) if safe is not None else None
        if reason:
            skipped[name] = reason
            continue
        signals = [s for s in cls.inputs if s not in trace]
        ports = [s for s in cls.inputs if s in unmapped]
        missing = [c for c in cls.constants if c not in constants]
        if not signals and not ports and not missing:
            chosen.append(cls)
            continue
        why = []
        if signals:
            why.append(f"needs {_listed('signal', signals)}, which no block in the chain "
                       "produces")
        if ports:
            why.append(f"needs {_listed('plant output', ports)}, which the plant does not "
                       "map")
        if missing:
            why.append(f"needs {_listed('constant', missing)}, which no block in the chain "
                       "publishes")
        skipped[name] = "; ".join(why)
    return chosen, skipped


def _listed(what: str, names: list[str]) -> str:
    quoted = ", ".join(f"'{n}'" for n in names)
    return f"the {what}{'s' * (len(names) > 1)} {quoted}"
