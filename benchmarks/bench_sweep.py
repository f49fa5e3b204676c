"""What a sweep point costs against its loop, and sweep efficiency.

1. ``--per-step``: the cost per simulated step of a sweep point (every run of it, as a Dask
   worker runs it: ``run_point``, the plant FMU kept open) against the same runs' fused loops
   alone (``simulate`` with nothing between chunks), point by point, interleaved, for
   pipelines/paper_two_link.toml (its two runs) and pipelines/monte_carlo.toml (its three);
   also the same points through ``execute`` on one local Dask worker. Target ≤ 1.3×.

       .venv/bin/python benchmarks/bench_sweep.py --per-step [--points 6] [--duration S]

2. ``--memory``: the peak memory (RSS) of the `cosim sweep` client for 10³ and 10⁴ points
   of a tiny run (rows streamed to disk, not held), sampled every 50 ms; target ≤ 1.2×.

       .venv/bin/python benchmarks/bench_sweep.py --memory [--points 1000]

3. Otherwise, sweep efficiency: rows per second of `cosim sweep` on Dask against what its
workers could do at the loop's speed, i.e. workers × the rows per second of in-process
`run()` of one row (the same pipeline and point, kernels loaded, the plant FMU kept open as
a worker keeps it).

    .venv/bin/python benchmarks/bench_sweep.py [--points 24] [--duration 5] [--workers 2]
    .venv/bin/python benchmarks/bench_sweep.py --external   # 2 `dask worker` processes

``--external``: the workers are `dask worker` processes started apart against a `dask
scheduler` process (as on a cluster), not a LocalCluster.

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

from monte_carlo import RUNS as MONTE_CARLO_RUNS
from monte_carlo import SAMPLES as MONTE_CARLO_SAMPLES

from cosim.assemble import assemble
from cosim.config import load_pipeline
from cosim.engine import simulate
from cosim.plant_source import open_plant
from cosim.runner import run
from cosim.sweep import (
    SweepSpec,
    assignments,
    cluster_client,
    execute,
    parse_grid,
    parse_sample,
    points,
    points_per_task,
    run_point,
)

ROOT = Path(__file__).resolve().parent.parent
PIPELINE = str(ROOT / "pipelines" / "paper_two_link.toml")
TARGET = 0.85
PER_STEP_TARGET = 1.3


def loops_alone(spec: SweepSpec, point: dict, plant: object) -> tuple[float, int]:
    """(seconds, steps) of the point's runs' fused loops alone: each run assembled on the
    open plant and stepped with nothing between its chunks (no evaluation, no trace kept)."""
    from cosim.sweep.spec import only_runs

    pipeline = only_runs(load_pipeline(spec.pipeline, assignments(spec, point), warn=None),
                         spec.runs)
    scenario = assemble(pipeline, plant)
    seconds, steps = 0.0, 0
    for plan in scenario.runs.values():
        seconds += simulate(plant, plan, plan.new_trace(scenario.steps), engine="fused")
        steps += scenario.steps
    return seconds, steps


def per_step(name: str, spec: SweepSpec, repeat: int) -> None:
    """Print µs per simulated step: the sweep point (run_point in-process, and execute() on
    one local Dask worker) against the same runs' fused loops, best of ``repeat``
    interleaved repeats."""
    all_points = points(spec)
    plant = open_plant(load_pipeline(spec.pipeline, spec.base, warn=None))
    run_point(spec.pipeline, assignments(spec, all_points[0]), spec.runs, 0, all_points[0])
    client, cluster = cluster_client(1, None)
    try:
        point = all_points[0]  # the worker's first point: imports, kernels, the FMU
        client.run(run_point, spec.pipeline, assignments(spec, point), spec.runs, 0, point)
        loop, swept, dasked = [], [], []
        for _ in range(repeat):  # interleaved: the machine is shared
            seconds = steps = 0
            for point in all_points:
                s, n = loops_alone(spec, point, plant)
                seconds, steps = seconds + s, steps + n
            loop.append(seconds / steps * 1e6)
            began = time.perf_counter()
            for index, point in enumerate(all_points):
                rows = run_point(spec.pipeline, assignments(spec, point), spec.runs, index,
                                 point)
                assert all(r["status"] == "ok" for r in rows), rows
            swept.append((time.perf_counter() - began) / steps * 1e6)
            began = time.perf_counter()
            rows, _ = execute(spec, all_points, client)
            dasked.append((time.perf_counter() - began) / steps * 1e6)
            assert all(r["status"] == "ok" for r in rows), rows
    finally:
        client.close()
        cluster.close()
        plant.close()
    best = min(loop)
    print(f"{name}: {len(all_points)} point(s) × {len(spec.runs)} run(s) "
          f"({', '.join(spec.runs)}), {steps // len(all_points):,} steps a point; µs per "
          f"simulated step, best of {repeat} interleaved")
    print(f"  fused loops alone          {best:7.2f}  ({', '.join(f'{v:.2f}' for v in loop)})")
    for label, values in (("sweep point (run_point)", swept),
                          ("sweep on 1 Dask worker", dasked)):
        ratio = min(values) / best
        print(f"  {label:<26} {min(values):7.2f}  ({', '.join(f'{v:.2f}' for v in values)})"
              f"  = {ratio:.2f}× the loop (target ≤ {PER_STEP_TARGET}: "
              f"{'met' if ratio <= PER_STEP_TARGET else 'NOT met'})")


def per_step_both(points_count: int, duration: float | None, repeat: int) -> None:
    """:func:`per_step` for the paper pipeline (a payload sample) and the Monte Carlo's."""
    base = [f"simulation.duration={duration}"] if duration else []
    payload = parse_sample('plant.parameters."m[2]"=uniform(2.3,3.3)')
    paper = SweepSpec(PIPELINE, samples=[payload],
                      count=points_count, seed=1, runs=["proposed", "baseline"], base=base)
    monte_carlo = SweepSpec(str(ROOT / "pipelines" / "monte_carlo.toml"),
                            samples=[parse_sample(s) for s in MONTE_CARLO_SAMPLES],
                            count=points_count, seed=1, runs=list(MONTE_CARLO_RUNS), base=base)
    per_step("paper_two_link.toml", paper, repeat)
    per_step("monte_carlo.toml", monte_carlo, repeat)


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
    wall = time.perf_counter() - began
    if plant is not None:
        plant.close()
    return wall


