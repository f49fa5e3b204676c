"""Round three of the hostile catalogue (issue 33): the seams between run, compare, export,
view, plugins, caches and the environment. Each case asserts the whole message, the exit
status, and that nothing outside the run folder changed."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import PAPER, assert_message, cosim_cli, error_line

ROOT = Path(__file__).resolve().parents[1]
SHORT = ["--set", "simulation.duration=0.5", "--no-figures"]
COSIM = str(Path(sys.executable).parent / "cosim")  # the console script, as a user runs it

# A plugin block: its outputs and step are the case's. {outputs} maps each port to a
# Signal; {step} is the body of step(k).
PLUGIN = '''
import ctypes
import sys

import numpy as np

from cosim.blocks import Block, register_block
from cosim.config import Section
from cosim.signals import Signal


class Params(Section):
    factor: float = 1.0  # 1


@register_block
class Hostile(Block):
    kind = "{kind}"
    Params = Params

    def __init__(self, params, context):
        super().__init__(params, context)
        self.inputs = ("tau",)
        self.outputs = {{"tau": Signal("n", "N·m", "the torque, passed on", "{kind}/tau"),
                        **{{name: Signal("1", "1", "a plugin's value", kept=True) for name in {names}}}}}

    def reset(self, ports):
        self.ports = ports

    def step(self, k):
        self.ports.outputs["tau"][k] = self.ports.inputs["tau"][k]
        for name in {names}:
            self.ports.outputs[name][k] = k
{step}
'''
CHAIN = '["reference", "sensor", "inertia_model", "observer", "controller", "{kind}"]'


def plugin(folder: Path, kind: str, names: tuple[str, ...] = (),
           step: str = "        return True", duration: float = 0.2) -> Path:
    """``folder/p.toml``: the paper's pipeline, one run through the plugin block ``kind``
    (in ``folder/<kind>.py``)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{kind}.py").write_text(PLUGIN.format(kind=kind, names=repr(names), step=step),
                                       encoding="utf-8")
    pipeline = folder / "p.toml"
    pipeline.write_text(f'extends = "{ROOT / PAPER}"\nname = "{kind}"\n'
                        f'plugins = ["{kind}.py"]\n'
                        f"[simulation]\nduration = {duration}\n"
                        f'[runs.hostile]\nblocks = {CHAIN.format(kind=kind)}\n'
                        'controller = { variant = "baseline", kz = 0.1, z_b = 10.0 }\n',
                        encoding="utf-8")
    return pipeline


def run_in(folder: Path, *args: str, env: dict | None = None,
           program: tuple[str, ...] = (sys.executable, "-m", "cosim.cli")
           ) -> subprocess.CompletedProcess:
    return subprocess.run([*program, *args], capture_output=True, text=True, timeout=300,
                          cwd=folder, env=env)


def tree(folder: Path) -> dict[str, tuple[int, int]]:
    """Every entry under ``folder``: a file's or link's (size, modification time); a
    folder's (0, 0) (its time moves when an entry comes and goes)."""
    return {str(p.relative_to(folder)): (0, 0) if p.is_dir() and not p.is_symlink()
            else (p.lstat().st_size, p.lstat().st_mtime_ns) for p in sorted(folder.rglob("*"))}


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A complete run folder: 0.5 s of the paper's two runs, no figures."""
    out = tmp_path_factory.mktemp("round3") / "run"
    done = cosim_cli("run", PAPER, "--out", str(out), "--no-recording", *SHORT)
    assert done.returncode == 0, done.stderr[-2000:]
    return out


# Data loss -----------------------------------------------------------------------------------

def test_force_replaces_only_what_the_folders_summary_lists(finished, tmp_path):
    """--force: files whose names merely look like cosim's (a figure, a trace, an export, a
    temporary) and a copy of an earlier run kept inside are the user's: refused, untouched."""
    folder = tmp_path / "run"
    shutil.copytree(finished, folder)
    for name in ("fig_final_for_paper.png", "trace_backup_do_not_delete.npz",
                 "export_my_measurements.csv", ".notes.tmp"):
        (folder / name).write_text("the user's")
    shutil.copytree(finished, folder / "earlier_run")
    before = tree(folder)
    done = cosim_cli("run", PAPER, "--out", str(folder), "--force", "--no-recording", *SHORT)
    assert_message(error_line(done),
                   f"--out {folder}: --force replaces only what cosim wrote, and this folder "
                   "holds 5 entries it did not write (.notes.tmp, earlier_run, "
                   "export_my_measurements.csv, fig_final_for_paper.png, "
                   "trace_backup_do_not_delete.npz); nothing was "
                   "deleted: choose another --out, or remove them yourself")
    assert tree(folder) == before


