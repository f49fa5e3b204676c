"""Signals and the trace.

A block declares the signals it reads and writes (:class:`Signal`: shape per row, unit,
meaning, where the recording shows it). The assembled scenario collects those declarations,
and the trace, the recording's entities and the run folder's arrays are all derived from
them: a new signal is one line in the block that produces it.

Row k of the trace holds the values at t_k = k·h; the torque in row k is held over
[t_k, t_k+1). SI units, radians.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

SHAPES = ("n", "nn", "1")  # per joint, n×n, scalar


@dataclass(frozen=True)
class Signal:
    """One signal's declaration.

    ``entity`` is its path under ``/<run>/`` in the recording (``None``: not recorded, with
    the reason in the declaring block); ``label`` the series-name stem there (joint j of a
    per-joint signal is ``label`` + j). ``kept``: an unrecorded signal that stays in the
    trace files even when no block reads it (an offer to later blocks, like the observer's
    error bound), rather than being refused as unused. ``estimates``: the signal (a plant
    output) this one is an estimate of; the recording shows the estimation error, true
    minus estimate, beside it.
    """

    shape: str  # one of SHAPES
    unit: str
    description: str
    entity: str | None = None
    label: str | None = None
    kept: bool = False
    estimates: str | None = None

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f"Signal shape {self.shape!r}: must be one of {SHAPES}")

    def rows_shape(self, rows: int, links: int) -> tuple[int, ...]:
        return {"n": (rows, links), "nn": (rows, links, links), "1": (rows,)}[self.shape]

    def width(self, links: int) -> int:
        return {"n": links, "nn": links * links, "1": 1}[self.shape]


class Trace:
    """Preallocated arrays, one per declared signal, ``steps + 1`` rows, NaN until written.
    ``rows_done`` counts the rows that are complete."""

    def __init__(self, signals: Mapping[str, Signal], links: int, steps: int, dt: float):
        self.signals = dict(signals)
        self.links, self.steps, self.dt = links, steps, dt
        self.rows_done = 0
        rows = steps + 1
        self.arrays: dict[str, np.ndarray] = {
            name: np.full(signal.rows_shape(rows, links), np.nan)
            for name, signal in self.signals.items()}
        self.time = np.arange(rows) * dt

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def __contains__(self, name: str) -> bool:
        return name in self.arrays

    def completed(self) -> Trace:
        """A view holding only the rows that were completed."""
        k = self.rows_done
        view = Trace.__new__(Trace)
        view.signals, view.links, view.dt = self.signals, self.links, self.dt
        view.steps, view.rows_done = k - 1, k
        view.arrays = {name: a[:k] for name, a in self.arrays.items()}
        view.time = self.time[:k]
        return view


# The trace file's own entries beside the signals: the time column, the units, and each
# check's and barrier's values.
TRACE_PREFIXES = ("check_", "barrier_", "_")


def trace_name_clash(signal: str) -> str | None:
    """Why a signal cannot be called ``signal`` in the trace files (None: it can)."""
    if signal == "time":
        return "the name of the trace's time column"
    prefix = next((p for p in TRACE_PREFIXES if signal.startswith(p)), None)
    if prefix:
        return (f"and names starting with {prefix!r} are the trace file's own "
                f"({', '.join(repr(p) for p in TRACE_PREFIXES)}: the checks', the barriers' "
                "values, the units)")
    return None
