"""The catalogue of user mistakes and faults: every case ends with one clear message that
names the culprit, exit status 2 and no traceback; run folders are never silently reused,
never claimed complete when they are not, and nothing of a previous complete run is lost."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest
from cli_helpers import PAPER, assert_message, cosim_cli, error_line, here, signal_when

from plant_fmu import build_fmu

SHORT = ["--set", "simulation.duration=0.5"]


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A complete run folder (0.5 s of the paper's scenario)."""
    out = tmp_path_factory.mktemp("done") / "run"
    done = cosim_cli("run", PAPER, "--out", str(out), "--no-figures", *SHORT)
    assert done.returncode == 0, done.stderr
    return out


def snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {p.name: (p.stat().st_size, p.stat().st_mtime_ns) for p in folder.iterdir()}


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


# Cases that need nothing but arguments: (id, cosim arguments, fragments of the message).
NAMING = ("use up to 64 letters, digits, '_', '-' and '.', starting with a letter or digit "
          "(it names files and recording entities)")
# (id, arguments, the whole message after "cosim: error: "; a compiled pattern where the
# machine's memory or cores appear in it)
CASES = [
    ("zero steps", [*SHORT, "--set", "simulation.step=0.1", "--set", "simulation.duration=0.05"],
     f"{PAPER}: simulation.step = 0.1 s is longer than simulation.duration = 0.05 s: the run "
     "would have no step"),
    ("duration not whole steps", ["--set", "simulation.duration=1.0005"],
     f"{PAPER}: simulation.duration = 1.0005 s is not a whole number of steps of 0.001 s "
     "(1000.5); use 1 or 1.001 s"),
    ("runs not a table", ["--set", "runs=5"],
     f"{PAPER}: runs must be a table of runs ([runs.NAME] ...), got 5"),
    ("run name with a slash", [*SHORT, "--set", 'runs."a/b".controller.kv=20'],
     f"{PAPER}: run name 'a/b': {NAMING}"),
    ("absolute pipeline name", [*SHORT, "--set", 'name="/abs/path"'],
     f"{PAPER}: pipeline name '/abs/path': {NAMING}"),
    ("pipeline name climbing out", [*SHORT, "--set", 'name="../.."'],
     f"{PAPER}: pipeline name '../..': {NAMING}"),
    ("memory refused before allocating", ["--set", "simulation.duration=1e7"],
     re.compile(r"the traces would need 8\.16e\+03 GB \(2 run\(s\) × 10,000,000,001 rows of "
                r"51 values × 8 B\) but [\d.]+ GB of memory is available \(at most 80% is "
                r"used\); shorten simulation\.duration \(1e\+07 s\) or lengthen "
                r"simulation\.step \(0\.001 s\)")),
    ("unknown key", [*SHORT, "--set", "controller.kvv=1"],
     "--set controller.kvv=1: unknown key 'controller.kvv'; allowed keys here: variant, kv, "
     "lambda, f, g, kappa, kz, z_b, z_wc, c0, c1, delta, psi_b, hidden, velocity, init, "
     "init_scale, seed, scale"),
    ("negative sensor seed", [*SHORT, "--set", "sensor.seed=-1"],
     "--set sensor.seed=-1: key 'sensor.seed': Input should be greater than or equal to 0 "
     "(got -1)"),
    ("negative controller seed", [*SHORT, "--set", "runs.proposed.controller.seed=-3"],
     "--set runs.proposed.controller.seed=-3: key 'runs.proposed.controller.seed': Input "
     "should be greater than or equal to 0 (got -3)"),
    ("a list with a bad entry where a number or a list is taken",
     [*SHORT, "--set", "cbf_filter.torque_limit=[1000,0]"],
     "--set cbf_filter.torque_limit=[1000,0]: key 'cbf_filter.torque_limit.1': Input should "
     "be greater than 0 (got 0)"),
    ("plant sub-steps beyond the cap", [*SHORT, "--set", "plant.parameters.rk4_step=1e-10"],
     f"{PAPER}: plant.parameters.rk4_step = 1e-10 s makes 10,000,000 RK4 sub-steps per step "
     "of 0.001 s, more than simulation.max_plant_substeps = 1000: use rk4_step ≥ 1e-06 s, or "
     "raise max_plant_substeps if the run is meant to take that long"),
    ("a --set inside a table refused as a whole",
     [*SHORT, "--set", "reference.waypoints.times=[0.0,2.0,1.0]",
      "--set", "reference.waypoints.positions=[[0,0],[1,1],[0,0]]"],
     "--set reference.waypoints.times=[0.0,2.0,1.0]: key 'reference.waypoints': "
     "reference.waypoints.times[2] = 1 s does not increase (times[1] = 2 s); times must "
     "increase strictly"),
    ("a payload range that allows a negative mass",
     [*SHORT, "--set", "uncertainty.payload=[-3,1]"],
     "uncertainty.payload = [-3, 1] (run 'baseline'): the low end allows a plant with a "
     "negative mass: the payload is added to the last link's mass, m[2] = 2.3 kg in the "
     "nominal model, which must stay positive; give low > -2.3 kg"),
    ("a run the pipeline does not have", [*SHORT, "--run", "proposed", "--run", "nope"],
     f"--run nope: {PAPER} has no such run; its runs are baseline, proposed; nothing was run"),
]


