"""Sweep efficiency: rows per second of `cosim sweep` on Dask against what its workers could
do at the loop's speed, i.e. workers × the rows per second of in-process `run()` of one row
(the same pipeline and point, kernels loaded, the plant FMU kept open as a worker keeps it).

    .venv/bin/python benchmarks/bench_sweep.py [--points 24] [--duration 5] [--workers 2]

Points: the paper's proposed run over a grid of Kv. Printed, each measured on its own:
- the in-process rate (best of the interleaved repeats; also with the FMU opened per row,
  as a plain `run(pipeline)` does);
- the steady-state sweep rate: `execute()` on a LocalCluster whose workers have run a point
  (imported cosim, loaded their kernels, opened the FMU), and its efficiency = sweep rate /
  (workers × in-process rate), target ≥ 0.85;
- apart, what a sweep pays once: the cluster's start-up, each worker's first point, and the
  whole `cosim sweep` command end to end (validation, cluster, rows, results files).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from cosim.assemble import open_plant
from cosim.config import load_pipeline
from cosim.runner import run
from cosim.sweep import (
    SweepSpec,
    assignments,
    cluster_client,
    execute,
    parse_grid,
    points,
    points_per_task,
    run_point,
)

ROOT = Path(__file__).resolve().parent.parent
PIPELINE = str(ROOT / "pipelines" / "paper_two_link.toml")
TARGET = 0.85


def in_process(spec: SweepSpec, all_points: list[dict], keep_plant: bool) -> float:
    """Seconds for every point's one row through run() in this process."""
    plant = None
    began = time.perf_counter()
    for point in all_points:
        pipeline = load_pipeline(spec.pipeline, assignments(spec, point), warn=None)
        pipeline.runs = {"proposed": pipeline.runs["proposed"]}
        if keep_plant and plant is None:
            plant = open_plant(pipeline)
        run(pipeline, None, progress=False, plant=plant)
    if plant is not None:
        plant.close()
    return time.perf_counter() - began


def on_dask(spec: SweepSpec, all_points: list[dict], workers: int, repeat: int,
            per_task: int | None) -> tuple[list[float], float, float]:
    """(steady-state seconds for all points, per repeat; cluster start-up; the workers'
    first point)."""
    began = time.perf_counter()
    client, cluster = cluster_client(workers, None)
    started = time.perf_counter() - began
    try:
        began = time.perf_counter()
        # each worker runs a point first: imports, kernels from the cache, the FMU opened
        point = all_points[0]
        client.run(run_point, spec.pipeline, assignments(spec, point), spec.runs, 0, point)
        first = time.perf_counter() - began
        walls = []
        for _ in range(repeat):
            began = time.perf_counter()
            rows, _ = execute(spec, all_points, client, per_task=per_task)
            walls.append(time.perf_counter() - began)
            assert all(r["status"] == "ok" for r in rows), rows
        return walls, started, first
    finally:
        client.close()
        cluster.close()


def command(spec_args: list[str], workers: int) -> float:
    """Wall seconds of the whole `cosim sweep` command."""
    with tempfile.TemporaryDirectory(prefix="cosim_bench_sweep_") as tmp:
        began = time.perf_counter()
        subprocess.run([sys.executable, "-m", "cosim.cli", "sweep", PIPELINE, *spec_args,
                        "--workers", str(workers), "--out", f"{tmp}/out", "--quiet"],
                       check=True, capture_output=True, cwd=ROOT)
        return time.perf_counter() - began


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=24)
    parser.add_argument("--duration", type=float, default=5.0, help="simulated seconds")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3, help="interleaved repeats")
    parser.add_argument("--per-task", type=int, default=None, metavar="K",
                        help="points per Dask task (default: what cosim sweep picks)")
    args = parser.parse_args()
    values = ",".join(str(20 + 2 * i) for i in range(args.points))
    grid = f"runs.proposed.controller.kv={values}"
    base = [f"simulation.duration={args.duration}"]
    spec = SweepSpec(PIPELINE, [parse_grid(grid)], runs=["proposed"], base=base)
    all_points = points(spec)
    n = len(all_points)
    in_process(spec, all_points[:2], keep_plant=True)  # kernels loaded in this process
    kept, fresh, sweeps = [], [], []
    started = first = 0.0
    for _ in range(args.repeat):  # interleaved: the machine is shared
        kept.append(in_process(spec, all_points, keep_plant=True))
        fresh.append(in_process(spec, all_points, keep_plant=False))
        walls, started, first = on_dask(spec, all_points, args.workers, 1, args.per_task)
        sweeps += walls
    end_to_end = command(["--grid", grid, "--runs", "proposed", "--set", base[0]],
                         args.workers)
    rate = n / min(kept)
    sweep_rate = n / min(sweeps)
    efficiency = sweep_rate / (args.workers * rate)
    print(f"{n} rows (points of the paper's proposed run), {args.duration:g} s each at 1 kHz")
    print(f"  in-process run(), plant kept open: {rate:.2f} rows/s (best of {args.repeat}: "
          f"{', '.join(f'{n / w:.2f}' for w in kept)})")
    print(f"  in-process run(), FMU opened per row: {n / min(fresh):.2f} rows/s")
    steps = load_pipeline(PIPELINE, base).simulation.steps
    per_task = args.per_task or points_per_task(n, args.workers, steps)
    print(f"  cosim sweep on {args.workers} Dask workers, steady state: {sweep_rate:.2f} rows/s "
          f"(best of {len(sweeps)}: {', '.join(f'{n / w:.2f}' for w in sweeps)}; "
          f"{per_task} point(s) a task)")
    print(f"  sweep efficiency = {sweep_rate:.2f} / ({args.workers} × {rate:.2f}) = "
          f"{efficiency:.3f} (target ≥ {TARGET}: {'met' if efficiency >= TARGET else 'NOT met'})")
    print(f"  apart (paid once per sweep, not in the steady state): cluster start-up "
          f"{started:.2f} s; each worker's first point (imports, kernels from the cache, the "
          f"FMU) {first:.2f} s; the whole `cosim sweep` command {end_to_end:.1f} s = "
          f"{n / end_to_end:.2f} rows/s end to end")


if __name__ == "__main__":
    main()
