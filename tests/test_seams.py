"""The seams between run, compare, export, view, plugins, caches and the environment, as a
hostile user meets them: data loss, plugins' code, compare as a CI gate, export's files,
FMU archives and versions, caches, pipeline files. Each case asserts the whole message, the
exit status, and that nothing outside the run folder changed."""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from contextlib import chdir, redirect_stderr
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import PAPER, assert_message, error_line, here, tree

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
                        **{{name: Signal("1", "1", "a value", kept=True) for name in {names}}}}}

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


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A complete run folder: 0.5 s of the paper's two runs, no figures."""
    out = tmp_path_factory.mktemp("seams") / "run"
    done = here("run", PAPER, "--out", str(out), "--no-recording", *SHORT)
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
    done = here("run", PAPER, "--out", str(folder), "--force", "--no-recording", *SHORT)
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
    done = here("run", pipeline.name, "--run", "hostile", "--out", "out", "--no-figures",
                "--no-recording", cwd=tmp_path)
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
    done = here("run", pipeline.name, "--run", "hostile", "--out", "out", "--no-figures",
                "--no-recording", cwd=tmp_path)
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
        done = here(*command, cwd=tmp_path)
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
    done = here("run", pipeline.name, "--run", "hostile", "--out", "out", "--no-figures",
                "--no-recording", cwd=pipeline.parent)
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
        done = here("run", pipeline.name, "--run", "hostile", "--out", "out",
                    "--no-figures", "--no-recording", cwd=pipeline.parent)
        assert_message(error_line(done), f"run 'hostile': the {kind} block writes '{name}', "
                       f"{why}; rename that output")
        assert not (pipeline.parent / "out").exists()


@pytest.mark.parametrize("kind", ["runs", "plant", "safety", "robot"])
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
        "of a pipeline's own key (name, description, plugins, simulation, robot, plant, "
        "safety, uncertainty, runs, extends); a block's table would collide with it: choose "
        "another "
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
    from cosim.cli.supervisor import supervise

    err = io.StringIO()
    with redirect_stderr(err), chdir(tmp_path):
        os.environ["COSIM_STOP_GRACE_S"] = "abc"
        try:
            status = supervise(["run", str(ROOT / PAPER), "--out", "out"])
        finally:
            del os.environ["COSIM_STOP_GRACE_S"]
    done = subprocess.CompletedProcess([], status, "", err.getvalue())
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
    missing = here("run", str(ROOT / PAPER), "--set", 'plant.fmu="missing.fmu"', cwd=tmp_path)
    assert "missing.fmu" in error_line(missing)
    dead = here("run", str(ROOT / PAPER), "--connect", "rerun+http://127.0.0.1:9/proxy",
                cwd=tmp_path)
    assert error_line(dead).endswith("; nothing was run")
    assert tree(tmp_path) == before


# compare as a CI gate ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def others(finished, tmp_path_factory) -> dict[str, Path]:
    """Run folders to hold against ``finished`` (A), run side by side: the baseline's kv
    lowered (checks it already violated get worse), wider bounds, a shorter duration, and
    a run stopped early (diverged at 0.05 s)."""
    base = tmp_path_factory.mktemp("others")
    cases = {"worse": ["--set", "runs.baseline.controller.kv=15"],
             "wider": ["--set", "safety.velocity_bound=1000"],
             "shorter": ["--set", "simulation.duration=0.4"],
             "early": ["--set", 'observer.basis="lagged"', "--set", "observer.kp=10",
                       "--set", "observer.kd=10", "--set", "observer.nu=1.0"]}
    for name, extra in cases.items():
        done = here("run", PAPER, "--out", str(base / name), "--no-recording", *SHORT, *extra)
        assert done.returncode == (2 if name == "early" else 0), done.stderr[-2000:]
    return {name: base / name for name in cases}


