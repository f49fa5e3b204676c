"""Sweep throughput: points per second of `cosim sweep` on 1 and 2 Dask workers against the
naive one-point-at-a-time loop (load, open and extract the FMU, run, for each point), with
the per-point overheads measured on their own.

    .venv/bin/python benchmarks/bench_sweep.py [--points 16] [--duration 5]

Points: the paper's proposed run over a grid of Kv. Cluster start-up is timed apart.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from cosim.assemble import open_plant
from cosim.config import load_pipeline
from cosim.runner import run
from cosim.sweep import SweepSpec, cluster_client, execute, parse_grid, points

PIPELINE = str(Path(__file__).resolve().parent.parent / "pipelines" / "paper_two_link.toml")
JIT_PROBE = ("import time; t = time.perf_counter(); from cosim.config import load_pipeline; "
             "from cosim.runner import run; p = load_pipeline({path!r}, "
             "['simulation.duration=0.01']); p.runs = {{'proposed': p.runs['proposed']}}; "
             "run(p, None, progress=False); print(time.perf_counter() - t)")


def naive(spec: SweepSpec, all_points: list[dict]) -> float:
    from cosim.sweep import assignments

    began = time.perf_counter()
    for point in all_points:
        pipeline = load_pipeline(spec.pipeline, assignments(spec, point), warn=None)
        pipeline.runs = {"proposed": pipeline.runs["proposed"]}
        run(pipeline, None, progress=False)
    return time.perf_counter() - began


def on_dask(spec: SweepSpec, all_points: list[dict], workers: int) -> tuple[float, float]:
    began = time.perf_counter()
    client, cluster = cluster_client(workers, None)
    started = time.perf_counter() - began
    try:
        execute(spec, all_points[:workers], client)  # each worker loads its kernels first
        began = time.perf_counter()
        rows, _ = execute(spec, all_points, client)
        assert all(r["status"] == "ok" for r in rows)
        return time.perf_counter() - began, started
    finally:
        client.close()
        cluster.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=16)
    parser.add_argument("--duration", type=float, default=5.0, help="simulated seconds")
    args = parser.parse_args()
    values = ",".join(str(20 + 2 * i) for i in range(args.points))
    spec = SweepSpec(PIPELINE, [parse_grid(f"runs.proposed.controller.kv={values}")],
                     runs=["proposed"], base=[f"simulation.duration={args.duration}"])
    all_points = points(spec)
    pipeline = load_pipeline(PIPELINE, spec.base)
    opened = []
    for _ in range(5):
        began = time.perf_counter()
        plant = open_plant(pipeline)
        plant.start(0.0)
        opened.append(time.perf_counter() - began)
        plant.close()
    jit = float(subprocess.run([sys.executable, "-c", JIT_PROBE.format(path=PIPELINE)],
                               capture_output=True, text=True, check=True).stdout.split()[-1])
    naive(spec, all_points[:1])  # kernels loaded in this process
    serial = naive(spec, all_points)
    results = {w: on_dask(spec, all_points, w) for w in (1, 2)}
    n = len(all_points)
    print(f"{n} points of the paper's proposed run, {args.duration:g} s each at 1 kHz")
    print(f"  naive loop (re-open the FMU each point): {n / serial:.2f} points/s")
    for workers, (wall, started) in results.items():
        print(f"  cosim sweep, {workers} worker(s):          {n / wall:.2f} points/s "
              f"(cluster start-up {started:.1f} s, not counted)")
    print(f"  per-point overheads: open + extract + initialise the FMU "
          f"{1e3 * min(opened):.1f} ms (a sweep worker pays it once); first run in a fresh "
          f"process (imports, kernels from the numba cache) {jit:.2f} s (once per worker)")


if __name__ == "__main__":
    main()
