"""The run folder's files: summary.json (every run's metrics and safety checks) and
trace_<run>.npz (every declared signal, SI units)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def jsonable(x):
    """``x`` with numpy scalars as Python numbers and non-finite floats as None (JSON null)."""
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [jsonable(v) for v in x]
    if isinstance(x, float) and not np.isfinite(x):
        return None
    if isinstance(x, np.floating | np.integer):
        return jsonable(x.item())
    return x


def write_summary(out: Path, pipeline, results: dict, plant_info: dict) -> None:
    """summary.json over the runs so far, written to a temporary file and renamed."""
    complete = all(r.complete for r in results.values()) and len(results) == len(pipeline.runs)
    summary = {
        "complete": complete,
        "pipeline": pipeline.model_dump(by_alias=True),
        "plant": {"path": plant_info["file"], "model_name": plant_info["model_name"],
                  "fmi_version": plant_info["fmi_version"],
                  "guid": plant_info["instantiation_token"],
                  "variables": plant_info["variables"],
                  "parameters": plant_info["parameters"]},
        "runs": {name: r.summary() for name, r in results.items()},
    }
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(jsonable(summary), indent=2) + "\n")
    tmp.replace(out / "summary.json")


def write_trace(out: Path, name: str, trace, evaluation=None) -> None:
    """trace_<name>.npz: the time column and every signal of the completed rows, and their
    evaluation: ``check_<name>`` (each safety check's value) and ``barrier_<name>`` (H1, H2,
    H and the condition Ḣ + αH)."""
    extra = {}
    if evaluation is not None:
        extra.update({f"check_{n}": c.value for n, c in evaluation.checks.items()})
        extra.update({f"barrier_{n}": v for n, v in evaluation.barriers.items()})
    np.savez_compressed(out / f"trace_{name}.npz", time=trace.time, **trace.arrays, **extra)
