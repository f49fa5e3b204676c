"""A sweep's statistics: the share of points keeping each set, per run (and per value of a grid
key), and the robust filter's guarantee by class, with Wilson 95 % intervals; their text."""

from __future__ import annotations

import math

from .checks import family_kept, table_checks
from .spec import SweepSpec, toml_value


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


def safety_table(rows: list[dict]) -> list[dict]:
    """Per run: points, failed, and the rate at which every set is kept (as the run's
    verdict counts them) and each family (its every joint and norm), with Wilson 95 %
    intervals (over the points that completed)."""
    table = []
    for run in dict.fromkeys(r["run"] for r in rows):
        mine = [r for r in rows if r["run"] == run]
        ok = [r for r in mine if r["status"] == "ok"]
        entry = {"run": run, "points": len(mine), "failed": len(mine) - len(ok)}
        columns = [("all sets", lambda r: bool(r.get("safe"))),
                   *[(family, lambda r, checks=checks: family_kept(r, checks))
                     for family, checks in table_checks(ok or mine)]]
        for name, kept_in in columns:
            kept = sum(kept_in(r) for r in ok)
            low, high = wilson(kept, len(ok))
            entry[name] = (kept / len(ok) if ok else math.nan, low, high)
        table.append(entry)
    return table


def safety_by_value(rows: list[dict], spec: SweepSpec) -> dict[str, list[dict]]:
    """Per grid key of two or more values: :func:`safety_table` for each of its values (the
    other keys pooled), so a table says which value kept the sets, not only how often all
    points did. Sampled keys are continuous: their rates are in sweep_safety.png."""
    out = {}
    for axis in spec.grid:
        column = f"set:{axis.key}"
        values = list(dict.fromkeys(r.get(column) for r in rows))
        if len(values) < 2:
            continue
        out[axis.key] = [{"value": value, **entry} for value in values
                         for entry in safety_table([r for r in rows if r.get(column) == value])]
    return out


# The classes of the robust-safety evaluation: which runs the filter's guarantee speaks for.
CLASSES = (
    ("starts inside", lambda r: r.get("guarantee.starts_inside") is True),
    ("covered", lambda r: r.get("guarantee.starts_inside") is True
     and r.get("guarantee.feasible") is True and r.get("guarantee.within_bounds") is True),
    ("infeasible", lambda r: r.get("guarantee.starts_inside") is True
     and r.get("guarantee.feasible") is False),
    ("outside bounds", lambda r: r.get("guarantee.starts_inside") is True
     and r.get("guarantee.within_bounds") is False),
    ("starts outside", lambda r: r.get("guarantee.starts_inside") is False),
)


def guarantee_table(rows: list[dict]) -> list[dict]:
    """Per run and class (:data:`CLASSES`; a run may be in several, "covered" is the one the
    guarantee speaks for): how many, the share keeping every joint's hard sets (position,
    true velocity) with its Wilson 95 % interval, and the broken guarantees (left a hard set while
    covered). Failed points are counted apart, never as unsafe."""
    table = []
    for run in dict.fromkeys(r["run"] for r in rows):
        mine = [r for r in rows if r["run"] == run]
        ok = [r for r in mine if r["status"] == "ok"]
        if not any("guarantee.starts_inside" in r for r in ok):
            continue
        entry = {"run": run, "points": len(mine), "failed": len(mine) - len(ok),
                 "broken": sum(bool(r.get("guarantee.broken")) for r in ok)}
        for name, member in CLASSES:
            rows_in = [r for r in ok if member(r)]
            kept = sum(bool(r.get("hard_sets_kept")) for r in rows_in)
            low, high = wilson(kept, len(rows_in))
            entry[name] = (len(rows_in), kept / len(rows_in) if rows_in else math.nan, low,
                           high)
        table.append(entry)
    return table


def format_guarantee_table(table: list[dict], width: int = 100) -> str:
    """:func:`guarantee_table` as text: one line per run, one column per class, the classes
    paged into groups so that no line is wider than ``width``."""
    names = [name for name, _ in CLASSES]
    lines = ["every joint's hard sets (position, true velocity) kept, by class (Wilson 95 %);",
             "covered = starts inside, hard QP feasible throughout, within the declared "
             "uncertainty"]
    per_line = max(1, (width - 25) // 30)
    for group in (names[i:i + per_line] for i in range(0, len(names), per_line)):
        lines.append(f"{'run':<16}{'broken':>7}  " + "  ".join(f"{n:<28}" for n in group)
                     .rstrip())
        for e in table:
            cells = [f"{count:>4}: {100 * rate:5.1f} % [{100 * lo:5.1f},{100 * hi:6.1f}]"
                     if count else f"{0:>4}: -" for count, rate, lo, hi in (e[n] for n in group)]
            lines.append(f"{e['run']:<16}{e['broken']:>7}  "
                         + "  ".join(f"{c:<28}" for c in cells).rstrip())
    return "\n".join(lines)


def format_table(table: list[dict], key: str | None = None, width: int = 100) -> str:
    """The safety-rate table; ``key``: a per-value table of that grid key (a first column
    holds the value). Its columns are "all sets" and each family of checks, paged into
    groups so that no line is wider than ``width``."""
    names = ["all sets", *dict.fromkeys(n for e in table for n in e
                                         if isinstance(e[n], tuple) and n != "all sets")]
    title = "safety rate per run (every joint's sets kept; Wilson 95 % interval)"
    value_width = max([len(key or ""), *(len(toml_value(e["value"])) for e in table
                                         if "value" in e)])
    first = f"{key:<{value_width}}  " if key else ""
    lead = len(first) + 32
    per_line = max(1, (width - lead) // 24)
    lines = [f"{title[:-1]}; by {key})" if key else title]
    for group in (names[i:i + per_line] for i in range(0, len(names), per_line)):
        lines.append(f"{first}{'run':<18}{'points':>7}{'failed':>7}  "
                     + "  ".join(f"{n:<22}" for n in group).rstrip())
        for entry in table:
            cells = [f"{100 * r:5.1f} % [{100 * lo:5.1f}, {100 * hi:5.1f}]"
                     if n in entry and not math.isnan(r) else "-"
                     for n in group for r, lo, hi in [entry.get(n, (math.nan,) * 3)]]
            value = f"{toml_value(entry['value']):<{value_width}}  " if key else ""
            lines.append(f"{value}{entry['run']:<18}{entry['points']:>7}{entry['failed']:>7}  "
                         + "  ".join(f"{c:<22}" for c in cells).rstrip())
    return "\n".join(lines)
