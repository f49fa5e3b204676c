"""The first run on a fresh machine, as the set-up (`make demo`, `make test`) leaves it: a
copy of the sources without bytecode and empty caches (numba's kernels, the fused loops, the
built FMU, matplotlib's font list, each in a temporary folder), then the set-up's warm-up step
(`cosim warm-up`, which `make venv` and `make test-venv` run) timed on its own, then the
first `cosim run` of the pipeline, timed: the figure to reach is ≤ 5 s. Prints every line
each wrote to stderr with the second it appeared.

    .venv/bin/python benchmarks/cold_start.py [--pipeline pipelines/paper_two_link.toml]
        [--repeat 3] [--without-warm-up]

``--repeat N`` times N first runs, each with fresh caches and warm-up (the machine is
shared: the best is the figure, all are printed). ``--without-warm-up`` also times a first
run with empty caches and no warm-up (what a run costs that compiles everything itself).
The temporary folders are removed at the end; the user's own caches are never touched.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TARGET_S = 5.0


def child_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def timed(args: list[str], cwd: Path, env: dict[str, str]) -> tuple[float, float, list[str]]:
    """(wall seconds, CPU seconds of it and its children, stderr lines prefixed by the
    second they appeared) of ``python -m cosim.cli ARGS``."""
    cpu, began = child_cpu(), time.monotonic()
    child = subprocess.Popen([sys.executable, "-m", "cosim.cli", *args], cwd=cwd, env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines = [f"{time.monotonic() - began:6.2f} s  {line.rstrip()}" for line in child.stderr]
    if child.wait() != 0:
        raise SystemExit(f"cosim {' '.join(args)} failed:\n" + "\n".join(lines[-20:]))
    return time.monotonic() - began, child_cpu() - cpu, lines


def fresh_machine(tmp: Path) -> tuple[Path, dict[str, str]]:
    """A copy of the sources without bytecode, and an environment whose caches are empty
    folders under ``tmp``."""
    source = tmp / "src"
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for folder in ("cosim", "plant_fmu", "pipelines"):
        shutil.copytree(ROOT / folder, source / folder, ignore=ignore)
    env = {**os.environ, "PYTHONPATH": str(source), "NUMBA_CACHE_DIR": str(tmp / "numba"),
           "COSIM_CACHE": str(tmp / "fmus"), "COSIM_ENGINE_CACHE": str(tmp / "engine"),
           "MPLCONFIGDIR": str(tmp / "matplotlib")}
    return source, env


def show(title: str, wall: float, cpu: float, lines: list[str]) -> None:
    print(f"{title}: {wall:.2f} s wall ({cpu:.1f} s CPU with its processes); it printed:")
    print("\n".join(f"  {line}" for line in lines))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pipeline", default="pipelines/paper_two_link.toml")
    parser.add_argument("--repeat", type=int, default=1, metavar="N",
                        help="first runs to time, each on fresh caches (default 1)")
    parser.add_argument("--without-warm-up", action="store_true",
                        help="also time a first run on empty caches without the warm-up")
    args = parser.parse_args()
    run = ["run", args.pipeline, "--out"]
    set_ups, firsts = [], []
    for attempt in range(args.repeat):
        with tempfile.TemporaryDirectory(prefix="cosim_cold_") as tmp:
            source, env = fresh_machine(Path(tmp))
            wall, cpu, lines = timed(["warm-up", args.pipeline], source, env)
            set_ups.append(wall)
            show(f"[{attempt + 1}] set-up step (`cosim warm-up {args.pipeline}`, empty caches)",
                 wall, cpu, lines)
            wall, cpu, lines = timed([*run, str(Path(tmp) / "first")], source, env)
            firsts.append(wall)
            show(f"[{attempt + 1}] first run after it (`cosim {' '.join(run)} DIR`)", wall,
                 cpu, lines)
    if args.without_warm_up:
        with tempfile.TemporaryDirectory(prefix="cosim_cold_") as tmp:
            source, env = fresh_machine(Path(tmp))
            wall, cpu, lines = timed([*run, str(Path(tmp) / "cold")], source, env)
            show("a first run without the warm-up (empty caches: it compiles everything)",
                 wall, cpu, lines)
    print(f"set-up's warm-up step: {min(set_ups):.1f} s (best of {len(set_ups)}: "
          f"{', '.join(f'{s:.1f}' for s in set_ups)})")
    print(f"first run after the set-up: {min(firsts):.2f} s (best of {len(firsts)}: "
          f"{', '.join(f'{s:.2f}' for s in firsts)}); target ≤ {TARGET_S:g} s: "
          + ("met" if min(firsts) <= TARGET_S else "NOT met"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
