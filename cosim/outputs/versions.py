"""The package versions a run folder and a recording record."""

from __future__ import annotations

import functools
import sys
from importlib import metadata

PACKAGES = ("cosim", "fmpy", "numpy", "scipy", "numba", "rerun-sdk", "control", "pydantic")


def package_versions() -> dict[str, str]:
    return dict(_versions())


@functools.cache
def _versions() -> tuple[tuple[str, str], ...]:
    """Read once per process: each lookup scans the installed distributions (~25 ms), and a
    run asks at every summary it writes."""
    out = {"python": sys.version.split()[0]}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return tuple(out.items())