def test_compare_refuses_what_is_not_like_with_like(finished, others):
    """Wider bounds, another duration, a run stopped early: no verdict, exit 2, and what
    differs named (a false 'no regression' before)."""
    a = finished
    expected = {
        "wider": "safety.velocity_bound 13.5 in A, 1000.0 in B; compare",
        "shorter": "simulation.duration 0.5 s in A, 0.4 s in B",
        "early": "run baseline stopped early in B (at 0.",
    }
    for name, differs in expected.items():
        b = others[name]
        message = error_line(here("compare", str(a), str(b)))
        head = (f"A {a} and B {b} do not compare like with like, so no verdict: ")
        assert message.startswith(f"cosim: error: {head}{differs}"), message
        assert message.endswith("; compare runs of the same duration and bounds that both ran "
                                "to their end")
    early = error_line(here("compare", str(a), str(others["early"])))
    # a run that diverges does not stop the others: B's proposed ran, and stopped early too
    assert re.search(r"run baseline stopped early in B \(at 0\.0\d+ s of 0\.5 s: the run "
                     r"diverged in the observer block at t = 0\.0\d+ s: a non-finite value\); "
                     r"run proposed stopped early in B \(at 0\.0\d+ s of 0\.5 s: .+\); "
                     r"compare", early), early


def test_compare_counts_a_worse_violation_once_with_a_tolerance_and_as_json(finished, others):
    a, b = finished, others["worse"]
    worse = here("compare", str(a), str(b), "--run", "baseline", "--run", "baseline")
    assert worse.returncode == 1, worse.stderr
    tail = worse.stdout.split("\n4 regression(s):\n")[1].splitlines()
    assert [line.split(":")[0].strip() for line in tail] == [
        "baseline/error_joint2", "baseline/error_norm", "baseline/error_rate_joint2",
        "baseline/error_rate_norm"]
    assert re.fullmatch(r"  baseline/error_joint2: violated in A \(2\.386 VIOLATED\) and "
                        r"worse in B \(2\.\d+ VIOLATED\)", tail[0])
    assert worse.stdout.count("\nrun baseline\n") == 1 and "run proposed" not in worse.stdout
    tolerated = here("compare", str(a), str(b), "--tolerance", "0.3", "--json")
    assert tolerated.returncode == 1, tolerated.stderr
    document = json.loads(tolerated.stdout)
    assert [r.split(":")[0] for r in document["regressions"]] == ["baseline/error_joint2"]
    check = document["runs"]["baseline"]["checks"]["error_joint2"]
    assert check["unit"] == "rad" and check["bound"] == 1.0 and check["change"] == "worse"
    assert check["b_minus_a"] == pytest.approx(check["b"] - check["a"])
    assert document["runs"]["proposed"]["checks"]["error_joint2"]["regression"] is False
    assert document["runs"]["baseline"]["metrics"]["wall_time_s"]["timing"] is True
    same = here("compare", str(a), str(a), "--json")
    assert same.returncode == 0 and json.loads(same.stdout)["regressions"] == []
    bad = error_line(here("compare", str(a), str(a), "--tolerance", "-1"))
    assert_message(bad, "--tolerance -1: expected a fraction of each check's bound ≥ 0, e.g. "
                   "0.01")


def test_compare_of_another_plant_says_so_and_still_judges_every_run(finished, others,
                                                                   tmp_path):
    """B's plant differs (another FMU): the note says so, and every run is judged all the
    same (once the note's labels replaced the run names: no run was compared, exit 0)."""
    b = tmp_path / "b"
    shutil.copytree(others["worse"], b)
    summary = json.loads((b / "summary.json").read_text())
    summary["plant"]["guid"] = "{another}"
    summary["plant"]["model_name"] = "AnotherArm"
    (b / "summary.json").write_text(json.dumps(summary))
    result = here("compare", str(finished), str(b))
    assert result.returncode == 1, result.stdout + result.stderr
    assert "note: the plants differ: A " in result.stdout and "B AnotherArm (" in result.stdout
    assert "\nrun baseline\n" in result.stdout and "\nrun proposed\n" in result.stdout
    assert "\n4 regression(s):\n" in result.stdout


# export --------------------------------------------------------------------------------------

