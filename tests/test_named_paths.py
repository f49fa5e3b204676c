"""Paths a user names that are not what they should be, at every command that reads them:
an empty name (read as the folder it is relative to), a named pipe (opening one waits for a
writer: a hang), a device, a folder, a pipeline given where a recording is, a run name in an
edited summary.json that leads out of its folder. Each is one message naming the key or path
and what it is, at once, exit 2, and nothing of the user's is touched."""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import pytest
from cli_helpers import assert_message, error_line, here, tree

ROOT = Path(__file__).resolve().parents[1]
PD = ROOT / "pipelines" / "pd_control.toml"


def pipeline(folder: Path, text: str = "") -> Path:
    """``folder/p.toml``: the PD pipeline for 0.1 s, with ``text`` after."""
    path = folder / "p.toml"
    path.write_text(f'extends = "{PD}"\n[simulation]\nduration = 0.1\n{text}')
    return path


@pytest.mark.parametrize(("key", "shown"), [
    ("reference.csv", "reference.csv"), ("plant.fmu", "plant.fmu"),
    ("plant.urdf", "plant.urdf.file"), ("inertia_model.urdf", "inertia_model.urdf"),
    ("safety.urdf", "safety.urdf")])
def test_an_empty_file_name_is_refused_naming_its_key(key, shown, tmp_path):
    """An empty name was made relative to the pipeline's folder: that folder was then
    "not a CSV file", "no such URDF file" or the like."""
    table, name = key.split(".")
    path = pipeline(tmp_path, f'[{table}]\n{name} = ""\n')
    assert_message(error_line(here("run", str(path), "--dry-run")),
                   f"{path}: key '{shown}': String should have at least 1 character (got '')")


@pytest.mark.parametrize("kind", ["empty", "named pipe", "device"])
def test_what_extends_names_is_said_for_what_it_is(kind, tmp_path):
    """extends = "" read the pipeline's folder ("is a folder, not a pipeline file");
    /dev/zero was "no such pipeline file" (it exists)."""
    fifo = tmp_path / "base.toml"
    if kind == "named pipe":
        os.mkfifo(fifo)
    named = {"empty": "", "named pipe": str(fifo), "device": "/dev/zero"}[kind]
    path = tmp_path / "p.toml"
    path.write_text(f'extends = "{named}"\n')
    expected = {"empty": f"{path}: key 'extends' must be a file name (got '')",
                "named pipe": f"{fifo}: is a named pipe (FIFO), not a pipeline file (extended "
                              f"by {path})",
                "device": f"/dev/zero: is a device, not a pipeline file (extended by {path})"}
    assert_message(error_line(here("run", str(path), "--dry-run")), expected[kind])


def test_a_plugin_or_an_fmu_that_is_a_named_pipe_is_said_to_be_one(tmp_path):
    """Both were "no such file" or "does not exist"; the plugin's import would have waited."""
    os.mkfifo(tmp_path / "blocks.py")
    os.mkfifo(tmp_path / "plant.fmu")
    plugin = pipeline(tmp_path, "").parent / "q.toml"
    plugin.write_text(f'extends = "{PD}"\nplugins = ["blocks.py"]\n')
    assert_message(error_line(here("run", str(plugin), "--dry-run")),
                   f"plugins: {tmp_path / 'blocks.py'} is a named pipe (FIFO), not a .py file")
    fmu = pipeline(tmp_path, '[plant]\nfmu = "plant.fmu"\n')
    assert_message(error_line(here("run", str(fmu), "--dry-run")),
                   f"plant.fmu: {tmp_path / 'plant.fmu'} is a named pipe (FIFO), not an FMU "
                   "file")


@pytest.mark.parametrize("given", ["p.toml", "robot.urdf", "/dev/null"])
def test_view_of_what_is_not_a_recording_says_so(given, tmp_path):
    """A pipeline (or a URDF) given to `cosim view` was handed to Rerun: "To review
    p.toml: … run: rerun p.toml"."""
    pipeline(tmp_path)
    (tmp_path / "robot.urdf").write_text('<robot name="r"/>\n')
    named = given if given.startswith("/") else str(tmp_path / given)
    expected = {"p.toml": f"{named} is not a Rerun recording (a pipeline file: run it with "
                          f"cosim run {named}, then view its run folder): give a run folder or "
                          "an .rrd file",
                "robot.urdf": f"{named} is not a Rerun recording: give a run folder or an .rrd "
                              "file",
                "/dev/null": "/dev/null is a device, not a file: give a run folder or an .rrd "
                             "file"}
    assert_message(error_line(here("view", named)), expected[given])


