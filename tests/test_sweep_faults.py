"""`cosim sweep` under faults, as a hostile user would try it, and at scale: rows on disk as they
finish, a client killed with SIGKILL and resumed (every point once, none re-run), a resume of
another sweep refused by name, a worker killed mid-point and one joining mid-sweep against
separately started `dask scheduler` / `dask worker` processes, a worker of another cosim version
refused, bad --sample bounds, a sweep stopped before its first row, Dask's scratch space and
port warning, --record's values and a failing re-run, a plugin's sys.exit(0), units in
results.parquet, and benchmarks/monte_carlo.py's command runnable by a shell. (A segfaulting
point failing alone, its signal named, is in tests/test_sweep_tasks.py, beside the crashing FMU
it builds.)"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from cli_helpers import PAPER, assert_message, cosim_cli, dask_environment, error_line

ROOT = Path(__file__).resolve().parent.parent
DASK = str(Path(sys.executable).parent / "dask")
GRID = "runs.proposed.controller.kv=" + ",".join(str(20 + i) for i in range(24))
SMALL = ["--runs", "proposed", "--set", "simulation.duration=1"]


def cosim_here(capsys, *args: str) -> subprocess.CompletedProcess:
    """The cosim command run in this process (no interpreter to start): its exit status and
    output, as :func:`cosim_cli` gives them."""
    from cosim.cli import main

    capsys.readouterr()
    status = main(list(args))
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(["cosim", *args], status, out, err)


def journal(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "rows.jsonl").read_text().splitlines()]


def wait_for(ready, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not ready():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def journal_rows(out: Path) -> int:
    try:
        return (out / "rows.jsonl").read_text().count("\n")
    except FileNotFoundError:
        return 0


def start_sweep(out: Path, *args: str) -> subprocess.Popen:
    """The sweep in a process group of its own; its temporary files (a killed client cannot
    remove its cluster's scratch space) beside ``out``."""
    return subprocess.Popen([sys.executable, "-m", "cosim.cli", "sweep", PAPER, "--grid", GRID,
                             *SMALL, "--quiet", "--out", str(out), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,
                            env={**os.environ, "TMPDIR": str(out.parent)})


# -- streaming, SIGKILL, resume ------------------------------------------------------------

@pytest.fixture(scope="module")
def killed_and_resumed(tmp_path_factory):
    """A 24-point sweep on one local worker, the client and its cluster killed with SIGKILL
    once some rows are on disk, then resumed: (folder, rows before the kill, the resume)."""
    out = tmp_path_factory.mktemp("sweep") / "killed"
    child = start_sweep(out, "--workers", "1")
    try:
        wait_for(lambda: journal_rows(out) >= 3, 120)
        os.killpg(child.pid, signal.SIGKILL)  # the client and the workers it started
    finally:
        child.kill()
        child.communicate()
    before = journal(out)
    resumed = cosim_cli("sweep", PAPER, "--grid", GRID, *SMALL, "--quiet", "--workers", "1",
                        "--resume", str(out))
    return out, before, resumed


def test_rows_are_on_disk_as_points_finish_and_a_killed_sweep_resumes_each_point_once(
        killed_and_resumed):
    out, before, resumed = killed_and_resumed
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert 3 <= len(before) < 24  # rows written before the end, not all of them
    assert f"resuming {out}: {len(before)} of 24 point(s) already there; running the other " \
        f"{24 - len(before)}" in resumed.stderr
    after = journal(out)
    assert sorted(r["point"] for r in after) == list(range(24))  # each point exactly once
    assert after[:len(before)] == before  # the finished ones kept, not re-run
    rows = pq.read_table(out / "results.parquet").to_pylist()
    assert [r["point"] for r in rows] == list(range(24))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "complete" and summary["rows"] == 24


def test_a_resumed_sweep_has_the_rows_of_one_run_through_bit_for_bit(killed_and_resumed):
    from cosim.sweep import SweepSpec, assignments, parse_grid, points, run_point
    from cosim.sweep.worker import close_plants

    out = killed_and_resumed[0]
    spec = SweepSpec(PAPER, [parse_grid(GRID)], runs=["proposed"],
                     base=["simulation.duration=1"])
    rows = pq.read_table(out / "results.parquet").to_pylist()
    try:
        for index in (0, 11, 23):  # in-process, as one uninterrupted sweep computes them
            point = points(spec)[index]
            (expected,) = run_point(PAPER, assignments(spec, point), ["proposed"], index, point)
            got = {k: v for k, v in rows[index].items() if k in expected and k != "wall_time_s"}
            assert got == {k: v for k, v in expected.items() if k != "wall_time_s"}
    finally:
        close_plants()  # the plant run_point keeps open, as a worker does


def test_resuming_another_sweep_is_refused_naming_what_differs(killed_and_resumed):
    out = killed_and_resumed[0]
    before = (out / "rows.jsonl").read_bytes()
    done = cosim_cli("sweep", PAPER, "--grid", GRID, *SMALL, "--set", "controller.delta=5",
                     "--seed", "4", "--resume", str(out))
    assert_message(error_line(done), (
        f"--resume {out}: not the same sweep as the one started there; it differs in --set "
        '(["simulation.duration=1"] → ["simulation.duration=1", "controller.delta=5"]), '
        f"--seed (0 → 4), the pipeline {PAPER} (controller.delta: 1.0 → 5.0; "
        "runs.baseline.controller.delta: 1.0 → 5.0). Resume "
        "with the same command and files, or start a new sweep in another --out"))
    assert (out / "rows.jsonl").read_bytes() == before


def test_results_parquet_says_each_columns_unit(killed_and_resumed):
    schema = pq.read_schema(killed_and_resumed[0] / "results.parquet")
    units = json.loads(schema.metadata[b"units"])
    assert units["position_joint1.worst"] == units["position_joint1.bound"] == "rad"
    assert units["velocity_true_joint1.worst"] == "rad/s"
    assert units["wall_time_s"] == "s"
    assert schema.field("position_joint1.worst").metadata == {b"unit": b"rad"}
    # every metric's, as its evaluator declares it (a flag or a text has none)
    assert units["rms_error.2"] == "rad" and units["peak_torque.1"] == "N·m"
    assert units["theorem1.R"] == "rad/s" and units["feedback_gain.median"] == "N·m·s/rad"
    assert "guarantee.covered" not in units and "hard_sets_kept" not in units
    # the varied key's, as its meaning in the pipeline's schema names it
    assert units["set:runs.proposed.controller.kv"] == "N·m·s/rad"
    # results.csv: the same columns, each header with its unit
    with (killed_and_resumed[0] / "results.csv").open(encoding="utf-8") as f:
        header = next(csv.reader(f))
    assert header == [f"{name} ({units[name]})" if name in units else name
                      for name in schema.names]
    assert {"set:runs.proposed.controller.kv (N·m·s/rad)", "peak_torque.1 (N·m)", "point",
            "run"} <= set(header)


def test_a_first_exits_value_is_in_the_unit_of_the_set_it_left():
    """A first exit's value and bound are in the unit of the set left (its ``.unit``
    column): one unit where every row left sets of that unit, else a pointer to the column;
    a run's summary takes it from the run (its evaluator cannot declare it)."""
    import pyarrow as pa

    from cosim.evaluate.parts import units_said
    from cosim.sweep.files import column_units
    from cosim.sweep.journal import Rows

    def table(units: list[str | None]) -> Rows:
        exits = [None if u is None else 3.5 for u in units]
        return Rows(pa.table({"guarantee.first_exit.t": exits,
                              "guarantee.first_exit.value": exits,
                              "guarantee.first_exit.bound": exits,
                              "guarantee.first_exit.unit": units}))

    same = column_units(table(["rad/s", None, "rad/s"]), {})
    assert same["guarantee.first_exit.value"] == same["guarantee.first_exit.bound"] == "rad/s"
    assert same["guarantee.first_exit.t"] == "s"
    mixed = column_units(table(["rad", "rad/s"]), {})
    assert mixed["guarantee.first_exit.value"] == "see guarantee.first_exit.unit"
    assert "guarantee.first_exit.value" not in column_units(table([None, None]), {})
    metrics = {"guarantee": {"filtered": True, "first_exit": {
        "set": "position_joint2", "t": 0.25, "value": 1.3, "bound": 1.2, "unit": "rad"}}}
    assert units_said(metrics, {"guarantee.first_exit.t": "s"}) == {
        "guarantee.first_exit.value": "rad", "guarantee.first_exit.bound": "rad"}


# -- separately started scheduler and workers ------------------------------------------

def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def dask_scratch(tmp_path_factory) -> Path:
    """The scratch folder of the scheduler and workers this module starts."""
    return tmp_path_factory.mktemp("dask")


@pytest.fixture(scope="module")
def scheduler(dask_scratch):
    port = _free_port()
    process = subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                "--no-dashboard"], stderr=subprocess.DEVNULL,
                               env=dask_environment(dask_scratch))
    yield f"tcp://127.0.0.1:{port}"
    process.terminate()
    process.wait(timeout=30)


