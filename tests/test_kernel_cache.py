"""numba's cache of the block kernels is versioned by every kernel source: the blocks'
kernels land in the versioned folder (none beside it), and a changed kernel source makes a
fresh process compile anew into another folder, the old one left as it was."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# Compile the sensor's kernel (cache=True) in a fresh process; print numba's cache folder.
COMPILE = """
import numba, numpy as np
from cosim.blocks.sensor import SensorArgs, sensor_step
q = np.zeros((2, 2))
sensor_step(0, SensorArgs(q, np.zeros((2, 2)), 0.0, np.zeros((2, 2))))
print(numba.config.CACHE_DIR)
"""


def compile_in_fresh_process(source: Path, cache: Path) -> Path:
    env = {**os.environ, "PYTHONPATH": str(source), "NUMBA_CACHE_DIR": str(cache)}
    done = subprocess.run([sys.executable, "-c", COMPILE], capture_output=True, text=True,
                          env=env, cwd=source, timeout=300, check=True)
    return Path(done.stdout.strip().splitlines()[-1])


def sensor_entries(folder: Path) -> set[Path]:
    return {p for p in folder.rglob("*.nbi") if "sensor_step" in p.name}


def test_a_changed_kernel_source_recompiles_in_a_fresh_process(tmp_path):
    source, cache = tmp_path / "src", tmp_path / "numba"
    ignore = shutil.ignore_patterns("__pycache__")
    for package in ("cosim", "plant_fmu"):
        shutil.copytree(ROOT / package, source / package, ignore=ignore)
    first = compile_in_fresh_process(source, cache)
    assert first.parent == cache and first.name != ""  # cache/<digest of the sources>
    entries = sensor_entries(first)
    assert entries, list(cache.rglob("*"))
    assert sensor_entries(cache) == entries  # nothing cached outside the versioned folder
    before = {p: p.stat().st_mtime_ns for p in entries}
    assert compile_in_fresh_process(source, cache) == first  # unchanged: the same folder

    kernel = source / "cosim" / "blocks" / "sensor.py"
    kernel.write_text(kernel.read_text() + "\n# an edit\n")
    second = compile_in_fresh_process(source, cache)
    assert second != first and second.parent == cache
    assert sensor_entries(second)  # compiled anew for the new sources
    assert {p: p.stat().st_mtime_ns for p in sensor_entries(first)} == before
