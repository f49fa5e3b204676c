"""The robust-safety Monte Carlo (docs/sweeps.md, "Monte Carlo under declared uncertainty"):
runs `cosim sweep` on pipelines/monte_carlo.toml with its sampled conditions, then prints the
tables docs/sweeps.md quotes: the hard sets by class, the broken guarantees, the tracking
sets against the unfiltered controller, the cost of robustness and why samples fall outside
the declared uncertainty.

    .venv/bin/python benchmarks/monte_carlo.py --samples 1000 --out runs/mc1000
    .venv/bin/python benchmarks/monte_carlo.py --results runs/mc1000   # tables only

Sampled: q(0) = 0.1 ± 0.5 rad and q̇(0) = 10 ± 5 rad/s per joint, a payload of 0-1 kg at the
tip (m[2] from 2.3 to 3.3 kg), the sensor noise's seed; declared in the pipeline: the same
ranges, noise 1e-4 rad (bound 6e-4). SI units, radians.
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from cosim.paper.sweep_report import format_guarantee_table, guarantee_table
from cosim.sweep import wilson
from cosim.sweep.checks import family_kept, table_checks

SAMPLES = ['plant.parameters."q0[1]"=uniform(-0.4,0.6)',
           'plant.parameters."q0[2]"=uniform(-0.4,0.6)',
           'plant.parameters."qdot0[1]"=uniform(5,15)', 'plant.parameters."qdot0[2]"=uniform(5,15)',
           'plant.parameters."m[2]"=uniform(2.3,3.3)', "sensor.seed=integers(0,1000000)"]
RUNS = ("proposed", "proposed_cbf", "baseline_cbf")
TRACKING = ("error", "error_rate", "error_rate_true")  # check families, every joint


def sweep(samples: int, out: Path, seed: int, workers: int, duration: float) -> None:
    command = [str(Path(sys.executable).parent / "cosim"), "sweep", "pipelines/monte_carlo.toml",
               "--samples", str(samples), "--seed", str(seed), "--runs", *RUNS,
               "--workers", str(workers), "--out", str(out),
               "--set", f"simulation.duration={duration}"]
    for sample in SAMPLES:
        command += ["--sample", sample]
    print("$", shlex.join(command), file=sys.stderr)  # quoted: a shell can run it
    done = subprocess.run(command)
    if done.returncode:  # cosim sweep said why on stderr: no traceback of ours on top
        sys.exit(done.returncode)


def percent(kept: int, total: int) -> str:
    if not total:
        return "-"
    low, high = wilson(kept, total)
    return f"{100 * kept / total:.1f} % [{100 * low:.1f}, {100 * high:.1f}]"


def report(rows: list[dict]) -> str:
    lines = [format_guarantee_table(guarantee_table(rows)), ""]
    lines.append("tracking sets kept, every joint (all samples; Wilson 95 %), and the cost of "
                 "robustness")
    lines.append(f"{'run':<14}" + "".join(f"{c:<26}" for c in TRACKING)
                 + f"{'RMS |e1| (rad)':>16}{'filter active':>15}{'peak τ1 (N·m)':>16}")
    for name in RUNS:
        mine = [r for r in rows if r["run"] == name and r["status"] == "ok"]
        if not mine:
            continue
        families = dict(table_checks(mine))
        cells = [percent(sum(family_kept(r, families[c]) for r in mine), len(mine))
                 if c in families else "-" for c in TRACKING]
        active = [r.get("filter_active_fraction") for r in mine]
        active_text = (f"{100 * np.mean(active):.1f} %" if active[0] is not None else "-")
        lines.append(f"{name:<14}" + "".join(f"{c:<26}" for c in cells)
                     + f"{np.mean([r['rms_error.1'] for r in mine]):>16.4f}{active_text:>15}"
                     + f"{np.median([r['peak_torque.1'] for r in mine]):>16.0f}")
    lines.append("(RMS |e1|: mean over samples; peak τ1: median over samples)")
    lines.append("")
    reasons: dict[str, int] = {}
    for r in rows:
        for reason in filter(None, (r.get("guarantee.outside") or "").split("; ")):
            key = reason.split(" at ")[0].split(" (")[0]
            key = "payload outside" if key.startswith("payload") else key
            key = "noise above bound" if key.startswith("noise") else key
            reasons[f"{r['run']}: {key}"] = reasons.get(f"{r['run']}: {key}", 0) + 1
    lines.append("outside the declared uncertainty, why (samples):")
    lines += [f"  {key}: {count}" for key, count in sorted(reasons.items())] or ["  none"]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--duration", type=float, default=20.0, help="s per run")
    parser.add_argument("--out", type=Path, default=Path("runs/mc"))
    parser.add_argument("--results", type=Path, help="an existing sweep folder: tables only")
    args = parser.parse_args()
    folder = args.results
    if folder is None:
        sweep(args.samples, args.out, args.seed, args.workers, args.duration)
        folder = args.out
    rows = pq.read_table(folder / "results.parquet").to_pylist()
    print(report(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
