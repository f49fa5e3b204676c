"""The house's figures, read from the source (no run, no compile; < 2 s): how big the
modules and functions are, how much of the kernels' plumbing is written by hand, how far the
paper's package reaches past the documented API, and how often one parameter is written on
its way from the pipeline to a kernel.

    .venv/bin/python benchmarks/house.py [--parameter torque_limit]

Figures (each printed with what it counts):
- modules over 400 lines and functions over 80 (Python: cosim/, plant_fmu/; C: plant_fmu/);
- fields of the kernels' argument and work records (NamedTuple classes), written by hand;
- row-index constants written by hand (``A, B, C = range(3)`` and ``NAME = <int>`` in the
  filter's scratch), and the rows declared by name instead (members of a ``Rows`` class,
  cosim.records, numbered by their order);
- the lines of cosim/paper;
- cosim/paper's imports of project modules that docs/api.md does not document;
- the parameter's occurrences as a name in code (not in comments or strings), and in how
  many files; the places it is written (a field declared, a keyword argument, an
  assignment, a ``per_joint`` entry), each listed;
- of the kernel records' fields, how many declare their source (cosim.blocks.binding) and
  how many ``reset`` still gives by hand; the blocks listing ``per_joint`` by hand.
"""

from __future__ import annotations

import argparse
import ast
import io
import re
import sys
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from test_paper_api import undocumented_imports  # noqa: E402  (the test's own reading)

MODULE_LINES, FUNCTION_LINES = 400, 80


def python_files() -> list[Path]:
    return sorted([*ROOT.glob("cosim/**/*.py"), *ROOT.glob("plant_fmu/**/*.py")])


