"""The first run on a fresh machine: `cosim run` of a pipeline with empty caches (numba's
kernels, the fused loops and the built FMU, in folders of their own), then the same run
again warm. Prints each run's wall time and every line it wrote to stderr with the second
it appeared, so it shows what a user sees while the kernels compile.

    .venv/bin/python benchmarks/cold_start.py [--pipeline pipelines/paper_two_link.toml]

The caches are temporary folders removed at the end; the user's own are never touched.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def timed_run(pipeline: str, out: Path, env: dict[str, str]) -> tuple[float, list[str]]:
    """(wall seconds, stderr lines prefixed by the second they appeared)."""
    began = time.monotonic()
    child = subprocess.Popen([sys.executable, "-m", "cosim.cli", "run", pipeline, "--out",
                              str(out)], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
    lines = [f"{time.monotonic() - began:6.1f} s  {line.rstrip()}" for line in child.stderr]
    if child.wait() != 0:
        raise SystemExit("the run failed:\n" + "\n".join(lines[-20:]))
    return time.monotonic() - began, lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pipeline", default="pipelines/paper_two_link.toml")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="cosim_cold_") as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": f"{tmp}/numba", "COSIM_CACHE": f"{tmp}/fmus",
               "COSIM_ENGINE_CACHE": f"{tmp}/engine"}
        cold, lines = timed_run(args.pipeline, Path(tmp) / "cold", env)
        print(f"cold (empty kernel and FMU caches): {cold:.1f} s; what it printed:")
        print("\n".join(f"  {line}" for line in lines))
        warm, _ = timed_run(args.pipeline, Path(tmp) / "warm", env)
        print(f"warm (the same command again): {warm:.1f} s; cold / warm = {cold / warm:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
