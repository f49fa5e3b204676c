"""Where numba caches the compiled kernels: a folder per kernel module and version of its
sources, so that an edited kernel recompiles only the kernels it can change.

Numba checks a cached function against its own file only, not against the jitted functions
it calls in other files (a kernel calling ``inertia.chain_bias``, the fused loop calling
every kernel of its chain), nor against the constants it froze in from other modules, so an
edited callee would leave stale machine code. Every function of a module of ours is
therefore cached in ``<cache>/<module>-<digest>``, the digest that of its kernel sources
(:mod:`cosim.kernel_digest`). Editing ``observer.py`` recompiles the observer's kernels and
the fused loops that call them; the sensor's, the controller's and the filter's stay cached.
Modules outside the project (numba's own, a library's) keep numba's own locators. Two
processes saving at once, and a damaged entry, are handled here too.

``$NUMBA_CACHE_DIR`` (else ``~/.cache/cosim/numba``) holds the folders.
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TextIO

from .kernel_digest import is_kernel_module, module_digest, versioned_here
from .numba_compat import cache_locator_base, prepend_cache_locator

_PACKAGE = Path(__file__).parent


def default_base() -> Path:
    return Path(os.environ.get("NUMBA_CACHE_DIR") or Path.home() / ".cache" / "cosim" / "numba")


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
            if not os.path.isfile(py_file) or not versioned_here(module, py_file):
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
            if is_kernel_module(path):
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
        if not versioned_here(module, getattr(code, "co_filename", "")):
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