def test_a_plugin_block_that_segfaults_is_named_and_only_its_own_folder_marked(tmp_path):
    """The run process dies by SIGSEGV in a plugin's step: the supervisor names the plugin's
    line (not the plant), marks the crashed run's own summary, points latest at it; the
    user's own ``latest/`` folder (a copy) is left alone."""
    pipeline = plugin(tmp_path, "plugin_crash",
                      step="        if k == 50:\n            ctypes.string_at(0)\n"
                           "        return True")
    users_latest = tmp_path / "runs" / "plugin_crash" / "latest"
    users_latest.mkdir(parents=True)
    (users_latest / "summary.json").write_text('{"complete": true, "runs": {}}')
    before = tree(users_latest)
    done = run_in(tmp_path, "run", pipeline.name, "--run", "hostile", "--no-figures",
                  "--no-recording")
    runs = [p for p in (tmp_path / "runs" / "plugin_crash").iterdir() if p.name != "latest"]
    assert len(runs) == 1
    crashed = runs[0].relative_to(tmp_path)
    assert_message(error_line(done),
                   "the run process was killed by SIGSEGV, in a plugin's code "
                   f"({tmp_path}/plugin_crash.py, line 35, in step); what was computed is kept "
                   f"in {crashed} (summary.json marked crashed)")
    summary = json.loads((tmp_path / crashed / "summary.json").read_text())
    assert summary["status"] == "crashed" and summary["complete"] is False
    assert summary["error"] == ("the run process was killed by SIGSEGV in a plugin's code "
                                f"({tmp_path}/plugin_crash.py, line 35, in step)")
    assert tree(users_latest) == before


def test_sys_exit_in_a_blocks_step_stops_the_run_with_its_line(tmp_path):
    """SystemExit in a block's step is the block failing, not the command ending (exit 0,
    no message, the run gone from the summary)."""
    pipeline = plugin(tmp_path, "plugin_exit",
                      step="        if k == 100:\n            sys.exit(0)\n        return True")
    done = run_in(tmp_path, "run", pipeline.name, "--run", "hostile", "--out", "out",
                  "--no-figures", "--no-recording")
    assert_message(error_line(done),
                   f"the plugin exit block raised at t = 0.1 s: SystemExit: 0 ({tmp_path}/"
                   "plugin_exit.py, line 35, in step); what was computed is kept in out; "
                   "summary.json says what is incomplete")
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["status"] == "incomplete"
    assert summary["runs"]["hostile"]["metrics"]["simulated_time_s"] == pytest.approx(0.099)
    with np.load(tmp_path / "out" / "trace_hostile.npz") as trace:
        assert len(trace["tau"]) == 100


def test_a_step_returning_false_is_named_as_such_not_as_divergence(tmp_path):
    pipeline = plugin(tmp_path, "plugin_false",
                      step="        return k < 20")
    done = run_in(tmp_path, "run", pipeline.name, "--run", "hostile", "--out", "out",
                  "--no-figures", "--no-recording")
    assert_message(error_line(done),
                   "the plugin false block stopped the run at t = 0.02 s: its step returned False "
                   "(a block's step returns True to go on; False, or nothing, stops the run); "
                   "what was computed is kept in out; summary.json says what is incomplete")


# Plugins: what their code can do to a command --------------------------------------------

def test_a_plugin_that_calls_sys_exit_at_import_is_one_message(tmp_path):
    """sys.exit(0) at a plugin's import no longer ends run or params with status 0 and
    nothing done; the command says which plugin, and that it imports it."""
    (tmp_path / "quits.py").write_text("import sys\n\nsys.exit(0)\n")
    (tmp_path / "p.toml").write_text('plugins = ["quits.py"]\n')
    for command in (["run", "p.toml", "--out", "out"], ["params", "p.toml"]):
        done = run_in(tmp_path, *command)
        assert done.stderr.startswith(f"cosim: importing plugin {tmp_path}/quits.py (its code "
                                      "runs now)\n")
        assert_message(error_line(done),
                       f"plugins: {tmp_path}/quits.py: failed to import: it called "
                       f"sys.exit(0) ({tmp_path}/quits.py, line 3, in <module>); a plugin must "
                       "only define and register its blocks")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.toml", "quits.py"]


def test_a_plugin_that_segfaults_at_import_leaves_the_supervisor_to_say_so(tmp_path):
    (tmp_path / "crashes.py").write_text("import ctypes\n\nctypes.string_at(0)\n")
    (tmp_path / "p.toml").write_text('plugins = ["crashes.py"]\n')
    done = run_in(tmp_path, "run", "p.toml")
    assert_message(error_line(done),
                   f"the run process was killed by SIGSEGV in a plugin's code ({tmp_path}/"
                   "crashes.py, line 3, in <module>), before any run folder was made; nothing "
                   "was run or written")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["crashes.py", "p.toml"]


