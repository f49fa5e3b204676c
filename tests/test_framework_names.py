"""The framework names none of the paper's signals and imports none of plant_fmu's models.

The paper's study (cosim/paper/: its blocks, evaluators, theorem checks, the filter's
guarantee) plugs in through the registries a user's plugin uses. What the framework may
name of a run is the plant's ports (cosim/plant/ports.py) and the declared interface an
evaluated controller publishes (cosim/interface.py); every other signal, published constant
and evaluator series of the paper's runs, collected here from the assembled runs themselves,
must not appear as a string in the framework's source.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from test_recording import _TwoLinkArm

from cosim import interface
from cosim.assemble import assemble_run
from cosim.config import load_pipeline
from cosim.plant.ports import PORTS

ROOT = Path(__file__).resolve().parents[1] / "cosim"
# The framework: everything but the paper's package and the interface's declarations.
NOT_FRAMEWORK = ("paper", "interface.py")
PIPELINES = ("pipelines/paper_safety.toml", "pipelines/pd_control.toml")


def framework_files() -> list[Path]:
    return sorted(p for p in ROOT.rglob("*.py")
                  if p.relative_to(ROOT).parts[0] not in NOT_FRAMEWORK)


def paper_names() -> set[str]:
    """Every signal, published constant and evaluator series of the paper's runs, and the
    names and check families of the paper's evaluators (a check is named after its
    family), less the plant's ports and the declared interface."""
    from cosim.evaluate import EVALUATORS

    names: set[str] = set()
    for cls in EVALUATORS.values():
        if cls.__module__.startswith("cosim.paper."):
            names |= {cls.name, *(d.family for d in cls.declarations)}
    for path in PIPELINES:
        pipeline = load_pipeline(path)
        for run in pipeline.runs:
            plan = assemble_run(pipeline, run, _TwoLinkArm())
            names |= set(plan.signals) | set(plan.published())
    for cls in EVALUATORS.values():
        names |= set(cls.series_meanings)
    allowed = {port.name for port in PORTS} | set(interface.NAMES) | set(interface.SERIES)
    return {n for n in names - allowed if len(n) > 1}


def mentions(names: set[str]) -> list[str]:
    """file:line: name, for each string constant (or f-string part) that is a paper name."""
    found = []
    for path in framework_files():
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                    and node.value in names:
                found.append(f"{path.relative_to(ROOT.parent)}:{node.lineno}: {node.value}")
    return found


def model_imports() -> list[str]:
    found = []
    for path in framework_files():
        for node in ast.walk(ast.parse(path.read_text())):
            module = (node.module if isinstance(node, ast.ImportFrom) else None) or ""
            if isinstance(node, ast.Import):
                module = " ".join(a.name for a in node.names)
            if "plant_fmu.models" in module:
                found.append(f"{path.relative_to(ROOT.parent)}:{node.lineno}: {module}")
    return found


def test_the_framework_names_no_paper_signal():
    names = paper_names()
    assert {"r_hat", "k0", "qdot_hat", "nn_gains", "cbf_infeasible"} <= names
    assert mentions(names) == []


def test_the_framework_imports_no_plant_model():
    assert model_imports() == []


@pytest.mark.parametrize("name", sorted(interface.NAMES))
def test_the_declared_interface_is_what_the_paper_publishes(name):
    """Each interface name is a signal or constant some paper run really has."""
    have = set()
    for path in PIPELINES:
        pipeline = load_pipeline(path)
        for run in pipeline.runs:
            plan = assemble_run(pipeline, run, _TwoLinkArm())
            have |= set(plan.signals) | set(plan.published())
    assert name in have
