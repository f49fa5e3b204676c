"""cosim sweep on Dask: the same per-point results as single runs, the same table on a
LocalCluster and on an external scheduler and worker, failed points kept as rows, bad keys
refused before anything runs."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from cli_helpers import PAPER, assert_message, cosim_cli, dask_environment, error_line

from cosim.config import load_pipeline
from cosim.runner import run
from cosim.sweep import SweepSpec

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
    # one row of panels per run (proposed, baseline), one column per varied key: 5.5 × 6.4 in
    assert png_size(tmp_path / "mc" / "sweep_safety.png") == (550, 640)


def png_size(path: Path) -> tuple[int, int]:
    """(width, height) in pixels, from the PNG's IHDR chunk."""
    header = path.read_bytes()[:24]
    assert header[:8] == b"\x89PNG\r\n\x1a\n" and header[12:16] == b"IHDR"
    return int.from_bytes(header[16:20], "big"), int.from_bytes(header[20:24], "big")


def test_sweep_safety_plot_has_a_panel_per_run_and_key_and_the_kept_share(tmp_path):
    """Rows as a sweep writes them (two runs, a grid of strings and a sampled key, one failed
    point): the figure's layout; and the shares it draws (kept_share) against counts by
    hand."""
    from cosim.outputs.run_folder import RunFolder
    from cosim.sweep import kept_share, parse_grid, parse_sample, write_safety_plot

    rng = np.random.default_rng(0)
    rows = []
    for point in range(40):
        for run_name in ("proposed", "baseline"):
            gain = float(rng.uniform(5, 50))
            worst = 25.0 - gain / 5  # position_joint1 kept (≤ 20) from a gain of 25 up
            rows.append({"point": point, "run": run_name, "status": "ok", "safe": worst <= 20,
                         "set:observer.basis": ["lagged", "no_acceleration"][point % 2],
                         "set:controller.kv": gain, "position_joint1.worst": worst,
                         "position_joint1.bound": 20.0})
    rows.append({"point": 40, "run": "proposed", "status": "failed", "error": "diverged",
                 "set:observer.basis": "lagged", "set:controller.kv": 1.0})
    spec = SweepSpec(PAPER, [parse_grid('observer.basis="lagged","no_acceleration"')],
                     [parse_sample("controller.kv=uniform(5,50)")], 40)
    folder = RunFolder.create(tmp_path / "plot", False)
    write_safety_plot(folder, spec, rows)
    folder.release()
    assert png_size(tmp_path / "plot" / "sweep_safety.png") == (1100, 640)  # 2 keys × 2 runs

    gains = np.array([5.0, 30.0, 10.0, 40.0, 20.0, 50.0])
    kept = gains >= 25
    # a grid key: per value
    assert kept_share(np.array([0.0, 1, 0, 1, 0, 1]), kept, binned=False) == \
        ([0.0, 1.0], [0.0, 100.0])
    # a sampled key: 45 points in 2 groups of consecutive values (23 and 22 points)
    x = np.arange(45.0)
    centres, rates = kept_share(x[::-1].copy(), x[::-1] >= 30, binned=True)
    assert centres == [11.0, 33.5] and rates == pytest.approx([0.0, 100 * 15 / 22], rel=1e-12)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_external_scheduler_and_worker_give_the_same_table(tmp_path):
    args = ["--grid", "runs.baseline.controller.kv=20,60", "--runs", "baseline"]
    local = sweep(tmp_path / "local", *args, "--workers", "1")
    port = _free_port()
    dask = Path(sys.executable).parent / "dask"
    environment = dask_environment(tmp_path)
    scheduler = subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1", "--port",
                                  str(port), "--no-dashboard"], stderr=subprocess.DEVNULL,
                                 env=environment)
    worker = subprocess.Popen([str(dask), "worker", f"tcp://127.0.0.1:{port}", "--nthreads",
                               "1", "--nworkers", "1", "--host", "127.0.0.1",
                               "--no-dashboard"], stderr=subprocess.DEVNULL, env=environment)
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
    keys = ("variant, kv, lambda, f, g, kappa, kz, z_b, z_wc, c0, c1, delta, psi_b, hidden, "
            "velocity, init, init_scale, seed, scale")
    for args, message in [
            (["--grid", "controller.kvv=1,2"], "point 0 (controller.kvv=1): unknown "
             f"key 'controller.kvv'; allowed keys here: {keys}"),
            (["--sample", "controller.kv=gauss(1,2)"], "--sample 'controller.kv=gauss(1,2)': "
             "expected KEY=uniform(a,b), normal(mean,std) or integers(low,high)"),
            (["--sample", "controller.kv=uniform(1,2)"],
             "--sample needs --samples N (N ≥ 1 random draws)"),
            (["--runs", "nope"], f"--runs nope: not a run of {PAPER} (its runs: baseline, "
             "proposed)"),
            (["--grid", "controller.kv=-1,20"], "point 0 (controller.kv=-1): key "
             "'controller.kv': Input should be greater than 0 (got -1)")]:
        began = time.monotonic()
        done = cosim_cli("sweep", PAPER, "--out", str(out), *args)
        assert_message(error_line(done), message)
        assert time.monotonic() - began < 60 and not out.exists()