def test_export_writes_its_own_temporary_never_a_planted_link(finished, tmp_path):
    folder = tmp_path / "run"
    shutil.copytree(finished, folder)
    victim = tmp_path / "victim.txt"
    victim.write_text("the user's")
    (folder / ".export_proposed.csv.tmp").symlink_to(victim)
    done = here("export", str(folder), "--format", "csv", "--run", "proposed")
    assert done.returncode == 0, done.stderr
    assert victim.read_text() == "the user's"
    assert (folder / "export_proposed.csv").read_text().startswith("time (s),")


def _rewrite_trace(folder: Path, run: str, change) -> None:
    """trace_<run>.npz with ``change(arrays, units)`` applied (a trace as another writer,
    or an older cosim, might have left it)."""
    path = folder / f"trace_{run}.npz"
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    units = json.loads(str(arrays.pop("_units")))
    change(arrays, units)
    with zipfile.ZipFile(path, "w") as archive:
        for key, values in {**arrays, "_units": np.array(json.dumps(units))}.items():
            with archive.open(f"{key}.npy", "w") as f:
                np.lib.format.write_array(f, values)


def test_export_mat_keeps_every_signal_under_a_name_matlab_accepts(finished, tmp_path):
    """Names MATLAB refuses (a leading '_', over 63 characters, non-ASCII) were dropped
    silently; now each is made valid and the file's ``names`` maps it back."""
    from scipy.io import loadmat

    folder = tmp_path / "run"
    shutil.copytree(finished, folder)
    odd = {"_private": "1", "a_signal_name_that_goes_on_and_on_" + "x" * 40: "m",
           "δ_über": "rad"}

    def add(arrays, units):
        for i, (name, unit) in enumerate(odd.items()):
            arrays[name] = np.full(len(arrays["time"]), float(i))
            units[name] = {"unit": unit, "description": f"odd name {i}"}

    _rewrite_trace(folder, "proposed", add)
    done = here("export", str(folder), "--format", "mat", "--run", "proposed",
                     "--out", str(tmp_path / "mat"))
    assert done.returncode == 0, done.stderr
    mat = loadmat(tmp_path / "mat" / "export_proposed.mat")
    names = {str(v[0]): k for k, v in zip(mat["names"].dtype.names, mat["names"][0, 0],
                                          strict=True)}
    units = mat["units"][0, 0]
    for i, (name, unit) in enumerate(odd.items()):
        key = names[name]
        assert re.fullmatch(r"[A-Za-z][A-Za-z0-9_]{0,62}", key), key
        np.testing.assert_array_equal(mat[key].ravel(), float(i))
        assert str(units[key][0]) == unit
    assert names["tau"] == "tau"  # a valid name stays as it is


def test_export_of_a_zero_row_a_damaged_and_a_traceless_run(finished, tmp_path):
    folder = tmp_path / "run"
    shutil.copytree(finished, folder)
    _rewrite_trace(folder, "baseline",
                   lambda arrays, units: arrays.update({k: v[:0] for k, v in arrays.items()}))
    done = here("export", str(folder), "--format", "csv", "--run", "baseline")
    assert done.returncode == 0, done.stderr
    assert len((folder / "export_baseline.csv").read_text().splitlines()) == 1  # the header
    trace = folder / "trace_proposed.npz"
    trace.write_bytes(trace.read_bytes()[:5000])
    damaged = error_line(here("export", str(folder), "--run", "proposed"))
    assert damaged.startswith(f"cosim: error: {trace}: cannot be read, it is damaged (")
    assert damaged.endswith("); run the pipeline again to rewrite it")
    trace.unlink()
    before = tree(folder)
    traceless = error_line(here("export", str(folder)))
    assert_message(traceless, f"{folder}: run proposed has no trace file (trace_proposed.npz "
                   "missing: the run was cut short before writing it, or it was deleted); "
                   "nothing was exported: export the others with --run baseline")
    assert tree(folder) == before
    unwritable = error_line(here("export", str(folder), "--run", "baseline",
                                      "--out", "/proc"))
    assert_message(unwritable, "/proc/export_baseline.parquet: could not be written (No such "
                   "file or directory); choose a writable folder with --out")


