"""`cosim sweep --resume` against a folder or files changed since the sweep began: the files
its points name are hashed into sweep.json and a changed one is refused by name; a journal
(rows.jsonl) that repeats a row counts it once; one with a damaged line, a row of another
sweep, a named pipe or a link in its place is refused naming the line or what it is, with
nothing of the folder touched; and what every pipeline's named file is, by key."""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from cli_helpers import assert_message, error_line, here, tree

ROOT = Path(__file__).resolve().parents[1]
PD = ROOT / "pipelines" / "pd_control.toml"


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def swept(tmp_path_factory) -> tuple[Path, list[str]]:
    """A finished sweep of the PD pipeline for 0.1 s along a CSV reference (2 points, the
    full-state run): its folder's parent (with the pipeline and the CSV), and the command
    without --out."""
    base = tmp_path_factory.mktemp("resume")
    rows = "".join(f"{t / 100:g},{0.1 * t / 30:.6f},{-0.1 * t / 30:.6f}\n" for t in range(31))
    (base / "traj.csv").write_text("t,q1,q2\n" + rows)
    (base / "csvp.toml").write_text(
        f'extends = "{PD}"\n[simulation]\nduration = 0.1\n[reference]\ncsv = "traj.csv"\n'
        "safe_centre = [0.0, 0.0]\nsafe_velocity_centre = [0.0, 0.0]\n")
    command = ["sweep", str(base / "csvp.toml"), "--grid", "pd_controller.kp=100,200",
               "--runs", "pd_full_state", "--workers", "1", "--quiet"]
    done = here(*command, "--out", str(base / "sweep"))
    assert done.returncode == 0, done.stderr[-3000:]
    return base, command


@pytest.fixture
def copy(swept, tmp_path) -> Path:
    """A copy of the finished sweep's folder to change."""
    shutil.copytree(swept[0] / "sweep", tmp_path / "sweep")
    return tmp_path / "sweep"


def journal_lines(folder: Path) -> list[bytes]:
    return (folder / "rows.jsonl").read_bytes().splitlines(keepends=True)


def test_sweep_json_holds_the_digest_of_every_file_the_sweep_names(swept):
    base, _ = swept
    files = json.loads((base / "sweep" / "sweep.json").read_text())["files"]
    expected = [("reference.csv", base / "traj.csv"), ("the pipeline file", base / "csvp.toml"),
                ("extends", PD)]
    assert sorted(files, key=lambda e: e["path"]) == sorted(
        ({"key": key, "path": str(path), "sha256": digest(path),
          "bytes": path.stat().st_size} for key, path in expected), key=lambda e: e["path"])


def test_a_resume_after_a_named_file_changed_is_refused_by_its_name(swept, copy):
    """The false success of the catalogue: a reference CSV edited between a sweep and its
    --resume mixed two experiments in one table under the same keys."""
    base, command = swept
    csv = base / "traj.csv"
    before_file, before_folder = csv.read_bytes(), tree(copy)
    old = digest(csv)
    try:
        csv.write_bytes(before_file.replace(b"0.1,0.033333", b"0.1,0.034"))
        new = digest(csv)
        message = error_line(here(*command, "--resume", str(copy)))
    finally:
        csv.write_bytes(before_file)
    assert_message(message, f"--resume {copy}: not the same sweep as the one started there; it "
                   f"differs in the file reference.csv {csv} (its content changed: sha256 "
                   f"{old[:12]}… then, {new[:12]}… now). Resume with the same command and files, "
                   "or start a new sweep in another --out")
    assert tree(copy) == before_folder


