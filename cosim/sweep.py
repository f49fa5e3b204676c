"""Sweeps and Monte Carlo: one pipeline over a grid of values and/or seeded random samples of
any key ``--set`` accepts, every point run on Dask, one row per (point, run).

    cosim sweep pipelines/paper_safety.toml --grid controller.kv=20,40 --runs proposed
    cosim sweep P --sample 'plant.parameters."m[2]"=uniform(2.3,3.3)' --samples 500 --seed 1

Points: the Cartesian product of the grids; with samples, each grid point with ``--samples``
random draws (``uniform(a,b)``, ``normal(m,s)``, ``integers(a,b)``, seeded). Every point is
validated before anything runs. Each Dask worker keeps one plant FMU per file and mapping,
extracted once and ``reset()`` between points, and its compiled kernels stay loaded; short
points go a few to a task (Dask's own cost is per task). A point that diverges or whose FMU
fails is a row marked failed with its message; the sweep goes on. Ctrl-C keeps every
finished row. SI units, radians.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import re
import sys
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .config import PipelineError, load_pipeline
from .progress import phase

# The paper's joint-1 sets: a run is "safe" when it keeps all of them.
SAFE_SET_CHECKS = ("position_joint1", "velocity_true_joint1", "error_joint1",
                   "error_rate_joint1")
# The physical (hard) sets of joint 1: what the robust filter guarantees.
HARD_JOINT1_CHECKS = ("position_joint1", "velocity_true_joint1")
DISTRIBUTIONS = {"uniform": 2, "normal": 2, "integers": 2}
_SAMPLE = re.compile(r"^\s*(\w+)\s*\(\s*([^,]+?)\s*,\s*([^,]+?)\s*\)\s*$")


class SweepError(ValueError):
    """A sweep that cannot run; the message names the option or point at fault."""


@dataclass
class Axis:
    key: str
    values: list  # grid values (TOML), or None for a sampled key
    distribution: tuple[str, float, float] | None = None


@dataclass
class SweepSpec:
    pipeline: str
    grid: list[Axis] = field(default_factory=list)
    samples: list[Axis] = field(default_factory=list)
    count: int = 0  # random draws per grid point
    seed: int = 0
    runs: list[str] | None = None
    base: list[str] = field(default_factory=list)  # --set applied to every point

    @property
    def keys(self) -> list[str]:
        return [a.key for a in self.grid + self.samples]


def parse_grid(item: str) -> Axis:
    """``KEY=V1,V2,...`` with TOML values (lists too: ``kv=[20,30],[25,25]``)."""
    key, sep, raw = item.partition("=")
    if not sep or not key.strip() or not raw.strip():
        raise SweepError(f"--grid {item!r}: expected KEY=V1,V2,..., e.g. controller.kv=20,40")
    try:
        values = tomllib.loads(f"values = [{raw}]")["values"]
    except tomllib.TOMLDecodeError:
        raise SweepError(f"--grid {item!r}: {raw!r} is not a comma-separated list of TOML "
                         'values (quote strings: observer.law="paper","error_driven")') from None
    if not values:
        raise SweepError(f"--grid {item!r}: no values")
    return Axis(key.strip(), values)


def parse_sample(item: str) -> Axis:
    """``KEY=uniform(a,b)``, ``normal(mean,std)`` or ``integers(low,high)`` (inclusive)."""
    key, sep, raw = item.partition("=")
    match = _SAMPLE.match(raw)
    if not sep or not key.strip() or not match or match[1] not in DISTRIBUTIONS:
        raise SweepError(f"--sample {item!r}: expected KEY=uniform(a,b), normal(mean,std) or "
                         "integers(low,high)")
    try:
        a, b = float(match[2]), float(match[3])
    except ValueError:
        raise SweepError(f"--sample {item!r}: {match[2]!r} and {match[3]!r} must be "
                         "numbers") from None
    if (match[1] == "normal" and b < 0) or (match[1] != "normal" and b < a):
        raise SweepError(f"--sample {item!r}: the second value must be "
                         + ("≥ 0" if match[1] == "normal" else "≥ the first"))
    return Axis(key.strip(), None, (match[1], a, b))


def _toml(value) -> str:
    """A value as TOML for --set (repr keeps every digit of a float)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return str(value)

