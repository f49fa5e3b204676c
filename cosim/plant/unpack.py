"""Unpacking an FMU to load its binary: only safe entries, bounded in size, into a temporary
folder that this process owns and removes when it closes the plant or ends.

A folder is named ``cosim_fmu_<pid>_<random>`` in the system's temporary folder, so that one
left behind by a process that died without cleaning up (killed, crashed) is recognised as
ours and stale, and removed the next time any cosim process unpacks an FMU. Sweep workers
keep their FMU open between points and end without closing it: they are covered by the
exit hooks below (``atexit`` for a normal interpreter exit, multiprocessing's finalizers for
a worker process, which skips ``atexit``).
"""

from __future__ import annotations

import atexit
import contextlib
import multiprocessing.util
import os
import re
import shutil
import signal
import tempfile
import threading
import zipfile
from pathlib import Path, PurePosixPath
from zlib import error as zlib_error

from .errors import FmuError

# An FMU is a model's binaries plus its resources: tens of MB is large. The caps stop an
# archive that unpacks to far more than it weighs (a "zip bomb": 2 GB of zeros in 2 MB) before
# a byte is written. Raise them with the environment variables for a truly large FMU.
_BAD_CAPS: list[str] = []  # a cap's variable set to what is not a count: said at first use


def _cap(variable: str, default: int) -> int:
    """A cap from the environment (a whole number > 0), else ``default``; a bad value is
    noted, to be said when an FMU is unpacked (not a traceback at import)."""
    text = os.environ.get(variable, "").strip()
    if not text:
        return default
    if text.isdigit() and int(text) > 0:
        return int(text)
    _BAD_CAPS.append(f"{variable}={text!r}: expected a whole number > 0 (default {default})")
    return default


MAX_MEGABYTES = _cap("COSIM_FMU_MAX_MB", 1024)  # uncompressed, MB
MAX_ENTRIES = _cap("COSIM_FMU_MAX_FILES", 10000)
PREFIX = "cosim_fmu_"
_OURS = re.compile(rf"^{PREFIX}(\d+)_")
_open: set[str] = set()  # folders this process unpacked and has not removed yet


def unsafe_entries(path: str | Path) -> list[str]:
    """Archive entries that would land outside the folder they are extracted to (``../``,
    absolute paths, drive letters): a real FMU never holds one."""
    with zipfile.ZipFile(path) as archive:
        names = archive.namelist()
    unsafe = []
    for name in names:
        pure = PurePosixPath(name.replace("\\", "/"))
        if pure.is_absolute() or ":" in name or ".." in pure.parts:
            unsafe.append(name)
    return unsafe


def size_problem(path: str | Path) -> str | None:
    """Why ``path`` is too large to unpack (its entry count or uncompressed size above the
    caps), or None; read from the archive's directory, nothing is unpacked."""
    if _BAD_CAPS:
        return _BAD_CAPS[0]
    with zipfile.ZipFile(path) as archive:
        entries = archive.infolist()
    total = sum(entry.file_size for entry in entries)
    if len(entries) > MAX_ENTRIES:
        return (f"it holds {len(entries)} files, more than the {MAX_ENTRIES} cosim unpacks "
                "(set COSIM_FMU_MAX_FILES to allow more)")
    if total > MAX_MEGABYTES * 1e6:
        return (f"it unpacks to {total / 1e6:,.0f} MB, more than the {MAX_MEGABYTES} MB cosim "
                "unpacks (set COSIM_FMU_MAX_MB to allow more)")
    return None


CHUNK = 1 << 20  # bytes read at a time while checking or unpacking an entry


