"""The filter's guarantee over a sweep's rows: per run and class (which runs the guarantee
speaks for), how many keep every joint's hard sets, with Wilson 95 % intervals, the broken
guarantees, and how the runs that left a hard set came back. Registered as a sweep report
(key "guarantee" in sweep.json)."""

from __future__ import annotations

import math

from ..evaluate.reports import register_sweep_report, wilson
from .guarantee import RETURN_WITHIN


def _viable(r: dict) -> bool | None:
    # rows of sweeps from before the viable set was reported: their box start stands in
    return r.get("guarantee.starts_viable", r.get("guarantee.starts_inside"))


def _covered(r: dict) -> bool:
    if "guarantee.covered" in r:
        return r["guarantee.covered"] is True
    # rows from before "covered" was reported: the rule of then
    return (r.get("guarantee.starts_inside") is True and r.get("guarantee.feasible") is True
            and r.get("guarantee.within_bounds") is True)


# The classes of the robust-safety evaluation: which runs the filter's guarantee speaks for
# ("covered"), and why the others are not: a start outside the box, a start in the box the
# filter cannot keep (not viable), or a plant or signal outside the declared uncertainty.
CLASSES = (
    ("starts inside", lambda r: r.get("guarantee.starts_inside") is True),
    ("viable", lambda r: _viable(r) is True),
    ("covered", _covered),
    ("inside but not viable", lambda r: r.get("guarantee.starts_inside") is True
     and _viable(r) is False),
    ("outside bounds", lambda r: _viable(r) is True
     and r.get("guarantee.within_bounds") is False),
    ("starts outside", lambda r: r.get("guarantee.starts_inside") is False),
)


def _recovery(ok: list[dict]) -> dict:
    """Of the runs that left a hard set (or started outside one): how many, the share back
    inside every set within :data:`RETURN_WITHIN` with its Wilson interval, and the longest
    time to return (s; a lower bound where a run was still outside at the end)."""
    left = [r for r in ok if r.get("guarantee.time_to_return_s") is not None]
    back = sum(r.get("guarantee.back_within_1s") is True for r in left)
    low, high = wilson(back, len(left))
    return {"left": len(left), "back_within_1s": back,
            "share": back / len(left) if left else math.nan, "low": low, "high": high,
            "longest_s": max((r["guarantee.time_to_return_s"] for r in left), default=None)}


def guarantee_table(rows: list[dict]) -> list[dict]:
    """Per run and class (:data:`CLASSES`; a run may be in several, "covered" is the one the
    guarantee speaks for): how many, the share keeping every joint's hard sets (position,
    true velocity) with its Wilson 95 % interval, the broken guarantees (a covered run that
    left a hard set, was infeasible, exceeded ε(t) or its torque limit), and the recovery of
    the runs that left a set. Failed points are counted apart, never as unsafe."""
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
        entry["recovery"] = _recovery(ok)
        table.append(entry)
    return table


def format_guarantee_table(table: list[dict], width: int = 100) -> str:
    """:func:`guarantee_table` as text: one line per run, one column per class, the classes
    paged into groups so that no line is wider than ``width``; then the recovery per run."""
    names = [name for name, _ in CLASSES]
    lines = ["every joint's hard sets (position, true velocity) kept, by class (Wilson 95 %);",
             "covered = starts inside the filter's viable set (a filtered run), within the "
             "declared uncertainty;",
             "broken = covered, yet left a hard set, was infeasible, exceeded ε(t) or its "
             "torque limit"]
    per_line = max(1, (width - 25) // 30)
    for group in (names[i:i + per_line] for i in range(0, len(names), per_line)):
        lines.append(f"{'run':<16}{'broken':>7}  " + "  ".join(f"{n:<28}" for n in group)
                     .rstrip())
        for e in table:
            cells = [f"{count:>4}: {100 * rate:5.1f} % [{100 * lo:5.1f},{100 * hi:6.1f}]"
                     if count else f"{0:>4}: -" for count, rate, lo, hi in (e[n] for n in group)]
            lines.append(f"{e['run']:<16}{e['broken']:>7}  "
                         + "  ".join(f"{c:<28}" for c in cells).rstrip())
    lines.append(f"runs that left a hard set (or started outside one), back inside every set "
                 f"within {RETURN_WITHIN:g} s (Wilson 95 %):")
    for e in table:
        rec = e.get("recovery")
        if not rec or not rec["left"]:
            lines.append(f"  {e['run']:<16}none left a hard set")
            continue
        lines.append(f"  {e['run']:<16}{rec['back_within_1s']}/{rec['left']}: "
                     f"{100 * rec['share']:5.1f} % [{100 * rec['low']:5.1f}, "
                     f"{100 * rec['high']:5.1f}]; the longest time to return "
                     f"{rec['longest_s']:.3f} s")
    return "\n".join(lines)


register_sweep_report("guarantee", guarantee_table, format_guarantee_table)