@pytest.mark.parametrize("args,expected", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_is_one_clear_message(args, expected, tmp_path):
    out = tmp_path / "out"
    assert_message(error_line(cosim_cli("run", PAPER, "--out", str(out), *args)), expected)
    assert not out.exists()  # refused before anything was written


def test_an_existing_run_folder_is_refused_and_left_as_it_was(finished):
    before = snapshot(finished)
    message = error_line(cosim_cli("run", PAPER, "--out", str(finished), *SHORT))
    assert_message(message, re.compile(
        rf"--out {re.escape(str(finished))}: already holds 5 files \(a complete run folder of "
        r"paper_two_link started \d{4}-\d\d-\d\dT[\d:]{8}\+00:00\); pass --force to replace "
        r"them, or choose another --out"))
    assert snapshot(finished) == before


def test_force_replaces_the_folder_without_stale_files(finished, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(finished, out)
    (out / ".trace_proposed.npz.tmp").write_bytes(b"stale")  # a killed writer's temporary
    done = cosim_cli("run", PAPER, "--out", str(out), "--force", "--no-figures",
                     "--no-recording", *SHORT)
    assert done.returncode == 0, done.stderr
    assert not (out / ".trace_proposed.npz.tmp").exists() and not (out / "recording.rrd").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] and set(summary["files"]) == {"trace_baseline.npz",
                                                            "trace_proposed.npz", "summary.md"}
    assert "- **proposed**: limits kept (every joint's position, velocity); tracking kept" in \
        (out / "summary.md").read_text()
    assert summary["provenance"]["command"][-1] == "simulation.duration=0.5"
    assert {"started", "host", "versions"} <= set(summary["provenance"])


def test_a_failing_rerun_does_not_claim_complete(finished, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(finished, out)
    result = cosim_cli("run", PAPER, "--out", str(out), "--force", "--set",
                       'observer.basis="lagged"', "--set", "observer.kp=10", "--set",
                       "observer.kd=10", "--set", "observer.nu=1.0")
    assert "diverged in the observer block" in error_line(result)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["status"] == "incomplete"
    # both runs diverge in their observer (a run that diverges does not stop the others)
    assert list(summary["runs"]) == ["baseline", "proposed"]
    assert not any(run["complete"] for run in summary["runs"].values())


def test_a_second_writer_is_refused_while_the_first_runs(tmp_path):
    out = tmp_path / "busy"
    first = subprocess.Popen([sys.executable, "-m", "cosim.cli", "run", PAPER, "--out",
                              str(out), "--no-figures", "--set", "simulation.duration=20"],
                             stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not (out / ".cosim.lock").exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        second = cosim_cli("run", PAPER, "--out", str(out), "--force", *SHORT)
        assert_message(error_line(second), re.compile(
            rf"--out {re.escape(str(out))}: another cosim run is writing this folder \(pid "
            r"\d+\); wait for it, or choose another --out"))
    finally:
        _, err = first.communicate(timeout=300)
    assert first.returncode == 0, err[-2000:]
    assert json.loads((out / "summary.json").read_text())["complete"] is True


def test_sigterm_keeps_the_truth(tmp_path):
    out = tmp_path / "term"
    process = subprocess.Popen([sys.executable, "-m", "cosim.cli", "run", PAPER, "--out",
                                str(out), "--no-figures", "--set", "simulation.duration=200"],
                               stderr=subprocess.PIPE, text=True)
    for line in process.stderr:
        if "baseline: 25 %" in line:
            break
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 2 and "Traceback" not in err
    assert "terminated (SIGTERM)" in err and str(out) in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["status"] == "incomplete"
    assert "terminated" in summary["error"]
    assert summary["files"]["recording.rrd"]["bytes"] > 0
    done = summary["runs"]["baseline"]["metrics"]["simulated_time_s"]
    assert 45 < done < 200  # stopped near 25 %


def test_a_sigterm_replaced_by_another_exception_in_the_compiled_loop_is_still_a_sigterm(
        monkeypatch):
    """Python raises a signal handler's exception at the next bytecode, which can be inside
    the machinery around the compiled loop's call, and there it can be replaced by an
    ordinary exception: a loaded make test once saw test_sigterm_keeps_the_truth's SIGTERM
    end the run as "a block of the compiled loop (rows 50001 to 51000) raised". Here the
    replacement is made on purpose, in this process, around the real loop's third call."""
    import cosim.engine.master as master
    from cosim.cli.stopping import on_sigterm
    from cosim.config import load_pipeline
    from cosim.runner import run

    real, calls = master.fused_loop, []

    def replacing(kernels: tuple, fmi_version: int):
        loop = real(kernels, fmi_version)

        def call(*args):
            calls.append(len(calls))
            if len(calls) == 3:
                try:
                    os.kill(os.getpid(), signal.SIGTERM)
                    time.sleep(5)  # the handler raises Terminated here, at once
                except KeyboardInterrupt:
                    raise SystemError("a result with an exception set") from None
            return loop(*args)
        return call

    monkeypatch.setattr(master, "fused_loop", replacing)
    pipeline = load_pipeline(PAPER, ["simulation.duration=5"], warn=None)
    pipeline.runs = {"baseline": pipeline.runs["baseline"]}
    previous = signal.signal(signal.SIGTERM, on_sigterm)
    try:
        with pytest.raises(KeyboardInterrupt) as info:
            run(pipeline, None, progress=False, record=False, figures=False)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert str(info.value) == "terminated (SIGTERM)" and len(calls) == 3


@pytest.mark.parametrize("kind", ["a file", "a name too long", "under a file"])
def test_out_os_errors_name_the_path(kind, tmp_path):
    blocker = _write(tmp_path / "plain", b"x")
    out = {"a file": blocker, "a name too long": tmp_path / ("n" * 300),
           "under a file": blocker / "sub"}[kind]
    message = error_line(cosim_cli("run", PAPER, "--out", str(out), *SHORT))
    assert_message(message, f"--out {out}: " + {
        "a file": "is a file, not a folder; choose another --out",
        "a name too long": "cannot create the run folder there: File name too long",
        "under a file": "cannot create the run folder there: Not a directory"}[kind])


@pytest.mark.parametrize("content", [os.urandom(512), "name = 'x'\n".encode("utf-16")],
                         ids=["binary", "utf-16"])
def test_pipeline_files_that_are_not_utf8_text(content, tmp_path):
    path = _write(tmp_path / "bad.toml", content)
    message = error_line(cosim_cli("run", str(path), "--out", str(tmp_path / "out")))
    # which byte fails, and why, depends on the random bytes
    assert_message(message, re.compile(rf"{re.escape(str(path))}: not a UTF-8 text file "
                                       r"\(invalid [a-z ]+ byte at byte \d+\)"))


def test_a_damaged_fmu_binary_is_named_by_run_and_by_inspect(tmp_path):
    source = build_fmu(2, 2)
    damaged = tmp_path / "damaged.fmu"
    with zipfile.ZipFile(source) as src, zipfile.ZipFile(damaged, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename.endswith(".so"):
                data = data[:64] + os.urandom(len(data) - 64)  # a valid zip, a broken ELF
            dst.writestr(item, data)
    message = error_line(cosim_cli("run", PAPER, "--out", str(tmp_path / "out"), "--set",
                                   f'plant.fmu="{damaged}"', *SHORT))
    # the loader's own reason in the parentheses depends on the C library
    assert_message(message, re.compile(
        rf"{re.escape(str(damaged))}: its binary cannot be loaded on this machine \(.+\); "
        "rebuild or re-export the FMU"))
    inspected = cosim_cli("inspect", str(damaged))
    assert inspected.returncode == 1 and "fits the cosim plant interface: no" in inspected.stdout
    assert "binary cannot be loaded" in inspected.stdout


def test_inspect_refuses_an_archive_with_unsafe_entries(tmp_path):
    path = tmp_path / "escaping.fmu"
    shutil.copyfile(build_fmu(2, 2), path)
    with zipfile.ZipFile(path, "a") as archive:
        archive.writestr("../escaped.txt", "x")
    inspected = cosim_cli("inspect", str(path))
    assert inspected.returncode == 1
    assert "'../escaped.txt' points outside the FMU's folder" in inspected.stdout


def test_connect_to_a_dead_address_fails_fast(tmp_path):
    began = time.monotonic()
    message = error_line(cosim_cli("run", PAPER, "--out", str(tmp_path / "out"), "--connect",
                                   "rerun+http://127.0.0.1:9/proxy", *SHORT))
    assert time.monotonic() - began < 30
    assert_message(message, "--connect rerun+http://127.0.0.1:9/proxy: cannot reach a Rerun "
                   "viewer at 127.0.0.1:9 (Connection refused within 3 s); start one with "
                   "`rerun --port 9`; nothing was run")
    assert not (tmp_path / "out").exists()


def test_build_fmu_into_a_folder_and_refused_paths(tmp_path):
    done = cosim_cli("build-fmu", "--output", str(tmp_path))
    assert done.returncode == 0 and Path(done.stdout.strip()).parent == tmp_path
    message = error_line(cosim_cli("build-fmu", "--output", str(_write(tmp_path / "f", b"x")
                                                                  / "x.fmu")))
    assert_message(message, f"--output {tmp_path / 'f' / 'x.fmu'}: cannot write the FMU there: "
                   f"{tmp_path / 'f'} is a file, not a folder; nothing was written")
    # a folder not yet there, named with a trailing slash, is made (not a zip named "new")
    done = cosim_cli("build-fmu", "--output", f"{tmp_path / 'new'}/")
    assert done.returncode == 0, done.stderr
    assert Path(done.stdout.strip()) == tmp_path / "new" / "PlanarArm2_fmi2.fmu"
    assert (tmp_path / "new" / "PlanarArm2_fmi2.fmu").is_file()
    # without the slash, a name that is not .fmu is refused, and nothing is written
    message = error_line(cosim_cli("build-fmu", "--output", str(tmp_path / "newer")))
    assert message == (f"cosim: error: --output {tmp_path / 'newer'}: an FMU's file name ends "
                       f"in .fmu (e.g. {tmp_path / 'newer.fmu'}); for a folder, end it with / "
                       "and the FMU is written into it; nothing was written")
    assert not (tmp_path / "newer").exists()


def test_build_fmu_blames_the_compiler_and_the_cache_not_the_output(tmp_path):
    """$CC may carry options, as make allows; a compiler that is not there, and a cache that
    cannot be written, are named as such (not as --output's fault)."""
    env = {**os.environ, "COSIM_CACHE": str(tmp_path / "cache"), "CC": "cc -O1"}
    done = subprocess.run([sys.executable, "-m", "cosim.cli", "build-fmu", "--links", "1",
                           "--output", str(tmp_path / "arm.fmu")], capture_output=True,
                          text=True, timeout=600, env=env)
    assert done.returncode == 0, done.stderr
    for variables, expected in (
            ({"CC": "/nonexistent/cc"}, "CC='/nonexistent/cc': no program '/nonexistent/cc' is "
             "found (on the PATH or at that path); set CC to an installed C compiler, or unset "
             "it"),
            ({"COSIM_CACHE": str(_write(tmp_path / "plain", b"x") / "cache")},
             f"the FMU cache {tmp_path / 'plain' / 'cache'}: cannot write there "
             f"({tmp_path / 'plain' / 'cache'}: Not a directory); set COSIM_CACHE to a folder "
             "you can write")):
        failed = subprocess.run([sys.executable, "-m", "cosim.cli", "build-fmu", "--links", "1",
                                 "--output", str(tmp_path / "other.fmu")], capture_output=True,
                                text=True, timeout=600, env={**env, **variables})
        assert_message(error_line(failed), expected)
    assert not (tmp_path / "other.fmu").exists()


def test_build_fmu_replaces_a_different_file_only_with_force(tmp_path):
    """The same build again leaves the FMU as it is; a different file at the path (another
    build, or the user's own) is refused, named and left untouched, unless --force."""
    target = tmp_path / "arm.fmu"
    assert cosim_cli("build-fmu", "--output", str(target)).returncode == 0
    built = target.read_bytes()
    assert cosim_cli("build-fmu", "--output", str(target)).returncode == 0
    assert target.read_bytes() == built
    # built afresh in another cache (the archive's dates differ, its entries do not): the same
    fresh = subprocess.run([sys.executable, "-m", "cosim.cli", "build-fmu", "--output",
                            str(target)], capture_output=True, text=True, timeout=600,
                           env={**os.environ, "COSIM_CACHE": str(tmp_path / "cache")})
    assert fresh.returncode == 0, fresh.stderr
    built = target.read_bytes()
    other = cosim_cli("build-fmu", "--links", "3", "--output", str(target))
    assert other.returncode == 2
    assert error_line(other) == (
        f"cosim: error: --output {target}: a different file is already there (another build, "
        "or a file cosim did not write); give --force to replace it, or another --output; "
        "nothing was written")
    assert target.read_bytes() == built
    mine = _write(tmp_path / "PlanarArm2_fmi2.fmu", b"my own notes")
    assert cosim_cli("build-fmu", "--output", f"{tmp_path}/").returncode == 2
    assert mine.read_bytes() == b"my own notes"
    forced = cosim_cli("build-fmu", "--links", "3", "--output", str(target), "--force")
    assert forced.returncode == 0 and target.read_bytes() != built


def test_view_screenshot_to_a_bad_path(finished, tmp_path):
    message = error_line(cosim_cli("view", str(finished), "--screenshot",
                                   str(tmp_path / "missing" / "shot.png")))
    assert_message(message, f"--screenshot {tmp_path / 'missing' / 'shot.png'}: cannot write "
                   f"there ({tmp_path / 'missing'} is not a writable folder)")


def test_dry_run_checks_everything_and_writes_nothing(tmp_path):
    out = tmp_path / "planned"
    done = cosim_cli("run", "pipelines/paper_safety.toml", "--out", str(out), "--dry-run")
    assert done.returncode == 0, done.stderr
    assert "proposed_cbf: reference -> sensor" in done.stdout
    assert "memory:" in done.stdout and "disk: about" in done.stdout
    assert "nothing was run" in done.stdout and not out.exists()
    bad = cosim_cli("run", PAPER, "--dry-run", "--set", "runs.proposed.blocks=[\"sensor\"]")
    assert_message(error_line(bad), "run 'proposed': no block produces 'tau', the plant's "
                   "torque input (chain: sensor)")


def test_dry_run_says_when_the_run_itself_would_be_refused(finished, tmp_path):
    """A --dry-run into a finished run folder (such as the runs/paper that `make demo` leaves)
    gives the run's own refusal, not an all-clear; with --force, the all-clear."""
    before = snapshot(finished)
    message = error_line(cosim_cli("run", PAPER, "--out", str(finished), "--dry-run"))
    assert message.startswith(f"cosim: error: --out {finished}: already holds ")
    assert "(a complete run folder of paper_two_link started " in message
    assert message.endswith("pass --force to replace them, or choose another --out (--dry-run: "
                            "the run would be refused here)")
    done = cosim_cli("run", PAPER, "--out", str(finished), "--dry-run", "--force")
    assert done.returncode == 0 and "nothing was run (--dry-run)" in done.stdout
    (tmp_path / "thesis.tex").write_text("mine")
    message = error_line(cosim_cli("run", PAPER, "--out", str(tmp_path), "--dry-run",
                                   "--force"))
    assert_message(message, f"--out {tmp_path}: --force replaces only what cosim wrote, and "
                   "this folder holds 1 entry it did not write (thesis.tex); nothing was "
                   "deleted: choose another --out, or remove them yourself (--dry-run: the run "
                   "would be refused here)")
    assert snapshot(finished) == before and (tmp_path / "thesis.tex").read_text() == "mine"


def test_set_on_a_table_merges_and_a_shadowed_set_is_named(tmp_path):
    done = cosim_cli("run", PAPER, "--dry-run", "--set", "safety={position_bound=21.0}",
                     "--set", "controller.kz=1")
    assert done.returncode == 0, done.stderr
    assert "does not reach run 'baseline', whose own controller.kz = 0.1 wins" in done.stderr
    from cosim.config import load_pipeline

    merged = load_pipeline(PAPER, ["safety={position_bound=21.0}"]).safety
    assert merged.position_bound == 21.0 and merged.velocity_bound == 13.5


def _mount_tmpfs(path: Path, size: str) -> bool:
    path.mkdir()
    return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True).returncode == 0


def test_a_full_disk_ends_in_seconds_naming_the_path(tmp_path):
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, "3m"):
        pytest.skip("mounting a small tmpfs is not allowed here (needs root)")
    try:
        out = disk / "run"
        began = time.monotonic()
        message = error_line(cosim_cli("run", PAPER, "--out", str(out)))
        assert time.monotonic() - began < 90
        # which file meets the full disk first depends on timing
        assert_message(message, re.compile(
            rf"{re.escape(str(out))}/[\w.]+: could not be written: No space left on device; "
            rf"what was computed is kept in {re.escape(str(out))}; summary\.json says what is "
            # the run after the one the disk stopped, if it was the first, named as not run
            r"incomplete(; not run: proposed \(run it with --run proposed\))?"))
        summary = json.loads((out / "summary.json").read_text())
        assert summary["complete"] is False and summary["status"] == "incomplete"
        incomplete = {n for n, f in summary["files"].items() if not f["complete"]}
        assert "recording.rrd" in incomplete and "trace_baseline.npz" in incomplete
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)


def test_a_diverging_run_is_named_as_such_and_the_runs_after_it_still_run(tmp_path):
    """A reference a million million radians out drives the baseline's plant until its
    state becomes non-finite within a step, which the plant says (not "the inertia matrix
    became singular", which it once said). The pipeline's run after it still runs (a run
    that diverges does not stop the others): the table is printed with both, then the
    failure named, exit 2; summary.json and summary.md have both runs, the failed one
    without figures. (Gains far too high for the step, which once did this, are refused
    before the run now: tests/test_sampled_loop.py.)"""
    out = tmp_path / "diverged"
    result = cosim_cli("run", PAPER, "--out", str(out), *SHORT,
                       "--set", "runs.baseline.reference.amplitude=[[1e15],[1e15]]")
    assert result.returncode == 2
    message = error_line(result)
    assert "doStep: the state diverged at t = " in message, message
    assert "the model itself is not at fault" in message and "singular" not in message
    assert "not run" not in message and message.endswith(
        f"; what was computed is kept in {out}; summary.json says what is incomplete"), message
    assert "verdict:" in result.stdout and "  proposed  limits kept" in result.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["not_run"] == [] and list(summary["runs"]) == ["baseline", "proposed"]
    assert summary["runs"]["proposed"]["complete"] is True
    assert summary["runs"]["baseline"]["complete"] is False
    assert "doStep: the state diverged" in summary["runs"]["baseline"]["error"]
    assert "(the run did not finish)" in (out / "summary.md").read_text()
    assert (out / "fig2_position_velocity.png").is_file()  # the proposed run's figures


def test_a_plant_that_crashes_mid_run_is_named_and_what_was_computed_is_kept(tmp_path):
    """A PythonFMU plant that kills its process (SIGSEGV) at t = 2.5 s, as a broken binary
    would: the command says so, naming the FMU, and summary.json says crashed; the
    recording holds what the writer had been handed."""
    from test_plant_swapping import FOREIGN_ARM, build_pythonfmu

    fmu = build_pythonfmu(FOREIGN_ARM, tmp_path / "fmu")
    out = tmp_path / "crashed"
    mapping = ['plant.variables.tau=["shoulder_torque", "elbow_torque"]',
               'plant.variables.q=["shoulder", "elbow"]',
               'plant.variables.qdot=["shoulder_rate", "elbow_rate"]',
               'plant.parameters.crash_at=2.5', 'runs.baseline.controller.kv=20.0']
    args = ["run", PAPER, "--out", str(out), "--no-figures", "--set", f'plant.fmu="{fmu}"',
            "--set", "simulation.duration=5"]
    for item in mapping:
        args += ["--set", item]
    message = error_line(cosim_cli(*args))
    assert_message(message, "the run process was killed by SIGSEGV, most likely inside the "
                   f"plant FMU's binary in {fmu.name}; what was computed is kept in {out} "
                   "(summary.json marked crashed)")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["status"] == "crashed"
    assert summary["not_run"] == ["baseline", "proposed"]  # the crash was in the first
    assert "SIGSEGV" in summary["error"]
    assert (out / "recording.rrd").stat().st_size > 0


def test_a_plant_deaf_to_signals_is_killed_after_the_grace_and_named(tmp_path):
    """A PythonFMU whose doStep never returns and blocks SIGINT/SIGTERM (as a binary stuck
    in a system call): the run process cannot run its handler, so it does not acknowledge
    the SIGTERM; the supervisor kills it after the grace (2 s here), says so naming the FMU,
    marks summary.json crashed, and leaves no process behind."""
    from test_plant_swapping import FOREIGN_ARM, build_pythonfmu

    fmu = build_pythonfmu(FOREIGN_ARM, tmp_path / "fmu")
    out, marker = tmp_path / "stuck", tmp_path / "hanging"
    args = [sys.executable, "-m", "cosim.cli", "run", PAPER, "--out", str(out), "--no-figures",
            "--set", f'plant.fmu="{fmu}"', "--set", "simulation.duration=5"]
    for item in ['plant.variables.tau=["shoulder_torque", "elbow_torque"]',
                 'plant.variables.q=["shoulder", "elbow"]',
                 'plant.variables.qdot=["shoulder_rate", "elbow_rate"]',
                 "plant.parameters.hang_at=0.5", "runs.baseline.controller.kv=20.0"]:
        args += ["--set", item]
    env = {**os.environ, "COSIM_STOP_GRACE_S": "2", "PYTHON_ARM_HANG_MARKER": str(marker)}
    child = subprocess.Popen(args, stderr=subprocess.PIPE, text=True, env=env)
    began = time.monotonic()
    descendants: list[int] = []

    def stuck() -> bool:  # the FMU hangs now: note the run process and the writer's pids
        if not marker.exists():
            return False
        level = [child.pid]
        while level:
            level = [int(pid) for parent in level for pid in subprocess.run(
                ["pgrep", "-P", str(parent)], capture_output=True, text=True).stdout.split()]
            descendants.extend(level)
        return True

    err = signal_when(child, stuck, "SIGTERM", 300)
    lines = [line for line in err.splitlines() if line.startswith("cosim: error:")]
    assert child.returncode == 2 and "Traceback" not in err, err[-2000:]
    assert lines == [f"cosim: error: the run process did not answer SIGTERM within 2 s (most "
                     f"likely blocked inside the plant FMU's doStep in {fmu.name}) and was "
                     f"killed; what was written before is kept in {out} (summary.json marked "
                     "crashed)"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["status"] == "crashed"
    assert summary["error"] == (f"killed: the run process did not answer SIGTERM within 2 s "
                                f"in {fmu.name}")
    assert time.monotonic() - began < 120
    assert len(descendants) == 2  # the run process and its recording writer ...
    deadline = time.monotonic() + 10
    while any(Path(f"/proc/{pid}").exists() for pid in descendants) and \
            time.monotonic() < deadline:
        time.sleep(0.1)  # ... which ends when its run process's pipe closes
    assert not [pid for pid in descendants if Path(f"/proc/{pid}").exists()]


def test_force_never_deletes_what_cosim_did_not_write(finished, tmp_path):
    """--force replaces a run folder of ours; a folder holding anything else (a project
    folder, a run folder with the user's notes added) is refused, naming what is there,
    and nothing in it changes."""
    project = tmp_path / "project"
    (project / "thesis").mkdir(parents=True)
    (project / "thesis" / "chapter1.tex").write_text("results")
    (project / "measurements.csv").write_text("t,q\n0,0\n")
    shutil.copy(PAPER, project / "paper_two_link.toml")
    ours = tmp_path / "annotated"
    shutil.copytree(finished, ours)
    (ours / "notes.txt").write_text("keep me")
    for folder, named in ((project, "3 entries it did not write (measurements.csv, "
                           "paper_two_link.toml, thesis)"),
                          (ours, "1 entry it did not write (notes.txt)")):
        before = snapshot(folder)
        done = cosim_cli("run", PAPER, "--out", str(folder), "--force", *SHORT)
        assert_message(error_line(done),
                       f"--out {folder}: --force replaces only what cosim wrote, and this "
                       f"folder holds {named}; nothing was deleted: choose another --out, or "
                       "remove them yourself")
        assert snapshot(folder) == before


def test_a_plant_path_that_is_a_folder_is_named_as_such(tmp_path):
    message = error_line(cosim_cli("run", PAPER, "--out", str(tmp_path / "out"), *SHORT,
                                   "--set", f'plant.fmu="{tmp_path}"'))
    assert_message(message, f"plant.fmu: {tmp_path} is a folder, not an FMU file (an "
                   "unpacked FMU cannot be used: give its .fmu archive)")
    assert not (tmp_path / "out").exists()


def test_paths_in_an_extended_file_are_relative_to_that_file(tmp_path):
    """base/base.toml names arm.fmu beside it; other/child.toml extends it and holds a decoy
    arm.fmu of its own, which must not be used. A child that names a plant replaces the
    parent's (the paper's pipeline names the built-in plant)."""
    from cosim.config import load_pipeline

    (tmp_path / "base").mkdir()
    (tmp_path / "other").mkdir()
    arm = tmp_path / "base" / "arm.fmu"
    shutil.copy(build_fmu(links=2, fmi_version=2), arm)
    (tmp_path / "other" / "arm.fmu").write_text("a decoy, not an FMU")
    (tmp_path / "base" / "base.toml").write_text(
        f'extends = "{Path(PAPER).resolve()}"\n[plant]\nfmu = "arm.fmu"\n')
    child = tmp_path / "other" / "child.toml"
    child.write_text('extends = "../base/base.toml"\nname = "child"\n')
    pipeline = load_pipeline(child)
    assert Path(pipeline.plant.fmu) == arm.resolve() and pipeline.plant.builtin is None
    done = cosim_cli("run", str(child), "--out", str(tmp_path / "out"), "--no-recording",
                     "--no-figures", "--set", "simulation.duration=0.05")
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["complete"]


def test_an_extends_symlink_loop_and_a_very_deep_chain_are_one_message(tmp_path):
    (tmp_path / "a.toml").symlink_to(tmp_path / "b.toml")
    (tmp_path / "b.toml").symlink_to(tmp_path / "a.toml")
    message = error_line(cosim_cli("run", str(tmp_path / "a.toml"), "--dry-run"))
    assert_message(message, f"{tmp_path / 'a.toml'}: cannot be read: a loop of symbolic links")
    for i in range(40):
        (tmp_path / f"level{i}.toml").write_text(f'extends = "level{i + 1}.toml"\n')
    (tmp_path / "level40.toml").write_text('name = "deep"\n')
    message = error_line(cosim_cli("run", str(tmp_path / "level0.toml"), "--dry-run"))
    assert_message(message, f"{tmp_path / 'level32.toml'}: the 'extends' chain is more than "
                   f"32 files deep (from {tmp_path / 'level0.toml'}); flatten it")


def test_view_screenshot_of_a_corrupt_recording_says_so_at_once(finished, tmp_path):
    truncated = tmp_path / "cut.rrd"
    truncated.write_bytes((finished / "recording.rrd").read_bytes()[:50_000])
    garbage = _write(tmp_path / "garbage.rrd", os.urandom(50_000))
    for bad, fragment in ((truncated, "Missing RRD footer"), (garbage, "Not an RRD file")):
        message = error_line(cosim_cli("view", str(bad), "--screenshot",
                                       str(tmp_path / "shot.png")))
        # Rerun's own reason in the parentheses
        assert_message(message, re.compile(
            rf"{re.escape(str(bad))}: not a readable Rerun recording \(.*{fragment}.*\); it "
            r"may be truncated \(an interrupted run's writer is given 5 s\) or not a "
            r"recording at all"))
    assert not (tmp_path / "shot.png").exists()


def test_view_screenshot_to_a_folder_or_not_a_png(finished, tmp_path):
    for target, expected in (
            (tmp_path, f"is a folder; give the PNG file to write, e.g. "
                       f"{tmp_path / 'recording.png'}"),
            (tmp_path / "shot.jpg", f"the screenshot is a PNG; give a name ending in .png, "
                                    f"e.g. {tmp_path / 'shot.png'}")):
        message = error_line(cosim_cli("view", str(finished), "--screenshot", str(target)))
        assert_message(message, f"--screenshot {target}: {expected}")
    shot = str(tmp_path / "shot.png")
    for size in ("10x10", "big", "1600x9000"):
        assert_message(error_line(cosim_cli("view", str(finished), "--screenshot", shot,
                                            "--size", size)),
                       f"--size {size!r}: expected WIDTHxHEIGHT in pixels, each from 200 to "
                       "8000, e.g. 1600x1000")
    assert_message(error_line(cosim_cli("view", str(finished), "--size", "800x600")),
                   "--size 800x600: sizes the --screenshot PNG; a window opened by `cosim "
                   "view` is resized by hand")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"])
def test_ctrl_c_during_build_fmu_is_one_line_and_leaves_nothing(tmp_path, signal_name):
    """A signal while the compiler runs (an empty cache forces a build): one message, no
    temporary left in the cache or beside the output."""
    cache, tmp = tmp_path / "cache", tmp_path / "tmp"
    tmp.mkdir()
    out = tmp_path / "out" / "arm.fmu"
    child = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "build-fmu", "--links", "7", "--output", str(out)],
        env={**os.environ, "COSIM_CACHE": str(cache), "TMPDIR": str(tmp)},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err = signal_when(child, lambda: bool(list(tmp.glob("plant_fmu_*"))), signal_name, 60)
    if child.returncode == 0:
        pytest.skip("the build finished before the signal arrived")
    result = subprocess.CompletedProcess(child.args, child.returncode, "", err)
    reason = "terminated (SIGTERM)" if signal_name == "SIGTERM" else "interrupted (Ctrl-C)"
    assert f"{reason} while building the FMU; nothing was written" in error_line(result)
    assert not out.exists() and not list(cache.glob(".*tmp")) and list(tmp.iterdir()) == []


# Sweeps ------------------------------------------------------------------------------------

V1000 = ",".join(str(i) for i in range(1000))
TWICE = "give each swept key once (one --grid with every value, or one --sample)"
WORKERS = re.compile(r"--workers (0|100000): give 1 to \d+ local worker processes \(this "
                     r"machine has \d+ cores?\)")
SWEEP_CASES = [
    ("zero workers", ["--workers", "0"], WORKERS),
    ("a huge worker count", ["--workers", "100000"], WORKERS),
    ("negative seed", ["--seed", "-1"], "--seed -1: a seed is a non-negative integer"),
    ("not a scheduler address", ["--scheduler", "not a url"],
     "--scheduler 'not a url': not a scheduler address; expected tcp://HOST:PORT (e.g. "
     "tcp://127.0.0.1:8786)"),
    ("a key in two grids", ["--grid", "controller.kv=10,20", "--grid", "controller.kv=30"],
     f"--grid controller.kv: the key is already given by --grid; {TWICE}"),
    ("a key in a grid and a sample", ["--grid", "controller.kv=10,20", "--sample",
                                      "controller.kv=uniform(1,2)", "--samples", "2"],
     f"--sample controller.kv: the key is already given by --grid; {TWICE}"),
    ("a key set and swept", ["--set", "controller.kv=5", "--grid", "controller.kv=10,20"],
     f"--grid controller.kv: the key is already given by --set; {TWICE}"),
    ("a run named twice", ["--runs", "proposed", "proposed"],
     "--runs: proposed given more than once"),
    ("10⁹ points", ["--grid", f"controller.kv={V1000}", "--grid", f"controller.f={V1000}",
                    "--grid", f"controller.g={V1000}"],
     "the sweep makes 1,000,000,000 points, more than --max-points 100,000; narrow the grid "
     "or the samples, or raise --max-points if it is meant to be that large"),
]


@pytest.mark.parametrize("args,expected", [c[1:] for c in SWEEP_CASES],
                         ids=[c[0] for c in SWEEP_CASES])
def test_bad_sweep_arguments_are_one_message_before_any_work(args, expected, tmp_path):
    began = time.monotonic()
    message = error_line(cosim_cli("sweep", PAPER, "--out", str(tmp_path / "out"), *args))
    assert_message(message, expected)
    assert time.monotonic() - began < 60  # no grid is built, no cluster started
    assert not (tmp_path / "out").exists()


def _server(banner: bytes | None):
    """A local TCP server that is not a Dask scheduler: silent (like a web server waiting
    for a request) or sending a banner at once (like SSH). Returns (port, stop)."""
    import threading

    listener = socket.create_server(("127.0.0.1", 0))
    listener.settimeout(0.2)
    stop = threading.Event()
    held = []

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = listener.accept()
            except TimeoutError:
                continue
            held.append(conn)
            if banner:
                conn.sendall(banner)
        for conn in held:
            conn.close()
        listener.close()

    threading.Thread(target=serve, daemon=True).start()
    return listener.getsockname()[1], stop.set


@pytest.mark.parametrize("banner", [None, b"SSH-2.0-OpenSSH_9.2p1 Debian-2\r\n" * 4],
                         ids=["silent", "banner"])
def test_a_scheduler_address_that_is_not_dask_fails_in_bounded_time(banner, tmp_path):
    port, stop = _server(banner)
    try:
        began = time.monotonic()
        message = error_line(cosim_cli("sweep", PAPER, "--out", str(tmp_path / "out"),
                                       "--scheduler", f"tcp://127.0.0.1:{port}", *SHORT))
        assert time.monotonic() - began < 120
    finally:
        stop()
    # with a banner, Dask reads it as a message length: its own error in the parentheses
    assert_message(message, f"--scheduler tcp://127.0.0.1:{port}: something answers there but "
                   "not as a Dask scheduler (no handshake within 10 s)" if banner is None else
                   re.compile(rf"--scheduler tcp://127\.0\.0\.1:{port}: no Dask scheduler "
                              r"answered there \(.+\)"))
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["complete"] is False and "--scheduler" in summary["error"]
    assert not (tmp_path / "out" / ".cosim.lock").exists()


def test_a_sweep_whose_scheduler_never_answered_says_so_and_how_to_go_on(tmp_path):
    """Something that answers in another protocol (its banner read as a message length):
    "no Dask scheduler answered there (MemoryError: Unable to allocate 2.8 EiB …)". The
    folder it leaves (its summary says why) was refused by the same command again as "an
    incomplete run folder of ?"; now named a sweep's, with --resume offered."""
    port, stop = _server(b"SSH-2.0-OpenSSH_9.2p1 Debian-2\r\n" * 4)
    out = tmp_path / "out"
    command = ["sweep", PAPER, "--out", str(out), "--scheduler", f"tcp://127.0.0.1:{port}",
               "--grid", "controller.kv=10,20", *SHORT]
    try:
        first, again = here(*command), here(*command)
    finally:
        stop()
    assert_message(error_line(first), re.compile(
        rf"--scheduler tcp://127\.0\.0\.1:{port}: no Dask scheduler answered there "
        r"\(something answered, but not in Dask's protocol: its first bytes, read as a "
        r"message's length, asked for [\d.]+ EiB\)"))
    assert_message(error_line(again), re.compile(
        rf"--out {re.escape(str(out))}: already holds 3 files \(an incomplete sweep folder "
        r"started \d{4}-\d\d-\d\dT[\d:]{8}\+00:00, 0 row\(s\) in its journal\); pass --force "
        rf"to replace them, `cosim sweep … --resume {re.escape(str(out))}` to go on with it, "
        r"or choose another --out"))


def test_a_finished_sweeps_summary_says_complete(tmp_path):
    out = tmp_path / "sweep"
    done = cosim_cli("sweep", PAPER, "--out", str(out), "--quiet", "--grid",
                     "controller.kv=10,20", "--workers", "1", *SHORT)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "it/s" not in done.stderr and "point/s" not in done.stderr  # --quiet: no bar
    assert " … " not in done.stderr  # and no phases announced
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is True and summary["status"] == "complete"
    assert (summary["points"], summary["rows"], summary["failed_rows"]) == (2, 4, 0)
    assert {"results.parquet", "results.csv", "sweep.json"} <= set(summary["files"])


def test_sigterm_mid_sweep_keeps_the_finished_rows_and_ends_every_worker(tmp_path):
    import pyarrow.parquet as pq

    out = tmp_path / "sweep"
    child = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "sweep", PAPER, "--out", str(out), "--quiet",
         "--grid", f"controller.kv={','.join(str(10 + i) for i in range(300))}",
         # 5 s runs: the 300 points take ~30 s on 2 idle cores (at 0.5 s, as the other
         # sweeps here, they had all finished within the 8 s below, and the signal found
         # the results being written)
         "--workers", "2", "--set", "simulation.duration=5"], stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, process_group=0)
    try:
        line = child.stderr.readline()
        while line and not line.startswith("sweeping"):
            line = child.stderr.readline()
        # some points finish (~0.2 s each once the kernels are loaded): the signal is sent
        # once the journal holds a finished row, however loaded the machine (a fixed wait
        # found none finished under load), and a little after, so that more may
        journal, waited = out / "rows.jsonl", time.monotonic() + 300
        while time.monotonic() < waited and child.poll() is None and not (
                journal.is_file() and journal.read_text().count("\n") >= 1):
            time.sleep(0.2)
        time.sleep(1.0)
        child.send_signal(signal.SIGTERM)
        _, err = child.communicate(timeout=120)
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
        child.wait()
    assert child.returncode == 2, err[-2000:]
    assert "Traceback" not in err and "finished row(s) are kept in" in err
    rows = pq.read_table(out / "results.parquet").to_pylist()
    assert 0 < len(rows) < 600 and all(r["status"] == "ok" for r in rows)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["status"] == "incomplete"
    assert summary["rows"] == len(rows)
    assert not (out / ".cosim.lock").exists()
    deadline = time.monotonic() + 30  # no worker of its process group survives
    while time.monotonic() < deadline:
        try:
            os.killpg(child.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.2)
    else:
        left = subprocess.run(["ps", "-o", "pid,cmd", "-g", str(child.pid)],
                              capture_output=True, text=True).stdout
        os.killpg(child.pid, signal.SIGKILL)
        pytest.fail(f"processes of the sweep outlived it:\n{left}")


