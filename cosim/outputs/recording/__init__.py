"""The Rerun recording of a pipeline: every declared signal, safe-set bound and barrier
value, written by a writer process (:mod:`.writer`) in the layout of :mod:`.layout`.
:class:`Recorder` is the parent's handle on it."""

from __future__ import annotations

import contextlib
import fcntl
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Mapping
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

# Not .writer: it runs as its own process (python -m), and importing it here first would
# make runpy warn.
from .layout import (
    BOUND_COLOR,
    JOINT_COLORS,
    VIOLATION_COLOR,
    RunSpec,
    UrdfArm,
    derived_entities,
)

F_SETPIPE_SZ = getattr(fcntl, "F_SETPIPE_SZ", 1031)  # Linux; elsewhere the call just fails
PIPE_BYTES = 1 << 20

__all__ = ["BOUND_COLOR", "JOINT_COLORS", "VIOLATION_COLOR", "Recorder", "derived_entities",
           "RecordingError", "RunSpec", "UrdfArm"]


class RecordingError(RuntimeError):
    """The recording could not be written; the message says where and why."""


class Recorder:
    """Writes ``path`` (recording.rrd) from trace rows, in a writer process.

    ``spawn`` starts a Rerun viewer that follows the run live; ``connect`` streams to a viewer
    already running at that URL (``rerun+http://host:port/proxy``). The file is written in
    either case.
    """

    def __init__(self, path: str | Path, name: str, run_names: list[str],
                 spawn: bool = False, connect: str | None = None, port: int = 9876,
                 views: dict[str, list] | None = None,
                 error_views: dict[str, list] | None = None,
                 check_views: dict[str, list] | None = None,
                 spatial: list[str] | None = None):
        self.path = Path(path)
        self.sent: dict[str, int] = {}
        self.handoff_seconds = 0.0  # time the caller spent handing rows over
        self._error: str | None = None
        self._ready = False
        header = {"name": name, "runs": run_names, "recording_id": str(uuid.uuid4()),
                  "views": views or {}, "error_views": error_views or {},
                  "check_views": check_views or {}, "spatial": spatial or []}
        live = {"spawn": spawn, "connect": connect, "port": port, "viewer": None}
        if spawn:
            from ..viewer import has_display, viewer_binary

            if not has_display():
                raise RecordingError("--spawn needs a display (DISPLAY and WAYLAND_DISPLAY "
                                     "are unset): run without it and open the recording "
                                     "with `cosim view` where there is one, or stream to a "
                                     "viewer with --connect URL")
            live["viewer"] = str(viewer_binary())
        # A plain child interpreter (not multiprocessing), so that calling run() from a
        # script without a __main__ guard works; two pipes carry pickled messages.
        from_parent, to_child = os.pipe()  # (read end, write end)
        from_child, to_parent = os.pipe()
        # Room for a few seconds of rows, so that handing a chunk over is a copy into the
        # pipe and the loop does not wait while the writer is busy with the previous one.
        with contextlib.suppress(OSError):
            fcntl.fcntl(to_child, F_SETPIPE_SZ, PIPE_BYTES)
        self._process = subprocess.Popen(
            [sys.executable, "-m", "cosim.outputs.recording.writer", str(from_parent),
             str(to_parent)],
            # The writer reports its own errors over the pipe; Rerun's log lines (a full
            # disk repeats one per chunk) would only break the one-line messages.
            pass_fds=(from_parent, to_parent), stderr=subprocess.DEVNULL)
        os.close(from_parent)
        os.close(to_parent)
        self._outbox = Connection(to_child, readable=False)
        self._inbox = Connection(from_child, writable=False)
        self._send((str(self.path), header, live))

    def _send(self, message: tuple, then=None) -> None:
        """Send ``message``, then call ``then()`` (bookkeeping), with Ctrl-C and SIGTERM
        held until both are done."""
        if self._error is not None:
            return  # the writer is gone; close() reports why
        # Ctrl-C or SIGTERM in the middle of a message would leave half of it in the pipe
        # (a large message is written in several os.write calls, and Python runs a signal's
        # handler between them). Blocking the signals is not enough: the kernel may deliver
        # them to another thread (OpenBLAS's), and the main thread then runs the handler at
        # its next bytecode. So their handlers are deferred until the message is written.
        pending: list[int] = []
        deferred = {}
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                deferred[signum] = signal.signal(signum, lambda s, _: pending.append(s))
        try:
            self._outbox.send(message)
            if then is not None:
                then()
        except OSError:
            kind, text = self._receive(5.0)
            self._error = text if kind == "error" else "the recording writer stopped"
        finally:
            for signum, handler in deferred.items():
                signal.signal(signum, handler)
            for signum in pending:  # now, with the message whole
                signal.raise_signal(signum)

    def _receive(self, timeout: float) -> tuple[str, str]:
        """The writer's next message, (kind, text); ("error", why) if none comes in
        ``timeout`` seconds or the pipe is closed."""
        try:
            if self._inbox.poll(timeout):
                return self._inbox.recv()
        except (EOFError, OSError):
            return "error", "the recording writer stopped unexpectedly"
        return "error", f"the recording writer did not answer within {timeout:g} s"

    def wait_ready(self, timeout: float = 60.0) -> None:
        """Block until the writer has opened its sinks (it imports Rerun first, about half a
        second), so that chunks do not pile up in the pipe while the loop runs. Called by
        the first :meth:`send_rows`, which the master makes at step 0, outside its timing
        and while the blocks' JIT kernels load. Raises :class:`RecordingError` if the writer
        could not start."""
        if self._ready or self._error is not None:
            return
        kind, text = self._receive(timeout)
        if kind != "ready":
            self._error = text
            raise RecordingError(f"{self.path}: the recording writer did not start: {text}")
        self._ready = True

    def set_properties(self, properties: dict[str, dict]) -> None:
        """Recording properties: name -> {field: value}."""
        self._send(("properties", properties))

    def begin_run(self, spec: RunSpec) -> None:
        self.sent[spec.name] = 0
        self._send(("begin", spec))

    def send_rows(self, run: str, start: int, stop: int, rows: Mapping[str, np.ndarray],
                  checks: Mapping[str, np.ndarray], barriers: Mapping[str, np.ndarray]) -> None:
        """Send one chunk of a run: the recorded signals' rows [start, stop), with their
        evaluated check and barrier values. Completed rows are never written again, so
        the views are sent as they are, without a copy."""
        if stop <= start:
            return
        self.wait_ready()  # the first call waits (the writer imports Rerun meanwhile)
        began = time.perf_counter()
        self._send(("rows", run, start, stop, dict(rows), dict(checks), dict(barriers)),
                   then=lambda: self.sent.__setitem__(run, stop))
        self.handoff_seconds += time.perf_counter() - began

    def end_run(self, run: str, summary: dict) -> None:
        self._send(("end", run, summary))

    def close(self, complete: bool, reason: str = "", timeout: float = 120.0) -> None:
        """Finish the file. Raises :class:`RecordingError` if the writer failed."""
        self._send(("close", {"complete": complete, "reason": reason}))
        if self._error is None:
            kind, text = self._receive(timeout)
            if kind == "ready":  # never waited for: no rows were sent
                kind, text = self._receive(timeout)
            if kind == "error":
                self._error = text
        self._outbox.close()
        self._inbox.close()
        try:
            self._process.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            self._process.kill()
        if self._error is not None:
            raise RecordingError(f"{self.path}: {self._error}")


