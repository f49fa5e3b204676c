"""What the co-simulation and recording tests share: the paper's pipeline, a way to run the
real `cosim` command, and overrides that make a run diverge."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable

PAPER = "pipelines/paper_two_link.toml"

# The printed observer basis with the lagged q̂̈ at low observer gains: diverges in the
# observer within 0.1 s.
LOW_GAIN_LAGGED = ["--set", 'observer.basis="lagged"', "--set", "observer.kp=10",
                   "--set", "observer.kd=10", "--set", "observer.nu=1.0"]


def cosim_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True,
                          text=True, timeout=600)


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
