"""What the co-simulation and recording tests share: the paper's pipeline, a way to run the
real `cosim` command, and overrides that make a run diverge."""

from __future__ import annotations

import subprocess
import sys

PAPER = "pipelines/paper_two_link.toml"

# The printed observer basis with the lagged q̂̈ at low observer gains: diverges in the
# observer within 0.1 s.
LOW_GAIN_LAGGED = ["--set", 'observer.basis="lagged"', "--set", "observer.kp=10",
                   "--set", "observer.kd=10", "--set", "observer.nu=1.0"]


def cosim_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], capture_output=True,
                          text=True, timeout=600)