def dask_worker(address: str, scratch: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen([DASK, "worker", address, "--nthreads", "1", "--host", "127.0.0.1",
                             "--no-dashboard", *args], stderr=subprocess.DEVNULL,
                            cwd=tempfile.gettempdir(), env=dask_environment(scratch))


def end(*processes: subprocess.Popen) -> None:
    for process in processes:
        process.terminate()
    for process in processes:
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def test_a_worker_killed_mid_point_and_one_joining_mid_sweep_lose_and_repeat_nothing(
        scheduler, dask_scratch, tmp_path):
    first = dask_worker(scheduler, dask_scratch, "--no-nanny")
    later = None
    out = tmp_path / "external"
    child = start_sweep(out, "--scheduler", scheduler)
    try:
        wait_for(lambda: journal_rows(out) >= 2, 120)
        later = dask_worker(scheduler, dask_scratch)  # joins mid-sweep
        wait_for(lambda: journal_rows(out) >= 6, 120)
        first.send_signal(signal.SIGKILL)  # mid-point: its points run again on the other
        _, err = child.communicate(timeout=300)
    finally:
        end(*[p for p in (child, first, later) if p is not None])
    assert child.returncode == 0, err[-3000:]
    rows = journal(out)
    assert sorted(r["point"] for r in rows) == list(range(24))  # none lost, none twice
    assert all(r["status"] == "ok" for r in rows), [r["error"] for r in rows]


def test_a_worker_of_another_cosim_version_is_refused_naming_both(scheduler, dask_scratch,
                                                                  tmp_path):
    preload = tmp_path / "other_version.py"
    preload.write_text("import cosim\ncosim.__version__ = '0.0.9'\n")
    worker = dask_worker(scheduler, dask_scratch, "--preload", str(preload))
    try:
        done = cosim_cli("sweep", PAPER, "--grid", "controller.kv=20,30", *SMALL,
                         "--scheduler", scheduler, "--out", str(tmp_path / "out"))
    finally:
        end(worker)
    assert_message(error_line(done), re.compile(
        rf"--scheduler {scheduler}: the worker tcp://127\.0\.0\.1:\d+ runs cosim 0\.0\.9, this "
        r"client cosim 0\.1\.0: install the same cosim on every worker \(the same wheel, or a "
        r"shared path\), or stop that worker"))


# -- a hostile user's sweeps ----------------------------------------------------------------

@pytest.mark.parametrize(("sample", "why"), [
    ("uniform(nan,nan)", "'nan' and 'nan' must be finite numbers"),
    ("integers(0,inf)", "'0' and 'inf' must be finite numbers"),
    ("uniform(1,inf)", "'1' and 'inf' must be finite numbers"),
    ("integers(1.5,1.7)", "integers(low,high) draws whole numbers from low to high "
     "inclusive; give whole-number bounds (got 1.5 and 1.7)")])
def test_sample_bounds_that_cannot_be_drawn_are_refused(sample, why, tmp_path, capsys):
    done = cosim_here(capsys, "sweep", PAPER, "--sample", f"controller.kv={sample}",
                      "--samples", "2", "--out", str(tmp_path / "out"))
    assert_message(error_line(done), f"--sample 'controller.kv={sample}': {why}")
    assert not (tmp_path / "out").exists()


def test_a_sweep_stopped_before_its_first_row_says_so_and_writes_no_empty_results(tmp_path):
    out = tmp_path / "early"
    child = subprocess.Popen([sys.executable, "-m", "cosim.cli", "sweep", PAPER, "--grid",
                              "controller.kv=20,30", "--runs", "proposed", "--workers", "1",
                              "--set", "simulation.duration=100", "--out", str(out)],
                             stderr=subprocess.PIPE, text=True)
    try:
        # stopped once the sweep is under way: 100 s points take seconds, none finished
        while not child.stderr.readline().startswith("sweeping"):
            pass
        child.send_signal(signal.SIGTERM)
        _, err = child.communicate(timeout=120)
    finally:
        child.kill()
        child.wait()
    assert child.returncode == 2, err[-2000:]
    assert "Traceback" not in err and "could not be written" not in err
    assert err.strip().splitlines()[-1] == (
        "cosim: interrupted before any point finished; no results were written (resume: the "
        f"same command with --resume {out})")
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["status"], summary["status_detail"], summary["rows"]) == (
        "incomplete", "interrupted before any point finished", 0)
    assert not (out / "results.csv").exists() and not (out / "results.parquet").exists()


