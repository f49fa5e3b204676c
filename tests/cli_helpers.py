"""What the co-simulation and recording tests share: the paper's pipeline, a way to run the
real `cosim` command, overrides that make a run diverge, and the barriers' gains read from a
run's tables."""

from __future__ import annotations

import io
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from contextlib import chdir, redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np

from cosim.paper.theorem import Gains

PAPER = "pipelines/paper_two_link.toml"

# The printed observer basis with the lagged q̂̈ at low observer gains: diverges in the
# observer within 0.1 s.
LOW_GAIN_LAGGED = ["--set", 'observer.basis="lagged"', "--set", "observer.kp=10",
                   "--set", "observer.kd=10", "--set", "observer.nu=1.0"]


def dask_environment(scratch: Path) -> dict[str, str]:
    """The environment of a `dask scheduler` or `dask worker` a test starts: its scratch space
    (Dask's temporary-directory) in ``scratch``, a folder of the test's, instead of
    /tmp/dask-scratch-space, which Dask leaves behind."""
    return {**os.environ, "DASK_TEMPORARY_DIRECTORY": str(scratch)}


def cosim_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True,
                          text=True, timeout=600)


def here(*args: str, cwd: Path | None = None, env: dict | None = None
         ) -> subprocess.CompletedProcess:
    """The command run in this process (``main(argv)``: no supervisor, the kernels already
    loaded), its output and status as :func:`cosim_cli` gives them: most cases need no process
    of their own, and a test suite's seconds count."""
    from cosim.cli import main

    out, err, saved = io.StringIO(), io.StringIO(), dict(os.environ)
    os.environ.update(env or {})
    try:
        with redirect_stdout(out), redirect_stderr(err), chdir(cwd or os.getcwd()):
            try:
                status = main(list(args))
            except SystemExit as exc:  # argparse: --version, --help, a bad option
                status = exc.code
    finally:
        os.environ.clear()
        os.environ.update(saved)
    return subprocess.CompletedProcess(args, status, out.getvalue(), err.getvalue())


def tree(folder: Path) -> dict[str, tuple[int, int]]:
    """Every entry under ``folder``: a file's or link's (size, modification time); a
    folder's (0, 0) (its time moves when an entry comes and goes)."""
    return {str(p.relative_to(folder)): (0, 0) if p.is_dir() and not p.is_symlink()
            else (p.lstat().st_size, p.lstat().st_mtime_ns) for p in sorted(folder.rglob("*"))}


def signal_when(child: subprocess.Popen, ready: Callable[[], bool], signal_name: str,
                timeout: float) -> str:
    """Wait until ``ready()`` (at most ``timeout`` s), send the signal, and return the
    child's stderr once it ends; the child is ended whatever happens."""
    try:
        deadline = time.monotonic() + timeout
        while not ready() and time.monotonic() < deadline:
            time.sleep(0.005)
        child.send_signal(getattr(signal, signal_name))
        _, err = child.communicate(timeout=timeout)
    finally:
        child.kill()
        child.wait()
    return err


def error_line(result: subprocess.CompletedProcess) -> str:
    """The one message: exit status 2, no traceback, one 'cosim: error:' line, last."""
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    assert "Traceback" not in result.stderr, result.stderr[-2000:]
    errors = [line for line in result.stderr.splitlines() if line.startswith("cosim: error:")]
    assert len(errors) == 1, result.stderr[-2000:]
    assert result.stderr.strip().splitlines()[-1] == errors[0]
    return errors[0]


def assert_message(message: str, expected: str | re.Pattern) -> None:
    """The whole message, exactly (or matching the whole pattern)."""
    body = message.removeprefix("cosim: error: ")
    if isinstance(expected, str):
        assert body == expected
    else:
        assert expected.fullmatch(body), body


def table_gains(run) -> Gains:
    """The gains the barriers use, read from the run's tables here (independently of what
    the blocks publish): Λ per joint, F, G, Fo, and output feedback for the proposed
    controller."""
    lam = np.broadcast_to(np.asarray(run.controller.lam, float), (2,))
    return Gains(lam, run.controller.f, run.controller.g, run.observer.fo,
                 run.controller.variant == "proposed")
