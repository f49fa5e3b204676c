"""The set-up's warm-up (`cosim warm-up`, cosim/warm.py): it compiles what a pipeline's runs
step and builds its FMU into the caches, after which the pipeline's first run compiles
nothing and says nothing of compiling; a second warm-up recognises the warm caches; and a
compile, when one happens, is announced module by module while it happens."""

from __future__ import annotations

import importlib.util
import io
import os
import subprocess
import sys
from pathlib import Path

from cosim import jit_cache

ROOT = Path(__file__).resolve().parent.parent
PD = "pipelines/pd_control.toml"  # few, small kernels: a short compile


def cosim(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)


def test_after_the_warm_up_a_first_run_compiles_nothing(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
           "COSIM_ENGINE_CACHE": str(tmp_path / "engine"), "COSIM_CACHE": str(tmp_path / "fmus"),
           "MPLCONFIGDIR": str(tmp_path / "matplotlib")}
    warm = cosim(["warm-up", PD, "--workers", "2"], env)
    assert warm.returncode == 0, warm.stderr[-3000:]
    # what it compiled, module by module, and the fused loop of the runs' chain
    assert "    cosim.paper.pd_controller: " in warm.stderr, warm.stderr
    assert "    the fused loop of " in warm.stderr, warm.stderr
    assert "cosim warm-up: done in " in warm.stderr
    assert list((tmp_path / "fmus").rglob("*.fmu")) and list((tmp_path / "engine").glob("*.py"))
    assert list((tmp_path / "numba").glob("warm-up-*.json"))

    again = cosim(["warm-up", PD], env)
    assert again.returncode == 0 and "the caches are warm" in again.stderr, again.stderr

    done = cosim(["run", PD, "--out", str(tmp_path / "run"), "--no-recording", "--no-figures",
                  "--set", "simulation.duration=0.05"], env)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "compiling" not in done.stderr, done.stderr  # neither the notice nor a module


def test_the_same_kernels_on_another_arm_are_another_fused_loop():
    """paper_safety.toml's and ur5.toml's proposed_cbf step the same kernels, on a planar and
    a spatial model: two fused loops to warm (the warm-up once kept the first alone, and the
    UR5's first filtered run compiled its loop after a warm-up that said it would not)."""
    from cosim.warm import _kernel_jobs

    modules, loops, _ = _kernel_jobs([ROOT / "pipelines/paper_safety.toml",
                                      ROOT / "pipelines/ur5.toml"])
    runs = {(Path(path).name, name) for path, name in loops}
    assert {("paper_safety.toml", "proposed_cbf"), ("ur5.toml", "proposed_cbf")} <= runs, runs
    assert len(modules["cosim.paper.cbf_filter.step"]) == 2  # cbf_step, planar and spatial


def test_the_filters_check_is_a_job_of_its_own_with_the_types_the_step_calls_it_with():
    """The filter names its check (Block.warm_parts) for a warm-up job of its own, compiled
    in another process while the step's other callees compile; the job is only worth its
    compile if the step then loads it from the cache: every signature the check was ever
    compiled with here (its cache index: the warm-up's parts and every run's steps, planar
    and spatial) is the part's, but for the arguments' record (a changed argument of
    ``verified`` would make the part a wasted compile, and this index two entries per arm)."""
    from numba import types

    from cosim.paper.cbf_filter.check import verified
    from cosim.warm import _kernel_jobs

    modules, _, _ = _kernel_jobs([ROOT / "pipelines/paper_safety.toml"])
    (name, part), = modules["cosim.paper.cbf_filter.check"]
    assert name == "verified" and part[0] == types.int64
    compiled = [key[0] for key in verified._cache._cache_file._load_index()]
    assert compiled, "the warm-up compiled no check"  # make test warms paper_safety first
    assert all(signature[0] == part[0] and signature[2:] == part[2:]
               for signature in compiled), compiled


def test_jobs_go_to_the_least_loaded_process_the_costliest_first():
    """The filter's step and its check, the two costliest, in two processes; the observer
    after the lighter of them (round robin would have put it after the step, in order of
    the list)."""
    from cosim.warm import _spread

    cost = {"step": 160, "observer": 100, "check": 115, "controller": 28, "sensor": 11}
    groups = _spread(list(cost), 2, cost.get)
    assert groups == [["step", "controller", "sensor"], ["check", "observer"]]
    assert _spread(["a", "b", "c"], 2) == [["a", "c"], ["b"]]  # without costs: round robin


def test_a_missing_pipeline_is_one_message(tmp_path):
    done = cosim(["warm-up", str(tmp_path / "nope.toml")], dict(os.environ))
    assert done.returncode == 2
    assert done.stderr.strip() == (f"cosim: error: {tmp_path / 'nope.toml'}: no such pipeline "
                                   "file; nothing was compiled")


def test_an_edited_urdf_is_not_warm(tmp_path):
    """The stamp is keyed by the content of the URDFs a pipeline names, through extends
    too: an edited URDF builds another FMU, so the caches of the old one are not warm."""
    from cosim.warm import stamp_path

    robot = tmp_path / "robot.urdf"
    robot.write_bytes((ROOT / "tests/urdf/slider_turret.urdf").read_bytes())
    (tmp_path / "base.toml").write_text('[plant.urdf]\nfile = "robot.urdf"\n')
    (tmp_path / "mine.toml").write_text('extends = "base.toml"\n')
    before = stamp_path(tmp_path / "mine.toml")
    assert stamp_path(tmp_path / "mine.toml") == before  # the same content, the same stamp
    robot.write_text(robot.read_text().replace("</robot>", "<!-- edited -->\n</robot>"))
    assert stamp_path(tmp_path / "mine.toml") != before


def test_a_compile_is_announced_module_by_module(tmp_path):
    """Each module of ours whose kernels compile gets a line with its seconds, its helpers
    counted with it; numba's own helpers (np.linalg here) are never named."""
    module = tmp_path / "probe_kernels.py"
    module.write_text("import numpy as np\nfrom numba import njit\n\n\n@njit\n"
                      "def helper(a):\n    return np.linalg.norm(a)\n\n\n@njit\n"
                      "def kernel(a):\n    return helper(a) + 1.0\n")
    spec = importlib.util.spec_from_file_location("probe_kernels", module)
    probe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(probe)
    stream = io.StringIO()
    import numpy as np

    with jit_cache.announce_compiles(stream) as compiled:
        assert probe.kernel(np.ones(3)) > 1.0
    lines = stream.getvalue().splitlines()
    assert compiled == ["probe_kernels"], lines
    assert lines[0].startswith("  compiling numba kernels"), lines
    assert len(lines) == 2 and lines[1].startswith("    probe_kernels: ") \
        and lines[1].endswith(" s"), lines
    stream.truncate(0)
    with jit_cache.announce_compiles(stream) as compiled:  # compiled already: silent
        probe.kernel(np.ones(3))
    assert compiled == [] and stream.getvalue() == ""
