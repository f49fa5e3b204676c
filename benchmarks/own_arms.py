"""Your own arm, first try (issue 51): for arms of example-robot-data, `cosim new --urdf` then
`cosim run` on the pipeline it wrote, as a user would (recording and figures included), and
per arm: whether every run finished, every joint's limits were kept (position, velocity,
effort), the filtered run was covered by its guarantee, the RMS tracking error of each run
(the norm over joints of each joint's RMS |e|, rad), and the wall time from URDF to verdict
(compiling included, if the caches are cold).

    .venv/bin/python benchmarks/own_arms.py                       # every arm below
    .venv/bin/python benchmarks/own_arms.py --arms xarm7 ur10 --friction keep
    .venv/bin/python benchmarks/own_arms.py --out runs/own_arms  # keep the run folders

SI units, radians.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PACKAGE = "package://example-robot-data/robots/"
ARMS = {  # light and heavy, 2 to 7 joints
    "xarm7": "xarm_description/urdf/xarm7.urdf",
    "ur10": "ur_description/urdf/ur10_robot.urdf",
    "ur5": "ur_description/urdf/ur5_robot.urdf",
    "panda": "panda_description/urdf/panda.urdf",
    "kinova": "kinova_description/robots/kinova.urdf",
    "z1": "z1_description/urdf/z1.urdf",
    "so101": "so_arm_description/urdf/so101.urdf",
    "finger": "finger_edu_description/robots/finger_edu.urdf",
    "twodof": "asr_twodof_description/urdf/TwoDofs.urdf",
}
FILTERED = "proposed_cbf"


def first_try(arm: str, folder: Path, friction: str) -> dict:
    """`cosim new` then `cosim run` for ``arm`` in ``folder``: what came of it."""
    cosim = str(Path(sys.executable).parent / "cosim")
    pipeline, out = folder / f"{arm}.toml", folder / "runs" / arm
    began = time.monotonic()
    made = subprocess.run([cosim, "new", "--urdf", PACKAGE + ARMS[arm], "--out", str(pipeline),
                           "--friction", friction, "--force"], capture_output=True, text=True)
    if made.returncode:
        return {"arm": arm, "error": made.stderr.strip().splitlines()[-1]}
    ran = subprocess.run([cosim, "run", str(pipeline), "--out", str(out), "--force",
                          "--quiet"], capture_output=True, text=True)
    seconds = time.monotonic() - began
    try:
        summary = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        return {"arm": arm, "error": (ran.stderr.strip().splitlines() or ["no summary"])[-1],
                "seconds": seconds}
    runs = summary["runs"]
    joints = len(next(iter(runs.values()))["metrics"]["rms_error"])
    return {
        "arm": arm, "joints": joints, "seconds": seconds, "status": ran.returncode,
        "finished": all(r["complete"] for r in runs.values()) and not summary["not_run"],
        "limits_kept": all(e["satisfied"] for r in runs.values()
                           for e in r["safety"].values() if e.get("kind") == "hard"),
        "covered": bool(runs.get(FILTERED, {}).get("metrics", {}).get("guarantee", {})
                        .get("covered")),
        "rms_error": {name: float(np.linalg.norm(r["metrics"]["rms_error"]))
                      for name, r in runs.items()},
        "error": None if ran.returncode == 0 else ran.stderr.strip().splitlines()[-1],
    }


def table(rows: list[dict]) -> str:
    names = sorted({n for r in rows for n in r.get("rms_error", {})})
    head = (f"{'arm':<8} {'joints':>6} {'finished':>8} {'limits':>6} {'covered':>7} "
            + " ".join(f"{'rms ' + n:>17}" for n in names) + f" {'URDF→verdict':>13}")
    lines = [head]
    for r in rows:
        if r.get("joints") is None:
            lines.append(f"{r['arm']:<8} error: {r['error']}")
            continue
        errors = " ".join(f"{r['rms_error'].get(n, float('nan')):>13.4f} rad" for n in names)
        lines.append(f"{r['arm']:<8} {r['joints']:>6} {str(r['finished']):>8} "
                     f"{str(r['limits_kept']):>6} {str(r['covered']):>7} {errors} "
                     f"{r['seconds']:>11.1f} s")
        if r["error"]:
            lines.append(f"         {r['error']}")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--arms", nargs="+", choices=list(ARMS), default=list(ARMS))
    parser.add_argument("--friction", choices=("auto", "keep", "none"), default="auto",
                        help="cosim new --friction (default auto)")
    parser.add_argument("--out", type=Path, default=None,
                        help="keep the pipelines and run folders here (default: a temporary "
                        "folder, removed)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="own_arms_") as scratch:
        folder = args.out or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        rows = []
        for arm in args.arms:
            rows.append(first_try(arm, folder, args.friction))
            print(table(rows[-1:]).splitlines()[-1], file=sys.stderr, flush=True)
    print(table(rows))
    return 0 if all(r.get("finished") and r.get("limits_kept") for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