def damaged_entry(path: str | Path) -> str | None:
    """Why the archive is damaged (an entry failing its CRC check), or None. An archive
    beyond the caps is not read at all (:func:`size_problem` says why, where it is
    unpacked); otherwise each entry is read as a stream, abandoned at the first byte beyond
    the cap, so a zip bomb costs nothing."""
    if size_problem(path):
        return None
    total = 0
    with zipfile.ZipFile(path) as archive:
        for entry in archive.infolist():
            try:
                with archive.open(entry) as stream:
                    while chunk := stream.read(CHUNK):
                        total += len(chunk)
                        if total > MAX_MEGABYTES * 1e6:
                            return (f"it unpacks to more than the {MAX_MEGABYTES} MB cosim "
                                    "unpacks (set COSIM_FMU_MAX_MB to allow more)")
            except (zipfile.BadZipFile, OSError, EOFError, zlib_error):
                return f"the archive is damaged: entry {entry.filename!r} fails its CRC check"
    return None


def extract(path: str | Path) -> str:
    """Unzip into a fresh temporary folder of this process, refusing an archive with unsafe
    entries or beyond the caps; an interrupted unzip leaves nothing behind."""
    path = Path(path)
    unsafe = unsafe_entries(path)
    if unsafe:
        raise FmuError(f"{path}: refusing to extract: the archive entry {unsafe[0]!r} "
                          "points outside the FMU's folder")
    problem = size_problem(path)
    if problem:
        raise FmuError(f"{path}: refusing to extract: {problem}")
    remove_stale()
    with _signals_held():  # made and registered at once: an interruption finds it in _open
        target = str(Path(tempfile.mkdtemp(prefix=f"{PREFIX}{os.getpid()}_")).resolve())
        _open.add(target)
    try:
        _extract_capped(path, Path(target))
    except BaseException:  # Ctrl-C, SIGTERM, a full disk: no half-unpacked FMU is left
        remove(target)
        raise
    return target


@contextlib.contextmanager
def _signals_held():
    """SIGINT and SIGTERM held back (in the main thread: a handler runs there) until the
    block ends, then delivered."""
    held = {signal.SIGINT, signal.SIGTERM}
    main = threading.current_thread() is threading.main_thread()
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held) if main else None
    try:
        yield
    finally:
        if previous is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _extract_capped(path: Path, target: Path) -> None:
    """Unzip entry by entry as streams, counting the bytes actually written against the
    cap (not only what the archive's directory declares)."""
    total = 0
    with zipfile.ZipFile(path) as archive:
        for entry in archive.infolist():
            destination = target / PurePosixPath(entry.filename.replace("\\", "/"))
            if entry.is_dir():
                destination.mkdir(parents=True, exist_ok=True)
                continue
            destination.parent.mkdir(parents=True, exist_ok=True)
            with archive.open(entry) as stream, destination.open("wb") as out:
                while chunk := stream.read(CHUNK):
                    total += len(chunk)
                    if total > MAX_MEGABYTES * 1e6:
                        raise FmuError(f"{path}: refusing to extract: it unpacks to more "
                                       f"than the {MAX_MEGABYTES} MB cosim unpacks (set "
                                       "COSIM_FMU_MAX_MB to allow more)")
                    out.write(chunk)
            mode = entry.external_attr >> 16
            if mode & 0o111:  # keep an executable bit (a binary's own tools)
                destination.chmod(0o755)


def remove(folder: str) -> None:
    """Remove a folder :func:`extract` made (and forget it)."""
    shutil.rmtree(folder, ignore_errors=True)
    _open.discard(folder)


def remove_all() -> None:
    """Every folder this process unpacked and still holds (at exit)."""
    for folder in list(_open):
        remove(folder)


def remove_stale() -> list[str]:
    """Remove the unpacked FMUs of cosim processes that no longer exist; returns them."""
    removed = []
    root = Path(tempfile.gettempdir())
    for folder in root.glob(f"{PREFIX}*_*"):
        match = _OURS.match(folder.name)
        if match and folder.is_dir() and not folder.is_symlink() \
                and not _alive(int(match.group(1))):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(str(folder))
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        return True
    return True


atexit.register(remove_all)
multiprocessing.util.Finalize(None, remove_all, exitpriority=10)
