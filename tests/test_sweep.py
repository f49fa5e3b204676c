"""cosim sweep on Dask: the same per-point results as single runs, the same table on a
LocalCluster and on an external scheduler and worker, failed points kept as rows, bad keys
refused before anything runs."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from cli_helpers import PAPER, cosim_cli

from cosim.config import load_pipeline
from cosim.runner import run

DURATION = ["--set", "simulation.duration=1"]
CHECKS = ("position_joint1", "velocity_true_joint1", "error_joint1", "error_rate_joint1")


def sweep(out: Path, *args: str) -> list[dict]:
    done = cosim_cli("sweep", PAPER, "--out", str(out), "--quiet", *DURATION, *args)
    assert done.returncode == 0, done.stderr[-3000:]
    return pq.read_table(out / "results.parquet").to_pylist()


def single(sets: list[str], run_name: str):
    pipeline = load_pipeline(PAPER, ["simulation.duration=1", *sets])
    pipeline.runs = {run_name: pipeline.runs[run_name]}
    return run(pipeline, None, progress=False)[run_name]


def point_sets(row: dict) -> list[str]:
    return [f"{k.removeprefix('set:')}={json.dumps(v) if isinstance(v, str) else repr(v)}"
            for k, v in row.items() if k.startswith("set:")]


def test_grid_and_monte_carlo_equal_single_runs_bit_for_bit(tmp_path):
    grid = sweep(tmp_path / "grid", "--grid", "runs.proposed.controller.kv=20,30",
                 "--runs", "proposed", "--workers", "2")
    carlo = sweep(tmp_path / "mc", "--sample", 'plant.parameters."qdot0[1]"=uniform(8,12)',
                  "--samples", "2", "--seed", "3", "--runs", "proposed", "baseline",
                  "--workers", "2")
    assert len(grid) == 2 and len(carlo) == 4
    assert len({r['set:plant.parameters."qdot0[1]"'] for r in carlo}) == 2
    for row in grid + carlo:
        assert row["status"] == "ok", row["error"]
        expected = single(point_sets(row), row["run"])
        for check in CHECKS:
            assert row[f"{check}.worst"] == expected.safety[check]["worst"], (row, check)
        assert row["peak_torque.1"] == expected.metrics["peak_torque"][0]
    summary = json.loads((tmp_path / "mc" / "sweep.json").read_text())
    assert summary["seed"] == 3 and summary["rows"] == 4
    assert summary["safety_by_value"] == {}  # a sampled key: its rates are in the plot
    # a grid key's table per value: each value's rate from its own rows only
    by_value = json.loads((tmp_path / "grid" / "sweep.json").read_text())["safety_by_value"]
    entries = by_value["runs.proposed.controller.kv"]
    assert [(e["value"], e["run"], e["points"], e["failed"]) for e in entries] == [
        (20.0, "proposed", 1, 0), (30.0, "proposed", 1, 0)]
    for entry in entries:
        mine = [r for r in grid if r["set:runs.proposed.controller.kv"] == entry["value"]]
        assert entry["all sets"][0] == float(mine[0]["safe"])
        assert entry["position"][0] == float(mine[0]["position_joint1.satisfied"])
    assert (tmp_path / "mc" / "results.csv").read_text().count("\n") == 5
    assert (tmp_path / "mc" / "sweep_safety.png").stat().st_size > 0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_external_scheduler_and_worker_give_the_same_table(tmp_path):
    args = ["--grid", "runs.baseline.controller.kv=20,60", "--runs", "baseline"]
    local = sweep(tmp_path / "local", *args, "--workers", "1")
    port = _free_port()
    dask = Path(sys.executable).parent / "dask"
    scheduler = subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1", "--port",
                                  str(port), "--no-dashboard"], stderr=subprocess.DEVNULL)
    worker = subprocess.Popen([str(dask), "worker", f"tcp://127.0.0.1:{port}", "--nthreads",
                               "1", "--nworkers", "1", "--host", "127.0.0.1",
                               "--no-dashboard"], stderr=subprocess.DEVNULL)
    try:
        remote = sweep(tmp_path / "remote", *args, "--scheduler", f"tcp://127.0.0.1:{port}")
    finally:
        for process in (worker, scheduler):
            process.terminate()
            process.wait(timeout=30)
    timing = {"wall_time_s"}
    assert [{k: v for k, v in r.items() if k not in timing} for r in local] == \
        [{k: v for k, v in r.items() if k not in timing} for r in remote]


def test_a_diverging_point_is_a_failed_row_and_the_others_complete(tmp_path):
    rows = sweep(tmp_path / "div", "--grid", 'observer.basis="lagged","no_acceleration"',
                 "--set", "observer.kp=10", "--set", "observer.kd=10", "--set",
                 "observer.nu=1.0", "--runs", "proposed", "--workers", "2")
    by_basis = {r["set:observer.basis"]: r for r in rows}
    assert by_basis["lagged"]["status"] == "failed"
    # the lagged basis diverges within 0.1 s (here the plant gives up first: its inertia
    # matrix becomes singular as the observer's torque term blows up)
    error = by_basis["lagged"]["error"]
    assert ("diverged" in error or "stopped the run" in error) and "at t = 0.0" in error
    assert by_basis["no_acceleration"]["status"] == "ok"


def test_a_bad_key_is_refused_before_anything_runs(tmp_path):
    out = tmp_path / "bad"
    for args, fragment in [(["--grid", "controller.kvv=1,2"], "unknown key 'controller.kvv'"),
                           (["--sample", "controller.kv=gauss(1,2)"], "expected KEY=uniform"),
                           (["--sample", "controller.kv=uniform(1,2)"], "needs --samples"),
                           (["--runs", "nope"], "--runs nope: not a run"),
                           (["--grid", "controller.kv=-1,20"], "point 0 (controller.kv=-1)")]:
        began = time.monotonic()
        done = cosim_cli("sweep", PAPER, "--out", str(out), *args)
        assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
        assert fragment in done.stderr, (fragment, done.stderr)
        assert time.monotonic() - began < 60 and not out.exists()


@pytest.mark.parametrize("count", [20])
def test_wilson_interval(count):
    from cosim.sweep import wilson

    low, high = wilson(count // 2, count)
    assert low < 0.5 < high and high - low == pytest.approx(0.4, abs=0.03)
    assert wilson(0, 10)[0] == 0.0 and wilson(10, 10)[1] == 1.0