# FMUs: archives and versions -----------------------------------------------------------------

def test_a_zip_bomb_fmu_is_refused_before_a_byte_is_decompressed(plant_fmu, tmp_path,
                                                                  monkeypatch):
    """Reading the model description checked every entry's CRC first (decompressing a
    bomb whole: 7 s for 8 GB); now the size caps come first and the check streams."""
    from cosim.plant import unpack
    from cosim.plant.errors import FmuError
    from cosim.plant.mapping import read_description

    bomb = tmp_path / "bomb.fmu"
    with zipfile.ZipFile(plant_fmu(2, 2)) as src, \
            zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as out:
        for item in src.infolist():
            out.writestr(item, src.read(item.filename))
        out.writestr("resources/zeros.bin", bytes(50_000_000))
    monkeypatch.setattr(unpack, "MAX_MEGABYTES", 2)
    read = []
    original = zipfile.ZipExtFile.read
    monkeypatch.setattr(zipfile.ZipExtFile, "read",
                        lambda self, n=-1: read.append(self.name) or original(self, n))
    read_description(bomb)  # the description is read; the bomb is not
    assert "resources/zeros.bin" not in read
    with pytest.raises(FmuError) as caught:
        unpack.extract(bomb)
    assert str(caught.value) == (f"{bomb}: refusing to extract: it unpacks to 50 MB, more "
                                 "than the 2 MB cosim unpacks (set COSIM_FMU_MAX_MB to allow "
                                 "more)")
    assert "resources/zeros.bin" not in read


def test_an_fmi1_fmu_is_named_as_such(plant_fmu, tmp_path):
    old = tmp_path / "old.fmu"
    with zipfile.ZipFile(plant_fmu(2, 2)) as src, zipfile.ZipFile(old, "w") as out:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = re.sub(rb'fmiVersion="[^"]*"', b'fmiVersion="1.0"', data)
            out.writestr(item, data)
    done = here("run", PAPER, "--out", str(tmp_path / "out"), "--set",
                     f'plant.fmu="{old}"')
    assert_message(error_line(done), f"{old}: an FMI 1.0 FMU: FMI 1.0 is not supported; "
                   "export the model as FMI 2.0 or 3.0 Co-Simulation")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.fmu"]


# Caches and the environment ------------------------------------------------------------------

def test_a_damaged_numba_cache_entry_is_compiled_again(tmp_path):
    """One damaged cache file failed every run for good (UnpicklingError); now it is a
    miss: compiled again and rewritten."""
    script = tmp_path / "damage.py"
    script.write_text(
        "import importlib, os, sys\nfrom pathlib import Path\n"
        "sys.path.insert(0, os.getcwd())\n"
        "from cosim.jit_cache import use_versioned_cache\nuse_versioned_cache()\n"
        "Path('kern.py').write_text('from numba import njit\\n@njit(cache=True)\\n"
        "def f(x):\\n    return x + 1\\n')\n"
        "import kern\nassert kern.f(1) == 2\n"
        "for p in Path(os.environ['NUMBA_CACHE_DIR']).rglob('*.nbc'):\n"
        "    p.write_bytes(b'damaged')\n"
        "importlib.reload(kern)\nprint(kern.f(2))\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          cwd=tmp_path, timeout=300,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")})
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout == "3\n"


def test_a_truncated_fmu_in_the_build_cache_is_built_again(plant_fmu, tmp_path):
    from plant_fmu import build_fmu

    cached = plant_fmu(2, 2)
    cache = tmp_path / "fmus"
    cache.mkdir()
    copy = cache / cached.name
    copy.write_bytes(cached.read_bytes()[:20_000])  # a copy cut short
    assert build_fmu(links=2, fmi_version=2, cache_dir=cache) == copy
    with zipfile.ZipFile(copy) as archive:
        assert archive.testzip() is None
    assert copy.read_bytes() != cached.read_bytes()[:20_000]


