"""A sweep's statistics: the share of points keeping each set, per run (and per value of a grid
key), with Wilson 95 % intervals, and their text; the reports evaluators register
(:func:`cosim.evaluate.reports.register_sweep_report`) beside them."""

from __future__ import annotations

import math

from ..evaluate.reports import wilson
from .checks import family_kept, margin, table_checks
from .spec import SweepSpec, toml_value


def safety_table(rows: list[dict]) -> list[dict]:
    """Per run: points, failed, and the rate at which every set is kept (as the run's
    verdict counts them) and each family (its every joint and norm), with Wilson 95 %
    intervals (over the points that completed)."""
    table = []
    for run in dict.fromkeys(r["run"] for r in rows):
        mine = [r for r in rows if r["run"] == run]
        ok = [r for r in mine if r["status"] == "ok"]
        entry = {"run": run, "points": len(mine), "failed": len(mine) - len(ok)}
        families = table_checks(ok or mine)
        columns = [("all sets", lambda r: bool(r.get("safe")), None),
                   *[(family, lambda r, checks=checks: family_kept(r, checks), checks)
                     for family, checks in families]]
        entry["worst"] = {}  # per column: the largest worst value / bound over the points
        for name, kept_in, checks in columns:
            kept = sum(kept_in(r) for r in ok)
            low, high = wilson(kept, len(ok))
            entry[name] = (kept / len(ok) if ok else math.nan, low, high)
            entry["worst"][name] = max((m for r in ok if not math.isnan(m := margin(r, checks))),
                                       default=math.nan)
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


def format_table(table: list[dict], key: str | None = None, width: int = 100) -> str:
    """The safety-rate table; ``key``: a per-value table of that grid key (a first column
    holds the value). Its columns are "all sets" and each family of checks, each cell the
    rate with its interval and the largest worst value / bound over the points (every joint
    and the norm; ≤ 1: kept), paged into groups so that no line is wider than ``width``."""
    names = ["all sets", *dict.fromkeys(n for e in table for n in e
                                         if isinstance(e[n], tuple) and n != "all sets")]
    title = "safety rate per run (every joint's sets kept; Wilson 95 % interval)"
    legend = "w: the largest worst value / bound over the completed points (≤ 1: kept)"
    value_width = max([len(key or ""), *(len(toml_value(e["value"])) for e in table
                                         if "value" in e)])
    first = f"{key:<{value_width}}  " if key else ""
    lead = len(first) + 32
    cell = 32
    per_line = max(1, (width - lead) // (cell + 2))
    lines = [f"{title[:-1]}; by {key})" if key else title, legend]
    for group in (names[i:i + per_line] for i in range(0, len(names), per_line)):
        lines.append(f"{first}{'run':<18}{'points':>7}{'failed':>7}  "
                     + "  ".join(f"{n:<{cell}}" for n in group).rstrip())
        for entry in table:
            cells = [_cell(entry, n) for n in group]
            value = f"{toml_value(entry['value']):<{value_width}}  " if key else ""
            lines.append(f"{value}{entry['run']:<18}{entry['points']:>7}{entry['failed']:>7}  "
                         + "  ".join(f"{c:<{cell}}" for c in cells).rstrip())
    return "\n".join(lines)


def _cell(entry: dict, name: str) -> str:
    """A rate, its interval and the worst over the points: "97.5 % [ 93.2,  99.1] w 0.93"."""
    rate, low, high = entry.get(name, (math.nan,) * 3)
    if name not in entry or math.isnan(rate):
        return "-"
    worst = entry.get("worst", {}).get(name, math.nan)
    shown = f" w {worst:.3f}" if not math.isnan(worst) else ""
    return f"{100 * rate:5.1f} % [{100 * low:5.1f}, {100 * high:5.1f}]{shown}"
