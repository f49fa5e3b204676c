"""What a Dask worker runs: a task's points one after another, each run of a point on its own,
one row per (point, run). A worker process keeps one open plant FMU per file and mapping.
Dask finds these functions on a worker by their module path (cosim.sweep.worker)."""

from __future__ import annotations

import json
import logging
import os
from typing import TYPE_CHECKING

from ..config import Pipeline, PipelineError, load_pipeline
from ..outputs.compare import TIMING
from .checks import check_columns, hard_sets_kept, row_is_safe

if TYPE_CHECKING:
    from ..runner import RunResult

_PLANTS: dict[str, object] = {}  # per worker process: one open plant per plant and mapping


def _plant_for(pipeline: Pipeline) -> object:
    """This process's open plant for the pipeline's plant (an FMU, a URDF's, a system) and
    mapping (created once; each point sets its parameters)."""
    from ..plant_source import open_plant

    key = json.dumps(pipeline.plant.model_dump(exclude={"parameters"}), sort_keys=True)
    if key not in _PLANTS:
        _PLANTS[key] = open_plant(pipeline)
    return _PLANTS[key]


def close_plants() -> None:
    """Close this process's open plants (a worker's are closed as it ends)."""
    while _PLANTS:
        _PLANTS.popitem()[1].close()


def point_row(index: int, point: dict, run: str) -> dict:
    """A row's first columns: the point's index, its values (``set:KEY``), the run."""
    return {"point": index, **{f"set:{k}": _cell(v) for k, v in point.items()}, "run": run}


def _cell(value: object) -> object:
    return json.dumps(value) if isinstance(value, list) else value


def run_point(pipeline_path: str, sets: list[str], runs: list[str] | None, index: int,
              point: dict) -> list[dict]:
    """One point, every run on its own (a diverging run does not stop the others): one row
    per run."""
    from ..engine import Diverged
    from ..runner import run

    rows = []
    pipeline = load_pipeline(pipeline_path, sets, warn=None)
    for name in runs or list(pipeline.runs):
        # The point's pipeline with this run alone: a shallow copy (a run reads its tables,
        # never writes them), not a second read and validation of the file per run.
        single = pipeline.model_copy(update={"runs": {name: pipeline.runs[name]}})
        row = point_row(index, point, name)
        try:
            result = run(single, None, progress=False, plant=_plant_for(single))[name]
            row.update(status="ok", error="", **result_columns(result))
        except (Diverged, PipelineError) as exc:
            row.update(status="failed", error=str(exc))
        rows.append(row)
    return rows


class WorkerMismatch(RuntimeError):
    """A worker that cannot run the client's sweep as the client would: another cosim (its
    rows would not be comparable) or without the pipeline's files."""


def cosim_version() -> str:
    import cosim

    return cosim.__version__


def run_points(pipeline_path: str, runs: list[str] | None,
               jobs: list[tuple[int, list[str], dict]], version: str | None = None
               ) -> list[dict]:
    """Several points (index, --set assignments, point), one after another in one task:
    their rows. ``version``: the client's cosim, which this worker's must be (a worker may
    join a cluster mid-sweep)."""
    import socket

    if version is not None and cosim_version() != version:
        raise WorkerMismatch(f"the Dask worker on {socket.gethostname()} (pid {os.getpid()}) "
                           f"runs cosim {cosim_version()}, this client cosim {version}: "
                           "install the same cosim on every worker (the same wheel, or a "
                           "shared path), or stop that worker")
    if not os.path.isfile(pipeline_path):
        raise WorkerMismatch(f"the Dask worker on {socket.gethostname()} (pid {os.getpid()}) "
                             f"cannot read the pipeline {pipeline_path}: every worker needs "
                             "the pipeline's files at the same path as this client (a shared "
                             "folder), or stop that worker")
    rows = []
    for index, sets, point in jobs:
        rows.extend(run_point(pipeline_path, sets, runs, index, point))
    return rows


def result_columns(result: RunResult) -> dict:
    """A run's checks (what each is, its bound, worst value, whether it held, time outside),
    whether it is safe and kept its hard sets, and every metric, flat (per joint
    ``name.j``)."""
    out = {}
    for check, entry in result.safety.items():
        out.update(check_columns(check, entry))
    out["safe"] = row_is_safe(result.safety)
    out["hard_sets_kept"] = hard_sets_kept(result.safety)
    # What measures the machine stays out of a row, but for the point's wall time.
    out.update(flat({key: value for key, value in result.metrics.items()
                     if key not in TIMING or key == "wall_time_s"}))
    return out


def flat(metrics: dict, prefix: str = "") -> dict:
    """The leaves of a metrics tree by dotted name: per-joint lists as ``name.j``, lists of
    text joined by "; ", an absent sub-tree (None) as one empty cell."""
    out: dict = {}
    for key, value in metrics.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flat(value, f"{name}."))
        elif isinstance(value, list) and all(isinstance(v, str) for v in value):
            out[name] = "; ".join(value)
        elif isinstance(value, list):
            out.update({f"{name}.{j + 1}": v for j, v in enumerate(value)})
        else:
            out[name] = value
    return out


class HeartbeatAtClose(logging.Filter):
    """Drops the traceback a local worker logs when its heartbeat meets the scheduler's comm
    already closed: Dask's own race as the cluster scales to 0 at its close (the scheduler
    removes the worker while a heartbeat is in flight). The sweep's rows are on disk and its
    one message is ours; the traceback landed after it on the user's stderr (seen once in a
    fresh-clone CI, distributed 2026.8.0). A scheduler lost mid-sweep is the client's to
    report (cosim.sweep.execution), not this log's."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(
            "Failed to communicate with scheduler during heartbeat")


def quiet_heartbeats() -> None:
    """:class:`HeartbeatAtClose` on this worker process's log (once)."""
    log = logging.getLogger("distributed.worker")
    if not any(isinstance(f, HeartbeatAtClose) for f in log.filters):
        log.addFilter(HeartbeatAtClose())
