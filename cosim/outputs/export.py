"""Take a run folder's traces elsewhere (`cosim export`): every signal of a run, with its unit
and meaning, as Parquet (field metadata), CSV (the unit in each header) or MATLAB's MAT.

The source is the run folder's ``trace_<run>.npz``, which carries its own units (the
``_units`` entry, written since traces became self-describing). A per-joint signal becomes
one column per joint (``q[1]``, ``q[2]``), an n×n one one per entry (``M[1,2]``), 1-based
like the FMU's variable names; the MAT file keeps the arrays' own shapes.
"""

from __future__ import annotations

import csv
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .folder_owner import ours_summary
from .formats import EXPORT_FORMATS
from .run_folder import UNITS_KEY

FORMATS = tuple(EXPORT_FORMATS)
SUFFIX = EXPORT_FORMATS


class ExportError(Exception):
    """A folder, run or target that cannot be exported: one line naming it."""


@dataclass(frozen=True)
class Column:
    name: str
    values: np.ndarray  # (rows,)
    unit: str
    description: str


def trace_runs(folder: Path) -> list[str]:
    """The runs of a run folder that have a trace file, in summary.json's order."""
    summary = ours_summary(folder) if folder.is_dir() else None
    if summary is None:
        raise ExportError(f"{folder}: not a cosim run folder (no summary.json of ours); give "
                          "the folder `cosim run --out` wrote")
    runs = [r for r in summary_runs(folder, summary) if (folder / f"trace_{r}.npz").is_file()]
    if not runs:
        raise ExportError(f"{folder}: holds no trace_<run>.npz (a sweep folder's rows are "
                          "already in results.parquet and results.csv)")
    return runs


def runs_without_trace(folder: Path) -> list[str]:
    """The runs summary.json names whose trace file is missing."""
    summary = ours_summary(folder) or {}
    return [r for r in summary_runs(folder, summary)
            if not (folder / f"trace_{r}.npz").is_file()]


def summary_runs(folder: Path, summary: dict) -> list[str]:
    """The runs a folder's summary.json names, each checked to be a run name: a summary
    edited to name '../x' must not make a trace read, or an export written, outside it."""
    from ..config.sections import check_name

    runs = list(summary.get("runs") or {})
    for run in runs:
        try:
            check_name(run, "run name")
        except ValueError as exc:
            raise ExportError(f"{folder}: its summary.json names the {exc}") from None
    return runs


def read_trace(folder: Path, run: str) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
    """A run's arrays and their units and meanings, ``{name: {"unit", "description"}}``."""
    path = folder / f"trace_{run}.npz"
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except Exception as exc:  # noqa: BLE001 (a damaged file: zip, header or data errors)
        raise ExportError(f"{path}: cannot be read, it is damaged ({type(exc).__name__}: "
                          f"{exc}); run the pipeline again to rewrite it") from None
    if UNITS_KEY not in arrays:
        raise ExportError(f"{path}: written by a cosim without units in its traces; run the "
                          "pipeline again to export it")
    units = json.loads(str(arrays.pop(UNITS_KEY)))
    return arrays, units


def columns(arrays: dict[str, np.ndarray], units: dict[str, dict]) -> list[Column]:
    """Every array as flat columns, ``time`` first."""
    out = []
    for name in ["time", *(k for k in arrays if k != "time")]:
        values, meaning = arrays[name], units.get(name, {"unit": "", "description": ""})
        flat = values.reshape(len(values), int(np.prod(values.shape[1:])))  # 0 rows too
        if values.ndim == 1:
            labels = [name]
        elif values.ndim == 2:
            labels = [f"{name}[{i + 1}]" for i in range(flat.shape[1])]
        else:
            n = values.shape[1]
            labels = [f"{name}[{i + 1},{j + 1}]" for i in range(n) for j in range(n)]
        out.extend(Column(label, flat[:, c], meaning["unit"], meaning["description"])
                   for c, label in enumerate(labels))
    return out