MAX_WORKERS = 64  # and at most 4 per core: each worker is a process holding an FMU


def count_points(spec: SweepSpec) -> int:
    """How many points the spec makes, without making them."""
    total = math.prod(len(a.values) for a in spec.grid)
    return total * (spec.count if spec.samples else 1)


def check_spec(spec: SweepSpec, max_points: int, workers: int | None,
               scheduler: str | None = None) -> int:
    """Refuse what would be wrong or unbounded before any work: repeated or conflicting keys
    and runs, a negative seed, a worker count outside 1..cap, a scheduler that is not an
    address, too many points. Returns the number of points."""
    seen: dict[str, str] = {}
    for option, keys in (("--set", [a.split("=", 1)[0].strip() for a in spec.base]),
                         ("--grid", [a.key for a in spec.grid]),
                         ("--sample", [a.key for a in spec.samples])):
        for key in keys:
            if key in seen and not (option == "--set" and seen[key] == "--set"):
                raise SweepError(f"{option} {key}: the key is already given by {seen[key]}; "
                                 "give each swept key once (one --grid with every value, or "
                                 "one --sample)")
            seen.setdefault(key, option)
    if spec.runs and len(set(spec.runs)) != len(spec.runs):
        twice = sorted({r for r in spec.runs if spec.runs.count(r) > 1})
        raise SweepError(f"--runs: {', '.join(twice)} given more than once")
    if scheduler is not None and not _ADDRESS.match(scheduler):
        raise SweepError(f"--scheduler {scheduler!r}: not a scheduler address; expected "
                         "tcp://HOST:PORT (e.g. tcp://127.0.0.1:8786)")
    if spec.seed < 0:
        raise SweepError(f"--seed {spec.seed}: a seed is a non-negative integer")
    if workers is not None:
        import os

        cap = min(MAX_WORKERS, 4 * (os.cpu_count() or 1))
        if not 1 <= workers <= cap:
            raise SweepError(f"--workers {workers}: give 1 to {cap} local worker processes "
                             f"(this machine has {os.cpu_count()} cores)")
    total = count_points(spec)
    if total > max_points:
        raise SweepError(f"the sweep makes {total:,} points, more than --max-points "
                         f"{max_points:,}; narrow the grid or the samples, or raise "
                         "--max-points if it is meant to be that large")
    return total


def points(spec: SweepSpec) -> list[dict]:
    """Every point: {key: value}, grid first, in a fixed order (the seed fixes the draws)."""
    grid = list(itertools.product(*[a.values for a in spec.grid])) or [()]
    rng = np.random.default_rng(spec.seed)
    out = []
    for combination in grid:
        fixed = dict(zip((a.key for a in spec.grid), combination, strict=True))
        for _ in range(spec.count if spec.samples else 1):
            point = dict(fixed)
            for axis in spec.samples:
                kind, a, b = axis.distribution
                point[axis.key] = (float(rng.uniform(a, b)) if kind == "uniform"
                                   else float(rng.normal(a, b)) if kind == "normal"
                                   else int(rng.integers(int(a), int(b) + 1)))
            out.append(point)
    return out


def assignments(spec: SweepSpec, point: dict) -> list[str]:
    return [*spec.base, *(f"{key}={_toml(value)}" for key, value in point.items())]


def validate(spec: SweepSpec, all_points: list[dict]) -> None:
    """Every point loads (keys, types, ranges), the runs exist, and the first point
    assembles (plant FMU, wiring, sizes): :class:`SweepError` naming the point."""
    from .assemble import assemble

    def once(text: str) -> None:  # the first point's warnings, for the swept runs only
        if not spec.runs or any(f"run '{r}'" in text for r in spec.runs):
            print(f"cosim: warning: {text}", file=sys.stderr)

    for index, point in enumerate(all_points):
        try:
            pipeline = load_pipeline(spec.pipeline, assignments(spec, point),
                                     warn=once if index == 0 else None)
        except PipelineError as exc:
            raise SweepError(f"point {index} ({_label(point)}): {exc}") from None
        missing = [r for r in spec.runs or [] if r not in pipeline.runs]
        if missing:
            raise SweepError(f"--runs {' '.join(missing)}: not a run of {spec.pipeline} (its "
                             f"runs: {', '.join(pipeline.runs)})")
        if index == 0:
            try:
                assemble(_only(pipeline, spec.runs)).close()
            except PipelineError as exc:
                raise SweepError(f"point 0 ({_label(point)}): {exc}") from None