def test_record_when_every_row_failed_says_so(tmp_path):
    from cli_helpers import LOW_GAIN_LAGGED

    out = tmp_path / "sweep"
    message = error_line(cosim_cli("sweep", PAPER, "--out", str(out), "--quiet", "--runs",
                                   "proposed", "--grid", "controller.kv=10,20", "--workers",
                                   "1", "--record", "best,worst", *SHORT, *LOW_GAIN_LAGGED))
    assert_message(message, "--record best,worst: no row completed, so there is no point to "
                   f"record; the 2 row(s) and their errors are in {out / 'results.csv'}")
    rows = pq_rows(out)
    assert len(rows) == 2 and all(r["status"] == "failed" for r in rows)
    assert not [p for p in out.iterdir() if p.name.startswith(("best_", "worst_"))]
    # without --record, a sweep whose every row failed is no success either (it exited 0):
    # the same sweep resumed (every point done, nothing runs) says so, exit 2
    again = cosim_cli("sweep", PAPER, "--resume", str(out), "--quiet", "--runs", "proposed",
                      "--grid", "controller.kv=10,20", "--workers", "1", *SHORT,
                      *LOW_GAIN_LAGGED)
    assert_message(error_line(again), re.compile(
        r"every row failed \(2 of 2; the first, point 0 run proposed: .+\); each row's "
        r"error is in "
        rf"{re.escape(str(out / 'results.csv'))}"))
    assert "2 row(s) in" in again.stdout and "2 failed" in again.stdout


