"""A Monte Carlo for any arm's pipeline (issues 32, 51): its filtered output-feedback run
over a payload and an initial state drawn per sample, through `cosim sweep`; prints the
share of the viable starts whose every joint kept its position and velocity limits and
|τ_i| ≤ its effort limit (Wilson 95 %), and the broken guarantees (a covered run that left a
hard set, was infeasible, exceeded ε(t) or its torque limit).

    .venv/bin/python benchmarks/arm_monte_carlo.py --samples 200 --out runs/panda_mc
    .venv/bin/python benchmarks/arm_monte_carlo.py --pipeline xarm7.toml --samples 100 \
        --out runs/xarm7_mc                                       # a `cosim new` pipeline
    .venv/bin/python benchmarks/arm_monte_carlo.py --samples 200 --out runs/panda_mc --resume
    .venv/bin/python benchmarks/arm_monte_carlo.py --results runs/panda_mc   # report only

Sampled per run, about the pipeline's own start: the payload over the pipeline's declared
range (uncertainty.payload, kg at the tip); each joint's q(0) within ±``--spread-q`` of its
start (plant.parameters q0[i], else the plant's default), clipped to its position set less
the margin; q̇(0) within ±``--spread-v``; the observer starts at x̂2(0) = 0, so its initial
error is |q̇(0)| ≤ spread-v, declared as uncertainty.initial_velocity_error = spread-v +
0.05 rad/s.
The default pipeline is pipelines/panda.toml (its ready pose ±0.3 rad, ±0.3 rad/s).
SI units, radians.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from cosim.paper.sweep_report import format_guarantee_table, guarantee_table
from cosim.sweep import wilson

PIPELINE = "pipelines/panda.toml"
SPREAD_Q, SPREAD_V = 0.3, 0.3  # rad, rad/s
RUN = "proposed_cbf"
LIMITS = ("position", "velocity_true", "effort")  # check families, every joint


def samples(pipeline_file: Path, spread_q: float, spread_v: float) -> tuple[list, list]:
    """The --sample and --set flags for ``pipeline_file``'s arm (module docstring)."""
    from cosim.assemble import assemble
    from cosim.config import load_pipeline
    from cosim.declared import joint_boxes

    pipeline = load_pipeline(pipeline_file, warn=None)
    scenario = assemble(pipeline)
    try:
        n = scenario.plant.links
        defaults = scenario.plant.info()["parameters"]
    finally:
        scenario.close()
    start = np.array([pipeline.plant.parameters.get(f"q0[{i}]", defaults.get(f"q0[{i}]", 0.0))
                      for i in range(1, n + 1)])
    boxes = joint_boxes(pipeline.safety, n)
    low, high = start - spread_q, start + spread_q
    if boxes is not None:  # inside every position set, less the margin
        low = np.maximum(low, boxes.position_centre - boxes.position_half)
        high = np.minimum(high, boxes.position_centre + boxes.position_half)
    payload = pipeline.uncertainty.payload
    flags = [f"plant.parameters.payload=uniform({payload[0]:g},{payload[1]:g})",
             *(f'plant.parameters."q0[{i + 1}]"=uniform({low[i]:.6g},{high[i]:.6g})'
               for i in range(n)),
             *(f'plant.parameters."qdot0[{i + 1}]"=uniform({-spread_v:g},{spread_v:g})'
               for i in range(n))]
    return flags, [f"uncertainty.initial_velocity_error={spread_v + 0.05:g}"]


def sweep(pipeline: Path, count: int, out: Path, seed: int, workers: int,
          duration: float | None, spread: tuple[float, float], resume: bool = False) -> int:
    """The sweep into ``out`` (replacing it), or, with ``resume``, the points it lacks; the
    exit status of ``cosim sweep``."""
    sampled, settings = samples(pipeline, *spread)
    command = [str(Path(sys.executable).parent / "cosim"), "sweep", str(pipeline),
               "--samples", str(count), "--seed", str(seed), "--runs", RUN,
               "--workers", str(workers),
               *(["--resume", str(out)] if resume else ["--out", str(out), "--force"]),
               *(["--set", f"simulation.duration={duration}"] if duration else [])]
    for setting in settings:
        command += ["--set", setting]
    for sample in sampled:
        command += ["--sample", sample]
    print("$", " ".join(command), file=sys.stderr)
    return subprocess.run(command).returncode  # cosim said what went wrong, if anything