EXTERNAL: list[subprocess.Popen] = []  # the external cluster's processes, while it runs


def external_cluster(workers: int) -> tuple[str, list[subprocess.Popen]]:
    """A `dask scheduler` and ``workers`` single-threaded `dask worker` processes, started
    apart: (address, processes)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    dask = str(Path(sys.executable).parent / "dask")
    address = f"tcp://127.0.0.1:{port}"
    processes = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port",
                                   str(port), "--no-dashboard"], stderr=subprocess.DEVNULL)]
    processes += [subprocess.Popen([dask, "worker", address, "--nthreads", "1", "--host",
                                    "127.0.0.1", "--no-dashboard"], stderr=subprocess.DEVNULL,
                                   cwd=ROOT) for _ in range(workers)]
    EXTERNAL[:] = processes
    return address, processes


def end(processes: list[subprocess.Popen]) -> None:
    for process in reversed(processes):
        process.terminate()
        process.wait(timeout=30)


def on_dask(spec: SweepSpec, all_points: list[dict], workers: int, repeat: int,
            per_task: int | None, scheduler: str | None = None
            ) -> tuple[list[float], float, float]:
    """(steady-state seconds for all points, per repeat; cluster start-up; the workers'
    first point). ``scheduler``: an external cluster's address (its workers started)."""
    began = time.perf_counter()
    client, cluster = cluster_client(workers, scheduler)
    if scheduler:
        client.wait_for_workers(workers, timeout=120)
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
        if cluster is not None:
            cluster.close()


def command(spec_args: list[str], workers: int) -> float:
    """Wall seconds of the whole `cosim sweep` command."""
    with tempfile.TemporaryDirectory(prefix="cosim_bench_sweep_") as tmp:
        began = time.perf_counter()
        subprocess.run([sys.executable, "-m", "cosim.cli", "sweep", PIPELINE, *spec_args,
                        "--workers", str(workers), "--out", f"{tmp}/out", "--quiet"],
                       check=True, capture_output=True, cwd=ROOT)
        return time.perf_counter() - began


