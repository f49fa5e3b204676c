"""Running a sweep's points on Dask: the points grouped a few to a task, the rows gathered as
tasks finish, a dead worker's points run again alone (the cluster itself: :mod:`.cluster`)."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ..config import load_pipeline
from ..environment import seconds_from_environment
from .cluster import DEATHS, WORKER_CONFIG
from .spec import SweepError, SweepSpec, assignments
from .worker import WorkerMismatch, cosim_version, point_row, run_points

if TYPE_CHECKING:
    from dask.distributed import Client, Future, LocalCluster

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
# Tasks submitted ahead per worker slot: enough that a worker never waits for the next one
# (Dask sends a worker its next task while it runs one), few enough that a sweep of 10⁶
# points is not 10⁶ futures in this process and the scheduler.
TASKS_IN_FLIGHT = 4
# A local cluster's nanny restarts a worker its plant killed, but on a loaded machine it
# sometimes does not (seen with 4 CPU-bound processes on 2 cores: no worker, no error, in 3
# of 8 sweeps whose plant crashes every point), and nothing else brings one back. After
# REVIVE_AFTER s with no worker the sweep replaces the cluster's workers (a restart takes
# 3-5 s there); after STRANDED_AFTER s with none it ends (COSIM_SWEEP_STRANDED_S sets
# another wait). The scheduler is asked every WATCH_EVERY s.
STRANDED_VARIABLE, STRANDED_AFTER = "COSIM_SWEEP_STRANDED_S", 300.0
REVIVE_AFTER = 60.0
WATCH_EVERY = 2.0


def stranded_after() -> float:
    """How long a local cluster's sweep waits with no worker (COSIM_SWEEP_STRANDED_S, s);
    :class:`SweepError` for a value that is not a positive number."""
    try:
        return seconds_from_environment(STRANDED_VARIABLE, STRANDED_AFTER)
    except ValueError as exc:
        raise SweepError(str(exc)) from None


def points_per_task(points: int, slots: int, steps_per_point: int = 0) -> int:
    """How many of ``points`` to put in one task for ``slots`` workers, a point being
    ``steps_per_point`` steps of simulation (every run of it)."""
    by_steps = STEPS_PER_TASK // steps_per_point if steps_per_point > 0 else MAX_POINTS_PER_TASK
    return max(1, min(MAX_POINTS_PER_TASK, by_steps,
                      points // (TASKS_PER_WORKER * max(1, slots))))


def execute(spec: SweepSpec, all_points: list[dict], client: Client,
            on_rows: Callable[[int], None] | None = None,
            per_task: int | None = None, sink: Callable[[list[dict]], None] | None = None,
            indices: list[int] | None = None,
            stranded_after: float | None = None,
            revive_after: float = REVIVE_AFTER) -> tuple[list[dict], bool]:
    """The points ``indices`` (default every one) of ``all_points`` on the Dask ``client``,
    ``per_task`` points a task (default :func:`points_per_task` for the client's workers);
    returns (rows, interrupted). With ``sink``, each task's rows are handed to it as they
    come and not kept (the rows returned are none). ``on_rows(points)`` is told of each
    task's points as they finish. A bounded number of tasks is in flight at a time
    (:data:`TASKS_IN_FLIGHT` per worker), so neither this process nor the scheduler holds
    the whole sweep. Ctrl-C cancels what has not finished and keeps the rows of every
    finished task (the points of a task in progress are dropped with it). A task whose
    worker died (a plant that crashes its process) is run again point by point, and such a
    point again alone, so that only the point that kills its worker is a failed row, one per
    run. ``stranded_after`` (s; a local cluster's, whose workers nothing else will bring
    back): a sweep left with no worker for ``revive_after`` s has its cluster's workers
    replaced, and left with none that long ends with :class:`SweepError`, the rows of the
    finished tasks kept."""
    pipeline = load_pipeline(spec.pipeline, spec.base, warn=None)
    runs = spec.runs or list(pipeline.runs)
    todo = list(range(len(all_points))) if indices is None else list(indices)
    slots = sum(client.nthreads().values()) or 1  # the tasks that run at once
    if per_task is None:
        per_task = points_per_task(len(todo), slots, pipeline.simulation.steps * len(runs))
    tasks = _Tasks(spec, all_points, client, slots,
                   [todo[start:start + per_task] for start in range(0, len(todo), per_task)])
    tasks.top_up()
    rows: list[dict] = []
    stranded = _watch_for_no_worker(client, tasks.futures, stranded_after, revive_after)
    try:
        for future in tasks.pending:
            if stranded.is_set():  # its tasks cancelled, to end the wait here
                replaced = (f" nor new workers every {revive_after:g} s"
                            if revive_after < stranded_after else "")
                raise SweepError(
                    f"the local cluster has had no worker for {stranded_after:g} s (its "
                    f"worker processes ended, and neither their restarts{replaced} joined: a "
                    "crashing plant on a machine too loaded to start them); the rows of the "
                    "finished points are kept: go on with --resume")
            batch, was_alone = tasks.finished(future)
            try:
                made = future.result()
            except WorkerMismatch as exc:
                raise SweepError(str(exc)) from None
            except Exception as exc:  # the worker itself failed, or the scheduler is gone
                if client.status not in ("running", "connecting"):
                    raise SchedulerLost(f"{type(exc).__name__}: {exc}") from None
                if not was_alone:  # which point killed it is unknown: each on its own
                    tasks.again.extend(batch)
                    tasks.next_alone()
                    tasks.top_up()
                    continue
                made = [{**point_row(batch[0], all_points[batch[0]], run), "status": "failed",
                         "error": worker_death(exc)} for run in runs]  # one per run
            if sink is None:
                rows.extend(made)
            else:
                sink(made)
            if on_rows is not None:
                on_rows(len(batch))
            tasks.next_alone()
            tasks.top_up()
    except KeyboardInterrupt:
        client.cancel(list(tasks.futures))
        return sorted(rows, key=_order), True
    except SweepError:
        client.cancel(list(tasks.futures))
        raise
    finally:
        stranded.set()  # ends the watch
    return sorted(rows, key=_order), False


class _Tasks:
    """A sweep's tasks on the client: the batches of points still to submit, the futures in
    flight (a bounded number), and the points of a task whose worker died, run again one
    at a time."""

    def __init__(self, spec: SweepSpec, all_points: list[dict], client: Client, slots: int,
                 batches: list[list[int]]) -> None:
        import uuid

        from dask.distributed import as_completed

        self.spec, self.all_points, self.client = spec, all_points, client
        # Keys unique to this call: a scheduler still holding another sweep's (or an
        # earlier call's) "point 3" would hand back its result for this one.
        self.sweep_id = uuid.uuid4().hex[:12]
        # Workers need not run where this process does: the pipeline by its absolute path
        # (the same files on every machine: a shared folder).
        self.pipeline_path = str(Path(spec.pipeline).resolve())
        self.batches = iter(batches)
        self.futures: dict = {}  # future -> its points
        self.pending = as_completed()
        self.slots = slots
        self.threads = {"count": slots, "asked": time.monotonic()}
        # Points of a task whose worker died, run again one at a time: alone on a worker,
        # the point that kills it is the only one its death fails (Dask fails every task a
        # dying worker holds once it has died under them too often).
        self.again: list[int] = []
        self.alone: list = []  # the one such point's future in flight

    def submit(self, indices: list[int], again: bool = False) -> Future:
        jobs = [(i, assignments(self.spec, self.all_points[i]), self.all_points[i])
                for i in indices]
        # A point run again has a key of its own: the scheduler may still hold the failed
        # task, and a submit of its key would hand back that failure.
        key = f"cosim-points-{self.sweep_id}-{indices[0]}-{len(indices)}{'-again' * again}"
        future = self.client.submit(run_points, self.pipeline_path, self.spec.runs, jobs,
                                    cosim_version(), pure=False, key=key)
        self.futures[future] = indices
        self.pending.add(future)
        return future

    def top_up(self) -> None:
        """Tasks submitted up to TASKS_IN_FLIGHT per worker thread the scheduler has (asked
        every few seconds, not at every task: workers may join mid-sweep)."""
        if time.monotonic() - self.threads["asked"] > 2.0:
            info = self.client.scheduler_info(n_workers=0)
            self.threads.update(count=max(self.slots, info.get("total_threads", 0)),
                                asked=time.monotonic())
        while len(self.futures) < TASKS_IN_FLIGHT * max(1, self.threads["count"]):
            batch = next(self.batches, None)
            if batch is None:
                return
            self.submit(batch)

    def next_alone(self) -> None:
        """The next point to run again alone, if none is in flight."""
        if self.again and not self.alone:
            self.alone.append(self.submit([self.again.pop(0)], again=True))

    def finished(self, future: Future) -> tuple[list[int], bool]:
        """(a finished future's points, whether it was a point run again alone)."""
        batch = self.futures.pop(future)
        was_alone = future in self.alone
        if was_alone:
            self.alone.remove(future)
        return batch, was_alone


def _watch_for_no_worker(client: Client, futures: dict, after: float | None,
                         revive_after: float) -> threading.Event:
    """An event set (and every task in ``futures`` cancelled, which ends the wait for them)
    once the scheduler has had no worker for ``after`` s; never set by the watch when
    ``after`` is None. Every ``revive_after`` s of that wait the client's local cluster has
    its workers replaced. Set the event to end the watch."""
    event = threading.Event()
    if after is None:
        return event
    cluster = getattr(client, "cluster", None)
    size = len(cluster.worker_spec) if cluster is not None else 0

    def watch() -> None:
        empty_since = revived = None
        while not event.wait(WATCH_EVERY):
            try:
                workers = len(client.nthreads())
            except Exception:  # the scheduler gone: the loop says so
                return
            now = time.monotonic()
            if workers:
                empty_since = revived = None
                continue
            empty_since = empty_since or now
            if now - empty_since >= after:
                event.set()
                client.cancel(list(futures.copy()))
                return
            if size and now - (revived or empty_since) >= revive_after:
                revived = now
                _replace_workers(cluster, size)

    threading.Thread(target=watch, daemon=True, name="cosim-no-worker-watch").start()
    return event


def _replace_workers(cluster: LocalCluster, size: int) -> None:
    """``cluster``'s workers closed (their nannies too, whatever state they are stuck in)
    and ``size`` new ones started, with cosim's worker settings."""
    import dask

    # A nanny reads its settings (the pre-spawn environment) when it is made, in the
    # cluster's event loop: they stay set until the new workers have joined, or 60 s.
    with dask.config.set(WORKER_CONFIG):
        cluster.scale(0)
        cluster.scale(size)
        with contextlib.suppress(Exception):  # still none: the watch goes on waiting
            cluster.wait_for_workers(size, timeout=60)


class SchedulerLost(ConnectionError):
    """The client lost its scheduler mid-sweep (Dask gave up reconnecting)."""


def worker_death(exc: BaseException) -> str:
    """A failed row's error for a point whose task failed on its own: the signal that ended
    its worker process when this process saw it (a local cluster's nannies are here)."""
    text = f"{type(exc).__name__}: {exc}"
    if type(exc).__name__ != "KilledWorker":
        return text
    signal = DEATHS.last()
    why = f"killed by signal {signal}" if signal else "died (its log says why)"
    return (f"the point's worker process {why} every time it ran the point, alone: a crash "
            f"of the plant FMU or a block's native code ({text})")


def _order(row: dict) -> tuple:
    return (row["point"], row["run"])
