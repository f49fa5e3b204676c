"""Blocks from outside the package: the block guide of docs/extending.md run as written,
plugin files and modules named by a pipeline, the ``cosim.blocks`` entry point group, and
the one clear message for each way a user's block can be wrong."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet
import pytest
from cli_helpers import assert_message, error_line

ROOT = Path(__file__).resolve().parents[1]


def readme_guide() -> tuple[dict[str, str], list[str]]:
    """The custom-block section of docs/extending.md: its files (named by each block's
    first-line comment) and its shell commands, as written."""
    text = (ROOT / "docs" / "extending.md").read_text(encoding="utf-8")
    start = text.index("## Your own block, step by step")
    section = text[start:text.index("\n## ", start + 1)]
    files, commands = {}, []
    for language, body in re.findall(r"```(\w+)\n(.*?)```", section, re.S):
        if language == "sh":
            commands += [line for line in body.splitlines() if line.strip()]
        else:
            files[body.splitlines()[0].lstrip("# ").strip()] = body
    return files, commands


def cosim_in(folder: Path, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True,
                          text=True, timeout=600, cwd=folder, env=env)


def test_the_readmes_custom_block_guide_runs_as_written(tmp_path):
    files, commands = readme_guide()
    assert set(files) == {"my_blocks.py", "limited.toml"} and len(commands) == 2
    for name, body in files.items():
        (tmp_path / name).write_text(body, encoding="utf-8")
    outputs = []
    for command in commands:
        program, *args = shlex.split(command)
        assert program == "cosim"
        result = cosim_in(tmp_path, *args)
        assert result.returncode == 0, result.stderr[-3000:]
        outputs.append(result.stdout)
    # cosim params: the plugin's table, with the pipeline's value marked as changed
    assert outputs[0].strip() == "* torque_limiter.limit = 150.0" + " " * 20 + \
        "[number]  # N·m, per joint"
    folder = (tmp_path / "runs" / "limited" / "latest").resolve()
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["complete"] is True
    assert summary["pipeline"]["plugins"] == [str(tmp_path / "my_blocks.py")]
    limited = np.load(folder / "trace_limited.npz")
    asked, applied = limited["tau_controller"], limited["tau"]
    assert np.abs(asked).max() > 150  # the limiter had work to do ...
    np.testing.assert_array_equal(applied, np.clip(asked, -150.0, 150.0))  # ... and did it
    free = np.load(folder / "trace_free.npz")
    assert "tau_controller" not in free and np.abs(free["tau"]).max() > 150
    units = json.loads(str(limited["_units"]))
    assert units["tau"] == {"unit": "N·m", "description": "limited torque"}  # the plugin's
    assert units["tau_controller"]["unit"] == "N·m"


GAIN_BLOCK = '''
from cosim.blocks import Block, register_block
from cosim.config import Section
from cosim.signals import Signal


class Params(Section):
    factor: float = 0.5  # 1, applied to the torque


@register_block
class Gain(Block):
    kind = "{kind}"
    Params = Params

    def __init__(self, params, context):
        super().__init__(params, context)
        self.inputs = ("tau",)
        self.outputs = {{"tau": Signal("n", "N·m", "scaled torque", "{kind}/tau")}}

    def reset(self, ports):
        self.before, self.after = ports.inputs["tau"], ports.outputs["tau"]

    def step(self, k):
        {step}
        return True
'''
CHAIN = '["reference", "sensor", "inertia_model", "observer", "controller", "{kind}"]'


def gain_block(path: Path, kind: str, step: str = "self.after[k] = "
               "self.params.factor * self.before[k]") -> Path:
    path.write_text(GAIN_BLOCK.format(kind=kind, step=step), encoding="utf-8")
    return path


def test_plugins_add_up_through_extends_each_relative_to_its_own_file(tmp_path):
    from cosim.blocks import BLOCKS
    from cosim.config import load_pipeline

    (tmp_path / "base").mkdir()
    (tmp_path / "mine").mkdir()
    gain_block(tmp_path / "base" / "blocks.py", "plugin_gain_base")
    gain_block(tmp_path / "mine" / "blocks.py", "plugin_gain_mine")  # the same file name
    (tmp_path / "base" / "base.toml").write_text('plugins = ["blocks.py"]\n')
    (tmp_path / "mine" / "mine.toml").write_text(
        'extends = "../base/base.toml"\nplugins = ["blocks.py"]\n'
        f'[runs.a]\nblocks = {CHAIN.format(kind="plugin_gain_base")}\n'
        f'[runs.b]\nblocks = {CHAIN.format(kind="plugin_gain_mine")}\n'
        '[plugin_gain_mine]\nfactor = 0.25\n')
    pipeline = load_pipeline(tmp_path / "mine" / "mine.toml")
    assert pipeline.plugins == [str(tmp_path / "base" / "blocks.py"),
                                str(tmp_path / "mine" / "blocks.py")]
    assert pipeline.runs["b"].plugin_gain_mine.factor == 0.25
    assert pipeline.runs["a"].plugin_gain_base.factor == 0.5
    # Two modules, each registered once; loading the pipeline again imports nothing again.
    base, mine = BLOCKS["plugin_gain_base"], BLOCKS["plugin_gain_mine"]
    assert base.__module__ != mine.__module__
    assert base.__module__ in sys.modules and mine.__module__ in sys.modules
    load_pipeline(tmp_path / "mine" / "mine.toml")
    assert BLOCKS["plugin_gain_base"] is base and BLOCKS["plugin_gain_mine"] is mine


def test_one_pipelines_plugin_is_not_offered_to_another_in_the_same_process(tmp_path):
    """A process that loaded a pipeline with a plugin (a notebook, a sweep's worker, a test
    session) keeps the plugin's blocks registered; another pipeline's wiring message names
    only the blocks it may use, and the plugin's own pipeline still names its block; a
    pipeline that does not name the plugin cannot use its blocks."""
    from cosim.assemble import assemble_run
    from cosim.config import PipelineError, load_pipeline

    class TwoLinkArm:  # what assembly needs to know of a plant
        links, mapped = 2, frozenset({"q", "qdot", "M"})

    gain_block(tmp_path / "blocks.py", "plugin_gain_elsewhere")
    (tmp_path / "p.toml").write_text(f'extends = "{ROOT / "pipelines/paper_two_link.toml"}"\n'
                                     'plugins = ["blocks.py"]\n')
    no_tau = ['runs.proposed.blocks=["reference", "sensor", "inertia_model", "observer"]']
    hints = {}
    for pipeline in (tmp_path / "p.toml", ROOT / "pipelines/paper_two_link.toml"):
        with pytest.raises(PipelineError) as info:
            assemble_run(load_pipeline(pipeline, no_tau), "proposed", TwoLinkArm())
        hints[pipeline.name] = set(str(info.value).partition("produced by: ")[2]
                                   .rstrip(")").split(", "))
    assert "plugin_gain_elsewhere" in hints["p.toml"]
    paper = hints["paper_two_link.toml"]
    assert {"cbf_filter", "controller", "pd_controller"} <= paper  # the built-in ones
    assert not any(kind.startswith("plugin_") for kind in paper), paper
    # Nor may it run that plugin's block without naming the plugin, as in a fresh process.
    (tmp_path / "q.toml").write_text(
        f'extends = "{ROOT / "pipelines/paper_two_link.toml"}"\n'
        f'[runs.proposed]\nblocks = {CHAIN.format(kind="plugin_gain_elsewhere")}\n')
    with pytest.raises(PipelineError) as info:
        load_pipeline(tmp_path / "q.toml")
    message = str(info.value)
    assert "blocks: 'plugin_gain_elsewhere' is not a registered block (registered: " in message
    assert "plugin_gain_elsewhere," not in message and "plugin_gain_elsewhere)" not in message
    assert load_pipeline(tmp_path / "p.toml").plugins  # its own pipeline still loads


def test_a_plugin_block_runs_on_a_sweeps_dask_workers(tmp_path):
    """A worker process imports the plugin as it loads the pipeline (nothing is pickled
    across but the path)."""
    gain_block(tmp_path / "blocks.py", "plugin_gain_sweep")
    (tmp_path / "p.toml").write_text(
        'plugins = ["blocks.py"]\n[simulation]\nduration = 0.5\n'
        f'[runs.scaled]\nblocks = {CHAIN.format(kind="plugin_gain_sweep")}\n')
    result = cosim_in(tmp_path, "sweep", "p.toml", "--grid", "plugin_gain_sweep.factor=0.5,1",
                      "--workers", "1", "--out", "sweep", "--quiet")
    assert result.returncode == 0, result.stderr[-3000:]
    rows = pyarrow.parquet.read_table(tmp_path / "sweep" / "results.parquet").to_pylist()
    assert [row["status"] for row in rows] == ["ok", "ok"]
    by_factor = {row["set:plugin_gain_sweep.factor"]: row for row in rows}
    # Halving the controller's torque changes the run (a different peak torque).
    assert by_factor[0.5]["peak_torque.1"] != by_factor[1.0]["peak_torque.1"]


def test_an_installed_packages_entry_point_offers_its_blocks_to_every_pipeline(tmp_path):
    """A real distribution on sys.path (a .dist-info with entry_points.txt, as pip makes
    it), found through importlib.metadata: no pipeline names it."""
    site = tmp_path / "site"
    (site / "demo_blocks").mkdir(parents=True)
    gain_block(site / "demo_blocks" / "__init__.py", "entry_point_gain")
    info = site / "demo_blocks-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: demo-blocks\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[cosim.blocks]\ndemo = demo_blocks\n")
    env = {**os.environ, "PYTHONPATH": str(site)}
    listed = cosim_in(tmp_path, "params", "--grep", "entry_point_gain", env=env)
    assert listed.returncode == 0, listed.stderr
    assert listed.stdout.split() == ["entry_point_gain.factor", "=", "0.5", "[number]", "#",
                                     "1,", "applied", "to", "the", "torque"]
    chain = CHAIN.format(kind="entry_point_gain")
    (tmp_path / "p.toml").write_text("")  # the pipeline names no plugin
    dry = cosim_in(tmp_path, "run", "p.toml", "--set", f"runs.x.blocks={chain}", "--dry-run",
                   env=env)
    assert dry.returncode == 0, dry.stderr
    assert "entry_point_gain" in dry.stdout


def test_a_broken_entry_point_is_one_message_naming_it(tmp_path):
    site = tmp_path / "site"
    info = site / "broken-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[cosim.blocks]\nbroken = no_such_module\n")
    env = {**os.environ, "PYTHONPATH": str(site)}
    assert_message(error_line(cosim_in(tmp_path, "params", env=env)),
                   "entry point 'broken' = 'no_such_module' (group cosim.blocks): failed to "
                   "import: ModuleNotFoundError: No module named 'no_such_module'")


def test_each_way_a_plugin_can_be_wrong_is_one_message_naming_it(tmp_path):
    gain_block(tmp_path / "one.py", "plugin_twin")
    gain_block(tmp_path / "two.py", "plugin_twin")
    (tmp_path / "syntax.py").write_text("def broken(:\n")
    (tmp_path / "raises.py").write_text("\n\nraise RuntimeError('no licence server')\n")
    (tmp_path / "p.toml").write_text("")
    cases = [
        ('["missing.py"]', f"plugins: {tmp_path}/missing.py: no such file (a .py file is "
         "relative to the pipeline file that names it)"),
        ('["no_such_package.blocks"]', "plugins: no_such_package.blocks: failed to import: "
         "ModuleNotFoundError: No module named 'no_such_package'"),
        ('["raises.py"]', f"plugins: {tmp_path}/raises.py: failed to import: RuntimeError: "
         f"no licence server ({tmp_path}/raises.py, line 3, in <module>)"),
        ('["one.py", "two.py"]', f"plugins: {tmp_path}/two.py: failed to import: ValueError: "
         "a block of kind 'plugin_twin' is registered already (cosim_plugin_one_"
         f"{_digest(tmp_path / 'one.py')}.Gain) ({tmp_path}/two.py, line 11, in <module>)"),
        ('"one.py"', "--set plugins=\"one.py\": key 'plugins': Input should be a valid list "
         "(got 'one.py')"),  # the assignment at fault, not p.toml
    ]
    for plugins, expected in cases:
        result = cosim_in(tmp_path, "run", "p.toml", "--set", f"plugins={plugins}",
                          "--dry-run")
        assert_message(error_line(result), expected)
    syntax = error_line(cosim_in(tmp_path, "run", "p.toml", "--set", 'plugins=["syntax.py"]',
                                 "--dry-run"))
    assert syntax.startswith(f"cosim: error: plugins: {tmp_path}/syntax.py: failed to "
                             "import: SyntaxError: invalid syntax")


def _digest(path: Path) -> str:
    import hashlib

    return hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:8]


def test_a_block_that_raises_mid_run_stops_it_with_its_line_and_keeps_the_rows(tmp_path):
    gain_block(tmp_path / "blocks.py", "plugin_gain_late",
               step="self.after[k] = self.before[k] * (1 / (k < 300))")
    (tmp_path / "p.toml").write_text(
        'plugins = ["blocks.py"]\n[simulation]\nduration = 1.0\n'
        f'[runs.late]\nblocks = {CHAIN.format(kind="plugin_gain_late")}\n')
    result = cosim_in(tmp_path, "run", "p.toml", "--out", "run", "--no-figures")
    assert_message(error_line(result),
                   "the plugin gain late block raised at t = 0.3 s: ZeroDivisionError: "
                   f"division by zero ({tmp_path}/blocks.py, line 25, in step); what was "
                   "computed is kept in run; summary.json says what is incomplete")
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["complete"] is False
    assert summary["runs"]["late"]["metrics"]["simulated_time_s"] == 0.299
    trace = np.load(tmp_path / "run" / "trace_late.npz")
    assert len(trace["tau"]) == 300
    np.testing.assert_array_equal(trace["tau"], trace["tau_controller"])
