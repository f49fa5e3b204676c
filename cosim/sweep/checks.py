"""Which of a run's checks the sweep counts, read from their declarations
(:mod:`cosim.evaluate.checks`): a row is safe as a run is (:func:`is_safe`: every attainable
hard and soft set, every joint and the norm), the guarantee's hard sets are every joint's,
and the tables' columns are the declared families. Every other module of the sweep asks
these functions, never names a check itself."""

from __future__ import annotations

import math

from ..evaluate.checks import Kind, family_of, is_safe, kept


def row_is_safe(safety: dict) -> bool:
    """Whether a run's checks (``result.safety``) keep every set, as its verdict says."""
    return is_safe(safety)


def hard_sets_kept(safety: dict) -> bool:
    """Whether a run's checks (``result.safety``) keep every joint's hard sets."""
    return kept(safety, [Kind.HARD])


def check_columns(check: str, entry: dict) -> dict:
    """A check's columns in a row: what it is (kind, unit), its bound, worst value, whether
    it held and could be held, and its time outside."""
    return {f"{check}.kind": entry.get("kind", str(Kind.SOFT)), f"{check}.unit": entry.get("unit"),
            f"{check}.bound": entry["bound"], f"{check}.worst": entry["worst"],
            f"{check}.satisfied": entry["satisfied"],
            f"{check}.attainable": entry.get("attainable"),
            f"{check}.time_outside_s": entry.get("time_outside_s")}


def _checks(rows: list[dict]) -> list[str]:
    """The checks of the rows' columns that count in a verdict (not a sufficient
    condition), in column order."""
    names = dict.fromkeys(key.removesuffix(".satisfied") for row in rows for key in row
                          if key.endswith(".satisfied"))
    return [n for n in names if all(r.get(f"{n}.kind") != Kind.SUFFICIENT for r in rows)]


def table_checks(rows: list[dict]) -> list[tuple[str, list[str]]]:
    """The safety tables' columns after "all sets": each family (its every joint and norm)
    of the checks the rows hold, (column name, its checks)."""
    families: dict[str, list[str]] = {}
    for check in _checks(rows):
        families.setdefault(family_of(check), []).append(check)
    return list(families.items())


def family_kept(row: dict, checks: list[str]) -> bool:
    """Whether a row kept every one of ``checks`` (a set the reference itself leaves is not
    counted, as in the run's verdict)."""
    return all(row.get(f"{c}.satisfied") is not False or row.get(f"{c}.attainable") is False
               for c in checks)


def margin(row: dict, checks: list[str] | None = None) -> float:
    """A row's worst check relative to its bound, over ``checks`` (default those that count
    in a verdict; ≤ 1: every set kept). NaN when none has a value."""
    return max((row[f"{c}.worst"] / row[f"{c}.bound"]
                for c in (_checks([row]) if checks is None else checks)
                if row.get(f"{c}.worst") is not None and row.get(f"{c}.bound")
                and row.get(f"{c}.attainable") is not False),
               default=math.nan)