def pq_rows(out: Path) -> list[dict]:
    import pyarrow.parquet as pq

    return pq.read_table(out / "results.parquet").to_pylist()


def test_a_worker_killed_by_its_plant_leaves_failed_rows_named_by_run(tmp_path):
    from test_plant_swapping import FOREIGN_ARM, build_pythonfmu

    fmu = build_pythonfmu(FOREIGN_ARM, tmp_path / "fmu")
    sets = [f'plant.fmu="{fmu}"', 'plant.variables.tau=["shoulder_torque", "elbow_torque"]',
            'plant.variables.q=["shoulder", "elbow"]',
            'plant.variables.qdot=["shoulder_rate", "elbow_rate"]',
            "plant.parameters.crash_at=0.2", "runs.baseline.controller.kv=20.0",
            "simulation.duration=0.5"]
    args = ["sweep", PAPER, "--out", str(tmp_path / "sweep"), "--quiet", "--workers", "1"]
    for item in sets:
        args += ["--set", item]
    done = cosim_cli(*args)
    assert "Traceback" not in done.stderr
    assert (tmp_path / "sweep" / "results.parquet").exists(), (done.returncode, done.stderr)
    rows = pq_rows(tmp_path / "sweep")
    assert {r["run"] for r in rows} == {"baseline", "proposed"}
    assert all(r["status"] == "failed" for r in rows)


