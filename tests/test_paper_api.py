"""The paper's package plugs into the framework like anyone's would: every name cosim/paper
imports from the framework (cosim.*, plant_fmu.*) is documented in docs/api.md, as an object
its reference lists or a member of a module it lists. Read from the source, every import at
module level or inside a function."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest
from test_layers import import_statements, is_project

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "cosim" / "paper"


def documented() -> set[str]:
    """The dotted names docs/api.md's reference lists (``::: name``)."""
    text = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    return set(re.findall(r"^::: ([\w.]+)\s*$", text, flags=re.MULTILINE))


def is_module(name: str) -> bool:
    path = ROOT.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def framework_imports(path: Path) -> list[str]:
    """The framework names ``path`` imports: ``module.name`` for ``from module import
    name``, ``module`` for ``import module`` (relative imports resolved)."""
    return [name for _, names in import_statements(path) for name in names
            if is_project(name) and not name.startswith("cosim.paper")]


def resolve(name: str) -> object:
    """The object a dotted name imports (a module, or an attribute of the longest module
    prefix), or None where it does not resolve."""
    parts = name.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            target = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attribute in parts[cut:]:
            target = getattr(target, attribute, None)
        return target
    return None


def is_documented(name: str, listed: set[str]) -> bool:
    """``name`` is listed, lies inside a listed module (a module's reference documents its
    members), or is a documented class or function re-exported under another name."""
    parts = name.split(".")
    if name in listed or any(".".join(parts[:i]) in listed and is_module(".".join(parts[:i]))
                             for i in range(1, len(parts))):
        return True
    target = resolve(name)
    if not callable(target):
        return False
    home = f"{target.__module__}.{target.__qualname__}"
    return (home != name and is_documented(home, listed)) or any(
        resolve(entry) is target for entry in listed)


def undocumented_imports() -> list[tuple[str, str]]:
    """(module of cosim/paper, the name it imports) for each import past docs/api.md."""
    listed = documented()
    return [(str(path.relative_to(ROOT)), name)
            for path in sorted(PAPER.rglob("*.py"))
            for name in framework_imports(path) if not is_documented(name, listed)]


def test_the_paper_imports_only_the_documented_api() -> None:
    reaches = undocumented_imports()
    assert not reaches, ("cosim/paper imports names docs/api.md does not document (document "
                         "them there, or use what is documented):\n"
                         + "\n".join(f"  {module}: {name}" for module, name in reaches))


def test_the_reading_finds_a_reach_and_resolves_relative_imports() -> None:
    """The check is not empty: an undocumented name is found through a relative import, a
    documented one passes, and a member of a documented module passes."""
    listed = documented()
    assert "cosim.runner.run" in listed and is_documented("cosim.runner.run", listed)
    assert is_documented("cosim.interface.TRACKING_ERROR", listed)
    assert not is_documented("cosim.runner.something_private", listed)
    assert not is_documented("cosim.sweep.execution.execute", listed)
    # a re-export of a documented class is the documented class
    assert is_documented("cosim.blocks.set_default_chain", listed)
    assert not is_documented("plant_fmu.models.planar_arm.LINK_PARAMETERS", listed)
    module = PAPER / "cbf_filter" / "block.py"
    names = framework_imports(module)
    assert "cosim.blocks.base.register_block" in names  # `from ...blocks.base import …`


def test_the_paper_owns_its_barrier_bounds_and_adds_them_to_safety() -> None:
    """The framework's [safety] holds the safe sets only; the paper's package declares the
    bounds of its barriers and adds them (the pipeline key stays safety.z_wo_tilde); a key
    no package declares is still refused, by name."""
    from pydantic import ValidationError

    from cosim.config import load_pipeline
    from cosim.declared import Safety, safety_section
    from cosim.paper.barrier_bounds import BarrierBounds, barrier_bounds
    from cosim.schema import PipelineError

    paper_keys = set(BarrierBounds.model_fields)
    assert paper_keys == {"observer_error_bound", "z_wo_tilde", "z_wc_tilde", "z_vc_tilde",
                          "barrier_alpha"}
    assert not paper_keys & set(Safety.model_fields)
    assert paper_keys <= set(safety_section().model_fields)
    with pytest.raises(ValidationError, match="z_wo_tilde"):
        Safety(z_wo_tilde=3.0)
    path = ROOT / "pipelines" / "paper_two_link.toml"
    changed = load_pipeline(path, ["safety.z_wo_tilde=7.5"], warn=None)
    assert barrier_bounds(changed.safety).z_wo_tilde == 7.5
    assert barrier_bounds(Safety()) == BarrierBounds()  # a section without them: the defaults
    with pytest.raises(PipelineError, match="z_wo_tilda"):
        load_pipeline(path, ["safety.z_wo_tilda=7.5"], warn=None)
