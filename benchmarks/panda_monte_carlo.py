"""The Panda Monte Carlo (issue 32): pipelines/panda.toml's filtered output-feedback run over
a payload and an initial state drawn per sample, through `cosim sweep`; prints the share of
the viable starts whose every joint kept its position and velocity limits and |τ_i| ≤ its
effort limit (Wilson 95 %), and the broken guarantees (a covered run that left a hard set,
was infeasible, exceeded ε(t) or its torque limit).

    .venv/bin/python benchmarks/panda_monte_carlo.py --samples 200 --out runs/panda_mc
    .venv/bin/python benchmarks/panda_monte_carlo.py --samples 200 --out runs/panda_mc --resume
    .venv/bin/python benchmarks/panda_monte_carlo.py --results runs/panda_mc   # report only

Sampled per run: the payload at the flange, 0-3 kg (the declared range); each joint's q(0)
within ±0.3 rad of the waypoints' start (the ready pose, inside every limit less the
margin) and q̇(0) within ±0.3 rad/s; the observer starts at x̂2(0) = 0, so its initial error
is |q̇(0)| ≤ 0.3 rad/s, declared as uncertainty.initial_velocity_error = 0.35 rad/s.
SI units, radians.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq

from cosim.paper.sweep_report import format_guarantee_table, guarantee_table
from cosim.sweep import wilson

PIPELINE = "pipelines/panda.toml"
READY = (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785)  # rad, the waypoints' start
SPREAD_Q, SPREAD_V = 0.3, 0.3  # rad, rad/s
SAMPLES = ['plant.parameters.payload=uniform(0,3)',
           *(f'plant.parameters."q0[{i + 1}]"=uniform({q - SPREAD_Q:g},{q + SPREAD_Q:g})'
             for i, q in enumerate(READY)),
           *(f'plant.parameters."qdot0[{i + 1}]"=uniform({-SPREAD_V:g},{SPREAD_V:g})'
             for i in range(len(READY)))]
SETTINGS = ["uncertainty.initial_velocity_error=0.35"]
RUN = "proposed_cbf"
LIMITS = ("position", "velocity_true", "effort")  # check families, every joint


def sweep(samples: int, out: Path, seed: int, workers: int, duration: float | None,
          resume: bool = False) -> int:
    """The sweep into ``out`` (replacing it), or, with ``resume``, the points it lacks; the
    exit status of ``cosim sweep``."""
    command = [str(Path(sys.executable).parent / "cosim"), "sweep", PIPELINE,
               "--samples", str(samples), "--seed", str(seed), "--runs", RUN,
               "--workers", str(workers),
               *(["--resume", str(out)] if resume else ["--out", str(out), "--force"]),
               *(["--set", f"simulation.duration={duration}"] if duration else [])]
    for setting in SETTINGS:
        command += ["--set", setting]
    for sample in SAMPLES:
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
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--seed", type=int, default=32)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--duration", type=float,
                        help="s per run (default: the pipeline's, 8.5 s: the whole waypoints)")
    parser.add_argument("--out", type=Path, default=Path("runs/panda_mc"))
    parser.add_argument("--resume", action="store_true",
                        help="go on with the interrupted sweep in --out (same other flags)")
    parser.add_argument("--results", type=Path, help="an existing sweep folder: report only")
    args = parser.parse_args()
    folder = args.results
    if folder is None:
        status = sweep(args.samples, args.out, args.seed, args.workers, args.duration,
                       args.resume)
        if status:
            return status
        folder = args.out
    problem = not_a_panda_sweep(folder)
    if problem:
        print(f"panda_monte_carlo.py: error: {problem}", file=sys.stderr)
        return 2
    rows = pq.read_table(folder / "results.parquet").to_pylist()
    print(report(rows))
    return 0


def not_a_panda_sweep(folder: Path) -> str | None:
    """Why ``folder`` is not a finished sweep of this script's pipeline (None if it is)."""
    try:
        spec = json.loads((folder / "sweep.json").read_text())
    except (OSError, ValueError):
        return (f"{folder}: not a sweep folder (no readable sweep.json); give the --out of a "
                "finished sweep of this script")
    pipeline = Path(str(spec.get("pipeline_file")))
    if pipeline.name != Path(PIPELINE).name or RUN not in (spec.get("runs") or []):
        return (f"{folder}: a sweep of {pipeline} (runs {', '.join(spec.get('runs') or [])}),"
                f" not of {PIPELINE}'s {RUN}; give the --out of a sweep of this script")
    if not (folder / "results.parquet").is_file():
        return (f"{folder}: no results.parquet: the sweep did not finish; go on with "
                f"--resume --out {folder}")
    return None


if __name__ == "__main__":
    sys.exit(main())
