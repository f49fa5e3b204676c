"""Sweep pipeline keys over a grid for one run and print its safety checks (every joint),
verdict, peak torque and torque reversals (chattering) per point: how the paper pipeline's
gains were chosen.

    .venv/bin/python benchmarks/sweep.py pipelines/paper_two_link.toml proposed \\
        --grid runs.proposed.controller.delta=1,4,6 --grid runs.proposed.controller.psi_b=20,25

Each --grid KEY=V1,V2,... takes TOML values, as `cosim run --set` does; the grid is their
product. SI units, radians.
"""

from __future__ import annotations

import argparse
import itertools

from cosim.config import PipelineError, load_pipeline
from cosim.engine import Diverged
from cosim.evaluate import is_safe
from cosim.evaluate.checks import is_left
from cosim.runner import run

# The check families shown; each cell is the family's worst value relative to its bound
# over every joint and the norm, with "!" where the run left one of its sets (as its
# verdict counts them).
FAMILIES = ("position", "velocity_estimated", "velocity_true", "error", "error_rate")


def cell(safety: dict, family: str) -> str:
    mine = {n: e for n, e in safety.items() if e.get("family") == family
            and e.get("worst") is not None}
    if not mine:
        return "-"
    ratio = max(e["worst"] / e["bound"] for e in mine.values())
    return f"{ratio:.3f}{'!' if any(is_left(e) for e in mine.values()) else ''}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pipeline")
    parser.add_argument("run", help="the run to sweep (the others are skipped)")
    parser.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2,...")
    args = parser.parse_args()
    axes = []
    for item in args.grid:
        key, _, values = item.partition("=")
        if not key or not values:
            parser.error(f"--grid {item!r}: expected KEY=V1,V2,..., e.g. controller.kv=20,30")
        axes.append([f"{key}={v}" for v in values.split(",")])
    try:
        pipeline = load_pipeline(args.pipeline, [axis[0] for axis in axes])
    except PipelineError as exc:
        parser.exit(2, f"sweep: error: {exc}\n")
    if args.run not in pipeline.runs:
        parser.exit(2, f"sweep: error: no run {args.run!r} in {args.pipeline} (its runs: "
                    f"{', '.join(pipeline.runs)})\n")
    print("point | " + " | ".join(f"{f} (worst/bound)" for f in FAMILIES)
          + " | verdict | peak torque (N·m) | reversals/s")
    for point in itertools.product(*axes):
        try:
            pipeline = load_pipeline(args.pipeline, list(point))
        except PipelineError as exc:
            parser.exit(2, f"sweep: error: {exc}\n")
        pipeline.runs = {args.run: pipeline.runs[args.run]}
        label = " ".join(p.split(".")[-1] for p in point) or "(as is)"
        try:
            result = run(pipeline, None, progress=False)[args.run]
        except Diverged as exc:
            print(f"{label} | diverged: {exc}")
            continue
        cells = [cell(result.safety, family) for family in FAMILIES]
        m = result.metrics
        print(f"{label} | " + " | ".join(cells)
              + f" | {'safe' if is_safe(result.safety) else 'UNSAFE'}"
              + f" | {'/'.join(f'{x:.0f}' for x in m['peak_torque'])}"
              + f" | {'/'.join(f'{x:.1f}' for x in m['torque_reversals_per_s'])}", flush=True)


if __name__ == "__main__":
    main()