def peak_rss(command: list[str]) -> tuple[float, float]:
    """(peak RSS of the process in MB, sampled every 50 ms; wall seconds) of ``command``
    (its worker processes apart)."""
    import psutil

    began = time.perf_counter()
    process = psutil.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    peak = 0
    while process.poll() is None:
        try:
            peak = max(peak, process.memory_info().rss)
        except psutil.NoSuchProcess:
            break
        time.sleep(0.05)
    assert process.returncode == 0, process.returncode
    return peak / 1e6, time.perf_counter() - began


def memory(points_count: int, workers: int) -> None:
    """Print the client's peak memory for ``points_count`` and 10 × as many points of the
    paper's proposed run, 10 steps each (what grows with the points is the client's)."""
    peaks = {}
    for n in (points_count, 10 * points_count):
        with tempfile.TemporaryDirectory(prefix="cosim_bench_memory_") as tmp:
            peaks[n] = peak_rss([sys.executable, "-m", "cosim.cli", "sweep", PIPELINE,
                                 "--sample", "controller.kv=uniform(10,40)", "--samples",
                                 str(n), "--runs", "proposed", "--set",
                                 "simulation.duration=0.01", "--workers", str(workers),
                                 "--quiet", "--out", f"{tmp}/out"])
            rows = (Path(tmp) / "out" / "rows.jsonl").stat().st_size
        print(f"  {n:>7,} points: client peak RSS {peaks[n][0]:7.1f} MB, "
              f"{peaks[n][1]:6.1f} s, rows.jsonl {rows / 1e6:.1f} MB")
    small, large = peaks[points_count][0], peaks[10 * points_count][0]
    print(f"  peak memory ratio {10 * points_count:,} / {points_count:,} points = "
          f"{large / small:.3f} (target ≤ 1.2: {'met' if large / small <= 1.2 else 'NOT met'})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=None,
                        help="points (default 24; 6 with --per-step)")
    parser.add_argument("--duration", type=float, default=None,
                        help="simulated seconds (default 5; the pipelines' own with --per-step)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3, help="interleaved repeats")
    parser.add_argument("--per-task", type=int, default=None, metavar="K",
                        help="points per Dask task (default: what cosim sweep picks)")
    parser.add_argument("--external", action="store_true",
                        help="the workers as `dask scheduler` / `dask worker` processes")
    parser.add_argument("--memory", action="store_true",
                        help="the client's peak memory for --points and 10 × --points points")
    parser.add_argument("--per-step", action="store_true",
                        help="µs per simulated step of a sweep point against its fused loops")
    args = parser.parse_args()
    if args.per_step:
        per_step_both(args.points or 6, args.duration, args.repeat)
        return
    if args.memory:
        memory(args.points or 1000, args.workers)
        return
    args.points, args.duration = args.points or 24, args.duration or 5.0
    values = ",".join(str(20 + 2 * i) for i in range(args.points))
    grid = f"runs.proposed.controller.kv={values}"
    base = [f"simulation.duration={args.duration}"]
    spec = SweepSpec(PIPELINE, [parse_grid(grid)], runs=["proposed"], base=base)
    all_points = points(spec)
    n = len(all_points)
    in_process(spec, all_points[:2], keep_plant=True)  # kernels loaded in this process
    kept, fresh, sweeps = [], [], []
    started = first = 0.0
    address, processes = (external_cluster(args.workers) if args.external else (None, []))
    try:
        for _ in range(args.repeat):  # interleaved: the machine is shared
            kept.append(in_process(spec, all_points, keep_plant=True))
            fresh.append(in_process(spec, all_points, keep_plant=False))
            walls, started, first = on_dask(spec, all_points, args.workers, 1, args.per_task,
                                            address)
            sweeps += walls
    finally:
        end(processes)
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
    kind = "separately started `dask worker`s" if args.external else "local Dask workers"
    print(f"  cosim sweep on {args.workers} {kind}, steady state: {sweep_rate:.2f} rows/s "
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