def test_a_named_pipe_for_summary_json_hangs_no_command(tmp_path):
    """A folder whose summary.json is a named pipe: `run --force` into it, `view`, `export`
    and `compare` each read it and would have waited forever."""
    folder = tmp_path / "out"
    folder.mkdir()
    os.mkfifo(folder / "summary.json")
    path = pipeline(tmp_path)
    before = tree(tmp_path)
    assert_message(error_line(here("run", str(path), "--out", str(folder),
                                   "--force", "--no-recording", "--no-figures")),
                   f"--out {folder}: --force replaces only what cosim wrote, and this folder "
                   "holds 1 entry it did not write (summary.json); nothing was deleted: choose "
                   "another --out, or remove them yourself")
    for command, expected in (
            (["view"], f"{folder} has no recording.rrd (was it run with --no-recording?)"),
            (["export"], f"{folder}: not a cosim run folder (no summary.json of ours); give "
                         "the folder `cosim run --out` wrote"),
            (["compare", str(folder)], f"A {folder}: its summary.json cannot be read "
                                       f"({folder / 'summary.json'} is a named pipe (FIFO), "
                                       "not a file); give folders `cosim run --out` wrote, as "
                                       "it wrote them")):
        assert_message(error_line(here(command[0], str(folder), *command[1:])), expected)
    assert tree(tmp_path) == before


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A run folder of the PD pipeline (0.1 s, no recording, no figures)."""
    base = tmp_path_factory.mktemp("named")
    done = here("run", str(pipeline(base)), "--out", str(base / "run"), "--no-recording",
                "--no-figures")
    assert done.returncode == 0, done.stderr[-2000:]
    return base / "run"


def test_an_edited_summarys_run_name_leads_nowhere_outside_the_folder(finished, tmp_path):
    """A run named '../x' in summary.json (a shared folder, edited): export read
    trace_../x.npz and would write export_../x.csv, both outside the folder given a
    'trace_..' or 'export_..' folder inside it."""
    folder = tmp_path / "shared"
    shutil.copytree(finished, folder)
    summary = json.loads((folder / "summary.json").read_text())
    summary["runs"]["../x"] = summary["runs"]["pd_full_state"]
    (folder / "summary.json").write_text(json.dumps(summary))
    (folder / "trace_..").mkdir()
    shutil.copy(folder / "trace_pd_full_state.npz", folder / "trace_.." / "x.npz")
    (folder / "export_..").mkdir()
    before = tree(tmp_path)
    rule = ("run name '../x': use up to 64 letters, digits, '_', '-' and '.', starting with a "
            "letter or digit (it names files and recording entities)")
    assert_message(error_line(here("export", str(folder), "--format", "csv")),
                   f"{folder}: its summary.json names the {rule}")
    assert_message(error_line(here("compare", str(finished), str(folder))),
                   f"B {folder}: summary.json's runs: {rule}")
    assert tree(tmp_path) == before


def test_a_duration_of_1e300_s_is_refused_in_words_a_reader_can_count(tmp_path):
    """The refusal printed the row count as a 301-digit number."""
    message = error_line(here("run", str(pipeline(tmp_path)), "--dry-run", "--set",
                              "simulation.duration=1e300"))
    assert_message(message, re.compile(
        r"the traces would need 4\.8e\+296 GB \(2 run\(s\) × 1e\+303 rows of 30 values × 8 B\) "
        r"but [\d.e+]+ GB of memory is available.* \(at most 80% is used\); shorten "
        r"simulation\.duration \(1e\+300 s\) or lengthen simulation\.step \(0\.001 s\)"))


def test_a_urdf_joint_without_a_velocity_limit_is_named(tmp_path):
    """safety.limits = "urdf" over a URDF whose joint says velocity 0 (none): "a joint has
    no velocity limit" said which one only by the user's search."""
    from cosim.config import PipelineError
    from cosim.declared import Safety, joint_boxes

    urdf = tmp_path / "robot.urdf"
    inertial = ('<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" '
                'ixz="0" iyz="0"/></inertial>')
    urdf.write_text(
        f'<robot name="r"><link name="l0"/><link name="l1">{inertial}</link><link name="l2">'
        f'{inertial}</link><joint name="shoulder" type="revolute"><parent link="l0"/><child '
        'link="l1"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="5" velocity="2"/>'
        '</joint><joint name="elbow" type="revolute"><parent link="l1"/><child link="l2"/>'
        '<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="5" velocity="0"/></joint>'
        "</robot>")
    with pytest.raises(PipelineError) as caught:
        joint_boxes(Safety(limits="urdf", urdf=str(urdf)), 2)
    assert str(caught.value) == ('safety.limits = "urdf": joint 2 (elbow, <limit velocity> '
                                 "none or 0) has no velocity limit in the URDF; give "
                                 "safety.velocity_limit per joint, rad/s")
