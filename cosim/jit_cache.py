"""Where numba caches the compiled kernels: a folder per kernel module and version of its
sources, so that an edited kernel recompiles only the kernels it can change.

Numba checks a cached function against its own file only, not against the jitted functions
it calls in other files (a kernel calling ``inertia.chain_bias``, the fused loop calling
every kernel of its chain), nor against the constants it froze in from other modules, so an
edited callee would leave stale machine code. Every function of a module of ours is
therefore cached in ``<cache>/<module>-<digest>``, the digest taken over the module's
source and, recursively, the source of every *kernel module* it imports (one that imports
numba or cosim.numba_compat), plus the plain values (numbers, strings, tuples, arrays) it
imports from the project's other modules. Editing ``observer.py`` recompiles the observer's
kernels and the fused loops that call them; the sensor's, the controller's and the
filter's stay cached.
Modules outside the project (numba's own, a library's) keep numba's own locators.

``$NUMBA_CACHE_DIR`` (else ``~/.cache/cosim/numba``) holds the folders.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib.util
import os
import re
import sys
import sysconfig
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TextIO

from .numba_compat import cache_locator_base, prepend_cache_locator

_PACKAGE = Path(__file__).parent
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


def default_base() -> Path:
    return Path(os.environ.get("NUMBA_CACHE_DIR") or Path.home() / ".cache" / "cosim" / "numba")


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
def _is_kernel_module(path: Path) -> bool:
    try:
        return bool(_IMPORTS_NUMBA.search(path.read_bytes()))
    except OSError:
        return False


def _plain(value) -> bytes | None:
    """A plain value's bytes (what numba would freeze into machine code), else None."""
    if value is None or isinstance(value, bool | int | float | complex | str | bytes):
        return repr(value).encode()
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
            if imported not in seen and found is not None and _is_kernel_module(found):
                seen[imported] = found
                todo.append((imported, found))
    _closures[name] = tuple(sorted(seen))
    return _closures[name]


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
            if found is None or _is_kernel_module(found):
                continue  # a kernel module is in the closure with its whole source
            loaded = sys.modules.get(imported)
            for attribute in names:
                value = _plain(getattr(loaded, attribute, None)) if loaded else None
                if value is not None:
                    h.update(f"{imported}.{attribute}=".encode() + value)
    _digests[name] = h.hexdigest()[:16]
    return _digests[name]


def _ours(module: str, path: str) -> bool:
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


# The numba locator -------------------------------------------------------------------------

def _locator_class():
    """numba's cache locator for our modules (made on first use: numba loads lazily)."""

    class KernelModuleLocator(cache_locator_base()):
        """Caches a function of ours in ``<base>/<module>-<digest>``; its source stamp is
        that digest, so only a change of what it depends on makes it stale (not a touched
        file or a fresh checkout)."""

        def __init__(self, py_func, py_file: str):
            import numba

            # numba reads both where a function cannot be cached (a large global array):
            # its warning names the file and line
            self._py_file, self._lineno = py_file, py_func.__code__.co_firstlineno
            module = py_func.__module__
            self._digest = module_digest(module, Path(py_file))
            base = numba.config.CACHE_DIR or str(default_base())
            self._cache_path = os.path.join(base, f"{module}-{self._digest}")

        def get_cache_path(self) -> str:
            return self._cache_path

        def get_source_stamp(self) -> str:
            return self._digest

        def get_disambiguator(self) -> str:
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file: str):
            module = getattr(py_func, "__module__", None) or ""
            if not os.path.isfile(py_file) or not _ours(module, py_file):
                return None  # numba's next locator takes it
            try:
                self = cls(py_func, py_file)
                self.ensure_cache_path()
            except (OSError, SyntaxError, ValueError):
                return None
            return self

    return KernelModuleLocator


def use_versioned_cache() -> Path:
    """Point numba's cache at ``$NUMBA_CACHE_DIR`` (else ~/.cache/cosim/numba) and version
    each of our modules' kernels in a folder of its own there. Called before any kernel is
    compiled or loaded (cosim.blocks does it on import). Returns the base folder."""
    import numba

    base = default_base()
    numba.config.CACHE_DIR = str(base)
    prepend_cache_locator(_locator_class())
    _tolerate_damaged_entries()
    _serialise_saves()
    return base


def _tolerate_damaged_entries() -> None:
    """A damaged cache entry (a truncated or corrupted index or data file: a disk that
    filled, a copy cut short) is a cache miss, compiled again and rewritten, rather than an
    error every later run meets (numba raises the unpickling error as it is)."""
    from numba.core import caching

    original = caching.Cache.load_overload
    if getattr(original, "tolerates_damage", False):
        return

    def load_overload(self, sig, target_context):
        try:
            return original(self, sig, target_context)
        except Exception:  # noqa: BLE001 (pickle, EOF, zlib, OS errors: all mean damaged)
            index = getattr(getattr(self, "_cache_file", None), "_index_path", None)
            if index:
                try:
                    os.unlink(index)  # the data files it listed are replaced on saving
                except OSError:
                    pass
            return None

    load_overload.tolerates_damage = True
    caching.Cache.load_overload = load_overload


