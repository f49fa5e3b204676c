"""Which sources a kernel module's machine code depends on, and their digest
(:func:`module_digest`), read statically (nothing is imported to find them): the module's
own source, recursively the source of every *kernel module* it imports (one that imports
numba or cosim.numba_compat), and the plain values (numbers, strings, tuples, arrays) it
imports from the project's other modules, which numba freezes into machine code.
:mod:`cosim.jit_cache` caches each module's kernels under that digest."""

from __future__ import annotations

import ast
import enum
import functools
import hashlib
import importlib.util
import re
import sys
import sysconfig
from collections.abc import Iterator
from pathlib import Path

_PROJECT = ("cosim", "plant_fmu")  # top-level packages whose imports the digest follows
# A module whose source imports numba, or cosim's fence around it (numba_compat), holds
# kernels (or helpers kernels call).
_IMPORTS_NUMBA = re.compile(
    rb"^[ \t]*(from[ \t]+numba\b|import[ \t]+numba\b|from[ \t]+[.\w]*numba_compat\b)", re.M)
# Installed code (the standard library, site-packages) is not ours to version: numba's own
# locators cache it. cosim itself is ours wherever it is installed.
_INSTALLED = tuple(sorted({str(Path(p).resolve()) for key in ("stdlib", "platstdlib",
                                                               "purelib", "platlib")
                           if (p := sysconfig.get_paths().get(key))}))

_closures: dict[str, tuple[str, ...]] = {}  # module name -> its kernel-module closure
_digests: dict[str, str] = {}  # module name -> digest (sources do not change under a run)
_parsed: dict[tuple[str, str], list] = {}  # (module, file) -> its project imports


# Finding a module's kernel-module imports, statically (nothing is imported to find them) --

def module_file(name: str) -> Path | None:
    """The source file of module ``name`` (a .py file), or None: from sys.modules when it is
    loaded, else from its top-level package's folder, without importing anything."""
    module = sys.modules.get(name)
    if module is not None:
        path = getattr(module, "__file__", None)
        return Path(path) if path and path.endswith(".py") else None
    top, _, rest = name.partition(".")
    package = sys.modules.get(top)
    try:
        origin = getattr(package, "__file__", None) if package is not None else \
            importlib.util.find_spec(top).origin  # a top-level spec: no import happens
    except (ImportError, AttributeError, ValueError):
        return None
    if not origin or not origin.endswith("__init__.py"):
        return Path(origin) if origin and not rest and origin.endswith(".py") else None
    base = Path(origin).parent.joinpath(*rest.split(".")) if rest else Path(origin).parent
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _top_level(body: list[ast.stmt]) -> Iterator[ast.stmt]:
    """The module-level statements, also inside ``if``/``try`` (a guarded import): the
    imports a jitted function can see (it cannot import anything itself)."""
    for node in body:
        yield node
        if isinstance(node, ast.If | ast.Try):
            for block in (node.body, node.orelse, getattr(node, "finalbody", []),
                          *(h.body for h in getattr(node, "handlers", []))):
                yield from _top_level(block)


def _imports(name: str, path: Path) -> list[tuple[str, list[str]]]:
    """(module, names imported from it) for every module-level import in ``path`` of a
    module of the project (or of ``name``'s own top-level package); ``from . import x`` of
    a submodule gives the submodule. Parsed once per file and process."""
    key = (name, str(path))
    if key in _parsed:
        return _parsed[key]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    ours = {*_PROJECT, name.partition(".")[0]}
    out: list[tuple[str, list[str]]] = []
    for node in _top_level(ast.parse(path.read_bytes()).body):
        if isinstance(node, ast.Import):
            found = [(alias.name, []) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".") if package else []
                if node.level - 1 > len(parts):
                    continue
                parts = parts[:len(parts) - (node.level - 1)]
                base = ".".join([*parts, *([node.module] if node.module else [])])
            else:
                base = node.module or ""
            if base.partition(".")[0] not in ours:
                continue
            found = []
            for alias in node.names:
                submodule = f"{base}.{alias.name}"
                if alias.name != "*" and module_file(submodule) is not None:
                    found.append((submodule, []))
                else:
                    found.append((base, [alias.name]))
        else:
            continue
        out += [(module, names) for module, names in found
                if module and module.partition(".")[0] in ours]
    _parsed[key] = out
    return out