def test_warm_up_names_a_cache_folder_it_cannot_write(tmp_path):
    done = here("warm-up", str(ROOT / PAPER), env={"NUMBA_CACHE_DIR": "/proc/cosim-cache"})
    assert_message(error_line(done), "the cache folder /proc/cosim-cache cannot be written (No "
                   "such file or directory); set NUMBA_CACHE_DIR to a writable folder; nothing "
                   "was compiled")


def test_the_memory_check_sees_the_address_space_limit(tmp_path):
    """Under ``ulimit -v`` the check passed (MemAvailable is the machine's) and the
    allocation failed with a traceback; now the limit is the one checked against."""
    import resource

    def limited():
        resource.setrlimit(resource.RLIMIT_AS, (3_000_000_000, resource.RLIM_INFINITY))

    done = subprocess.run([COSIM, "run", str(ROOT / PAPER), "--out", "out", "--no-recording",
                           "--no-figures", "--set", "simulation.duration=3000"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=300,
                          preexec_fn=limited)
    assert_message(error_line(done), re.compile(
        r"the traces would need 2\.45 GB \(2 run\(s\) × 3,000,001 rows of 51 values × 8 B\) "
        r"but [\d.]+ GB of memory is available under the address-space limit, ulimit -v \(at "
        r"most 80% is used\); shorten simulation\.duration \(3000 s\) or lengthen "
        r"simulation\.step \(0\.001 s\)"))
    assert list(tmp_path.iterdir()) == []


# Pipeline files ------------------------------------------------------------------------------

def test_a_typo_in_an_extended_file_is_named_against_that_file(tmp_path):
    (tmp_path / "base.toml").write_text("[controller]\nkvv = 3\n")
    (tmp_path / "top.toml").write_text('extends = "base.toml"\nname = "top"\n')
    done = here("params", "top.toml", cwd=tmp_path)
    assert_message(error_line(done), "base.toml (extended by top.toml): unknown key "
                   "'controller.kvv'; allowed keys here: variant, kv, lambda, f, g, kappa, kz, "
                   "z_b, z_wc, c0, c1, delta, psi_b, hidden, velocity, init, init_scale, seed, "
                   "scale")


def test_a_pipeline_file_with_a_byte_order_mark_reads_as_its_text(tmp_path):
    (tmp_path / "bom.toml").write_bytes("\ufeffname = \"bom\"\n".encode())
    done = here("run", "bom.toml", "--dry-run", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("pipeline bom: 1 run(s)")


# The newcomer's frictions --------------------------------------------------------------------

def test_version_python_m_cosim_quiet_and_the_overrides_in_the_header(tmp_path):
    from importlib.metadata import version

    python_m = run_in(tmp_path, "--version", program=(sys.executable, "-m", "cosim"))
    for done in (python_m, here("--version")):
        assert (done.returncode, done.stdout) == (0, f"cosim {version('cosim')}\n")
    quiet = here("run", str(ROOT / PAPER), "--out", "q", "--quiet", "--run", "proposed",
                 "--no-recording", *SHORT, cwd=tmp_path)
    assert quiet.returncode == 0 and quiet.stderr == "", quiet.stderr
    assert quiet.stdout.rstrip().endswith("run folder: q")
    told = here("run", str(ROOT / PAPER), "--out", "t", "--run", "proposed",
                "--no-recording", *SHORT, cwd=tmp_path)
    assert ("running paper_two_link with simulation.duration=0.5: proposed (0.5 s at 1000 Hz)"
            " -> t\n") in told.stderr


def test_view_of_a_sweep_folder_points_to_its_recorded_points(tmp_path):
    sweep = tmp_path / "sweep"
    (sweep / "best_proposed_point2").mkdir(parents=True)
    (sweep / "summary.json").write_text('{"complete": true, "kind": "sweep", '
                                        '"runs": ["proposed"], "provenance": {}}')
    done = here("view", str(sweep))
    assert_message(error_line(done), f"{sweep} is a sweep folder: its rows are in results.csv, "
                   "with no recording; run the sweep again with --record best,worst to record "
                   "each run's best and worst points")
    (sweep / "best_proposed_point2" / "recording.rrd").write_bytes(b"")
    done = here("view", str(sweep))
    assert_message(error_line(done), f"{sweep} is a sweep folder, with no recording of its "
                   f"own; view one of its recorded points: cosim view "
                   f"{sweep}/best_proposed_point2")


def test_a_viewer_that_fails_is_named_by_its_cause_not_its_backtrace():
    from cosim.outputs.viewer import viewer_failure

    stderr = ("\x1b[2m[2026-11-25T17:00:00Z WARN  re_renderer] Vulkan: no ICD found\x1b[0m\n"
              "thread 'main' panicked at crates/viewer/re_renderer/src/context.rs:231:14:\n"
              "Failed to create wgpu adapter: No graphics adapter was found\n"
              "stack backtrace:\n" + "".join(f"  {i}: rust_begin_unwind\n             at "
                                             f"/rustc/src/panicking.rs:{i}:5\n"
                                             for i in range(40)))
    assert viewer_failure(stderr) == ("Failed to create wgpu adapter: No graphics adapter was "
                                      "found")


def test_figures_keep_legends_off_the_data_and_torques_on_one_scale():
    """Five runs: the checks figure's legend sits above every panel (it covered data inside
    one); the torque panels share one scale, each legend beside its panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cosim.config import load_pipeline
    from cosim.outputs.figures import _checks_figure, _torque_figure, check_figures
    from cosim.runner import run

    extra = [f"runs.kv{kv}.controller.kv={kv}" for kv in (10, 30, 40)]
    pipeline = load_pipeline(PAPER, ["simulation.duration=0.3", *extra], warn=None)
    results = run(pipeline, None, progress=False, figures=False)
    assert len(results) == 5
    time = {n: r.trace.time for n, r in results.items()}
    checks = {n: r.evaluation.checks for n, r in results.items()}
    for columns in check_figures(checks).values():
        fig = _checks_figure(plt, columns, time, checks)
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        (legend,) = fig.legends
        box = legend.get_window_extent(renderer)
        assert set(results) <= {t.get_text() for t in legend.get_texts()}
        assert not any(box.overlaps(ax.get_window_extent(renderer)) for ax in fig.axes
                       if ax.axison)
        plt.close(fig)
    fig = _torque_figure(plt, time, {n: r.trace["tau"] for n, r in results.items()}, {})
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    assert len({ax.get_ylim() for ax in fig.axes}) == 1
    for ax in fig.axes:
        assert not ax.get_legend().get_window_extent(renderer).overlaps(
            ax.get_window_extent(renderer))
    plt.close(fig)


@pytest.mark.parametrize("variable", ["COSIM_CACHE", "COSIM_ENGINE_CACHE"])
def test_a_cache_folder_a_run_cannot_write_is_one_message(variable, tmp_path):
    done = here("run", str(ROOT / PAPER), "--out", "out", "--no-recording", cwd=tmp_path,
                env={variable: "/proc/cosim-cache"})
    assert_message(error_line(done), "the cache folder /proc/cosim-cache cannot be written (No "
                   f"such file or directory); set {variable} to a writable folder; nothing was "
                   "run")
    assert list(tmp_path.iterdir()) == []


def test_the_supervisor_knows_where_an_fmu_is_unpacked():
    from cosim.cli.supervisor import UNPACKED
    from cosim.plant.unpack import PREFIX

    assert UNPACKED == PREFIX


def test_a_reader_that_stops_early_ends_the_output_not_the_command(finished, others):
    """`cosim params | head`: a BrokenPipeError traceback before; and a compare piped so
    keeps its exit status (1: a regression), a gate even when its output is cut."""
    for args, status in ((["params", PAPER], 0),
                         (["compare", str(finished), str(others["worse"])], 1)):
        child = subprocess.Popen([sys.executable, "-m", "cosim.cli", *args],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        child.stdout.close()  # the reader is gone before the first line
        err = child.stderr.read()
        child.stderr.close()
        assert (child.wait(timeout=120), err) == (status, "")


def test_a_crash_before_the_run_starts_claims_nothing_kept_and_leaves_no_folder(tmp_path):
    """A plugin block whose constructor crashes the process (assembling, before the run
    folder is made): no "kept in" a folder that holds nothing, no empty runs/NAME/<time>."""
    pipeline = plugin(tmp_path, "plugin_early")
    source = (tmp_path / "plugin_early.py").read_text()
    (tmp_path / "plugin_early.py").write_text(source.replace(
        "        super().__init__(params, context)\n",
        "        super().__init__(params, context)\n        ctypes.string_at(0)\n"))
    done = run_in(tmp_path, "run", pipeline.name, "--run", "hostile", "--no-recording")
    assert_message(error_line(done), "the run process was killed by SIGSEGV, in a plugin's "
                   f"code ({tmp_path}/plugin_early.py, line 23, in __init__); nothing was "
                   "written (the run had not started)")
    assert list((tmp_path / "runs" / "plugin_early").iterdir()) == []


def test_view_of_a_folder_of_runs_names_one_to_view(tmp_path):
    base = tmp_path / "runs" / "paper"
    for name in ("20261125-100000", "20261125-110000"):
        (base / name).mkdir(parents=True)
        (base / name / "recording.rrd").write_bytes(b"")
    (base / "latest").symlink_to("20261125-100000", target_is_directory=True)
    assert_message(error_line(here("view", str(base))),
                   f"{base} holds run folders (2 with a recording), not a recording: view one, "
                   f"e.g. cosim view {base}/latest")


def test_a_bad_fmu_cap_in_the_environment_is_said_when_an_fmu_is_unpacked(plant_fmu,
                                                                         monkeypatch):
    """COSIM_FMU_MAX_MB=abc was a ValueError traceback at import, in every command."""
    from cosim.plant import unpack
    from cosim.plant.errors import FmuError

    monkeypatch.setenv("COSIM_FMU_MAX_MB", "abc")
    monkeypatch.setattr(unpack, "_BAD_CAPS", [])
    assert unpack._cap("COSIM_FMU_MAX_MB", 1024) == 1024
    with pytest.raises(FmuError) as caught:
        unpack.extract(plant_fmu(2, 2))
    assert str(caught.value) == (f"{plant_fmu(2, 2)}: refusing to extract: "
                                 "COSIM_FMU_MAX_MB='abc': expected a whole number > 0 (default "
                                 "1024)")


def test_the_notes_of_a_supervisor_killed_before_cleaning_up_are_removed(tmp_path):
    from cosim.cli.supervisor import NOTE_PREFIX, _remove_stale_notes

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    stale = [tmp_path / f"{NOTE_PREFIX}{dead}-abc{suffix}" for suffix in (".json", ".fault")]
    live = tmp_path / f"{NOTE_PREFIX}{os.getpid()}-def.json"
    users = tmp_path / f"{NOTE_PREFIX}{dead}-notes.txt"
    for path in (*stale, live, users):
        path.write_text("{}")
    _remove_stale_notes(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, users.name])


def test_a_plugin_that_changes_the_working_folder_does_not_move_the_run_folder(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    pipeline = plugin(tmp_path, "plugin_chdir")
    source = (tmp_path / "plugin_chdir.py").read_text()
    (tmp_path / "plugin_chdir.py").write_text(f"import os\nos.chdir({str(elsewhere)!r})\n"
                                              + source)
    done = here("run", pipeline.name, "--run", "hostile", "--out", "out", "--no-figures",
                "--no-recording", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "out" / "summary.json").is_file() and list(elsewhere.iterdir()) == []


def test_latest_stays_on_a_run_started_later(tmp_path):
    """Runs end in any order: latest names the last one started (a run that crashes or
    ends after a newer one has finished does not take it back)."""
    from cosim.outputs.run_folder import point_latest

    older, newer = tmp_path / "20261125-100000", tmp_path / "20261125-100000-2"
    older.mkdir()
    newer.mkdir()
    point_latest(newer)
    point_latest(older)
    assert os.readlink(tmp_path / "latest") == newer.name
    (tmp_path / "20261125-110000").mkdir()
    point_latest(tmp_path / "20261125-110000")
    assert os.readlink(tmp_path / "latest") == "20261125-110000"
