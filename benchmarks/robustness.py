"""Which of the paper's sets every controller keeps, every joint, under each robustness condition
of pipelines/robustness.toml, as a table.

    .venv/bin/python benchmarks/robustness.py [--duration 20]

One condition changes one thing against the paper's scenario (the noise rows add only
noise, the others none). Cells list the sets left on some joint (P position, V true
velocity, E error, Ė error rate; "all kept" when none), the peak torque (N·m) and, from 2
up, the torque reversals per second. SI units, radians.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from cosim.config import PipelineError, load_pipeline
from cosim.engine import Diverged
from cosim.evaluate import left_sets
from cosim.runner import run

PIPELINE = Path(__file__).resolve().parent.parent / "pipelines" / "robustness.toml"
CONDITIONS = {
    "nominal (no noise)": ["sensor.noise_std=0"],
    "noise 1e-4 rad": [],
    "noise 1e-3 rad": ["sensor.noise_std=1e-3", "uncertainty.noise_bound=6e-3"],
    "quantisation 1e-3 rad": ["sensor.noise_std=0", "sensor.resolution=1e-3",
                              "uncertainty.noise_bound=5e-4"],
    "payload 0.5 kg, nominal M̂": ["sensor.noise_std=0", 'plant.parameters."m[2]"=2.8',
                                  'inertia_model.source="nominal"'],
    "payload, declared 0-1 kg": ["sensor.noise_std=0", 'plant.parameters."m[2]"=2.8',
                                 'inertia_model.source="nominal"', "uncertainty.payload=[0.0,1.0]"],
    "q̇1(0) = 5 ≠ q̇_d1(0) = 10 rad/s": ["sensor.noise_std=0",
                                        'plant.parameters."qdot0[1]"=5.0',
                                        "uncertainty.initial_velocity_error=5.0"],
    "observer from zero velocity": ["sensor.noise_std=0", 'observer.initial_velocity="zero"',
                                    "uncertainty.initial_velocity_error=10.0"],
}
SETS = {"position": "P", "velocity_true": "V", "error": "E", "error_rate": "Ė"}


def cell(result) -> str:
    if not result.complete:
        return f"diverged at {result.metrics['simulated_time_s']:.2f} s"
    families = dict.fromkeys(entry["family"] for _, entry in left_sets(result.safety))
    left = [SETS.get(family, family) for family in families]  # every joint, every set
    chatter = max(result.metrics["torque_reversals_per_s"])
    peak = max(result.metrics["peak_torque"])
    text = "all kept" if not left else "left: " + " ".join(left)
    return f"{text} ({peak:.0f} N·m{f', {chatter:.0f} rev/s' if chatter >= 2 else ''})"


def table(path: Path, conditions: dict[str, list[str]], duration: float,
          label: str = "condition") -> int:
    """Print the markdown table: a row per condition (its ``--set`` overrides of the
    pipeline at ``path``), a column per run, each cell by :func:`cell`. Each run on its own,
    so that a diverging run does not stop the others."""
    header = None
    for condition, sets in conditions.items():
        began = time.perf_counter()
        try:
            pipeline = load_pipeline(path, [*sets, f"simulation.duration={duration}"])
        except PipelineError as exc:
            print(f"{path.stem}: {exc}", file=sys.stderr)
            return 2
        results = {}
        for name in list(pipeline.runs):
            single = pipeline.model_copy()
            single.runs = {name: pipeline.runs[name]}
            try:
                results[name] = run(single, None, progress=False)[name]
            except Diverged as exc:
                results[name] = exc
        if header is None:
            header = list(results)
            print(f"| {label} | " + " | ".join(header) + " |")
            print("|---" * (len(header) + 1) + "|")
        cells = [cell(r) if not isinstance(r, Diverged) else f"stopped: {r}"
                 for r in results.values()]
        print(f"| {condition} | " + " | ".join(cells) + " |", flush=True)
        print(f"  ({time.perf_counter() - began:.1f} s)", file=sys.stderr)
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds")
    args = parser.parse_args()
    return table(PIPELINE, CONDITIONS, args.duration)


if __name__ == "__main__":
    sys.exit(main())