def test_plugin_signal_names_the_trace_cannot_hold_are_refused_before_the_run(tmp_path):
    """``file`` and ``allow_pickle`` are plain names now (kept in the trace); ``time``,
    ``_units`` and ``check_*`` are the trace file's own: refused, naming the block."""
    pipeline = plugin(tmp_path / "fine", "plugin_names", names=("file", "allow_pickle"))
    done = run_in(pipeline.parent, "run", pipeline.name, "--run", "hostile", "--out", "out",
                  "--no-figures", "--no-recording")
    assert done.returncode == 0, done.stderr[-2000:]
    with np.load(pipeline.parent / "out" / "trace_hostile.npz") as trace:
        np.testing.assert_array_equal(trace["allow_pickle"], np.arange(201))
        np.testing.assert_array_equal(trace["file"], np.arange(201))
    clash = ("the trace file's own ('check_', 'barrier_', '_': the checks', the barriers' "
             "values, the units)")
    for name, why in (("time", "the name of the trace's time column"),
                      ("_units", f"and names starting with '_' are {clash}"),
                      ("check_mine", f"and names starting with 'check_' are {clash}")):
        kind = f"plugin_{name.strip('_')}"
        pipeline = plugin(tmp_path / kind, kind, names=(name,))
        done = run_in(pipeline.parent, "run", pipeline.name, "--run", "hostile", "--out",
                      "out", "--no-figures", "--no-recording")
        assert_message(error_line(done), f"run 'hostile': the {kind} block writes '{name}', "
                       f"{why}; rename that output")
        assert not (pipeline.parent / "out").exists()


@pytest.mark.parametrize("kind", ["runs", "plant", "safety"])
def test_a_plugin_block_kind_may_not_take_a_pipeline_key(kind, tmp_path):
    from cosim.blocks.plugins import load_plugins
    from cosim.schema import PipelineError

    source = PLUGIN.format(kind=kind, names="()", step="        return True")
    path = tmp_path / f"kind_{kind}.py"
    path.write_text(source, encoding="utf-8")
    with pytest.raises(PipelineError) as caught:
        load_plugins([str(path)])
    assert str(caught.value) == (
        f"plugins: {path}: failed to import: ValueError: Hostile.kind = {kind!r} is the name "
        "of a pipeline's own key (name, description, plugins, simulation, plant, safety, "
        "uncertainty, runs, extends); a block's table would collide with it: choose another "
        f"kind ({path}, line 16, in <module>)")


def test_the_run_process_does_not_import_the_working_folders_modules(tmp_path):
    """`cosim run` starts its run process without the working folder on the module path: a
    random.py or json.py there does not shadow the standard library."""
    for name in ("random.py", "json.py"):
        (tmp_path / name).write_text("raise RuntimeError('shadowed the standard library')\n")
    done = run_in(tmp_path, "run", str(ROOT / PAPER), "--out", "out", "--no-recording",
                  *SHORT, program=(COSIM,))
    assert done.returncode == 0, done.stderr[-2000:]
    assert "shadowed" not in done.stderr


def test_a_bad_stop_grace_is_one_message_before_anything_runs(tmp_path):
    done = run_in(tmp_path, "run", str(ROOT / PAPER), "--out", "out",
                  env={**os.environ, "COSIM_STOP_GRACE_S": "abc"})
    assert_message(error_line(done), "COSIM_STOP_GRACE_S='abc': expected a number of seconds "
                   "> 0 (default 10); nothing was run")
    assert list(tmp_path.iterdir()) == []


def test_a_refused_run_without_out_leaves_no_folder_and_latest_as_it_was(finished, tmp_path):
    """A run refused before writing anything (a missing plant FMU, a dead --connect) says
    nothing was run and means it: no empty runs/NAME/<time>, latest not moved."""
    base = tmp_path / "runs" / "paper_two_link"
    base.mkdir(parents=True)
    shutil.copytree(finished, base / "earlier")
    (base / "latest").symlink_to("earlier", target_is_directory=True)
    before = tree(tmp_path)
    missing = run_in(tmp_path, "run", str(ROOT / PAPER), "--set", 'plant.fmu="missing.fmu"')
    assert "missing.fmu" in error_line(missing)
    dead = run_in(tmp_path, "run", str(ROOT / PAPER), "--connect",
                  "rerun+http://127.0.0.1:9/proxy")
    assert error_line(dead).endswith("; nothing was run")
    assert tree(tmp_path) == before