def long_functions(path: Path) -> list[tuple[str, int]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [(node.name, node.end_lineno - node.lineno + 1) for node in ast.walk(tree)
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > FUNCTION_LINES]


def long_c_functions(path: Path) -> list[tuple[str, int]]:
    """C functions over the bound: a definition's line at column 0 to its closing brace."""
    out, name, start = [], None, 0
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        match = re.match(r"^[A-Za-z_][\w \*]*?\b(\w+)\s*\([^;]*$", line)
        if name is None and match:
            name, start = match.group(1), number
        elif name is not None and line.startswith("}"):
            if number - start + 1 > FUNCTION_LINES:
                out.append((name, number - start + 1))
            name = None
    return out


def record_fields() -> dict[str, int]:
    """NamedTuple class -> its field count, over cosim/."""
    out = {}
    for path in ROOT.glob("cosim/**/*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef) and any(
                    getattr(base, "id", None) == "NamedTuple" for base in node.bases):
                out[f"{path.relative_to(ROOT)}:{node.name}"] = sum(
                    isinstance(item, ast.AnnAssign) for item in node.body)
    return out


SOURCES = ("parameter", "reads", "writes", "uncertainty", "master_step", "scratch",
           "published")


def declares_source(field: ast.AnnAssign) -> bool:
    """Whether a record's field names its source in its annotation (``reads()`` …)."""
    return isinstance(field.annotation, ast.Call) and getattr(
        field.annotation.func, "id", None) in SOURCES


def declared_fields() -> dict[str, int]:
    """Kernel record (Args, Work, Envelope) -> its fields whose annotation names a source."""
    out = {}
    for path in ROOT.glob("cosim/**/*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef) and re.search(r"(Args|Work|Envelope)$", node.name):
                out[f"{path.relative_to(ROOT)}:{node.name}"] = sum(
                    isinstance(item, ast.AnnAssign) and declares_source(item)
                    for item in node.body)
    return out


def per_joint_lists() -> list[str]:
    """Blocks whose class assigns ``per_joint`` by hand."""
    return [f"{path.relative_to(ROOT)}:{node.name}" for path in ROOT.glob("cosim/**/*.py")
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
            if isinstance(node, ast.ClassDef) and any(
                isinstance(item, ast.Assign) and getattr(item.targets[0], "id", "") == "per_joint"
                for item in node.body)]


def writes_of(name: str) -> list[tuple[str, str]]:
    """(where, how) ``name`` is written over cosim/: a class field declared with it, a
    keyword argument, an assignment to it (a name or an attribute), a ``per_joint`` entry;
    and, as "bound", the kernel records' fields that declare its source
    (cosim.blocks.binding): the framework binds them, nothing writes them by hand."""
    out = []
    for path in sorted(ROOT.glob("cosim/**/*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            where = f"{path.relative_to(ROOT)}:{getattr(node, 'lineno', '')}"
            if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", None) == name:
                out.append((where, "bound" if declares_source(node) else "field"))
            elif isinstance(node, ast.keyword) and node.arg == name:
                out.append((f"{path.relative_to(ROOT)}:{node.value.lineno}", "keyword"))
            elif isinstance(node, ast.Assign):
                targets = [t for target in node.targets
                           for t in (target.elts if isinstance(target, ast.Tuple) else [target])]
                if any(getattr(t, "id", getattr(t, "attr", None)) == name for t in targets):
                    out.append((where, "assignment"))
                if any(getattr(t, "id", None) == "per_joint" for t in targets) and any(
                        isinstance(c, ast.Constant) and c.value == name
                        for c in ast.walk(node.value)):
                    out.append((where, "per_joint"))
    return out


def index_constants(path: Path) -> int:
    """Module-level names bound to ``range(...)`` unpacking or to an int literal."""
    count = range_constants(path)
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if not isinstance(node, ast.Assign):
            continue
        value = node.value
        if isinstance(value, ast.Constant) and type(value.value) is int:
            count += 1
        elif isinstance(value, ast.Tuple) and all(
                isinstance(e, ast.Constant) and type(e.value) is int for e in value.elts):
            count += len(value.elts)
    return count


def range_constants(path: Path) -> int:
    """Module-level names bound by unpacking ``range(...)``: row indices numbered by hand."""
    return sum(len(node.targets[0].elts) if isinstance(node.targets[0], ast.Tuple) else 1
               for node in ast.parse(path.read_text(encoding="utf-8")).body
               if isinstance(node, ast.Assign) and isinstance(node.value, ast.Call)
               and getattr(node.value.func, "id", None) == "range")


def declared_rows() -> tuple[int, int]:
    """(rows declared as members of a ``Rows`` class, numbered by their order, the classes)
    over cosim/."""
    members, classes = 0, 0
    for path in ROOT.glob("cosim/**/*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef) and any(
                    getattr(base, "id", None) == "Rows" for base in node.bases):
                classes += 1
                members += sum(isinstance(item, ast.Assign) for item in node.body)
    return members, classes


def name_occurrences(name: str) -> tuple[int, int]:
    """(occurrences of ``name`` as a code token or an attribute, files) over cosim/."""
    total, files = 0, 0
    for path in ROOT.glob("cosim/**/*.py"):
        tokens = tokenize.generate_tokens(io.StringIO(path.read_text(encoding="utf-8")).readline)
        here = sum(token.type == tokenize.NAME and token.string == name for token in tokens)
        total += here
        files += here > 0
    return total, files


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parameter", default="torque_limit",
                        help="the parameter whose occurrences are counted (default: "
                             "torque_limit)")
    args = parser.parse_args()

    sizes = {p: len(p.read_text(encoding="utf-8").splitlines()) for p in python_files()}
    big = sorted(((n, p) for p, n in sizes.items() if n > MODULE_LINES), reverse=True)
    print(f"Python modules over {MODULE_LINES} lines: {len(big)}")
    for lines, path in big:
        print(f"  {lines:5d}  {path.relative_to(ROOT)}")
    functions = [(n, f"{p.relative_to(ROOT)}:{f}") for p in python_files()
                 for f, n in long_functions(p)]
    print(f"Python functions over {FUNCTION_LINES} lines: {len(functions)}")
    for lines, where in sorted(functions, reverse=True):
        print(f"  {lines:5d}  {where}")
    c_functions = [(n, f"{p.relative_to(ROOT)}:{f}") for p in sorted(ROOT.glob("plant_fmu/**/*.c"))
                   for f, n in long_c_functions(p)]
    print(f"C functions over {FUNCTION_LINES} lines: {len(c_functions)}")
    for lines, where in sorted(c_functions, reverse=True):
        print(f"  {lines:5d}  {where}")

    records = record_fields()
    kernel = {k: v for k, v in records.items() if re.search(r"(Args|Work|Envelope)$", k)}
    print(f"kernel argument/work record fields written by hand: {sum(kernel.values())} "
          f"in {len(kernel)} records (all NamedTuple fields: {sum(records.values())})")
    declared = declared_fields()
    print(f"  of which declare their source (bound by the framework): "
          f"{sum(declared.values())}; given by reset: "
          f"{sum(kernel.values()) - sum(declared.values())}")
    for where, count in sorted(kernel.items(), key=lambda item: -item[1]):
        print(f"  {count:4d}  {where} ({declared.get(where, 0)} declared)")
    lists = per_joint_lists()
    print(f"blocks listing per_joint by hand: {len(lists)}")
    scratch = ROOT / "cosim/paper/cbf_filter/scratch.py"
    print(f"index constants by hand in {scratch.relative_to(ROOT)}: {index_constants(scratch)}")
    by_range = {path: count for path in python_files()
                if (count := range_constants(path))}
    print(f"  row constants numbered by range() over cosim/ and plant_fmu/: "
          f"{sum(by_range.values())}")
    for path, count in by_range.items():
        print(f"    {count:4d}  {path.relative_to(ROOT)}")
    members, classes = declared_rows()
    print(f"  rows declared by name (Rows classes, numbered by the framework): {members} in "
          f"{classes} classes")

    paper = [p for p in python_files() if p.is_relative_to(ROOT / "cosim/paper")]
    print(f"lines of cosim/paper: {sum(sizes[p] for p in paper)} in {len(paper)} modules")
    reaches = undocumented_imports()
    print(f"cosim/paper imports past the documented API (docs/api.md): {len(reaches)}")
    for module, imported in reaches:
        print(f"  {module} -> {imported}")
    total, files = name_occurrences(args.parameter)
    print(f"'{args.parameter}' as a name in code: {total} times in {files} files of cosim/")
    places = writes_of(args.parameter)
    written = [(where, how) for where, how in places if how != "bound"]
    print(f"'{args.parameter}' written: {len(written)} places")
    for where, how in written:
        print(f"  {where} {how}")
    bound = [where for where, how in places if how == "bound"]
    print(f"'{args.parameter}' read by a kernel record through a declared source: {len(bound)}")
    for where in bound:
        print(f"  {where}")


if __name__ == "__main__":
    main()