def test_a_sweep_leaves_no_scratch_space_and_prints_no_port_warning(tmp_path):
    """Nothing left in the temporary folder (Dask's scratch space), nothing said of the port
    8787 taken (the scheduler's HTTP server's default, held by another cluster)."""
    import socket

    scratch = tmp_path / "tmp"
    scratch.mkdir()
    with socket.socket() as taken:
        with contextlib.suppress(OSError):  # else another cluster holds it: the same case
            taken.bind(("127.0.0.1", 8787))
        done = subprocess.run([sys.executable, "-m", "cosim.cli", "sweep", PAPER, "--grid",
                               "controller.kv=5,60", *SMALL, "--workers", "1", "--out",
                               str(tmp_path / "out")], capture_output=True, text=True,
                              env={**os.environ, "TMPDIR": str(scratch)}, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Port" not in done.stderr and "Warning" not in done.stderr, done.stderr
    assert list(scratch.iterdir()) == []


def test_a_local_sweep_left_with_no_worker_ends_with_one_message(tmp_path):
    """A local cluster whose last worker is gone for good (on a loaded machine a nanny can
    fail to restart a worker a crashing plant killed, and nothing else restarts it): the
    sweep ends after ``stranded_after`` s with one message naming --resume; it waited
    forever. A real Dask cluster, its worker closed mid-sweep."""
    import threading

    import dask
    from dask.distributed import Client, LocalCluster

    from cosim.sweep.execution import execute
    from cosim.sweep.spec import SweepError, SweepSpec

    spec = SweepSpec(PAPER, runs=["baseline"], base=["simulation.duration=200"])
    # its scratch space (the scheduler's too) in tmp_path, not left in the temporary folder
    with dask.config.set({"temporary-directory": str(tmp_path)}), \
            LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                         dashboard_address=None, local_directory=tmp_path) as cluster, \
            Client(cluster) as client:
        threading.Timer(2.0, lambda: cluster.scale(0)).start()
        began = time.monotonic()
        with pytest.raises(SweepError) as info:
            execute(spec, [{"sensor.seed": 1}, {"sensor.seed": 2}], client, per_task=1,
                    stranded_after=2.0)
    assert re.fullmatch(r"the local cluster has had no worker for 2 s \(.*\); the rows of the "
                        r"finished points are kept: go on with --resume", str(info.value))
    assert time.monotonic() - began < 60


