"""The commands of README.md and of the documentation's pages, in the order a newcomer meets
them (README.md, then docs/ in the order of mkdocs.yml's nav), as written, in a folder of
their own (a copy of `pipelines/`): each `cosim` command must succeed.

`cosim run` and `cosim sweep` are checked with `--dry-run` (every key, point, run name and
`--out` checked, nothing run: their real runs take minutes); `make readme` runs them for real
(COSIM_README_FULL=1). `make demo` is stood in for by its own command at 1 s of simulated
time, so that the commands after it have `runs/paper` to read. The benchmark scripts are run
with `--help`, each option the pages give them checked against it. What cannot run here
is listed in SKIPPED with the reason, and a command that matches nothing is an error: a new
command is tested or explicitly skipped."""

from __future__ import annotations

import io
import os
import re
import runpy
import shlex
import shutil
import subprocess
import sys
from contextlib import chdir, redirect_stdout
from pathlib import Path

import pytest
import yaml
from cli_helpers import here

from cosim.outputs.viewer import headless_renderer_available

ROOT = Path(__file__).resolve().parents[1]
FULL = os.environ.get("COSIM_README_FULL") == "1"

# command (its words; a trailing "…" matches any more) -> why the test does not run it (each
# is covered where named)
SKIPPED = {
    "cosim view runs/paper": "opens a window (tests/test_recording.py: without a display it "
    "says how to view the file elsewhere)",
    "cosim view runs/xarm7": "opens a window (tests/test_recording_arm3d.py reads the 3-D "
    "view back from a Panda's recording)",
    "cosim view runs/ur10": "opens a window (tests/test_recording_arm3d.py reads the 3-D "
    "view back from a Panda's recording)",
    "cosim run pipelines/paper_two_link.toml --spawn": "starts a viewer window "
    "(tests/test_recording.py: refused without a display)",
    "cosim run pipelines/paper_two_link.toml --connect …": "needs a running viewer "
    "(tests/test_recording.py: test_live_viewer_follows_a_run)",
    "cosim sweep ... …": "an elided command (the sweep above on another cluster; "
    "tests/test_sweep.py runs one on an external scheduler)",
    "make test": "this suite",
}


def matches(argv: list[str], key: str) -> bool:
    words = key.split()
    return argv == words or (words[-1] == "…" and argv[:len(words) - 1] == words[:-1])


def skipped(argv: list[str]) -> bool:
    return any(matches(argv, key) for key in SKIPPED)


def documents() -> list[Path]:
    """README.md, then every page of the documentation in the order of mkdocs.yml's nav (a
    section's pages in their order where it nests)."""
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))

    def pages(entries: list) -> list[str]:
        return [page for entry in entries for value in entry.values()
                for page in (pages(value) if isinstance(value, list) else [value])]

    folder = ROOT / config["docs_dir"]
    return [ROOT / "README.md", *(folder / page for page in pages(config["nav"]))]


def readme_commands() -> list[list[str]]:
    """Every shell command of the indented code blocks of README.md and the documentation's
    pages, in order, as its words (continuation lines joined, comments dropped); the fenced
    custom-block guide is test_plugins.py's."""
    commands, fenced, pending = [], False, ""
    for document in documents():
        for line in document.read_text(encoding="utf-8").splitlines():
            if line.startswith("```"):
                fenced = not fenced
                continue
            if fenced:
                continue
            if pending:
                pending += " " + line.strip()
            elif re.match(r"    (cosim|make|\.venv/bin/python) ", line):
                pending = line.strip()
            else:
                continue
            if pending.endswith("\\"):
                pending = pending[:-1].rstrip()
                continue
            commands.append(shlex.split(pending, comments=True))
            pending = ""
    return commands


def test_every_page_of_the_documentation_is_in_the_order_read():
    """A page left out of mkdocs.yml's nav would have its commands left out of this test."""
    docs = ROOT / "docs"
    listed = [path.relative_to(docs) for path in documents()[1:]]
    assert len(listed) == len(set(listed))
    assert set(listed) == {path.relative_to(docs) for path in docs.rglob("*.md")}


