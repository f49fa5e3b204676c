"""Bounded resources: an FMU that unpacks to far more than it weighs is refused before a
byte is written, every unpacked FMU is removed when its process ends (sweep workers too),
and those of processes that died are cleaned up by the next one. Real FMUs, real `cosim`
processes, each with its own temporary folder (TMPDIR) so that what is left can be counted."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from cli_helpers import signal_when

from cosim.plant.unpack import PREFIX, extract, remove

PAPER = "pipelines/paper_two_link.toml"


def cosim(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True,
                          text=True, timeout=300, env={**os.environ, **env})


def unpacked(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.glob(f"{PREFIX}*"))


def padded(source: Path, dest: Path, megabytes: int) -> Path:
    """A copy of an FMU with ``megabytes`` of zeros added: a few kB compressed."""
    with zipfile.ZipFile(source) as src, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as out:
        for item in src.infolist():
            out.writestr(item, src.read(item.filename))
        out.writestr("resources/zeros.bin", bytes(megabytes * 1_000_000))
    return dest


def test_an_fmu_that_unpacks_beyond_the_cap_is_refused_before_anything_is_written(
        plant_fmu, tmp_path):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    bomb = padded(plant_fmu(2, 2), tmp_path / "bomb.fmu", 5)
    assert bomb.stat().st_size < 200_000
    env = {"TMPDIR": str(tmp), "COSIM_FMU_MAX_MB": "2"}
    out = tmp_path / "run"
    done = cosim("run", PAPER, "--set", f'plant.fmu="{bomb}"',
                 "--set", "simulation.duration=0.1", "--out", str(out), "--no-recording",
                 env=env)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert "unpacks to 5 MB, more than the 2 MB" in done.stderr
    assert "COSIM_FMU_MAX_MB" in done.stderr
    assert unpacked(tmp) == []
    inspected = cosim("inspect", str(bomb), env=env)
    assert inspected.returncode == 1  # the report says why: it does not fit
    assert "unpacks to 5 MB" in inspected.stdout
    assert "fits the cosim plant interface: no" in inspected.stdout
    assert unpacked(tmp) == []
    # under the default cap (1 GB) the same FMU runs
    done = cosim("run", PAPER, "--set", f'plant.fmu="{bomb}"',
                 "--set", "simulation.duration=0.1", "--out", str(out), "--no-recording",
                 "--no-figures", env={"TMPDIR": str(tmp)})
    assert done.returncode == 0, done.stderr
    assert unpacked(tmp) == []


def test_sweep_workers_remove_the_fmus_they_unpacked(tmp_path):
    """Each worker keeps its plant open between points and is ended by the cluster."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    done = cosim("sweep", PAPER, "--grid", "controller.kv=10,20", "--set",
                 "simulation.duration=0.1", "--workers", "2", "--quiet", "--out",
                 str(tmp_path / "sweep"), env={"TMPDIR": str(tmp)})
    assert done.returncode == 0, done.stderr
    assert unpacked(tmp) == []


def test_the_unpacked_fmus_of_dead_processes_are_cleaned_up_and_no_others(
        plant_fmu, tmp_path, monkeypatch):
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f"{PREFIX}{dead.pid}_abc"
    alive = tmp_path / f"{PREFIX}{os.getpid()}_def"  # this process's: in use
    unknown = tmp_path / f"{PREFIX}old"  # not named by a process: not provably ours
    foreign = tmp_path / "someone_else"
    for folder in (stale, alive, unknown, foreign):
        (folder / "binaries").mkdir(parents=True)
    fresh = extract(plant_fmu(2, 2))
    try:
        assert not stale.exists()
        assert alive.exists() and unknown.exists() and foreign.exists()
        assert Path(fresh).parent == tmp_path.resolve()
        assert Path(fresh).name.startswith(f"{PREFIX}{os.getpid()}_")
    finally:
        remove(fresh)
    assert not Path(fresh).exists()


@pytest.mark.parametrize("signal_name", ["SIGTERM", "SIGINT"])
def test_an_interrupted_run_leaves_no_unpacked_fmu(plant_fmu, tmp_path, signal_name):
    """A signal while a large FMU is being unzipped (or, if the unzip wins the race, while
    the run steps): nothing unpacked is left, and the message names no run folder that does
    not exist."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    big = padded(plant_fmu(2, 2), tmp_path / "big.fmu", 800)
    out = tmp_path / "run"
    child = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "run", PAPER, "--set", f'plant.fmu="{big}"',
         "--out", str(out), "--no-recording"],
        env={**os.environ, "TMPDIR": str(tmp)}, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)
    err = signal_when(child, lambda: bool(unpacked(tmp)), signal_name, 120)
    assert child.returncode == 2, err
    assert "Traceback" not in err
    assert unpacked(tmp) == []
    if not (out / "summary.json").exists():
        assert f"kept in {out}" not in err and "nothing was written" in err
