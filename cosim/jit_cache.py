"""Where numba caches the compiled kernels: a folder per version of their sources.

Numba checks a cached function against its own file only, not against the jitted functions
it calls in other files (a kernel calling ``inertia.planar_bias``, the fused loop calling
every kernel), so an edited callee would leave stale machine code. Keying the cache folder
by a digest of every file kernels come from makes any edit a fresh cache.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

_PACKAGE = Path(__file__).parent
_SOURCES = ("blocks", "engine")  # where kernels and the fused loop's template live


def sources_digest() -> str:
    h = hashlib.sha256()
    for folder in _SOURCES:
        for path in sorted((_PACKAGE / folder).glob("*.py")):
            h.update(path.name.encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


def use_versioned_cache() -> Path:
    """Point numba's cache at ``$NUMBA_CACHE_DIR`` (else ~/.cache/cosim/numba) / digest.
    Called before any kernel is compiled or loaded."""
    import numba

    base = os.environ.get("NUMBA_CACHE_DIR") or str(Path.home() / ".cache" / "cosim" / "numba")
    folder = Path(base) / sources_digest()
    numba.config.CACHE_DIR = str(folder)
    return folder


def cache_is_cold() -> bool:
    """True when numba's cache for these sources holds no compiled kernel yet: the first run
    after installing or updating cosim, which compiles every kernel it steps (~30 s on 2
    cores) before the loop starts."""
    import numba

    folder = Path(numba.config.CACHE_DIR)
    return not (folder.is_dir() and any(folder.rglob("*.nbi")))
