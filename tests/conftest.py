"""Shared fixtures: plant FMUs built once per session into a private cache."""

from __future__ import annotations

import os

import pytest

from plant_fmu import build_fmu

# The shared helpers assert too (a whole error message): pytest shows their values.
pytest.register_assert_rewrite("cli_helpers")


@pytest.fixture(scope="session")
def fmu_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("fmu_cache")


@pytest.fixture(scope="session")
def plant_fmu(fmu_cache):
    """plant_fmu(links, fmi_version) -> path of the built FMU (built once per session)."""

    def build(links: int = 2, fmi_version: int = 2):
        return build_fmu(links=links, fmi_version=fmi_version, cache_dir=fmu_cache)

    return build


@pytest.fixture(autouse=True)
def _environment_restored():
    """Every test ends with the process's environment as it began. Dask's nannies write their
    pre-spawn environment (MALLOC_TRIM_THRESHOLD_, PYTHONHASHSEED) into ``os.environ`` of
    the process that starts them, and every process started after inherits it: a plain
    LocalCluster in one test gave a later test's cosim workers Dask's malloc setting, a
    failure only when pytest-xdist put the two files on one worker in that order."""
    before = dict(os.environ)
    yield
    if os.environ != before:
        os.environ.clear()
        os.environ.update(before)
