"""What evaluators report over many runs (a sweep's rows): proportions with their Wilson
intervals, and the reports a package registers for `cosim sweep` to print and keep in
sweep.json beside its own safety rates (the paper's filter: its guarantee by class)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass


def wilson(successes: int, trials: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval (95 % by default) of a proportion."""
    if trials == 0:
        return (math.nan, math.nan)
    p = successes / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / (1 + z * z
                                                                                 / trials)
    # At k = 0 (k = n) the lower (upper) end is exactly 0 (1): centre ∓ half analytically,
    # which round-off would leave an ulp off the observed proportion.
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == trials else min(1.0, centre + half)
    return (low, high)


@dataclass(frozen=True)
class SweepReport:
    """``table(rows)``: its entries (JSON-able; none: nothing to report on these rows);
    ``text(entries)``: them as lines within 100 columns."""

    key: str  # its key in sweep.json
    table: Callable[[list[dict]], list[dict]]
    text: Callable[[list[dict]], str]


SWEEP_REPORTS: dict[str, SweepReport] = {}


def register_sweep_report(key: str, table: Callable[[list[dict]], list[dict]],
                          text: Callable[[list[dict]], str]) -> None:
    """Have every sweep print ``text(table(rows))`` and keep ``table(rows)`` in sweep.json
    under ``key``."""
    if key in SWEEP_REPORTS and SWEEP_REPORTS[key].table is not table:
        raise ValueError(f"a sweep report named {key!r} is registered already")
    SWEEP_REPORTS[key] = SweepReport(key, table, text)
