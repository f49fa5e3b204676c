"""A sweep's files: results.parquet and results.csv (one row per point and run), sweep.json
(the spec, the resolved pipeline, the tables) and sweep_safety.png."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np

from ..evaluate.parts import declared_metric_units, metric_unit
from ..evaluate.reports import SWEEP_REPORTS
from ..outputs.export import named_with_unit
from .checks import margin
from .journal import CHUNK, Rows
from .resume import SPEC_FILE
from .spec import SweepSpec
from .tables import safety_by_value

if TYPE_CHECKING:
    from pathlib import Path

    import pyarrow as pa
    from matplotlib.axes import Axes

    from ..outputs.run_folder import RunFolder


def _listed(entry: dict) -> dict:
    """A table entry for JSON: its tuples (rate, low, high) as lists."""
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in entry.items()}


def write_results(folder: RunFolder, spec: SweepSpec, rows: Rows, table: list[dict],
                  interrupted: bool, start: dict, key_units: dict[str, str]) -> None:
    """results.parquet (a row group per chunk of rows, each column's unit in its metadata)
    and results.csv (each column's unit in its header: ``name (unit)``), one row per point
    and run; sweep.json (``start``: what the sweep is, as written when it began, now with
    the safety tables); and sweep_safety.png. ``key_units``: the varied keys' units."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    units = column_units(rows, key_units)
    arrow = with_units(rows.table, units)

    def parquet(tmp: Path) -> None:
        with pq.ParquetWriter(tmp, arrow.schema) as writer:
            writer.write_table(arrow, row_group_size=CHUNK)

    folder.write("results.parquet", parquet)
    headed = arrow.rename_columns([named_with_unit(n, units.get(n)) for n in arrow.column_names])
    folder.write("results.csv", lambda tmp: pacsv.write_csv(headed, tmp))
    document = {**start, "rows": len(rows), "interrupted": interrupted,
                "safety": [_listed(e) for e in table],
                **{key: [_listed(e) for e in report.table(rows)]
                   for key, report in SWEEP_REPORTS.items()},
                "safety_by_value": {key: [_listed(e) for e in entries]
                                    for key, entries in safety_by_value(rows, spec).items()}}
    write_spec(folder, document)
    if len(rows) and spec.keys:
        write_safety_plot(folder, spec, rows)


def write_spec(folder: RunFolder, document: dict) -> None:
    """sweep.json: ``document`` (what the sweep is; at the end, its tables too)."""
    from ..outputs.run_folder import jsonable

    text = json.dumps(jsonable(document), indent=2, default=str) + "\n"
    folder.write(SPEC_FILE, lambda tmp: tmp.write_text(text))


def column_units(rows: Rows, key_units: dict[str, str]) -> dict[str, str]:
    """Each column's unit where the rows, the evaluators or the pipeline say it: a varied
    key's (``set:KEY``) its meaning's; a check's worst value and bound, and a first exit's
    value and bound, in the unit their ``.unit`` column gives (a first exit's depends on
    the set left: where rows left sets of different units, the column says to read
    ``.unit``); a metric's its evaluator's (Part.metric_units); times (``*_s``) s."""
    units = {f"set:{key}": unit for key, unit in key_units.items()}
    metrics = declared_metric_units()
    for name in rows.names:
        if name.endswith(".unit"):
            stem = name.removesuffix(".unit")
            said = {u for u in rows.column(name) if u is not None}
            unit = said.pop() if len(said) == 1 else f"see {name}" if said else None
            for sibling in (f"{stem}.worst", f"{stem}.bound", f"{stem}.value"):
                if unit is not None and sibling in rows.names:
                    units[sibling] = unit
        elif name.endswith("_s"):
            units[name] = "s"
        elif (unit := metric_unit(metrics, name)) is not None and _numeric(rows.column(name)):
            units.setdefault(name, unit)
    return units


def _numeric(values) -> bool:
    """A column of numbers (not flags, not text): the ones a unit is said of."""
    value = next((v for v in values if v is not None), None)
    return isinstance(value, int | float | np.number) and not isinstance(value, bool | np.bool_)


def with_units(table: pa.Table, units: dict[str, str]) -> pa.Table:
    """``table`` with each column's unit (``units``, from :func:`column_units`) in its
    field's metadata (``unit``) and all of them in the schema's (``units``, JSON)."""
    import pyarrow as pa

    fields = [field.with_metadata({"unit": units[field.name]}) if field.name in units
              else field for field in table.schema]
    schema = pa.schema(fields, metadata={"units": json.dumps(units, ensure_ascii=False)})
    return table.cast(schema)


def write_safety_plot(folder: RunFolder, spec: SweepSpec, rows: list[dict]) -> None:
    """One row of panels per run (each with its own scale), one column per varied key: each
    point's worst check, every joint, relative to its bound (≤ 1: every set kept), and on
    the right axis the share of points keeping every set (as the run's verdict counts
    them), per value of a grid key or per bin of a sampled one (about 20 points a bin).
    Failed points are left out."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = list(dict.fromkeys(r["run"] for r in rows))
    keys = spec.keys
    fig, axes = plt.subplots(len(runs), len(keys), figsize=(5.5 * len(keys), 3.2 * len(runs)),
                             squeeze=False, constrained_layout=True)
    for panels, run in zip(axes, runs, strict=True):
        mine = [r for r in rows if r["run"] == run]
        ok = [r for r in mine if r["status"] == "ok"]
        for ax, key in zip(panels, keys, strict=True):
            _safety_panel(ax, key, ok, sampled=key not in {a.key for a in spec.grid})
            ax.set_title(f"{run}: {len(ok)} point(s) completed"
                         + (f", {len(mine) - len(ok)} failed (not drawn)"
                            if len(mine) > len(ok) else ""), fontsize=9)
    folder.write("sweep_safety.png", lambda tmp: fig.savefig(tmp, dpi=100, format="png"))
    plt.close(fig)


def _safety_panel(ax: Axes, key: str, ok: list[dict], sampled: bool) -> None:
    values = [r[f"set:{key}"] for r in ok]
    numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)
    if numeric:
        x = np.array(values, float)
    else:  # strings, booleans, lists: one position per distinct value, labelled
        labels = list(dict.fromkeys(str(v) for v in values))
        x = np.array([labels.index(str(v)) for v in values], float)
        ax.set_xticks(range(len(labels)), labels, rotation=20, fontsize=7)
    worst = np.array([margin(r) for r in ok])
    kept = np.array([bool(r.get("safe")) for r in ok])
    ax.scatter(x, worst, s=8, alpha=0.5, label="worst / bound (left)")
    ax.axhline(1.0, color="darkred", lw=0.8, ls="--")
    ax.set_xlabel(key)
    ax.set_ylabel("max over every joint's sets of\nworst / bound (≤ 1 safe)", fontsize=8)
    if not len(x):
        return
    centres, rates = kept_share(x, kept, binned=sampled and numeric)
    rate_ax = ax.twinx()
    rate_ax.plot(centres, rates, "o-" if numeric else "o", color="tab:green", ms=3, lw=1,
                 label="every set kept (right)")
    rate_ax.set_ylim(-5, 105)
    rate_ax.set_ylabel("points keeping every set (%)", fontsize=8, color="tab:green")
    handles = ax.get_legend_handles_labels()[0] + rate_ax.get_legend_handles_labels()[0]
    ax.legend(handles=handles, fontsize=7, loc="best")


def kept_share(x: np.ndarray, kept: np.ndarray, binned: bool
               ) -> tuple[list[float], list[float]]:
    """(positions, % kept): per distinct value of ``x``, or, ``binned``, per group of about
    20 consecutive points in x's order (at the group's mean x)."""
    if binned:
        groups = [g for g in np.array_split(np.argsort(x, kind="stable"),
                                            max(1, len(x) // 20)) if len(g)]
        return [float(x[g].mean()) for g in groups], [100 * float(kept[g].mean())
                                                      for g in groups]
    centres = sorted(set(x.tolist()))
    return centres, [100 * float(kept[x == c].mean()) for c in centres]