@functools.cache
def is_kernel_module(path: Path) -> bool:
    try:
        return bool(_IMPORTS_NUMBA.search(path.read_bytes()))
    except OSError:
        return False


def _plain(value) -> bytes | None:
    """A plain value's bytes (what numba would freeze into machine code), else None: an
    IntEnum class (a scratch array's named rows, cosim.records.Rows) by its members' names
    and numbers, which kernels index with."""
    if value is None or isinstance(value, bool | int | float | complex | str | bytes):
        return repr(value).encode()
    if isinstance(value, type) and issubclass(value, enum.IntEnum):
        return repr([(member.name, int(member)) for member in value]).encode()
    if isinstance(value, tuple | list | frozenset):
        items = [_plain(v) for v in value]
        return None if any(i is None for i in items) else b"(" + b",".join(items) + b")"
    tobytes = getattr(value, "tobytes", None)  # a numpy array or scalar
    if callable(tobytes) and hasattr(value, "dtype"):
        return f"{value.dtype}{getattr(value, 'shape', ())}".encode() + tobytes()
    return None


def _closure(name: str, path: Path) -> tuple[str, ...]:
    """``name`` and every kernel module it imports, directly or through other kernel
    modules, sorted: the modules whose sources its machine code can depend on. (A set, so
    that modules importing each other get one answer whatever the order.)"""
    if name in _closures:
        return _closures[name]
    seen, todo = {name: path}, [(name, path)]
    while todo:
        module, file = todo.pop()
        for imported, _ in _imports(module, file):
            found = module_file(imported)
            if imported not in seen and found is not None and is_kernel_module(found):
                seen[imported] = found
                todo.append((imported, found))
    _closures[name] = tuple(sorted(seen))
    return _closures[name]


def closure(name: str) -> tuple[str, ...]:
    """Module ``name`` and every kernel module it imports, directly or through others
    (none but itself where it has no source file)."""
    path = module_file(name)
    return _closure(name, path) if path is not None else (name,)


def module_digest(name: str, path: Path | None = None) -> str:
    """The digest of module ``name``'s kernel sources: its own source, the sources of its
    kernel-module closure, and the plain values those modules import from the project's
    other modules (read from the loaded modules; numba freezes such globals)."""
    if name in _digests:
        return _digests[name]
    path = path or module_file(name)
    if path is None:
        raise ValueError(f"{name}: no source file to version its kernels by")
    h = hashlib.sha256()
    for member in _closure(name, path):
        file = path if member == name else module_file(member)
        source = file.read_bytes()
        h.update(f"{member}\0{len(source)}\0".encode())
        h.update(source)
        for imported, names in sorted(_imports(member, file)):
            found = module_file(imported)
            if found is None or is_kernel_module(found):
                continue  # a kernel module is in the closure with its whole source
            loaded = sys.modules.get(imported)
            for attribute in names:
                value = _plain(getattr(loaded, attribute, None)) if loaded else None
                if value is not None:
                    h.update(f"{imported}.{attribute}=".encode() + value)
    _digests[name] = h.hexdigest()[:16]
    return _digests[name]


def versioned_here(module: str, path: str) -> bool:
    """Whether ``module``'s functions are versioned here: cosim's own, code outside the
    installed packages (a pipeline's plugin file, the generated fused loops), and an
    installed package's module that calls cosim's kernels (a plugin offered by an entry
    point). numba's own helpers and other libraries are not."""
    if module.partition(".")[0] in _PROJECT:
        return True
    try:
        resolved = Path(path).resolve()
    except OSError:
        return False
    if not str(resolved).startswith(_INSTALLED):
        return True
    return _imports_project(module, resolved)


@functools.cache
def _imports_project(module: str, path: Path) -> bool:
    """An installed module that imports cosim (or plant_fmu) itself: read only if its
    source names them at all (numba's own modules, compiling inside ours, never do)."""
    try:
        if not any(name.encode() in path.read_bytes() for name in _PROJECT):
            return False
        return any(m.partition(".")[0] in _PROJECT for m, _ in _imports(module, path))
    except (OSError, SyntaxError, ValueError):
        return False