@pytest.mark.parametrize("count", [20])
def test_wilson_interval(count):
    from cosim.sweep import wilson

    low, high = wilson(count // 2, count)
    assert low < 0.5 < high and high - low == pytest.approx(0.4, abs=0.03)
    assert wilson(0, 10)[0] == 0.0 and wilson(10, 10)[1] == 1.0


def test_record_best_and_worst_per_run_re_runs_those_points_with_a_recording(tmp_path):
    """--record best,worst: for each run, the point whose worst joint-1 check is furthest
    inside (outside) its bound, picked here from the rows, re-run as a full run folder of
    that run alone that reproduces the row; each phase is announced (no --quiet)."""
    out = tmp_path / "rec"
    done = cosim_cli("sweep", PAPER, "--out", str(out), *DURATION, "--grid",
                     "controller.kv=5,60", "--workers", "1", "--record", "best,worst")
    assert done.returncode == 0, done.stderr[-3000:]
    for phase in ("checking every point against the pipeline's schema",
                  r"starting 1 Dask worker process\(es\)",
                  *[f"re-running {run_name}'s {kind} point \\(\\d\\) with its recording and "
                    "figures" for kind in ("best", "worst") for run_name in ("baseline",
                                                                             "proposed")]):
        assert re.search(f"^  {phase} … \\d+\\.\\d s$", done.stderr, re.M), phase
    rows = pq.read_table(out / "results.parquet").to_pylist()
    made = set()
    for run_name in ("baseline", "proposed"):
        mine = [r for r in rows if r["run"] == run_name]
        ratio = {r["point"]: max(r[f"{c}.worst"] / r[f"{c}.bound"] for c in CHECKS)
                 for r in mine}
        assert len(set(ratio.values())) == 2  # the two gains differ: best ≠ worst
        for kind, pick in (("best", min), ("worst", max)):
            point = pick(ratio, key=ratio.get)
            folder = out / f"{kind}_{run_name}_point{point}"
            made.add(folder.name)
            summary = json.loads((folder / "summary.json").read_text())
            assert summary["complete"] is True and list(summary["runs"]) == [run_name]
            assert (folder / "recording.rrd").stat().st_size > 0
            row = next(r for r in mine if r["point"] == point)
            for check in CHECKS:
                assert summary["runs"][run_name]["safety"][check]["worst"] == \
                    row[f"{check}.worst"]
            assert f"recorded: {folder}" in done.stdout
    assert made == {p.name for p in out.iterdir() if p.is_dir()}


def test_dry_run_checks_every_point_and_runs_nothing(tmp_path):
    out = tmp_path / "mc"
    done = cosim_cli("sweep", PAPER, "--sample", "controller.kv=uniform(10,40)", "--sample",
                     "sensor.seed=integers(0,1000000)", "--samples", "50", "--seed", "1",
                     "--grid", "controller.f=1,2", "--runs", "proposed", "--out", str(out),
                     "--dry-run", "--set", "simulation.duration=2")
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.splitlines() == [
        f"sweep of {PAPER}: 100 point(s) × 1 run(s) (proposed) = 100 row(s), 2 s simulated "
        f"each (2,000 steps), on {os.cpu_count() or 1} local Dask worker(s)",
        "  grid   controller.f = 1, 2",
        "  sample controller.kv = uniform(10, 40), 50 draw(s) per grid point, seed 1",
        "  sample sensor.seed = integers(0, 1000000), 50 draw(s) per grid point, seed 1",
        "  set    simulation.duration=2",
        f"results -> {out} (results.parquet, results.csv, sweep.json, sweep_safety.png)",
        "every point checked against the pipeline's schema; nothing was run"]
    assert not out.exists()
    # a point the schema refuses is refused as in a real sweep
    bad = cosim_cli("sweep", PAPER, "--grid", "controller.kv=-1,20", "--out", str(out),
                    "--dry-run")
    assert bad.returncode == 2 and "point 0 (controller.kv=-1)" in bad.stderr
    assert not out.exists()


def test_the_safety_table_counts_failed_points_apart_not_as_unsafe():
    """Rates and their Wilson intervals over the completed points only; failed ones counted
    in their own column (reference: SciPy's Wilson interval for 2 of 3)."""
    from scipy import stats

    from cosim.sweep import safety_table

    def row(run_name, status, safe=None):
        return {"run": run_name, "status": status, "safe": safe,
                "position_joint1.satisfied": safe}

    rows = [row("a", "ok", True), row("a", "ok", True), row("a", "ok", False),
            row("a", "failed"), row("a", "failed"), row("b", "failed")]
    a, b = safety_table(rows)
    assert (a["run"], a["points"], a["failed"]) == ("a", 5, 2)
    ci = stats.binomtest(2, 3).proportion_ci(2 * stats.norm.cdf(1.96) - 1, "wilson")
    for column in ("all sets", "position"):
        rate, low, high = a[column]
        assert rate == pytest.approx(2 / 3, abs=1e-15)
        assert (low, high) == (pytest.approx(ci.low, abs=1e-12),
                               pytest.approx(ci.high, abs=1e-12))
    assert (b["points"], b["failed"]) == (1, 1)
    assert all(np.isnan(v) for v in b["all sets"])  # no completed point: no rate