def test_an_inherited_supervisor_note_is_not_written_by_a_cosim_it_does_not_own(tmp_path):
    """COSIM_SUPERVISED=1 and COSIM_RUN_NOTE naming a user's file, inherited by a cosim that
    no supervisor started (a nested cosim, a user's shell): the file was overwritten with the
    run's note and a .fault file made beside it. Only the run process of a supervisor (its
    parent's pid in COSIM_SUPERVISED) writes the note, and only the one the supervisor made."""
    note = tmp_path / "notes.txt"
    note.write_text("the user's notes\n")
    (tmp_path / "blocks.py").write_text("# no blocks\n")
    pipeline = tmp_path / "p.toml"
    pipeline.write_text(f'extends = "{Path(PAPER).resolve()}"\nplugins = ["blocks.py"]\n')
    done = subprocess.run([sys.executable, "-m", "cosim.cli", "run", str(pipeline),
                           "--dry-run", *SHORT], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "COSIM_SUPERVISED": "1",
                               "COSIM_RUN_NOTE": str(note)})
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"cosim: importing plugin {tmp_path / 'blocks.py'}" in done.stderr  # (it told)
    assert note.read_text() == "the user's notes\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocks.py", "notes.txt", "p.toml"]


def test_the_run_process_ends_when_its_supervisor_is_killed(tmp_path):
    """SIGKILL to `cosim run` (the thin supervisor) must not orphan the process that runs:
    it notices within a second, ends as on SIGTERM and leaves a true summary."""
    out = tmp_path / "run"
    supervisor = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "run", PAPER, "--out", str(out), "--no-figures",
         "--set", "simulation.duration=600"], stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL)
    child = None
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            found = subprocess.run(["ps", "-o", "pid=", "--ppid", str(supervisor.pid)],
                                   capture_output=True, text=True).stdout.split()
            if found and (out / "summary.json").exists():
                child = int(found[0])
                break
            time.sleep(0.1)
        assert child is not None
        time.sleep(3.0)  # into the loop
        supervisor.kill()
        supervisor.wait()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                os.kill(child, 0)
            except ProcessLookupError:
                break
            time.sleep(0.2)
        else:
            os.kill(child, signal.SIGKILL)
            pytest.fail("the run process outlived its supervisor by 60 s")
    finally:
        supervisor.kill()
        supervisor.wait()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["status"] == "incomplete"
    assert not (out / ".cosim.lock").exists()


