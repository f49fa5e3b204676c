"""The package versions a run folder and a recording record."""

from __future__ import annotations

import sys
from importlib import metadata

PACKAGES = ("cosim", "fmpy", "numpy", "scipy", "numba", "rerun-sdk", "control", "pydantic")


def package_versions() -> dict[str, str]:
    out = {"python": sys.version.split()[0]}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out