def test_the_readme_has_the_commands_this_test_knows():
    commands = readme_commands()
    assert len(commands) >= 20
    for key in SKIPPED:  # a skip whose command left the pages is stale
        assert any(matches(c, key) for c in commands), key


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("readme")
    shutil.copytree(ROOT / "pipelines", folder / "pipelines")
    return folder


def cosim(folder: Path, args: list[str]) -> subprocess.CompletedProcess:
    """The command in ``folder``: in this process where nothing is run for real (the
    kernels, FMUs and modules loaded once for the ~50 commands rather than once each: most
    of this test's time was each process starting), in a process of its own for `make
    readme`'s real runs and sweeps."""
    if FULL:
        return subprocess.run([sys.executable, "-m", "cosim.cli", *args], cwd=folder,
                              capture_output=True, text=True, timeout=3600)
    return here(*args, cwd=folder)


def test_every_readme_command_runs_in_order_as_written(workspace):
    renderer = headless_renderer_available()
    ran = []
    for argv in readme_commands():
        if skipped(argv):
            continue
        command = shlex.join(argv)
        program, *args = argv
        if program == "make":
            _make(workspace, args)
        elif program == ".venv/bin/python":
            _benchmark_help(args)
        else:
            assert program == "cosim", command
            if args[0] == "view" and renderer:
                print(f"not run: {command}: cannot render headless here: {renderer}")
                continue
            if args[0] in ("run", "sweep") and not FULL:
                args = [*args, "--dry-run"]
            if args[0] == "compare":  # its two folders are placeholders: two runs of ours
                for name in args[1:3]:
                    shutil.copytree(workspace / "runs" / "paper", workspace / name)
            done = cosim(workspace, args)
            assert done.returncode == 0, (command, done.stderr[-3000:])
            _check_output(workspace, args, done)
        ran.append(command)
    assert len(ran) >= 15, ran
    print("\n".join(["commands run:", *ran]))


def _make(workspace: Path, args: list[str]) -> None:
    """`make demo`: its target exists; then its own cosim command, at 1 s of simulated time
    unless FULL, so that runs/paper exists for the commands after it."""
    plan = subprocess.run(["make", "-n", *args], cwd=ROOT, capture_output=True, text=True)
    assert plan.returncode == 0, plan.stderr
    line = next(x for x in plan.stdout.splitlines() if "bin/cosim run " in x)
    demo = shlex.split(line)[1:]
    done = cosim(workspace, [*demo, *([] if FULL else ["--set", "simulation.duration=1"])])
    assert done.returncode == 0, done.stderr[-3000:]
    assert (workspace / "runs" / "paper" / "recording.rrd").is_file()


def _benchmark_help(args: list[str]) -> None:
    """The script's --help, run in this process as its own `__main__` (it exits there),
    lists every option the page gives it."""
    script, *options = args
    out, argv, path = io.StringIO(), sys.argv, list(sys.path)
    sys.argv = [script, "--help"]
    sys.path.insert(0, str((ROOT / script).parent))  # as `python script`: its folder first
    try:
        with redirect_stdout(out), chdir(ROOT), pytest.raises(SystemExit) as exited:
            runpy.run_path(str(ROOT / script), run_name="__main__")
    finally:
        sys.argv, sys.path[:] = argv, path
    assert exited.value.code in (0, None), (script, out.getvalue()[-2000:])
    for option in (o for o in options if o.startswith("--")):
        assert option in out.getvalue(), (script, option)


def _check_output(workspace: Path, args: list[str], done: subprocess.CompletedProcess) -> None:
    """What a command says it made is there."""
    if args[0] == "view":
        png = workspace / args[args.index("--screenshot") + 1]
        header = png.read_bytes()[:24]
        size = tuple(int.from_bytes(header[i:i + 4], "big") for i in (16, 20))
        expected = args[args.index("--size") + 1] if "--size" in args else "1600x1000"
        assert size == tuple(int(v) for v in expected.split("x"))
    elif args[0] in ("export", "build-fmu"):
        for path in done.stdout.split():
            assert (workspace / path).is_file(), path
    elif args[0] in ("run", "sweep") and not FULL:
        assert "nothing was run" in done.stdout.splitlines()[-1], done.stdout[-2000:]
