"""The run folder: summary.json (every run's metrics and safety checks, the files and how
they ended), trace_<run>.npz (every declared signal and its evaluation, SI units), and
whatever the other outputs write into it.

A run folder is never reused silently: one that holds files is refused unless ``force``
(which clears it first); a lock refuses a second writer; every file is written to a
temporary and renamed; summary.json is written after each run (marked running) and last
of all, and says complete only when every run is and every file it lists exists and
verifies.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import socket
import sys
import zipfile
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from .folder_owner import LOCK, refusal_reason
from .versions import package_versions

# summary.json is created at once, padded to this size, so that a full disk later still
# leaves room to say what is incomplete (rewritten in place when a fresh write fails).
SUMMARY_RESERVE = 256 * 1024
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class RunFolderError(RuntimeError):
    """The run folder cannot be used or written; the message names the path and why."""


def jsonable(x):
    """``x`` with numpy scalars as Python numbers and non-finite floats as None (JSON null)."""
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [jsonable(v) for v in x]
    if isinstance(x, float) and not np.isfinite(x):
        return None
    if isinstance(x, np.floating | np.integer):
        return jsonable(x.item())
    return x


def _verify(path: Path, suffix: str | None = None) -> str | None:
    """None if the file is whole, else why not (a quick structural check by ``suffix``, the
    final name's: a temporary's own is .tmp)."""
    suffix = path.suffix if suffix is None else suffix
    if not path.is_file():
        return "missing"
    if path.stat().st_size == 0:
        return "empty"
    if suffix == ".npz":
        try:
            with zipfile.ZipFile(path) as archive:
                bad = archive.testzip()
        except (zipfile.BadZipFile, OSError) as exc:
            return f"not a readable npz ({exc})"
        return f"entry {bad} is damaged" if bad else None
    if suffix == ".png":
        with path.open("rb") as f:
            return None if f.read(8) == PNG_MAGIC else "not a PNG"
    return None


class RunFolder:
    """A run folder being written; use :meth:`create`."""

    def __init__(self, path: Path, lock_file):
        self.path = path
        self._lock = lock_file
        self.files: dict[str, dict] = {}
        self.started = datetime.now(UTC).isoformat(timespec="seconds")
        # the files the pipeline names, with their digests (cosim.config.named_files)
        self.named_files: list[dict] = []

    @classmethod
    def create(cls, path: str | Path, force: bool = False, keep: bool = False,
               option: str = "--out") -> RunFolder:
        """The folder at ``path``, locked: emptied (refused if it holds files, unless
        ``force`` and they are cosim's), or, ``keep``, as it is (a sweep resumed there).
        ``option``: what named the folder, for messages."""
        path = Path(path)
        try:
            if path.exists() and not path.is_dir():
                raise RunFolderError(f"{option} {path}: is a file, not a folder; choose "
                                     "another --out")
            path.mkdir(parents=True, exist_ok=True)
            lock_file = (path / LOCK).open("a+")
        except OSError as exc:
            raise RunFolderError(f"{option} {path}: cannot create the run folder there: "
                                 f"{exc.strerror or exc}") from None
        try:
            fcntl.flock(lock_file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock_file.seek(0)
            owner = lock_file.read().strip() or "unknown"
            lock_file.close()
            raise RunFolderError(f"{option} {path}: another cosim run is writing this folder "
                                 f"(pid {owner}); wait for it, or choose another --out") from None
        folder = cls(path, lock_file)
        if keep:
            lock_file.seek(0)
            lock_file.truncate()
            lock_file.write(str(os.getpid()))
            lock_file.flush()
            return folder
        existing = sorted(p.name for p in path.iterdir() if p.name != LOCK)
        refusal = refusal_reason(path, existing, force)
        if refusal:
            folder.release()
            raise RunFolderError(refusal)
        try:
            for name in existing:
                entry = path / name
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry)
                else:
                    entry.unlink()
            lock_file.seek(0)
            lock_file.truncate()
            lock_file.write(str(os.getpid()))
            lock_file.flush()
            placeholder = json.dumps({"complete": False, "status": "starting",
                                      "provenance": folder._provenance()}, indent=2)
            folder.write("summary.json",
                         lambda tmp: tmp.write_text(placeholder.ljust(SUMMARY_RESERVE) + "\n"))
        except (OSError, RunFolderError) as exc:
            folder.release()
            why = exc.strerror if isinstance(exc, OSError) else str(exc)
            raise RunFolderError(f"--out {path}: cannot prepare it: {why}") from None
        return folder

    def release(self) -> None:
        if self._lock is not None:
            try:
                (self.path / LOCK).unlink(missing_ok=True)
            except OSError:
                pass
            self._lock.close()
            self._lock = None

    # Writing ----------------------------------------------------------------------------------

    def write(self, name: str, produce: Callable[[Path], None]) -> None:
        """``produce(tmp)`` writes the file at a temporary path, which is then verified and
        renamed to ``name``. An OS error (disk full, permissions) raises
        :class:`RunFolderError` naming the file; the file is listed as incomplete."""
        target = self.path / name
        tmp = self.path / f".{name}.tmp"
        try:
            produce(tmp)
            problem = _verify(tmp, target.suffix)
            if problem:
                raise OSError(f"the written file is {problem}")
            os.replace(tmp, target)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            reason = exc.strerror or str(exc)
            self.files[name] = {"complete": False, "reason": reason}
            raise RunFolderError(f"{target}: could not be written: {reason}") from None
        self.files[name] = {"complete": True, "bytes": target.stat().st_size}

    def disk_full(self) -> bool:
        try:
            return os.statvfs(self.path).f_bavail == 0
        except OSError:
            return False

    def note(self, name: str, complete: bool, reason: str = "") -> None:
        """Record a file another process wrote (the recording) and how it ended."""
        path = self.path / name
        problem = _verify(path)
        if problem is None and self.disk_full():
            problem = "the disk is full: it was cut short"
        entry = {"complete": complete and problem is None}
        if path.is_file():
            entry["bytes"] = path.stat().st_size
        if reason or problem:
            entry["reason"] = reason or problem
        self.files[name] = entry

    def incomplete(self, name: str, reason: str) -> None:
        self.files[name] = {"complete": False, "reason": reason}

    def write_trace(self, name: str, trace, evaluation=None) -> None:
        """trace_<name>.npz: the time column and every signal of the completed rows, and
        their evaluation: ``check_<name>`` (each safety check's value) and
        ``barrier_<name>`` (H1, H2, H and the condition Ḣ + αH). ``units`` (a JSON string)
        gives each array's unit and meaning, so the file describes itself."""
        from ..evaluate.parts import EVALUATORS

        meanings = {n: m for cls in EVALUATORS.values() for n, m in cls.series_meanings.items()}

        extra = {}
        units = {"time": {"unit": "s", "description": "time t_k = k·step"}}
        units.update({n: {"unit": s.unit, "description": s.description}
                      for n, s in trace.signals.items()})
        if evaluation is not None:
            extra.update({f"check_{n}": c.value for n, c in evaluation.checks.items()})
            extra.update({f"barrier_{n}": v for n, v in evaluation.barriers.items()})
            units.update({f"check_{n}": {
                "unit": c.declared.unit if c.declared else "",
                "description": f"{c.label or n}: the value the {n} check bounds by {c.upper:g}"}
                for n, c in evaluation.checks.items()})
            units.update({f"barrier_{n}": {"unit": "", "description": meanings.get(n, n)}
                          for n in evaluation.barriers})
        extra[UNITS_KEY] = np.array(json.dumps(units, ensure_ascii=False))

        entries = {"time": trace.time, **trace.arrays, **extra}

        def produce(tmp: Path) -> None:
            # np.savez's format, uncompressed: the signals are floats that deflate barely
            # shrinks (to 0.79 of their size, the paper's run), for 0.35 s a trace (0.26 s
            # at zlib's fastest level) on the way between one run and the next, against
            # 0.01 s stored. np.load reads both alike. Written entry by entry rather than
            # through np.savez's keywords, which a signal named ``file`` or
            # ``allow_pickle`` would collide with.
            with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as archive:
                for key, values in entries.items():
                    with archive.open(f"{key}.npy", "w", force_zip64=True) as f:
                        np.lib.format.write_array(f, np.asanyarray(values),
                                                  allow_pickle=False)

        self.write(f"trace_{name}.npz", produce)

    def write_summary(self, summary: dict, final: bool) -> bool:
        """summary.json: ``summary`` with the folder's provenance and its files. Final:
        complete only if the runs are and every listed file is. Returns that."""
        runs_complete = bool(summary.get("complete"))
        files_complete = all(f["complete"] for f in self.files.values())
        document = {
            "complete": final and runs_complete and files_complete,
            "status": ("complete" if final and runs_complete and files_complete
                       else "incomplete" if final else "running"),
            **{k: v for k, v in summary.items() if k != "complete"},
            "files": {k: v for k, v in sorted(self.files.items()) if k != "summary.json"},
            "provenance": self._provenance(),
        }
        text = json.dumps(jsonable(document), indent=2) + "\n"
        # until the final one, padded as the placeholder is: the space the final summary
        # may need on a full disk stays reserved (JSON allows the trailing blanks)
        written = text if final else text.rstrip("\n").ljust(SUMMARY_RESERVE) + "\n"
        try:
            self.write("summary.json", lambda tmp: tmp.write_text(written))
        except RunFolderError:
            self._rewrite_in_place("summary.json", text)
        return document["complete"]

    def _provenance(self) -> dict:
        return {"command": list(sys.argv), "started": self.started,
                "written": datetime.now(UTC).isoformat(timespec="seconds"),
                "host": socket.gethostname(), "versions": package_versions(),
                **({"files": self.named_files} if self.named_files else {})}

    def _rewrite_in_place(self, name: str, text: str) -> None:
        """Overwrite the reserved file's own blocks (no new space needed on a full disk)."""
        target = self.path / name
        data = text.encode()
        try:
            with target.open("r+b") as f:
                if len(data) > f.seek(0, os.SEEK_END):
                    raise OSError("the reserved space is too small")
                f.seek(0)
                f.write(data)
                f.truncate(len(data))
        except OSError as exc:
            raise RunFolderError(f"{target}: could not be written: "
                                 f"{exc.strerror or exc}") from None
        self.files[name] = {"complete": True, "bytes": len(data)}


UNITS_KEY = "_units"  # the trace file's array of units and meanings (a JSON string)
def new_run_folder(base: str | Path, create: bool = True) -> Path:
    """A run folder that never collides: ``base/YYYYmmdd-HHMMSS`` (``-2``, ``-3``, … for
    runs started within the same second), made at once so that two runs cannot pick the
    same one (``create=False``: only named, for --dry-run)."""
    base = Path(base)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    for attempt in range(1, 1000):
        path = base / (stamp if attempt == 1 else f"{stamp}-{attempt}")
        if not create:
            if not path.exists():
                return path
            continue
        try:
            path.mkdir(parents=True)
            return path
        except FileExistsError:
            continue
        except OSError as exc:
            raise RunFolderError(f"cannot create a run folder in {base}: "
                                 f"{exc.strerror or exc}; give --out") from None
    raise RunFolderError(f"{base}: 999 run folders started in one second; give --out")


LATEST = "latest"


def point_latest(out: Path) -> str | None:
    """``out``'s parent/latest → ``out`` (a relative link, replaced atomically), unless it
    points to a run started later already. A ``latest`` that is not a link is the user's:
    left alone, and what to tell the user of it returned (else None)."""
    link = out.parent / LATEST
    if link.exists() and not link.is_symlink():
        what = "a folder" if link.is_dir() else "a file"
        return (f"{link} is {what} cosim did not make, so it was left as it is and does not "
                f"lead to this run: view this one with cosim view {out}")
    if link.is_symlink() and (link.parent / os.readlink(link)).is_dir() \
            and os.readlink(link) > out.name:
        return  # a run started later (the names are start times) is the latest already
    tmp = out.parent / f".{LATEST}.{os.getpid()}.tmp"
    try:
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(out.name, target_is_directory=True)
        os.replace(tmp, link)
    except OSError:  # a file system without links: the folder itself is what matters
        tmp.unlink(missing_ok=True)
