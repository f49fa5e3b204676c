"""numba's cache of the kernels is versioned per kernel module: each module's kernels land in
a folder of their own, keyed by the module's source and the kernel modules it imports (none
beside them), and a changed kernel source makes a fresh process compile anew only that
module's kernels and those of the modules that import it, into new folders, the old ones
left as they were; the other kernels load from the cache untouched."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# A kernel module of the test's own, in the copied package: a kernel that calls another
# module's kernel (the planar chain's mass matrix), as the blocks and the fused loop do.
CALLER = '''"""A kernel calling another module's kernel (tests/test_kernel_cache.py)."""
import numpy as np
from numba import njit

from .inertia import planar_mass_matrix


@njit(cache=True)
def first_entry(q):
    out = np.empty((q.shape[0], q.shape[0]))
    ones = np.ones(q.shape[0])
    planar_mass_matrix(q, ones, ones, ones, np.zeros(q.shape[0]), out)
    return out[0, 0]
'''

# Compile (or load) three kernels in a fresh process; print each one's cache folder and
# how many of its signatures were loaded from the cache and how many compiled.
COMPILE = """
import json, numpy as np
from cosim.paper.sensor import SensorArgs, sensor_step
from cosim.dynamics.planar import planar_mass_matrix
from cosim.paper.cache_probe import first_entry
q = np.zeros((2, 2))
sensor_step(0, SensorArgs(q, np.zeros((2, 2)), 0.0, np.zeros((2, 2))))
planar_mass_matrix(np.zeros(2), np.ones(2), np.ones(2), np.ones(2), np.zeros(2),
                   np.empty((2, 2)))
first_entry(np.zeros(2))
print(json.dumps({f.py_func.__module__: [f.stats.cache_path, sum(f.stats.cache_hits.values()),
                                        sum(f.stats.cache_misses.values())]
                  for f in (sensor_step, planar_mass_matrix, first_entry)}))
"""
SENSOR, INERTIA, CALLER_MODULE = "cosim.paper.sensor", "cosim.dynamics.planar", \
    "cosim.paper.cache_probe"


def compile_in_fresh_process(source: Path, cache: Path) -> dict[str, tuple[Path, int, int]]:
    """module -> (its kernels' cache folder, signatures loaded, signatures compiled)."""
    env = {**os.environ, "PYTHONPATH": str(source), "NUMBA_CACHE_DIR": str(cache)}
    done = subprocess.run([sys.executable, "-c", COMPILE], capture_output=True, text=True,
                          env=env, cwd=source, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    return {module: (Path(folder), hits, misses)
            for module, (folder, hits, misses) in report.items()}


def entries(folder: Path) -> dict[Path, int]:
    """Every cache file (index and data) in ``folder``, with its modification time."""
    return {p: p.stat().st_mtime_ns for p in folder.glob("*.nb[ic]")}


def edit(path: Path) -> None:
    path.write_text(path.read_text() + "\n# an edit\n")


def test_a_changed_kernel_source_recompiles_only_its_kernels_in_a_fresh_process(tmp_path):
    source, cache = tmp_path / "src", tmp_path / "numba"
    ignore = shutil.ignore_patterns("__pycache__")
    for package in ("cosim", "plant_fmu"):
        shutil.copytree(ROOT / package, source / package, ignore=ignore)
    (source / "cosim" / "paper" / "cache_probe.py").write_text(CALLER)

    first = compile_in_fresh_process(source, cache)
    for module, (folder, hits, misses) in first.items():
        assert folder.parent == cache and folder.name.startswith(f"{module}-"), folder
        assert misses >= 1 and hits == 0, (module, hits, misses)  # compiled, not loaded
        assert entries(folder), list(cache.rglob("*"))
    folders = {folder for folder, _, _ in first.values()}
    assert len(folders) == 3  # a folder per kernel module
    # nothing of ours cached outside them (numba's own helpers are not cached at all)
    assert {p.parent for p in cache.rglob("*.nbi")} == folders
    before = {p: t for folder in folders for p, t in entries(folder).items()}

    # Unchanged sources: the same folders, every kernel loaded, no file rewritten.
    again = compile_in_fresh_process(source, cache)
    for module, (folder, hits, misses) in again.items():
        assert folder == first[module][0] and hits >= 1 and misses == 0, (module, again)
    assert {p: t for folder in folders for p, t in entries(folder).items()} == before

    # The sensor's source changes: only its kernel compiles, into a new folder.
    edit(source / "cosim" / "paper" / "sensor.py")
    third = compile_in_fresh_process(source, cache)
    assert third[SENSOR][0] != first[SENSOR][0] and third[SENSOR][0].parent == cache
    assert third[SENSOR][2] >= 1 and entries(third[SENSOR][0])  # compiled anew
    for module in (INERTIA, CALLER_MODULE):  # loaded as they were
        assert third[module][0] == first[module][0], (module, third)
        assert third[module][1] >= 1 and third[module][2] == 0, (module, third)
    assert {p: t for folder in folders for p, t in entries(folder).items()} == before

    # The planar chain's source changes: its kernels and its caller's compile anew (the
    # caller's machine code holds the callee's), the sensor's loads.
    edit(source / "cosim" / "dynamics" / "planar.py")
    fourth = compile_in_fresh_process(source, cache)
    for module in (INERTIA, CALLER_MODULE):
        assert fourth[module][0] not in (first[module][0], third[module][0]), (module, fourth)
        assert fourth[module][2] >= 1 and fourth[module][1] == 0, (module, fourth)
    assert fourth[SENSOR][0] == third[SENSOR][0]
    assert fourth[SENSOR][1] >= 1 and fourth[SENSOR][2] == 0
    assert {p: t for folder in folders for p, t in entries(folder).items()} == before


def test_a_fused_loop_is_versioned_by_the_kernels_it_calls(tmp_path, monkeypatch):
    """The generated loop imports its kernels by name: its folder's digest covers their
    modules' sources (and those they import), not only its own text."""
    from cosim import kernel_digest

    loop = tmp_path / "cosim_fused_probe.py"
    loop.write_text("from numba import njit\n\n"
                    "from cosim.paper.sensor import sensor_step as kernel_0\n"
                    "from cosim.paper.pd_controller import pd_step as kernel_1\n")
    monkeypatch.setattr(kernel_digest, "_closures", {})
    monkeypatch.setattr(kernel_digest, "_digests", {})
    closure = kernel_digest._closure("cosim_fused_probe", loop)
    # pd_controller calls the nominal model's kernels (cosim.dynamics, with what they import):
    # they are part of the loop's code; so is the layout its records reach kernels in
    # (cosim.records)
    assert closure == ("cosim.dynamics.model", "cosim.dynamics.planar", "cosim.dynamics.spatial",
                       "cosim.dynamics.spatial_forms", "cosim.numba_compat",
                       "cosim.paper.pd_controller", "cosim.paper.sensor", "cosim.records",
                       "cosim_fused_probe")
    digest = kernel_digest.module_digest("cosim_fused_probe", loop)
    assert kernel_digest.versioned_here("cosim_fused_probe", str(loop))
    import numpy

    # installed: numba's own way
    assert not kernel_digest.versioned_here("numpy.linalg", numpy.__file__)
    # a kernel module's digest changes with a callee's source, and with nothing else
    sensor = kernel_digest.module_digest("cosim.paper.sensor")
    monkeypatch.setattr(kernel_digest, "_digests", {})
    real = kernel_digest.module_file
    copy = tmp_path / "planar.py"
    copy.write_text(real("cosim.dynamics.planar").read_text() + "\n# an edit\n")
    monkeypatch.setattr(kernel_digest, "module_file",
                        lambda name: copy if name == "cosim.dynamics.planar" else real(name))
    assert kernel_digest.module_digest("cosim_fused_probe", loop) != digest
    assert kernel_digest.module_digest("cosim.paper.sensor") == sensor


def test_a_kernel_is_versioned_by_the_rows_it_indexes_with(monkeypatch):
    """The filter's kernels index their scratch by Rows classes of cosim/paper/cbf_filter/
    scratch.py, a module without numba (not in their closure): a row added, moved or
    renamed there changes the numbers numba froze into their machine code, so it changes
    their digest (an int imported from it always did)."""
    from cosim import kernel_digest
    from cosim.paper.cbf_filter import scratch
    from cosim.records import Rows

    monkeypatch.setattr(kernel_digest, "_digests", {})
    check = kernel_digest.module_digest("cosim.paper.cbf_filter.check")

    # the same rows, one added first: every number moves on
    Rollout = Rows("Rollout", ["ADDED", *(member.name for member in scratch.Rollout)])
    assert Rollout.Q == scratch.Rollout.Q + 1
    monkeypatch.setattr(scratch, "Rollout", Rollout)
    monkeypatch.setattr(kernel_digest, "_digests", {})
    assert kernel_digest.module_digest("cosim.paper.cbf_filter.check") != check


def test_a_kernel_that_cannot_be_cached_is_numbas_warning_naming_its_file(tmp_path):
    """A function of ours numba cannot cache (it reads a large global array: a dynamic
    global) runs, with numba's warning naming its file and line; the cache's locator once
    lacked the file numba reads there, and the run ended in an AttributeError."""
    (tmp_path / "big_global.py").write_text(
        "import numpy as np\nfrom numba import njit\n\nBIG = np.arange(3_000_000.0)\n\n\n"
        "@njit(cache=True)\ndef second():\n    return BIG[1]\n")
    script = ("import sys\nfrom cosim import jit_cache\njit_cache.use_versioned_cache()\n"
              f"sys.path.insert(0, {str(tmp_path)!r})\nimport big_global\n"
              "print(big_global.second())\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")},
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "1.0"
    assert f"{tmp_path / 'big_global.py'}:7" in done.stderr, done.stderr  # its decorator
    assert 'Cannot cache compiled function "second"' in done.stderr, done.stderr