def _label(point: dict) -> str:
    return ", ".join(f"{k}={_toml(v)}" for k, v in point.items()) or "as is"


def _only(pipeline, runs: list[str] | None):
    if runs:
        pipeline.runs = {name: pipeline.runs[name] for name in runs}
    return pipeline


# Work on a worker ----------------------------------------------------------------------------

_PLANTS: dict[tuple[str, str], object] = {}  # per worker process: one open FMU per file+mapping


def _plant_for(pipeline):
    """This process's open plant for the pipeline's FMU and mapping (created once)."""
    from .assemble import open_plant, plant_path

    mapping = pipeline.plant.variables.model_dump()
    key = (str(plant_path(pipeline)), json.dumps(mapping, sort_keys=True))
    if key not in _PLANTS:
        _PLANTS[key] = open_plant(pipeline)
    return _PLANTS[key]


def run_point(pipeline_path: str, sets: list[str], runs: list[str] | None, index: int,
              point: dict) -> list[dict]:
    """One point, every run on its own (a diverging run does not stop the others): one row
    per run."""
    from .engine import Diverged
    from .runner import run

    rows = []
    pipeline = load_pipeline(pipeline_path, sets, warn=None)
    for name in runs or list(pipeline.runs):
        # The point's pipeline with this run alone: a shallow copy (a run reads its tables,
        # never writes them), not a second read and validation of the file per run.
        single = pipeline.model_copy(update={"runs": {name: pipeline.runs[name]}})
        row = {"point": index, **{f"set:{k}": _cell(v) for k, v in point.items()}, "run": name}
        try:
            result = run(single, None, progress=False, plant=_plant_for(single))[name]
            row.update(status="ok", error="", **result_columns(result))
        except (Diverged, PipelineError) as exc:
            row.update(status="failed", error=str(exc))
        rows.append(row)
    return rows


def _cell(value):
    return json.dumps(value) if isinstance(value, list) else value


def result_columns(result) -> dict:
    """A run's checks (worst, satisfied, time outside) and metrics, flat."""
    out = {}
    for check, entry in result.safety.items():
        out[f"{check}.bound"] = entry["bound"]
        out[f"{check}.worst"] = entry["worst"]
        out[f"{check}.satisfied"] = entry["satisfied"]
        out[f"{check}.time_outside_s"] = entry.get("time_outside_s")
    out["safe"] = all(result.safety[c]["satisfied"] for c in SAFE_SET_CHECKS
                      if c in result.safety)
    m = result.metrics
    for key in ("peak_torque", "rms_error", "torque_reversals_per_s"):
        for j, value in enumerate(m.get(key) or []):
            out[f"{key}.{j + 1}"] = value
    out["hard_joint1_kept"] = all(result.safety[c]["satisfied"] for c in HARD_JOINT1_CHECKS
                                  if c in result.safety)
    for key, value in (m.get("guarantee") or {}).items():
        if key == "outside":
            value = "; ".join(value)
        elif key == "first_exit":
            value = value["set"] if value else ""
        out[f"guarantee.{key}"] = value
    if "cbf_active" in result.trace:
        out["filter_active_fraction"] = float(np.mean(result.trace["cbf_active"] > 0))
    gain = m.get("feedback_gain") or {}
    out["feedback_gain.median"] = gain.get("median")
    out["barrier_condition.fraction_failing"] = (m.get("barrier_condition")
                                                 or {}).get("fraction_failing")
    out["simulated_time_s"] = m["simulated_time_s"]
    out["wall_time_s"] = m["wall_time_s"]
    return out


# Execution -------------------------------------------------------------------------------------

def run_points(pipeline_path: str, runs: list[str] | None,
               jobs: list[tuple[int, list[str], dict]]) -> list[dict]:
    """Several points (index, --set assignments, point), one after another in one task:
    their rows."""
    rows = []
    for index, sets, point in jobs:
        rows.extend(run_point(pipeline_path, sets, runs, index, point))
    return rows