def test_without_out_every_run_gets_a_new_folder_and_latest_points_to_it(tmp_path):
    """Run folders never collide: without --out, runs/NAME/YYYYmmdd-HHMMSS (made at once,
    -2 within the same second), runs/NAME/latest → the newest; --dry-run names one and
    makes nothing; a `latest` that is the user's own file is left alone."""
    pipeline = str(Path(PAPER).resolve())
    args = [sys.executable, "-m", "cosim.cli", "run", pipeline, "--no-recording",
            "--no-figures", "--set", "simulation.duration=0.1"]
    made = []
    for _ in range(2):
        done = subprocess.run(args, cwd=tmp_path, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]
        made.append(done.stdout.split("run folder: ")[1].split()[0])
    base = tmp_path / "runs" / "paper_two_link"
    assert made[0] != made[1] and all(Path(m).parent == Path("runs/paper_two_link")
                                      for m in made)
    assert all(re.fullmatch(r"\d{8}-\d{6}(-\d+)?", Path(m).name) for m in made)
    assert all(json.loads((tmp_path / m / "summary.json").read_text())["complete"]
               for m in made)
    assert (base / "latest").resolve() == (tmp_path / made[1]).resolve()
    dry = subprocess.run([*args, "--dry-run"], cwd=tmp_path, capture_output=True, text=True,
                         timeout=600)
    assert dry.returncode == 0 and "runs/paper_two_link/" in dry.stdout
    assert sorted(p.name for p in base.iterdir()) == sorted([*(Path(m).name for m in made),
                                                             "latest"])
    (base / "latest").unlink()
    (base / "latest").write_text("the user's own")
    done = subprocess.run(args, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and (base / "latest").read_text() == "the user's own"
    # ... and said: `cosim view runs/NAME/latest` would show the user's thing, not this run
    third = done.stdout.split("run folder: ")[1].split()[0]
    assert "cosim: warning: runs/paper_two_link/latest is a file cosim did not make, so it " \
        "was left as it is and does not lead to this run: view this one with cosim view " \
        f"{third}\n" in done.stderr


def test_a_cold_kernel_cache_is_announced_not_silent(tmp_path):
    """The first run on a machine compiles every kernel (~30 s): cosim says so before the
    terminal goes quiet. Cold: an empty numba cache for these sources; warm once a kernel
    is compiled there (a real one: the inertia model's, in a fresh process)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    probe = ("import sys, numpy as np, cosim.blocks, cosim.jit_cache as j; "
             "print(j.cache_is_cold());"
             "from cosim.paper.inertia import planar_mass_matrix as f;"
             "out = np.empty((2, 2)); f(np.zeros(2), np.ones(2), np.ones(2), np.ones(2),"
             " np.zeros(2), out) if 'compile' in sys.argv else None")
    cold = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True,
                          text=True, timeout=300)
    assert cold.stdout.split() == ["True"], cold.stderr[-2000:]
    subprocess.run([sys.executable, "-c", probe, "compile"], env=env, check=True,
                   capture_output=True, timeout=300)
    warm = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True,
                          text=True, timeout=300)
    assert warm.stdout.split() == ["False"], warm.stderr[-2000:]


def test_a_pipeline_swallowed_by_sweep_runs_is_named(tmp_path):
    """`cosim sweep --runs proposed PIPELINE …`: --runs takes every name after it, the
    pipeline too; one message says so (argparse said only "required: pipeline")."""
    message = error_line(cosim_cli("sweep", "--runs", "proposed", PAPER, "--out",
                                   str(tmp_path / "out")))
    assert message == (f"cosim: error: --runs took the pipeline {PAPER} as a run name: give "
                       "the pipeline first (cosim sweep PIPELINE … --runs NAME …), or end the "
                       "run names with --")
    assert not (tmp_path / "out").exists()


def test_a_file_that_fails_verification_makes_the_folder_incomplete_and_is_named(tmp_path):
    """The bookkeeping itself: a trace whose bytes are not a readable npz is refused (never
    renamed into place) and named; a recording that another process left empty is noted as
    incomplete without an exception; either way the summary, though every run finished, is
    not complete, and says which file and why."""
    import json

    from cosim.outputs.run_folder import RunFolder, RunFolderError

    folder = RunFolder.create(tmp_path / "out")
    with pytest.raises(RunFolderError) as refused:
        folder.write("trace_x.npz", lambda tmp: tmp.write_bytes(b"PK\x03\x04 not a zip"))
    assert str(refused.value).startswith(f"{tmp_path / 'out' / 'trace_x.npz'}: could not be "
                                         "written: the written file is not a readable npz")
    assert not (tmp_path / "out" / "trace_x.npz").exists()
    assert not list((tmp_path / "out").glob(".*.tmp"))
    folder.write("notes.txt", lambda tmp: tmp.write_text("fine"))
    (tmp_path / "out" / "recording.rrd").write_bytes(b"")
    folder.note("recording.rrd", True)  # the writer said it closed, but the file is empty
    assert folder.write_summary({"complete": True}, final=True) is False
    folder.release()
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["complete"] is False and summary["status"] == "incomplete"
    assert summary["files"]["trace_x.npz"]["complete"] is False
    assert summary["files"]["trace_x.npz"]["reason"].startswith(
        "the written file is not a readable npz")
    assert summary["files"]["recording.rrd"] == {"complete": False, "bytes": 0,
                                                 "reason": "empty"}
    assert summary["files"]["notes.txt"]["complete"] is True

    # the same folder's rules with every file whole: complete
    whole = RunFolder.create(tmp_path / "whole")
    whole.write("notes.txt", lambda tmp: tmp.write_text("fine"))
    assert whole.write_summary({"complete": True}, final=True) is True
    whole.release()
