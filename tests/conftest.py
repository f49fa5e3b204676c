"""Shared fixtures: plant FMUs built once per session into a private cache."""

from __future__ import annotations

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