def test_a_local_sweep_left_with_no_worker_starts_new_ones_and_finishes(tmp_path):
    """A local cluster whose worker is gone and not restarted (a nanny on a loaded machine
    sometimes does not restart a worker its plant killed: 1 sweep in 3 with 4 CPU hogs):
    after ``revive_after`` s with none the sweep starts new workers and finishes, each
    point once. A real Dask cluster, its worker closed mid-sweep."""
    import threading

    import dask
    from dask.distributed import Client, LocalCluster

    from cosim.sweep.execution import execute
    from cosim.sweep.spec import SweepSpec

    spec = SweepSpec(PAPER, runs=["baseline"], base=["simulation.duration=0.2"])
    points = [{"sensor.seed": seed} for seed in range(6)]
    # its scratch space (the scheduler's too) in tmp_path, not left in the temporary folder
    with dask.config.set({"temporary-directory": str(tmp_path)}), \
            LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                         dashboard_address=None, local_directory=tmp_path) as cluster, \
            Client(cluster) as client:
        client.wait_for_workers(1, timeout=120)
        first = set(client.run(os.getpid).values())
        # early: with warm kernel caches the six points take well under 1 s
        threading.Timer(0.2, lambda: cluster.scale(0)).start()
        rows, interrupted = execute(spec, points, client, per_task=1, stranded_after=240.0,
                                    revive_after=4.0)
        now = set(client.run(os.getpid).values())
        assert len(now) == 1 and now.isdisjoint(first)  # a new worker, not the first back
    assert not interrupted
    assert [(r["point"], r["status"]) for r in rows] == [(i, "ok") for i in range(6)]