def _parquet(path: Path, cols: list[Column], about: dict[str, str]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    fields = [pa.field(c.name, pa.float64(), metadata={"unit": c.unit,
                                                      "description": c.description})
              for c in cols]
    schema = pa.schema(fields, metadata={f"cosim.{k}": v for k, v in about.items()})
    table = pa.Table.from_arrays([pa.array(c.values, pa.float64()) for c in cols],
                                 schema=schema)
    pq.write_table(table, path)


def named_with_unit(name: str, unit: str | None) -> str:
    """A CSV header: ``name (unit)``, or the name alone for a quantity without one."""
    return f"{name} ({unit})" if unit else name


def _csv(path: Path, cols: list[Column], about: dict[str, str]) -> None:
    data = np.column_stack([c.values for c in cols])
    with path.open("w", encoding="utf-8", newline="") as f:
        # csv quotes a header with a comma: "M[1,2] (kg·m²)"
        csv.writer(f).writerow(named_with_unit(c.name, c.unit) for c in cols)
        np.savetxt(f, data, delimiter=",", fmt="%.17g")  # 17 digits: floats round-trip


# MATLAB's names: a letter first, then letters, digits and '_', at most 63 characters.
MAT_NAME_LENGTH = 63


def mat_names(names: list[str]) -> dict[str, str]:
    """Each signal's name in the MAT file: itself when MATLAB accepts it, else made valid
    (other characters as '_', a leading 'x', cut to 63 characters with a short hash so
    that two long names stay apart). The file's ``names`` struct maps them back."""
    import hashlib
    import re

    out = {}
    for name in names:
        valid = re.sub(r"[^A-Za-z0-9_]", "_", name.encode("ascii", "replace").decode())
        if not valid[:1].isalpha():
            valid = f"x{valid}"
        if valid != name or len(valid) > MAT_NAME_LENGTH:
            digest = hashlib.sha1(name.encode()).hexdigest()[:8]
            valid = f"{valid[:MAT_NAME_LENGTH - 9]}_{digest}"
        out[name] = valid
    return out


def _mat(path: Path, arrays: dict[str, np.ndarray], units: dict[str, dict],
         about: dict[str, str]) -> None:
    from scipy.io import savemat

    reserved = {"units", "descriptions", "names", "cosim"}
    clash = reserved & set(arrays)
    if clash:
        raise ExportError(f"signal {sorted(clash)[0]!r} has a name the MAT file reserves")
    named = mat_names(list(arrays))
    content = {named[k]: v for k, v in arrays.items()}
    content["units"] = {named[k]: units.get(k, {}).get("unit", "") for k in arrays}
    content["descriptions"] = {named[k]: units.get(k, {}).get("description", "")
                               for k in arrays}
    content["names"] = {named[k]: k for k in arrays}
    content["cosim"] = about
    savemat(path, content, long_field_names=True, do_compression=True, oned_as="column")


def export(folder: str | Path, fmt: str = "parquet", runs: list[str] | None = None,
           out: str | Path | None = None, force: bool = False) -> list[Path]:
    """Write ``export_<run>.<ext>`` for each run (default: every run with a trace) into
    ``out`` (default: the run folder itself, where these files are cosim's own and are
    replaced). Elsewhere an existing file is refused unless ``force``. Returns the paths."""
    folder = Path(folder)
    if fmt not in FORMATS:
        raise ExportError(f"--format {fmt}: must be one of {', '.join(FORMATS)}")
    available = trace_runs(folder)
    missing = runs_without_trace(folder)
    if missing and not runs:
        raise ExportError(f"{folder}: run{'s' * (len(missing) > 1)} {', '.join(missing)} "
                          f"{'have' if len(missing) > 1 else 'has'} no trace file "
                          f"(trace_{missing[0]}.npz missing: the run was cut short before "
                          f"writing it, or it was deleted); nothing was exported: export the "
                          f"others with --run {' --run '.join(available)}")
    chosen = list(dict.fromkeys(runs or available))
    unknown = [r for r in chosen if r not in available]
    if unknown:
        raise ExportError(f"--run {unknown[0]}: {folder} has no trace of it; its runs are "
                          f"{', '.join(available)}")
    target = Path(out) if out is not None else folder
    if target.exists() and not target.is_dir():
        raise ExportError(f"--out {target}: is a file; give a folder")
    inside = target.resolve() == folder.resolve()
    paths = [target / f"export_{run}{SUFFIX[fmt]}" for run in chosen]
    if not inside and not force:
        taken = [p for p in paths if p.exists()]
        if taken:
            raise ExportError(f"{taken[0]}: already exists; pass --force to replace it")
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ExportError(f"--out {target}: cannot be made ({exc.strerror or exc})") from None
    summary = ours_summary(folder) or {}
    for run, path in zip(chosen, paths, strict=True):
        arrays, units = read_trace(folder, run)
        about = {"run": run, "source": str(folder.resolve() / f"trace_{run}.npz"),
                 "pipeline": str((summary.get("pipeline") or {}).get("name", "")),
                 "units": "SI, angles in radians"}
        tmp = None
        try:
            # a fresh temporary of our own (never one already there: a planted link would
            # be written through)
            handle, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp",
                                            dir=target)
            os.close(handle)
            tmp = Path(name)
            WRITERS[fmt](tmp, arrays, units, about)
            tmp.replace(path)
        except OSError as exc:
            if tmp is not None:
                tmp.unlink(missing_ok=True)
            raise ExportError(f"{path}: could not be written ({exc.strerror or exc}); "
                              "choose a writable folder with --out") from None
        except BaseException:
            if tmp is not None:
                tmp.unlink(missing_ok=True)
            raise
    return paths


# How each format is written: (file, arrays, units, what the file says of itself).
WRITERS = {"parquet": lambda path, arrays, units, about:
           _parquet(path, columns(arrays, units), about),
           "csv": lambda path, arrays, units, about: _csv(path, columns(arrays, units), about),
           "mat": _mat}
