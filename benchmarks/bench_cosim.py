"""Closed-loop cost against the FMU alone, in one process.

Times the full closed loop of the paper's proposed run (observer + NN controller + FMU) and
an FMU-only loop (the same FMU, same adapter, constant torque, same step count), each the
best of a few repetitions, and prints as its last line

    closed_loop_us_per_step=X fmu_only_us_per_step=Y ratio=X/Y

Run: .venv/bin/python benchmarks/bench_cosim.py [--duration 20] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from cosim.fmu import Fmu, PlantVariables
from cosim.master import simulate
from cosim.pipeline import load_pipeline
from cosim.runner import make_blocks, plant_path
from cosim.trace import Trace

PIPELINE = Path(__file__).resolve().parent.parent / "pipelines" / "paper_two_link.toml"


def closed_loop(plant: Fmu, duration: float) -> float:
    pipeline = load_pipeline(PIPELINE, [f"simulation.duration={duration}"])
    steps = int(round(duration / pipeline.simulation.step))
    trace = Trace(2, steps, pipeline.simulation.step)
    wall = simulate(plant, make_blocks(pipeline, pipeline.runs["proposed"], 2), trace)
    return wall / steps


def fmu_only(plant: Fmu, duration: float, h: float = 1e-3) -> float:
    steps = int(round(duration / h))
    plant.start(0.0)
    plant.tau[:] = 1.0
    start = time.perf_counter()
    for k in range(steps):
        plant.step(k * h, h)
    return (time.perf_counter() - start) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds")
    parser.add_argument("--repeat", type=int, default=3, help="repetitions (best is kept)")
    args = parser.parse_args()
    pipeline = load_pipeline(PIPELINE)
    plant = Fmu(plant_path(pipeline), PlantVariables.default(2))
    try:
        closed_loop(plant, 0.01)  # JIT compile outside the timing
        closed = min(closed_loop(plant, args.duration) for _ in range(args.repeat))
        alone = min(fmu_only(plant, args.duration) for _ in range(args.repeat))
    finally:
        plant.close()
    print(f"steps: {int(args.duration * 1000)} at 1 kHz, best of {args.repeat}")
    print(f"closed_loop_us_per_step={closed * 1e6:.2f} fmu_only_us_per_step={alone * 1e6:.2f} "
          f"ratio={closed / alone:.2f}")


if __name__ == "__main__":
    main()
