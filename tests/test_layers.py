"""The package's import graph, read from the source (every import, at module level or inside
a function): modules import only from their own layer or lower ones, and no modules import
each other round a cycle. A new module is placed in :data:`LAYERS`."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# Low to high; a module may import its own layer and those before it.
LAYERS = (
    ("cosim.schema", "cosim.declared", "cosim.signals", "cosim.numba_compat", "cosim.records",
     "cosim.jit_cache", "cosim.kernel_digest",
     "cosim.progress", "cosim.interface", "cosim.run_note", "cosim.environment",
     "cosim.interrupts", "plant_fmu"),
    ("cosim.plant", "cosim.system", "cosim.evaluate", "cosim.dynamics"),
    ("cosim.blocks", "cosim.paper"),
    ("cosim.config", "cosim.engine"),
    ("cosim.memory", "cosim.plant_source", "cosim.assemble"),
    ("cosim.outputs", "cosim.plan", "cosim.runner"),
    ("cosim.sweep", "cosim.warm"),
    ("cosim.cli", "cosim"),
)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def import_statements(path: Path) -> list[tuple[str | None, list[str]]]:
    """Each import in ``path`` (at module level or inside a function) as (the module a
    ``from`` import reads, None for ``import``; the dotted names it imports), relative
    imports resolved: ``from .x import y`` in cosim/a.py is ("cosim.x", ["cosim.x.y"])."""
    package = module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.append((None, [alias.name for alias in node.names]))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[:len(package) - node.level + 1] + ([base] if base else []))
            out.append((base, [f"{base}.{alias.name}" for alias in node.names]))
    return out


def is_project(name: str) -> bool:
    return name.split(".")[0] in ("cosim", "plant_fmu")


def imports(path: Path) -> set[str]:
    """The project modules ``path`` imports (relative imports resolved)."""
    return {n for base, names in import_statements(path)
            for n in ([base] if base is not None else []) + names if is_project(n)}


def layer(module: str) -> int:
    """The layer of the longest prefix of ``module`` that is listed."""
    best, rank = -1, None
    for index, members in enumerate(LAYERS):
        for prefix in members:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best:
                best, rank = len(prefix), index
    assert rank is not None, f"{module} is in no layer: place it in LAYERS"
    return rank


def graph() -> dict[str, set[str]]:
    files = [*ROOT.glob("cosim/**/*.py"), *ROOT.glob("plant_fmu/**/*.py")]
    modules = {module_name(p): p for p in files}
    out = {}
    for name, path in modules.items():
        # An imported name may be a module or an attribute of one: keep the modules. Importing
        # a.b.c runs the package a.b's __init__ first: an edge to a.b too, except to the
        # importer's own packages (entered already).
        own = {".".join(name.split(".")[:i]) for i in range(1, name.count(".") + 1)}
        targets = set()
        for imported in imports(path):
            parts = imported.split(".")
            targets.update(".".join(parts[:i]) for i in range(2, len(parts) + 1))
        out[name] = {m for m in targets if m in modules and m != name and m not in own}
    return out


def test_no_module_imports_from_a_higher_layer():
    upward = [f"{a} -> {b}" for a, targets in graph().items() for b in targets
              if layer(b) > layer(a)]
    assert upward == []


def test_the_import_graph_has_no_cycle():
    edges = graph()
    state: dict[str, int] = {}
    cycles = []

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for target in sorted(edges[node]):
            if state.get(target) == 1:
                cycles.append(" -> ".join(path[path.index(target):] + [target]))
            elif target not in state:
                visit(target, [*path, target])
        state[node] = 2

    for node in sorted(edges):
        if node not in state:
            visit(node, [node])
    assert cycles == []


# Libraries that take a second or more to import and that a command needs only for part of
# its work: a figure, a sweep, a recording, a trajectory of waypoints. Each `cosim run` and
# every bad input pays for what its start loads (the run process loads the pipeline before
# anything else); SciPy's interpolate alone was ~1 s of a refused --set's 2.5 s.
LOADED_ON_DEMAND = ("scipy.interpolate", "matplotlib", "dask", "distributed", "rerun",
                    "pinocchio", "pyarrow")


def test_loading_a_pipeline_loads_no_library_it_may_not_use():
    probe = ("import sys\n"
             "from cosim.config.load import load_pipeline\n"
             "import cosim.cli.run, cosim.runner\n"
             "load_pipeline('pipelines/paper_two_link.toml')\n"
             f"print(','.join(m for m in {LOADED_ON_DEMAND!r} if m in sys.modules))\n")
    done = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == ""