def test_a_repeated_journal_row_is_counted_once_and_said(swept, copy):
    """A row appended twice (point 0's) counted twice in every rate before; now the first
    is kept, the repeat named by its line and left in the journal (nothing is deleted)."""
    _, command = swept
    lines = journal_lines(copy)
    (copy / "rows.jsonl").write_bytes(b"".join([*lines, lines[0]]))
    done = here(*command, "--resume", str(copy))
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"cosim: warning: {copy / 'rows.jsonl'}: line 3 repeats the row of point 0, run " \
        "pd_full_state (line 1): left out\n" in done.stderr
    assert f"2 row(s) in {copy / 'results.parquet'} and results.csv" in done.stdout
    rows = pq.read_table(copy / "results.parquet").to_pylist()
    assert [(r["point"], r["run"]) for r in rows] == [(0, "pd_full_state"), (1, "pd_full_state")]
    assert journal_lines(copy) == [*lines, lines[0]]


def _row(lines: list[bytes], index: int, **changes) -> bytes:
    return (json.dumps({**json.loads(lines[index]), **changes}) + "\n").encode()


DAMAGED = {
    "cut mid-way": (lambda lines: [lines[0][:40] + b"\n", lines[1]],
                    "line 1 is not a JSON row (Expecting ',' delimiter at its end)"),
    "not UTF-8": (lambda lines: [*lines, b"\xff\xfe\n"], "line 3 is not UTF-8 text (byte 0)"),
    "unknown point": (lambda lines: [*lines, _row(lines, 0, point=99)],
                      "line 3 is a row of point 99, which this sweep has not (points 0 to 1)"),
    "unknown run": (lambda lines: [*lines, _row(lines, 0, run="nosuch")],
                    'line 3 is a row of run "nosuch", which this sweep does not run '
                    "(pd_full_state)"),
    "another point's values": (lambda lines: [lines[0], _row(lines, 1, **{
        "set:pd_controller.kp": 100})], "line 2 is a row of point 1 whose values are not "
        "that point's"),
}


@pytest.mark.parametrize("case", DAMAGED)
def test_a_damaged_journal_is_refused_naming_the_line_and_nothing_is_touched(swept, copy,
                                                                             case):
    """Each was a traceback (a row of an unknown point also left summary.json "running")."""
    _, command = swept
    change, why = DAMAGED[case]
    (copy / "rows.jsonl").write_bytes(b"".join(change(journal_lines(copy))))
    before = tree(copy)
    message = error_line(here(*command, "--resume", str(copy)))
    assert_message(message, f"--resume {copy}: {copy / 'rows.jsonl'} holds 1 line that is not "
                   f"a row of this sweep ({why}); nothing was run: remove it and resume (its "
                   "point is then run again), or start a new sweep in another --out")
    assert tree(copy) == before
    assert json.loads((copy / "summary.json").read_text())["status"] == "complete"


def test_a_journal_line_no_row_could_be_is_refused_unread(swept, copy):
    """A line of 65 MiB (no newline in it) was read whole into memory, then failed to parse."""
    _, command = swept
    with (copy / "rows.jsonl").open("ab") as journal:
        journal.write(b"x" * (65 * 2**20) + b"\n")
    before = tree(copy)
    assert_message(error_line(here(*command, "--resume", str(copy))),
                   f"--resume {copy}: {copy / 'rows.jsonl'} holds a line longer than 64 MiB "
                   "(line 3), which no row is; nothing was run: remove it and resume (its "
                   "point is then run again), or start a new sweep in another --out")
    assert tree(copy) == before


@pytest.mark.parametrize("kind", ["named pipe", "link"])
def test_a_journal_that_is_not_a_file_is_refused_without_blocking(swept, copy, tmp_path,
                                                                   kind):
    """A named pipe hung --resume forever; a link to a user's file would be cut and
    appended to."""
    _, command = swept
    journal = copy / "rows.jsonl"
    journal.unlink()
    users = tmp_path / "notes.txt"
    users.write_text("the user's own\n")
    if kind == "named pipe":
        os.mkfifo(journal)
    else:
        journal.symlink_to(users)
    before = tree(copy)
    message = error_line(here(*command, "--resume", str(copy)))
    what = "is a named pipe (FIFO), not a file" if kind == "named pipe" else \
        "is a symbolic link"
    assert_message(message, f"--resume {copy}: {journal} {what}: a sweep's rows are a file "
                   "cosim writes; nothing was run: remove it (every point is then run again), "
                   "or start a new sweep in another --out")
    assert tree(copy) == before and users.read_text() == "the user's own\n"