def test_a_bad_stranded_wait_is_one_message_before_anything_is_made(tmp_path):
    out = tmp_path / "sweep"
    result = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "sweep", PAPER, "--grid", "sensor.seed=1,2",
         "--out", str(out)], capture_output=True, text=True, timeout=120,
        env={**os.environ, "COSIM_SWEEP_STRANDED_S": "abc"})
    assert result.returncode == 2
    assert_message(error_line(result), "COSIM_SWEEP_STRANDED_S='abc': expected a number of "
                   "seconds > 0 (default 300); nothing was run")
    assert not out.exists()


def test_a_missing_pipeline_file_is_the_sweeps_fault_not_a_points(tmp_path):
    """A sweep of a pipeline file that is not there: one message naming the file, exit 2,
    no folder (it was blamed on point 0 and its values)."""
    out = tmp_path / "sweep"
    result = cosim_cli("sweep", str(tmp_path / "nosuch.toml"), "--grid", "sensor.seed=1,2",
                       "--out", str(out))
    assert result.returncode == 2
    assert_message(error_line(result),
                   f"{tmp_path / 'nosuch.toml'}: no such pipeline file; nothing was run")
    assert not out.exists()


def test_record_names_the_points_values_and_a_failing_re_run_is_one_message(tmp_path):
    """What --record prints of a point (its values, its worst check against its bound; the
    same text follows "recorded: FOLDER" when it succeeds), here in the message of a re-run
    that fails: the user's file where the point's folder would be, kept."""
    from cosim.sweep import SweepSpec, parse_grid, points
    from cosim.sweep.command import record_points
    from cosim.sweep.spec import SweepError

    spec = SweepSpec(PAPER, [parse_grid("controller.kv=5,60")], runs=["proposed"],
                     base=["simulation.duration=0.5"])
    row = {"point": 1, "run": "proposed", "status": "ok", "position_joint1.satisfied": True,
           "position_joint1.worst": 0.5, "position_joint1.bound": 2.0}
    (tmp_path / "best_proposed_point1").write_text("the user's")  # in the folder's way
    with pytest.raises(SweepError) as refused:
        record_points(spec, [row], ["best"], tmp_path, points(spec))
    folder = tmp_path / "best_proposed_point1"
    assert str(refused.value) == (
        "--record: re-running proposed's best point 1: controller.kv=60; its worst check "
        f"0.250 of its bound failed: --out {folder}: is a file, not a folder; choose another "
        f"--out; what it kept is in {folder} (the sweep's own results are complete in "
        f"{tmp_path})")
    assert folder.read_text() == "the user's"


def test_a_plugins_sys_exit_at_import_is_reported_not_a_silent_success(tmp_path, capsys):
    plugin = tmp_path / "exits.py"
    plugin.write_text("import sys\nsys.exit(0)\n")
    pipeline = tmp_path / "p.toml"
    pipeline.write_text(f'extends = "{ROOT / PAPER}"\nplugins = ["{plugin}"]\n')
    done = cosim_here(capsys, "sweep", str(pipeline), "--grid", "controller.kv=20,30",
                      "--out", str(tmp_path / "out"))
    message = error_line(done)
    assert message.startswith("cosim: error: point 0 (controller.kv=20): ") and \
        "sys.exit(0)" in message, message
    assert not (tmp_path / "out").exists()


