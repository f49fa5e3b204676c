"""Which of a run's checks the sweep counts: the sets whose keeping makes a row safe, the hard
sets the robust filter guarantees, and the per-check columns of the safety tables. Every
other module of the sweep asks these functions, never names a check itself."""

from __future__ import annotations

import math

# The paper's joint-1 sets: a run is "safe" when it keeps all of them.
_SAFE_SET_CHECKS = ("position_joint1", "velocity_true_joint1", "error_joint1",
                    "error_rate_joint1")
# The physical (hard) sets of joint 1: what the robust filter guarantees.
_HARD_JOINT1_CHECKS = ("position_joint1", "velocity_true_joint1")


def _all_kept(safety: dict, checks: tuple[str, ...]) -> bool:
    return all(safety[c]["satisfied"] for c in checks if c in safety)


def row_is_safe(safety: dict) -> bool:
    """Whether a run's checks (``result.safety``) keep every set that makes it safe (those
    it evaluated)."""
    return _all_kept(safety, _SAFE_SET_CHECKS)


def hard_sets_kept(safety: dict) -> bool:
    """Whether a run's checks (``result.safety``) keep joint 1's hard sets (those it
    evaluated)."""
    return _all_kept(safety, _HARD_JOINT1_CHECKS)


def table_checks() -> list[tuple[str, str]]:
    """The safety tables' per-check columns after "all sets": (column name, check)."""
    return [(check.removesuffix("_joint1"), check) for check in _SAFE_SET_CHECKS]


def margin(row: dict) -> float:
    """A row's worst joint-1 check relative to its bound (≤ 1: every set kept)."""
    return max((row[f"{c}.worst"] / row[f"{c}.bound"] for c in _SAFE_SET_CHECKS
                if row.get(f"{c}.worst") is not None), default=math.nan)
