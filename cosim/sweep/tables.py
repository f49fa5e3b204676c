"""A sweep's statistics: the share of points keeping each set, per run (and per value of a grid
key), with Wilson 95 % intervals, and their text; the reports evaluators register
(:func:`cosim.evaluate.reports.register_sweep_report`) beside them."""

from __future__ import annotations

import math

from ..evaluate.reports import wilson
from .checks import family_kept, table_checks
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