def test_the_monte_carlo_benchmark_prints_a_command_a_shell_can_run(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    import monte_carlo

    printed = []
    run = monte_carlo.subprocess.run
    monte_carlo.subprocess.run = lambda command: printed.append(command) or \
        subprocess.CompletedProcess(command, 0)
    try:
        monte_carlo.sweep(2, Path("runs/x"), 1, 1, 0.1)
    finally:
        monte_carlo.subprocess.run = run
    (command,) = printed
    assert shlex.split(shlex.join(command)) == command


def test_tables_stay_within_100_columns_and_give_the_worst_values():
    from cosim.sweep.tables import format_table, safety_table

    def row(run, kv, worst):
        return {"run": run, "status": "ok", "safe": worst <= 1, "set:kv": kv,
                "position_joint1.satisfied": worst <= 1, "position_joint1.worst": worst,
                "position_joint1.bound": 1.0, "position_joint1.kind": "hard",
                "velocity_true_joint1.satisfied": True, "velocity_true_joint1.worst": 0.5,
                "velocity_true_joint1.bound": 2.0, "velocity_true_joint1.kind": "hard"}

    text = format_table(safety_table([row("proposed", 1, 0.25), row("proposed", 2, 1.5)]))
    assert max(map(len, text.splitlines())) <= 100
    assert text.splitlines() == [
        "safety rate per run (every joint's sets kept; Wilson 95 % interval)",
        "w: the largest worst value / bound over the completed points (≤ 1: kept)",
        "run                points failed  all sets                          position",
        "proposed                2      0   50.0 % [  9.5,  90.5] w 1.500     50.0 % [  9.5, "
        " 90.5] w 1.500",
        "run                points failed  velocity_true",
        "proposed                2      0  100.0 % [ 34.2, 100.0] w 0.250"]


def test_a_slurm_sweep_takes_dask_jobqueues_configuration_and_its_job_script_is_shown(
        tmp_path):
    """--cluster slurm --dry-run (no SLURM here): the job script dask-jobqueue would
    submit, from the user's jobqueue.slurm configuration, each job one single-threaded
    worker running this Python (the same cosim, on a shared path); the scheduler it starts
    here leaves no scratch space in the temporary folder."""
    pytest.importorskip("dask_jobqueue")
    config = tmp_path / "jobqueue.yaml"
    config.write_text("jobqueue:\n  slurm:\n    queue: short\n    account: robots\n"
                      "    memory: 4GB\n    walltime: '02:00:00'\n"
                      "    job-extra-directives: ['--constraint=avx2']\n")
    temporary = tmp_path / "tmp"  # its temporary folder: the local scheduler's scratch space
    temporary.mkdir()
    done = subprocess.run([sys.executable, "-m", "cosim.cli", "sweep", PAPER, "--grid",
                           "controller.kv=20,30", *SMALL, "--cluster", "slurm", "--workers",
                           "40", "--out", str(tmp_path / "out"), "--dry-run"],
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, "DASK_CONFIG": str(tmp_path),
                               "TMPDIR": str(temporary)})
    assert done.returncode == 0, done.stderr[-3000:]
    assert list(temporary.iterdir()) == []  # nothing left behind (was dask-scratch-space)
    lines = done.stdout.splitlines()
    assert lines[0].endswith("on 40 SLURM job(s) of one worker")
    script = lines[lines.index("each SLURM job's script (sbatch):") + 1:-1]
    assert script[:9] == ["#!/usr/bin/env bash", "", "#SBATCH -J dask-worker",
                          "#SBATCH -p short", "#SBATCH -A robots", "#SBATCH -n 1",
                          "#SBATCH --cpus-per-task=1", "#SBATCH --mem=4G",
                          "#SBATCH -t 02:00:00"]
    assert "#SBATCH --constraint=avx2" in script
    worker = shlex.split(script[-1])
    assert worker[:3] == [sys.executable, "-m", "distributed.cli.dask_worker"]
    assert worker[-2:] == ["--nthreads", "1"] and "--nanny" in worker
    assert not (tmp_path / "out").exists()