def _serialise_saves() -> None:
    """One process at a time saves an entry of a function's cache. numba saves one by
    reading the function's index, choosing the first data file name it does not list,
    writing the index and then the data, with no lock: two processes compiling signatures of
    one function at once (the warm-up's workers, the test suite's) can both read the same
    index and choose the same name, and the index then points one signature at the other's
    machine code. An exclusive lock on a file beside the index (``….nbi.lock``) makes each
    save read the index the one before it wrote."""
    try:
        import fcntl
    except ImportError:  # not POSIX: numba's saves as they are
        return
    from numba.core import caching

    original = caching.IndexDataCacheFile.save
    if getattr(original, "serialised", False):
        return

    @functools.wraps(original)  # numba's own as save.__wrapped__
    def save(self, key, data):
        try:
            lock = open(f"{self._index_path}.lock", "a")  # noqa: SIM115 (closed below)
        except OSError:  # an unwritable folder: numba's own save meets it as numba does
            return original(self, key, data)
        with lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released as the file closes
            return original(self, key, data)

    save.serialised = True
    caching.IndexDataCacheFile.save = save


def kernel_modules() -> list[tuple[str, Path]]:
    """cosim's own kernel modules (name, file): the blocks', the nominal models'
    (cosim.dynamics), the paper's and the engine's, also those of their subpackages."""
    found = []
    for folder in ("blocks", "dynamics", "paper", "engine"):
        for path in sorted((_PACKAGE / folder).rglob("*.py")):
            if _is_kernel_module(path):
                parts = path.relative_to(_PACKAGE).with_suffix("").parts
                if parts[-1] == "__init__":
                    parts = parts[:-1]
                found.append((".".join(("cosim", *parts)), path))
    return found


def cache_folder(name: str, path: Path | None = None) -> Path:
    """The folder module ``name``'s kernels are cached in, for its sources as they are."""
    import numba

    base = numba.config.CACHE_DIR or str(default_base())
    return Path(base) / f"{name}-{module_digest(name, path)}"


def cache_is_cold() -> bool:
    """True when numba's cache holds no compiled kernel of cosim's kernel modules as their
    sources are now: the first run after installing or updating cosim without its set-up
    step (`cosim warm-up`, which `make demo` and `make test` run), which compiles every
    kernel it steps before the loop starts."""
    return not any(any(cache_folder(name, path).glob("*.nbi"))
                   for name, path in kernel_modules() if cache_folder(name, path).is_dir())


# Saying what compiles, while it compiles ---------------------------------------------------

@contextmanager
def announce_compiles(stream: TextIO, indent: str = "  ",
                      header: bool = True) -> Iterator[list[str]]:
    """While inside, say on ``stream`` what numba compiles (not what it loads from the
    cache): a header as the first compile starts (unless not ``header``), then one line per
    module of ours as its kernels are done, with the seconds they took (a fused loop's own,
    without the kernels it waited for), so that a compile of seconds to a minute is never
    silent. Yields the list of what was compiled."""
    from numba.core import event

    compiled: list[str] = []
    # One frame per compile of ours in progress: [label, began, seconds of nested lines].
    frames: list[list] = []

    def label_of(function) -> str | None:
        module = getattr(function, "__module__", "") or ""
        code = getattr(function, "__code__", None)
        if not _ours(module, getattr(code, "co_filename", "")):
            return None  # numba's own helpers compile inside ours, and count with them
        if module.startswith("cosim_fused_"):
            names = sorted((k, getattr(v, "__name__", "?"))
                           for k, v in function.__globals__.items()
                           if k.startswith("kernel_"))
            return f"the fused loop of {', '.join(n for _, n in names) or 'no kernel'}"
        return module

    class Listener(event.Listener):
        def on_start(self, ev) -> None:
            label = label_of(getattr(ev.data.get("dispatcher"), "py_func", None))
            if label is None:
                return
            if header and not compiled and not frames:
                print(f"{indent}compiling numba kernels (once per version of their "
                      "sources and kind of arm, planar or from a URDF, not per robot: a "
                      "first filtered run takes minutes on 2 cores, `cosim warm-up "
                      "PIPELINE` does it ahead; cached for later runs):", file=stream,
                      flush=True)
            frames.append([label, time.monotonic(), 0.0])

        def on_end(self, ev) -> None:
            label = label_of(getattr(ev.data.get("dispatcher"), "py_func", None))
            if label is None or not frames:
                return
            label, began, nested = frames.pop()
            took = time.monotonic() - began
            if frames and frames[-1][0] == label:
                return  # a helper of the same module: its time is the caller's
            if frames:
                frames[-1][2] += took
            if label not in compiled:
                compiled.append(label)
            print(f"{indent}  {label}: {took - nested:.1f} s", file=stream, flush=True)

    listener = Listener()
    event.register("numba:compile", listener)
    try:
        yield compiled
    finally:
        event.unregister("numba:compile", listener)