def limits_kept(row: dict) -> bool:
    """Every joint's position, true velocity and effort check of the row kept."""
    keys = [key for key in row if key.startswith(tuple(f"{f}_joint" for f in LIMITS))
            and key.endswith(".satisfied")]
    return bool(keys) and all(row[key] is True for key in keys)


def report(rows: list[dict]) -> str:
    ok = [r for r in rows if r["run"] == RUN and r["status"] == "ok"]
    viable = [r for r in ok if r.get("guarantee.covered")]
    kept = sum(limits_kept(r) for r in viable)
    broken = sum(bool(r.get("guarantee.broken")) for r in ok)
    low, high = wilson(kept, len(viable))
    lines = [format_guarantee_table(guarantee_table(rows)), "",
             f"{RUN}: {len(rows)} samples, {len(ok)} completed, {len(viable)} viable starts "
             "within the declared uncertainty (covered)",
             f"  every joint's position and velocity limits and |τ| ≤ effort kept: {kept} of "
             f"{len(viable)} = {100 * kept / max(len(viable), 1):.1f} % "
             f"[{100 * low:.1f}, {100 * high:.1f}] (Wilson 95 %)",
             f"  broken guarantees: {broken}"]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pipeline", type=Path, default=Path(PIPELINE),
                        help=f"the arm's pipeline, with a {RUN} run (default {PIPELINE})")
    parser.add_argument("--spread-q", type=float, default=SPREAD_Q,
                        help=f"q(0) within ± this of the start, rad (default {SPREAD_Q})")
    parser.add_argument("--spread-v", type=float, default=SPREAD_V,
                        help=f"q̇(0) within ± this, rad/s (default {SPREAD_V})")
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--seed", type=int, default=32)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--duration", type=float,
                        help="s per run (default: the pipeline's)")
    parser.add_argument("--out", type=Path, default=Path("runs/panda_mc"))
    parser.add_argument("--resume", action="store_true",
                        help="go on with the interrupted sweep in --out (same other flags)")
    parser.add_argument("--results", type=Path, help="an existing sweep folder: report only")
    args = parser.parse_args()
    folder = args.results
    if folder is None:
        status = sweep(args.pipeline, args.samples, args.out, args.seed, args.workers,
                       args.duration, (args.spread_q, args.spread_v), args.resume)
        if status:
            return status
        folder = args.out
    problem = not_a_monte_carlo(folder, args.pipeline if args.results is None else None)
    if problem:
        print(f"arm_monte_carlo.py: error: {problem}", file=sys.stderr)
        return 2
    rows = pq.read_table(folder / "results.parquet").to_pylist()
    print(report(rows))
    return 0


def not_a_monte_carlo(folder: Path, pipeline: Path | None) -> str | None:
    """Why ``folder`` is not a finished sweep of this script (of ``pipeline``, where given)
    (None if it is)."""
    try:
        spec = json.loads((folder / "sweep.json").read_text())
    except (OSError, ValueError):
        return (f"{folder}: not a sweep folder (no readable sweep.json); give the --out of a "
                "finished sweep of this script")
    swept = Path(str(spec.get("pipeline_file")))
    if (pipeline is not None and swept.name != pipeline.name) \
            or RUN not in (spec.get("runs") or []):
        return (f"{folder}: a sweep of {swept} (runs {', '.join(spec.get('runs') or [])}),"
                f" not of {pipeline or 'a pipeline'}'s {RUN}; give the --out of a sweep of "
                "this script")
    if not (folder / "results.parquet").is_file():
        return (f"{folder}: no results.parquet: the sweep did not finish; go on with "
                f"--resume --out {folder}")
    return None


if __name__ == "__main__":
    sys.exit(main())
