"""How `cosim sweep` hands points to Dask: a few points a task (fewer tasks, less of Dask's
own cost per row), each worker run with glibc's memory defaults and no profiler, keys unique
to each call, and a task whose worker a plant killed run again point by point, so that only
the point that killed it is a failed row."""

from __future__ import annotations

import os
import sys

import dask
import pytest
from cli_helpers import PAPER

from cosim.sweep import (
    MAX_POINTS_PER_TASK,
    STEPS_PER_TASK,
    SweepSpec,
    cluster_client,
    execute,
    parse_grid,
    points,
    points_per_task,
)


def test_points_per_task_keeps_every_worker_busy_and_tasks_short():
    assert points_per_task(1, 2) == 1 and points_per_task(15, 1) == 1
    assert points_per_task(16, 1) == 2 and points_per_task(48, 2) == 3
    assert points_per_task(10**6, 64) == MAX_POINTS_PER_TASK
    for count, slots in [(24, 2), (300, 2), (1000, 8), (7, 3)]:
        per_task = points_per_task(count, slots)
        assert count // per_task >= min(count, 8 * slots)  # ≥ 8 tasks a worker
    # short points grouped, long ones (the Monte Carlo's: 3 runs of 20 s) one a task
    assert points_per_task(1000, 2, 5_000) == STEPS_PER_TASK // 5_000
    assert points_per_task(1000, 2, 3 * 20_000) == 1


def _environ() -> dict[str, str]:
    return {k: os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_", "OMP_NUM_THREADS")}


def _profiling() -> bool:
    import dask

    return dask.config.get("distributed.worker.profile.enabled")


def test_workers_run_with_glibc_memory_defaults_and_no_profiler_and_keys_differ():
    client, cluster = cluster_client(1, None)
    try:
        (environ,) = client.run(_environ).values()
        assert environ == {"MALLOC_TRIM_THRESHOLD_": None, "OMP_NUM_THREADS": "1"}
        assert list(client.run(_profiling).values()) == [False]
        spec = SweepSpec(PAPER, [parse_grid("runs.proposed.controller.kv=20,40")],
                         runs=["proposed"], base=["simulation.duration=0.05"])
        first, _ = execute(spec, points(spec), client)
        other = SweepSpec(PAPER, [parse_grid("runs.proposed.controller.kv=60,80")],
                          runs=["proposed"], base=["simulation.duration=0.05"])
        second, _ = execute(other, points(other), client)  # the same indices, not results
        assert [r["set:runs.proposed.controller.kv"] for r in first + second] == \
            [20, 40, 60, 80]
        assert first[0]["peak_torque.1"] != second[0]["peak_torque.1"]
    finally:
        client.close()
        cluster.close()


@pytest.fixture(scope="module")
def crashing_arm(tmp_path_factory) -> list[str]:
    """--set of the PythonFMU arm, whose crash_at kills its process (SIGSEGV)."""
    from test_plant_swapping import FOREIGN_ARM, build_pythonfmu

    fmu = build_pythonfmu(FOREIGN_ARM, tmp_path_factory.mktemp("fmu"))
    return [f'plant.fmu="{fmu}"', 'plant.variables.tau=["shoulder_torque", "elbow_torque"]',
            'plant.variables.q=["shoulder", "elbow"]',
            'plant.variables.qdot=["shoulder_rate", "elbow_rate"]', "simulation.duration=0.3"]


def test_a_task_whose_worker_died_is_run_again_point_by_point(crashing_arm):
    """Four points in one task; the second kills its worker (the PythonFMU arm's crash_at):
    the task's points are run again one at a time (none beside another on a worker that
    dies), and only that point's rows fail."""
    spec = SweepSpec(PAPER, [parse_grid("plant.parameters.crash_at=1e300,0.1,1e300,1e300")],
                     runs=["baseline"], base=crashing_arm)
    import distributed  # noqa: F401 (its defaults first: set() would drop them on exit)

    # a killed task is not tried on another worker first (each try kills one)
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        client, cluster = cluster_client(1, None)
    told = []
    try:
        rows, interrupted = execute(spec, points(spec), client, told.append, per_task=4)
    finally:
        client.close()
        cluster.close()
    assert not interrupted and [r["point"] for r in rows] == [0, 1, 2, 3]
    assert [r["status"] for r in rows] == ["ok", "failed", "ok", "ok"], rows
    assert rows[1]["run"] == "baseline" and rows[1]["error"], rows
    assert sum(told) == 4  # each point once, when its rows came (not the failed task)


@pytest.mark.parametrize("per_task", [1, 3])
def test_rows_do_not_depend_on_points_per_task(per_task):
    spec = SweepSpec(PAPER, [parse_grid("runs.proposed.controller.kv=20,30,40,50")],
                     runs=["proposed"], base=["simulation.duration=0.05"])
    client, cluster = cluster_client(1, None)
    try:
        rows, _ = execute(spec, points(spec), client, per_task=per_task)
    finally:
        client.close()
        cluster.close()
    timing = {"wall_time_s"}
    assert [{k: v for k, v in r.items() if k not in timing} for r in rows] == \
        [{k: v for k, v in r.items() if k not in timing} for r in _rows_one_by_one(spec)]


def _rows_one_by_one(spec: SweepSpec) -> list[dict]:
    from cosim.sweep import assignments, run_point

    return [row for index, point in enumerate(points(spec))
            for row in run_point(spec.pipeline, assignments(spec, point), spec.runs, index,
                                 point)]


def test_a_segfaulting_point_fails_alone_and_its_signal_is_named(crashing_arm):
    """One worker, a point a task (issue 33): the point whose plant segfaults is the only
    failed row, not the healthy point Dask held on the same worker, and its error names the
    signal."""
    import distributed  # noqa: F401 (its defaults first: set() would drop them on exit)

    spec = SweepSpec(PAPER, [parse_grid("plant.parameters.crash_at=1e300,0.1,1e300,1e300")],
                     runs=["baseline"], base=crashing_arm)
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        client, cluster = cluster_client(1, None)
    try:
        rows, _ = execute(spec, points(spec), client, per_task=1)
    finally:
        client.close()
        cluster.close()
    assert [r["status"] for r in rows] == ["ok", "failed", "ok", "ok"], [r["error"] for r in rows]
    assert rows[1]["error"].startswith(
        "the point's worker process killed by signal 11 (SIGSEGV) every time it ran the "
        "point, alone: a crash of the plant FMU or a block's native code (KilledWorker: ")


def test_the_traceback_dask_logs_for_a_cancel_before_its_call_began_is_dropped():
    """distributed.utils.sync's cancel() reads ``future`` before the call has made it when
    a SIGTERM lands at once (a loaded make test printed that NameError's traceback from
    tornado's log in the middle of a sweep's clean stop); the client's callers drop that
    record, and only it."""
    import logging

    from cosim.sweep.cluster import CancelledBeforeStart

    def record(error: BaseException) -> logging.LogRecord:
        try:
            raise error
        except BaseException:
            info = sys.exc_info()
        return logging.LogRecord("tornado.application", logging.ERROR, __file__, 1,
                                 "Exception in callback %r", ("cancel",), info)

    dask_bug = NameError("cannot access free variable 'future' where it is not associated "
                         "with a value in enclosing scope")
    keep = CancelledBeforeStart().filter
    assert keep(record(dask_bug)) is False
    assert keep(record(NameError("name 'x' is not defined"))) is True
    assert keep(record(RuntimeError("'future'"))) is True
    assert keep(logging.LogRecord("tornado.application", logging.ERROR, __file__, 1, "text",
                                  (), None)) is True