# Points per Dask task. A task costs the scheduler and this process ~3.5 ms of CPU (and the
# worker ~1 ms) whatever it does: with one point a task, a sweep of 0.1 s points on two
# workers spent a twentieth of a core of two on Dask. Short points are therefore grouped, a
# few a task, while every worker still gets many tasks (the load stays balanced, the
# progress bar moves) and a task stays short (an interrupt drops the points of the tasks in
# progress: at most about STEPS_PER_TASK steps of work per worker). Long points (the
# Monte Carlo's 20 s runs) stay one a task.
MAX_POINTS_PER_TASK = 8
TASKS_PER_WORKER = 8
STEPS_PER_TASK = 20_000  # ~0.6 s of the paper's closed loop, with its evaluation


def points_per_task(points: int, slots: int, steps_per_point: int = 0) -> int:
    """How many of ``points`` to put in one task for ``slots`` workers, a point being
    ``steps_per_point`` steps of simulation (every run of it)."""
    by_steps = STEPS_PER_TASK // steps_per_point if steps_per_point > 0 else MAX_POINTS_PER_TASK
    return max(1, min(MAX_POINTS_PER_TASK, by_steps,
                      points // (TASKS_PER_WORKER * max(1, slots))))


def execute(spec: SweepSpec, all_points: list[dict], client,
            on_rows: Callable[[int], None] | None = None,
            per_task: int | None = None) -> tuple[list[dict], bool]:
    """Every point on the Dask ``client``, ``per_task`` points a task (default
    :func:`points_per_task` for the client's workers); returns (rows, interrupted).
    ``on_rows(points)`` is told of each task's points as they finish. Ctrl-C cancels what
    has not finished and keeps the rows of every finished task (the points of a task in
    progress are dropped with it). A task whose worker died (a plant that crashes its
    process) is run again point by point, so that only the point that killed it is a
    failed row, one per run."""
    import uuid

    from dask.distributed import as_completed

    pipeline = load_pipeline(spec.pipeline, spec.base, warn=None)
    runs = spec.runs or list(pipeline.runs)
    if per_task is None:
        slots = sum(client.nthreads().values()) or 1  # the tasks that run at once
        per_task = points_per_task(len(all_points), slots,
                                   pipeline.simulation.steps * len(runs))
    # Keys unique to this call: a scheduler still holding another sweep's (or an earlier
    # call's) "point 3" would hand back its result for this one.
    sweep_id = uuid.uuid4().hex[:12]

    def submit(indices: list[int]):
        jobs = [(i, assignments(spec, all_points[i]), all_points[i]) for i in indices]
        return client.submit(run_points, spec.pipeline, spec.runs, jobs, pure=False,
                             key=f"cosim-points-{sweep_id}-{indices[0]}-{len(indices)}")

    batches = [list(range(start, min(start + per_task, len(all_points))))
               for start in range(0, len(all_points), per_task)]
    futures = {submit(batch): batch for batch in batches}
    pending = as_completed(list(futures))
    # Points of a task whose worker died, run again one at a time: alone on a worker, the
    # point that kills it is the only one its death fails (Dask fails every task a dying
    # worker holds once it has died under them too often).
    again: list[int] = []
    alone: list = []  # the one such point's future in flight

    def next_alone() -> None:
        if again and not alone:
            index = again.pop(0)
            single = submit([index])
            futures[single] = [index]
            alone.append(single)
            pending.add(single)

    rows: list[dict] = []
    try:
        for future in pending:
            batch = futures[future]
            if future in alone:
                alone.remove(future)
            try:
                rows.extend(future.result())
            except Exception as exc:  # the worker itself failed
                if len(batch) > 1:  # which point killed it is unknown: each on its own
                    again.extend(batch)
                    next_alone()
                    continue
                index = batch[0]
                for run in runs:  # one failed row per run
                    rows.append({"point": index, **{f"set:{k}": _cell(v)
                                                    for k, v in all_points[index].items()},
                                 "run": run, "status": "failed",
                                 "error": f"{type(exc).__name__}: {exc}"})
            if on_rows is not None:
                on_rows(len(batch))
            next_alone()
    except KeyboardInterrupt:
        client.cancel(list(futures))
        return sorted(rows, key=_order), True
    return sorted(rows, key=_order), False


def _order(row: dict) -> tuple:
    return (row["point"], row["run"])


_ADDRESS = re.compile(r"^((tcp|tls|ws|wss)://)?[A-Za-z0-9_.\-\[\]:]+:\d{1,5}$")
CONNECT_TIMEOUT = 15.0  # s, the whole connection and handshake


def _connect(scheduler: str):
    """A client of the scheduler at ``scheduler``, or :class:`SweepError` within
    CONNECT_TIMEOUT: Client's own timeout covers the TCP connection, not the handshake, so a
    port that accepts and then says nothing (a web server) or something else (a banner, read
    as a message length of exabytes) would hang or exhaust memory. The attempt runs in a
    daemon thread that is abandoned if it does not finish."""
    import threading

    from dask.distributed import Client

    outcome: dict = {}

    def attempt() -> None:
        try:
            outcome["client"] = Client(scheduler, timeout=f"{CONNECT_TIMEOUT:g}s")
        except BaseException as exc:  # OSError, a garbled handshake, MemoryError
            outcome["error"] = exc

    thread = threading.Thread(target=attempt, daemon=True, name="cosim-connect")
    thread.start()
    thread.join(CONNECT_TIMEOUT + 5.0)
    if "client" in outcome:
        return outcome["client"]
    if "error" in outcome:
        exc = outcome["error"]
        detail = f"{type(exc).__name__}: {exc}"[:200]
        raise SweepError(f"--scheduler {scheduler}: no Dask scheduler answered there "
                         f"({detail})")
    raise SweepError(f"--scheduler {scheduler}: something answers there but not as a Dask "
                     f"scheduler (no handshake within {CONNECT_TIMEOUT + 5:g} s)")


def cluster_client(workers: int | None, scheduler: str | None):
    """A Dask client: on ``scheduler`` (an existing cluster), or a LocalCluster on
    127.0.0.1 with one single-threaded process per worker (FMUs are not thread-safe)."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        client = _connect(scheduler)
        try:
            client.wait_for_workers(1, timeout=60)
        except TimeoutError:
            client.close()
            raise SweepError(f"--scheduler {scheduler}: no worker joined within 60 s "
                             "(start one: dask worker ADDRESS --nthreads 1)") from None
        return client, None
    import logging

    import dask

    # Quiet workers: a cancelled point (Ctrl-C) is not a warning the user needs to read.
    with dask.config.set(WORKER_CONFIG):
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                               processes=True, host="127.0.0.1", dashboard_address=None,
                               silence_logs=logging.ERROR)
    return Client(cluster), cluster


# What a local worker runs with, against Dask's defaults, so that a point costs on a worker
# what it costs in-process (1.01 times it, against 1.18: the paper's proposed run, 5 s):
WORKER_CONFIG = {
    # Dask's nannies set MALLOC_TRIM_THRESHOLD_=65536 (to hand freed memory back to the OS
    # at once). That also turns off glibc's adaptive mmap threshold, so every trace and
    # evaluation array of every point is a fresh mmap, page-faulted in as it is written:
    # each point took 18 % longer. A worker holds a few traces at a time; glibc's defaults
    # reuse their memory.
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    # The statistical profiler samples every thread's stack every 10 ms, taking the GIL
    # from the point's own thread (2-3 % of a point); nobody reads it (no dashboard).
    "distributed.worker.profile.enabled": False,
}


# Summary -----------------------------------------------------------------------------------------

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
    """Per run: points, failed, and the rate at which every joint-1 set and each one is
    kept, with Wilson 95 % intervals (over the points that completed)."""
    table = []
    for run in dict.fromkeys(r["run"] for r in rows):
        mine = [r for r in rows if r["run"] == run]
        ok = [r for r in mine if r["status"] == "ok"]
        entry = {"run": run, "points": len(mine), "failed": len(mine) - len(ok)}
        for name, key in [("all sets", "safe"),
                          *[(c.removesuffix("_joint1"), f"{c}.satisfied")
                            for c in SAFE_SET_CHECKS]]:
            kept = sum(bool(r.get(key)) for r in ok)
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


# The classes of the robust-safety issue: which runs the filter's guarantee speaks for.
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
    guarantee speaks for): how many, the share keeping joint 1's hard sets (position, true
    velocity) with its Wilson 95 % interval, and the broken guarantees (left a hard set while
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
            kept = sum(bool(r.get("hard_joint1_kept")) for r in rows_in)
            low, high = wilson(kept, len(rows_in))
            entry[name] = (len(rows_in), kept / len(rows_in) if rows_in else math.nan, low,
                           high)
        table.append(entry)
    return table


def format_guarantee_table(table: list[dict]) -> str:
    names = [name for name, _ in CLASSES]
    lines = ["joint-1 hard sets (position, true velocity) kept, by class (Wilson 95 %); "
             "covered = starts inside, hard QP feasible throughout, within the declared "
             "uncertainty",
             f"{'run':<16}{'broken':>7}  " + "  ".join(f"{n:<25}" for n in names)]
    for e in table:
        cells = [f"{count:>4}: {100 * rate:5.1f} % [{100 * lo:5.1f},{100 * hi:6.1f}]"
                 if count else f"{0:>4}: -" for count, rate, lo, hi in (e[n] for n in names)]
        lines.append(f"{e['run']:<16}{e['broken']:>7}  " + "  ".join(f"{c:<25}" for c in cells))
    return "\n".join(lines)


def format_table(table: list[dict], key: str | None = None) -> str:
    """The safety-rate table; ``key``: a per-value table of that grid key (a first column
    holds the value)."""
    names = ["all sets", *[c.removesuffix("_joint1") for c in SAFE_SET_CHECKS]]
    title = "safety rate per run (joint-1 sets kept; Wilson 95 % interval)"
    width = max([len(key or ""), *(len(_toml(e["value"])) for e in table if "value" in e)])
    first = f"{key:<{width}}  " if key else ""
    lines = [f"{title[:-1]}; by {key})" if key else title,
             f"{first}{'run':<18}{'points':>7}{'failed':>7}  "
             + "  ".join(f"{n:<22}" for n in names)]
    for entry in table:
        cells = [f"{100 * r:5.1f} % [{100 * lo:5.1f}, {100 * hi:5.1f}]"
                 if not math.isnan(r) else "-" for r, lo, hi in (entry[n] for n in names)]
        value = f"{_toml(entry['value']):<{width}}  " if key else ""
        lines.append(f"{value}{entry['run']:<18}{entry['points']:>7}{entry['failed']:>7}  "
                     + "  ".join(f"{c:<22}" for c in cells))
    return "\n".join(lines)


def write_results(folder, spec: SweepSpec, rows: list[dict], table: list[dict],
                  interrupted: bool, total_points: int) -> None:
    """results.parquet and results.csv (one row per point and run), sweep.json (the spec,
    the resolved pipeline, the safety table), and sweep_safety.png."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    columns = list(dict.fromkeys(k for r in rows for k in r))
    arrow = pa.Table.from_pylist([{c: r.get(c) for c in columns} for r in rows])
    folder.write("results.parquet", lambda tmp: pq.write_table(arrow, tmp))
    folder.write("results.csv", lambda tmp: pacsv.write_csv(arrow, tmp))
    resolved = load_pipeline(spec.pipeline, spec.base, warn=None).model_dump(by_alias=True)
    document = {"pipeline_file": spec.pipeline, "base_sets": spec.base,
                "grid": {a.key: a.values for a in spec.grid},
                "samples": {a.key: list(a.distribution) for a in spec.samples},
                "samples_per_grid_point": spec.count, "seed": spec.seed, "runs": spec.runs,
                "points": total_points, "rows": len(rows), "interrupted": interrupted,
                "safety": [{k: (list(v) if isinstance(v, tuple) else v) for k, v in e.items()}
                           for e in table],
                "guarantee": [{k: (list(v) if isinstance(v, tuple) else v)
                               for k, v in e.items()} for e in guarantee_table(rows)],
                "safety_by_value": {key: [{k: (list(v) if isinstance(v, tuple) else v)
                                           for k, v in e.items()} for e in entries]
                                    for key, entries in safety_by_value(rows, spec).items()},
                "resolved_pipeline": resolved}
    from .outputs.run_folder import jsonable

    text = json.dumps(jsonable(document), indent=2, default=str) + "\n"
    folder.write("sweep.json", lambda tmp: tmp.write_text(text))
    if rows and spec.keys:
        write_safety_plot(folder, spec, rows)


def write_safety_plot(folder, spec: SweepSpec, rows: list[dict]) -> None:
    """One row of panels per run (each with its own scale), one column per varied key: each
    point's worst joint-1 check relative to its bound (≤ 1: every set kept), and on the
    right axis the share of points keeping every joint-1 set, per value of a grid key or
    per bin of a sampled one (about 20 points a bin). Failed points are left out."""
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


def _safety_panel(ax, key: str, ok: list[dict], sampled: bool) -> None:
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
    ax.set_ylabel("max over joint-1 sets of\nworst / bound (≤ 1 safe)", fontsize=8)
    if not len(x):
        return
    centres, rates = kept_share(x, kept, binned=sampled and numeric)
    rate_ax = ax.twinx()
    rate_ax.plot(centres, rates, "o-" if numeric else "o", color="tab:green", ms=3, lw=1,
                 label="every joint-1 set kept (right)")
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


def margin(row: dict) -> float:
    """A row's worst joint-1 check relative to its bound (≤ 1: every set kept)."""
    return max((row[f"{c}.worst"] / row[f"{c}.bound"] for c in SAFE_SET_CHECKS
                if row.get(f"{c}.worst") is not None), default=math.nan)


def record_points(spec: SweepSpec, rows: list[dict], which: list[str], out: Path,
                  progress: bool = False) -> list[str]:
    """Full run folders (recording, figures) of each run's best and/or worst point by
    :func:`margin`, re-run here: ``out/best_<run>_point<i>``, ``out/worst_<run>_point<i>``.
    A run with no completed row has nothing to record."""
    from .runner import run

    ok = [r for r in rows if r["status"] == "ok" and not math.isnan(margin(r))]
    written = []
    for kind in which:
        for name in dict.fromkeys(r["run"] for r in ok):
            mine = [r for r in ok if r["run"] == name]
            row = (min if kind == "best" else max)(mine, key=margin)
            point = {k.removeprefix("set:"): json.loads(v) if isinstance(v, str) and
                     v.startswith("[") else v for k, v in row.items() if k.startswith("set:")}
            folder = out / f"{kind}_{name}_point{row['point']}"
            pipeline = _only(load_pipeline(spec.pipeline, assignments(spec, point), warn=None),
                             [name])
            with phase(f"re-running {name}'s {kind} point ({row['point']}) with its "
                       "recording and figures", progress):
                run(pipeline, folder, progress=False, force=True)
            written.append(str(folder))
    return written


def _dry_run(spec: SweepSpec, all_points: list[dict], runs: list[str], out: Path,
             args) -> int:
    """What the sweep would do, every point checked (as before a real sweep), nothing run."""
    from .outputs.run_folder import would_refuse

    load = load_pipeline(spec.pipeline, spec.base, warn=None)
    steps = round(load.simulation.duration / load.simulation.step)
    where = args.scheduler or f"{args.workers or os.cpu_count() or 1} local Dask worker(s)"
    print(f"sweep of {spec.pipeline}: {len(all_points):,} point(s) × {len(runs)} run(s) "
          f"({', '.join(runs)}) = {len(all_points) * len(runs):,} row(s), "
          f"{load.simulation.duration:g} s simulated each ({steps:,} steps), on {where}")
    for axis in spec.grid:
        print(f"  grid   {axis.key} = {', '.join(json.dumps(v) for v in axis.values)}")
    for axis in spec.samples:
        name, *bounds = axis.distribution
        shown = ", ".join(str(int(b)) if float(b).is_integer() else f"{b:g}" for b in bounds)
        print(f"  sample {axis.key} = {name}({shown}), "
              f"{spec.count} draw(s) per grid point, seed {spec.seed}")
    for assignment in spec.base:
        print(f"  set    {assignment}")
    print(f"results -> {out} (results.parquet, results.csv, sweep.json, sweep_safety.png)"
          + (f"; then --record {args.record}" if args.record else ""))
    refusal = would_refuse(out, args.force)
    if refusal:
        raise SweepError(f"{refusal} (--dry-run: the sweep would be refused here)")
    print("every point checked against the pipeline's schema; nothing was run")
    return 0


def _on_sigterm(signum, frame) -> None:
    raise KeyboardInterrupt("terminated (SIGTERM)")


def main(args) -> int:
    """``cosim sweep`` (parsed arguments): returns the exit status. SIGTERM is handled like
    Ctrl-C in every phase: finished rows are written, the cluster ended, the lock released."""
    import signal

    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return _main(args)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _main(args) -> int:
    from tqdm import tqdm

    from .outputs.run_folder import RunFolder

    spec = SweepSpec(args.pipeline, [parse_grid(g) for g in args.grid],
                     [parse_sample(s) for s in args.sample], args.samples, args.seed,
                     args.runs or None, list(args.set))
    if spec.samples and spec.count < 1:
        raise SweepError("--sample needs --samples N (N ≥ 1 random draws)")
    if spec.count and not spec.samples:
        raise SweepError("--samples needs at least one --sample KEY=distribution(a,b)")
    record = [w.strip() for w in (args.record or "").split(",") if w.strip()]
    if set(record) - {"best", "worst"}:
        raise SweepError(f"--record {args.record!r}: expected best, worst or best,worst")
    check_spec(spec, args.max_points, args.workers, args.scheduler)
    out = Path(args.out)
    try:
        with phase("checking every point against the pipeline's schema", not args.quiet):
            all_points = points(spec)
            validate(spec, all_points)
    except KeyboardInterrupt as exc:
        raise SweepError(f"{str(exc) or 'interrupted (Ctrl-C)'} while checking the points; "
                         "nothing was run") from None
    runs = spec.runs or list(load_pipeline(spec.pipeline, spec.base, warn=None).runs)
    if args.dry_run:
        return _dry_run(spec, all_points, runs, out, args)
    folder = RunFolder.create(out, args.force)
    rows: list[dict] = []
    interrupted = False
    try:
        starting = (f"connecting to {args.scheduler}" if args.scheduler else
                    f"starting {args.workers or os.cpu_count() or 1} Dask worker process(es)")
        with phase(starting, not args.quiet):
            client, cluster = cluster_client(args.workers, args.scheduler)
        try:
            where = (args.scheduler
                     or f"a local cluster of {len(client.scheduler_info()['workers'])}")
            print(f"sweeping {len(all_points)} point(s) × {len(runs)} run(s) of "
                  f"{spec.pipeline} on {where} worker(s) -> {out}", file=sys.stderr)
            bar = tqdm(total=len(all_points), unit="point", file=sys.stderr,
                       disable=args.quiet or not sys.stderr.isatty())
            rows, interrupted = execute(spec, all_points, client, bar.update)
            bar.close()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    except KeyboardInterrupt:  # while the cluster started or closed: what finished is kept
        interrupted = True
    except BaseException as exc:  # the cluster could not start: say so in the folder too
        try:
            folder.write_summary({"complete": False, "kind": "sweep", "error": str(exc)},
                                 final=True)
        finally:
            folder.release()
        raise
    table = safety_table(rows)
    failed = sum(r["status"] != "ok" for r in rows)
    try:
        write_results(folder, spec, rows, table, interrupted, len(all_points))
        folder.write_summary({"complete": not interrupted, "kind": "sweep",
                              "status_detail": "interrupted" if interrupted else "finished",
                              "points": len(all_points), "runs": runs, "rows": len(rows),
                              "failed_rows": failed}, final=True)
    finally:
        folder.release()
    print(format_table(table))
    for key, entries in safety_by_value(rows, spec).items():
        print(format_table(entries, key))
    classes = guarantee_table(rows)
    if classes:
        print(format_guarantee_table(classes))
    print(f"{len(rows)} row(s) in {out / 'results.parquet'} and results.csv"
          + (f"; {failed} failed (see their error column)" if failed else ""))
    if interrupted:
        print(f"cosim: interrupted; the {len(rows)} finished row(s) are kept in {out}",
              file=sys.stderr)
        return 2
    if record:
        if not any(r["status"] == "ok" and not math.isnan(margin(r)) for r in rows):
            raise SweepError(f"--record {args.record}: no row completed, so there is no "
                             f"point to record; the {len(rows)} row(s) and their errors are "
                             f"in {out / 'results.csv'}")
        try:
            for path in record_points(spec, rows, record, out, not args.quiet):
                print(f"recorded: {path}")
        except KeyboardInterrupt as exc:
            raise SweepError(f"{str(exc) or 'interrupted (Ctrl-C)'} while recording; the sweep's "
                             f"results are complete in {out}") from None
    return 0