def test_a_sweep_json_of_an_older_cosim_is_resumed_with_a_warning(swept, copy):
    _, command = swept
    spec = json.loads((copy / "sweep.json").read_text())
    del spec["files"]
    (copy / "sweep.json").write_text(json.dumps(spec))
    done = here(*command, "--resume", str(copy))
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"cosim: warning: --resume {copy}: its sweep.json (an older cosim's) holds no " \
        "digest of the files the sweep names (reference CSVs, URDFs, plugins, FMUs): they " \
        "are taken to be unchanged\n" in done.stderr


def test_a_resume_while_another_holds_the_folder_names_resume(swept, copy):
    _, command = swept
    with (copy / ".cosim.lock").open("a+") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        lock.write("4242")
        lock.flush()
        message = error_line(here(*command, "--resume", str(copy)))
    assert_message(message, f"--resume {copy}: another cosim run is writing this folder (pid "
                   "4242); wait for it, or choose another --out")


def test_a_file_only_a_later_point_names_is_refused_before_anything_runs(swept, tmp_path):
    """--grid reference.csv with a missing file at point 1: only point 0 was assembled up
    front, so point 1 became a failed row after the work, exit 0."""
    base, command = swept
    grid = ["--grid", 'reference.csv="traj.csv","gone.csv"']
    message = error_line(here(*command[:2], *grid, *command[4:], "--out", str(tmp_path / "o")))
    assert_message(message, f'point 1 (reference.csv="gone.csv"): reference.csv: '
                   f"{base / 'gone.csv'} does not exist")
    assert not (tmp_path / "o").exists()


def test_every_file_a_pipeline_names_is_listed_by_its_key(tmp_path):
    """The plant's URDF and its mesh, a plugin, the nominal model's and the safe sets' URDF,
    a run's own CSV, the pipeline and what it extends: each by the key that names it."""
    from cosim.config import load_pipeline
    from cosim.config.named_files import file_digests, named_files

    urdf = ROOT / "tests" / "urdf" / "slider_turret.urdf"
    (tmp_path / "blocks.py").write_text("# no blocks\n")
    (tmp_path / "traj.csv").write_text("t,q1\n0,0\n1,0\n")
    (tmp_path / "base.toml").write_text(f'[plant]\nurdf = "{urdf}"\n')
    (tmp_path / "p.toml").write_text(
        'extends = "base.toml"\nplugins = ["blocks.py"]\n[inertia_model]\n'
        f'urdf = "{urdf}"\n[runs.a]\nreference = {{ csv = "traj.csv" }}\n')
    named = named_files(load_pipeline(tmp_path / "p.toml"))
    assert named == {str(tmp_path / "p.toml"): "the pipeline file",
                     str(tmp_path / "base.toml"): "extends",
                     str(tmp_path / "blocks.py"): "plugins",
                     str(urdf): "plant.urdf",
                     str(urdf.parent / "meshes" / "block.stl"): "a <mesh> of plant.urdf",
                     str(tmp_path / "traj.csv"): "runs.a.reference.csv"}
    assert [e["sha256"] for e in file_digests(named)] == [digest(Path(p)) for p in sorted(named)]


def test_compare_of_a_sweep_folder_says_it_is_one(swept):
    """It said "not a cosim run folder (no summary.json with runs)" of a sweep's folder."""
    folder = swept[0] / "sweep"
    assert_message(error_line(here("compare", str(folder), str(folder))), (
        f"A {folder}: a sweep's folder, not a run folder; compare two run folders (a sweep's "
        "--record writes its best and worst points' run folders), or read the sweep's "
        "results.parquet"))
