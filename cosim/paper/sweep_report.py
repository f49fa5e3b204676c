"""The filter's guarantee over a sweep's rows: per run and class (which runs the guarantee
speaks for), how many keep every joint's hard sets, with Wilson 95 % intervals, and the
broken guarantees. Registered as a sweep report (key "guarantee" in sweep.json)."""

from __future__ import annotations

import math

from ..evaluate.reports import register_sweep_report, wilson

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


register_sweep_report("guarantee", guarantee_table, format_guarantee_table)
