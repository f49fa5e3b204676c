"""The Rerun recording of a pipeline: every signal, safe-set bound and barrier value.

Layout (one subtree per run; one timeline, ``sim_time``, in seconds; SI units, radians):

    /<run>/reference/{q_d, qdot_d, qddot_d}
    /<run>/plant/{q, qdot, tau}                 true plant signals from the FMU
    /<run>/sensor/q_meas
    /<run>/observer/{q_hat, qdot_hat, q_err, qdot_err, k0, W_norm}
    /<run>/controller/{tau, e, edot, r_hat, nn_output, v_c, W_norm, V_norm}
    /<run>/safety/<check>/{value, upper, lower, violation}
    /<run>/barrier/{H1, H2, H}
    /<run>/arm/{links, joints, desired}         the arm, drawn at 50 Hz

Multi-joint signals are one entity with series ``<name>1``, ``<name>2``, ... in the same
colours in every run. Constant bounds are written as two rows (start and end of the run),
not repeated every step. ``violation`` holds the value at the rows where it leaves its
bound: its first row, then every 10 ms.

Rerun's Python side costs about 0.2 ms per ``send_columns`` call, and a run needs about 40
calls per simulated second, which would be a third of the control loop's own time. So the
recording is written by a separate writer process: the loop hands it each completed second
of trace rows over a pipe (one pickled dict, well under a millisecond) and carries on,
while the writer derives the safety and barrier values and talks to Rerun on the other core.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from importlib import metadata
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from .safety import Check, Gains, SafeSet, barriers, check_signals
from .trace import SIGNALS

# One colour per joint, the same in every run (matplotlib's tab10).
JOINT_COLORS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (148, 103, 189),
                (140, 86, 75), (227, 119, 194), (127, 127, 127)]
BOUND_COLOR = (0, 150, 60)
VIOLATION_COLOR = (220, 20, 20)
REFERENCE_COLOR = (120, 120, 120)
ARM_RATE_HZ = 50.0  # the arm drawing does not need 1 kHz
VIOLATION_RATE_HZ = 100.0

# entity under /<run>/ -> (trace signal, series-name stem). Per-joint signals get stem + j.
TRACE_ENTITIES: dict[str, tuple[str, str]] = {
    "reference/q_d": ("q_d", "q_d"),
    "reference/qdot_d": ("qdot_d", "qdot_d"),
    "reference/qddot_d": ("qddot_d", "qddot_d"),
    "plant/q": ("q", "q"),
    "plant/qdot": ("qdot", "qdot"),
    "plant/tau": ("tau", "tau"),
    "sensor/q_meas": ("q_meas", "q_meas"),
    "observer/q_hat": ("q_hat", "q_hat"),
    "observer/qdot_hat": ("qdot_hat", "qdot_hat"),
    "observer/k0": ("k0", "k0"),
    "observer/W_norm": ("W_o_norm", "‖Ŵo‖"),
    "controller/tau": ("tau", "tau"),
    "controller/e": ("e", "e"),
    "controller/edot": ("edot", "edot"),
    "controller/r_hat": ("r_hat", "r_hat"),
    "controller/nn_output": ("nn_output", "f_hat"),
    "controller/v_c": ("v_c", "v_c"),
    "controller/W_norm": ("W_norm", "‖Ŵc‖"),
    "controller/V_norm": ("V_norm", "‖V̂c‖"),
}
# Observer errors, true minus estimate (x̃1, x̃2 of the paper).
DERIVED_ENTITIES = {"observer/q_err": ("q", "q_hat", "q_err"),
                    "observer/qdot_err": ("qdot", "qdot_hat", "qdot_err")}
BARRIERS = ("H1", "H2", "H")
F_SETPIPE_SZ = getattr(fcntl, "F_SETPIPE_SZ", 1031)  # Linux; elsewhere the call just fails
PIPE_BYTES = 1 << 20

# The checks the figures show (paper Figs. 2-3), with their axis labels.
FIGURE_CHECKS = {
    "position_joint1": "position q1 − q_s1 (rad)",
    "velocity_estimated_joint1": "velocity x̂2,1 − q̇_s1 (rad/s)",
    "error_joint1": "position error e1 (rad)",
    "error_rate_joint1": "velocity error ė1 (rad/s)",
}


class RecordingError(RuntimeError):
    """The recording could not be written; the message says where and why."""


# --------------------------------------------------------------------------------------------
# What goes where: pure functions of trace rows (run in the writer process).


def scalar_columns(rows: Mapping[str, np.ndarray], checks: Mapping[str, Check], safe: SafeSet,
                   gains: Gains) -> Iterator[tuple[str, np.ndarray]]:
    """(entity under /<run>/, values per row) for every time series that has a value per
    step: trace signals, observer errors, safety check values and barriers."""
    for entity, (signal_name, _) in TRACE_ENTITIES.items():
        yield entity, rows[signal_name]
    for entity, (true, estimate, _) in DERIVED_ENTITIES.items():
        yield entity, rows[true] - rows[estimate]
    for name, check in checks.items():
        yield f"safety/{name}/value", check.value
    for name, values in barriers(rows, safe, gains).items():
        yield f"barrier/{name}", values


def violations(checks: Mapping[str, Check], first_row: int,
               stride: int) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
    """(check, row indices within the chunk, values) where a check leaves its bound: the
    first row of every excursion, then every ``stride``-th row (by global index) of it."""
    for name, check in checks.items():
        outside = (check.value > check.upper) | (check.value < check.lower)
        if not outside.any():
            continue
        index = first_row + np.arange(len(outside))
        starts = outside & ~np.concatenate(([False], outside[:-1]))
        where = np.flatnonzero(outside & ((index % stride == 0) | starts))
        yield name, where, check.value[where]


def arm_points(q: np.ndarray, link_lengths: np.ndarray) -> np.ndarray:
    """Joint positions (rows, n+1, 2) of the planar chain, base at the origin, angles from
    the horizontal and relative (q_i is link i's angle to link i-1); y drawn up, so negated
    for Rerun's y-down 2D views."""
    angles = np.cumsum(q, axis=1)
    steps = np.stack([np.cos(angles), -np.sin(angles)], axis=2) * link_lengths[None, :, None]
    out = np.zeros((q.shape[0], q.shape[1] + 1, 2))
    out[:, 1:] = np.cumsum(steps, axis=1)
    return out


def series_names(stem: str, width: int) -> list[str]:
    return [stem] if width == 1 else [f"{stem}{j + 1}" for j in range(width)]


def blueprint(run_names: list[str]):
    """Figs. 2-4 of the paper for every run side by side, then barriers, observer error and
    the arm; time panel on sim_time, paused."""
    import rerun.blueprint as rrb

    columns = []
    for run in run_names:
        views = [rrb.TimeSeriesView(origin=f"/{run}/safety/{check}", name=f"{run}: {label}")
                 for check, label in FIGURE_CHECKS.items()]
        views.append(rrb.TimeSeriesView(origin=f"/{run}/plant/tau",
                                        name=f"{run}: torque τ (N·m)"))
        views.append(rrb.Horizontal(
            rrb.TimeSeriesView(origin=f"/{run}/barrier", name=f"{run}: barriers H1, H2, H"),
            rrb.TimeSeriesView(origin=f"/{run}/observer/qdot_err",
                               name=f"{run}: observer error q̇ − x̂2 (rad/s)"),
            rrb.Spatial2DView(origin=f"/{run}/arm", name=f"{run}: arm (m)"),
        ))
        columns.append(rrb.Vertical(*views, name=run))
    return rrb.Blueprint(
        rrb.Horizontal(*columns),
        rrb.TimePanel(timeline="sim_time", play_state="paused", expanded=False),
        collapse_panels=True,
    )


def package_versions() -> dict[str, str]:
    out = {"python": sys.version.split()[0]}
    for name in ("cosim", "fmpy", "numpy", "scipy", "numba", "rerun-sdk", "control",
                 "pydantic"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


# --------------------------------------------------------------------------------------------
# The writer process.


@dataclass
class RunSpec:
    """What the writer needs to know of one run before its rows arrive."""

    name: str
    links: int
    dt: float
    duration: float
    safe: SafeSet
    gains: Gains
    link_lengths: np.ndarray


@dataclass
class _Writer:
    rec: object
    runs: dict[str, RunSpec] = field(default_factory=dict)
    styled_checks: set[str] = field(default_factory=set)

    def begin(self, spec: RunSpec) -> None:
        """Static styles: series names and joint colours, the arm's look."""
        import rerun as rr

        self.runs[spec.name] = spec
        root, n = f"/{spec.name}", spec.links
        colors = (JOINT_COLORS * n)[:n]
        for entity, (signal_name, stem) in TRACE_ENTITIES.items():
            width = 1 if SIGNALS[signal_name] == "1" else n
            self.rec.log(f"{root}/{entity}", rr.SeriesLines(
                names=series_names(stem, width), colors=colors[:width]), static=True)
        for entity, (_, _, stem) in DERIVED_ENTITIES.items():
            self.rec.log(f"{root}/{entity}", rr.SeriesLines(names=series_names(stem, n),
                                                              colors=colors), static=True)
        for i, name in enumerate(BARRIERS):
            self.rec.log(f"{root}/barrier/{name}", rr.SeriesLines(
                names=[name], colors=[JOINT_COLORS[i]]), static=True)
        # Only colours and radii are static: a static strip or point would hide the
        # animated ones.
        reach = float(np.sum(spec.link_lengths))
        self.rec.log(f"{root}/arm/links", rr.LineStrips2D.from_fields(
            colors=[(40, 40, 40)], radii=[0.03 * reach]), static=True)
        self.rec.log(f"{root}/arm/desired", rr.LineStrips2D.from_fields(
            colors=[REFERENCE_COLOR], radii=[0.012 * reach]), static=True)
        self.rec.log(f"{root}/arm/joints", rr.Points2D.from_fields(
            colors=[JOINT_COLORS[0]], radii=[0.05 * reach]), static=True)

    def _style_checks(self, spec: RunSpec, checks: dict) -> None:
        """Check styles and their constant bounds (two rows: start and end of the run)."""
        import rerun as rr

        ends = rr.TimeColumn("sim_time", duration=[0.0, spec.duration])
        for name, check in checks.items():
            base = f"/{spec.name}/safety/{name}"
            self.rec.log(f"{base}/value", rr.SeriesLines(
                names=[name], colors=[JOINT_COLORS[0]]), static=True)
            self.rec.log(f"{base}/violation", rr.SeriesPoints(
                names=["violation"], colors=[VIOLATION_COLOR], markers=["cross"],
                marker_sizes=[3.0]), static=True)
            for side, bound in (("upper", check.upper), ("lower", check.lower)):
                self.rec.log(f"{base}/{side}", rr.SeriesLines(
                    names=[f"{side} bound"], colors=[BOUND_COLOR], widths=[2.0]), static=True)
                self.rec.send_columns(f"{base}/{side}", indexes=[ends],
                                      columns=rr.Scalars.columns(scalars=[bound, bound]))
        self.styled_checks.add(spec.name)

    def rows(self, run: str, start: int, rows: dict[str, np.ndarray]) -> None:
        import rerun as rr

        spec = self.runs[run]
        checks = check_signals(rows, spec.safe, spec.gains)
        if run not in self.styled_checks:
            self._style_checks(spec, checks)
        root = f"/{run}"
        count = len(rows["q"])
        times = (start + np.arange(count)) * spec.dt
        index = [rr.TimeColumn("sim_time", duration=times)]
        for entity, values in scalar_columns(rows, checks, spec.safe, spec.gains):
            self.rec.send_columns(f"{root}/{entity}", indexes=index,
                                  columns=rr.Scalars.columns(scalars=values))
        stride = max(1, int(round(1.0 / (VIOLATION_RATE_HZ * spec.dt))))
        for name, where, values in violations(checks, start, stride):
            self.rec.send_columns(f"{root}/safety/{name}/violation",
                                  indexes=[rr.TimeColumn("sim_time", duration=times[where])],
                                  columns=rr.Scalars.columns(scalars=values))
        self._arm(spec, start, rows, times)

    def _arm(self, spec: RunSpec, start: int, rows: dict[str, np.ndarray],
             times: np.ndarray) -> None:
        import rerun as rr

        stride = max(1, int(round(1.0 / (ARM_RATE_HZ * spec.dt))))
        pick = np.flatnonzero((start + np.arange(len(times))) % stride == 0)
        if not len(pick):
            return
        index = [rr.TimeColumn("sim_time", duration=times[pick])]
        links = arm_points(rows["q"][pick], spec.link_lengths)
        desired = arm_points(rows["q_d"][pick], spec.link_lengths)
        for part, points in (("links", links), ("desired", desired)):
            self.rec.send_columns(f"/{spec.name}/arm/{part}", indexes=index,
                                  columns=rr.LineStrips2D.columns(strips=points))
        self.rec.send_columns(f"/{spec.name}/arm/joints", indexes=index,
                              columns=rr.Points2D.columns(positions=links.reshape(-1, 2))
                              .partition([spec.links + 1] * len(pick)))


def _writer_main(inbox: Connection, outbox: Connection) -> None:
    """The writer process: Rerun sinks, blueprint and name, "ready", then properties and rows
    as they arrive until "close", or until the pipe closes (the parent died): what was
    received stays readable in the file."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when to stop
    os.nice(5)  # where the writer and the control loop compete for a core, the loop wins
    try:
        import rerun as rr

        path, header, live = inbox.recv()
        rec = rr.RecordingStream("cosim", recording_id=header["recording_id"])
        sinks = [rr.FileSink(path)]
        if live.get("spawn"):
            rr.spawn(port=live["port"], connect=False, recording=rec,
                     executable_path=live["viewer"])
            sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{live['port']}/proxy"))
        elif live.get("connect"):
            sinks.append(rr.GrpcSink(live["connect"]))
        rec.set_sinks(*sinks, default_blueprint=blueprint(header["runs"]))
        rec.send_recording_name(header["name"])
        outbox.send(("ready", ""))
        writer = _Writer(rec)
        while True:
            try:
                message = inbox.recv()
            except EOFError:
                break
            kind = message[0]
            if kind == "properties":
                for key, values in message[1].items():
                    rec.send_property(key, rr.AnyValues(**values))
            elif kind == "begin":
                writer.begin(message[1])
            elif kind == "rows":
                writer.rows(*message[1:])
            elif kind == "end":
                _, run, summary = message
                rec.send_property(f"run_{run}", rr.AnyValues(
                    complete=summary["complete"], error=summary.get("error"),
                    metrics=json.dumps(summary["metrics"], default=_json_default),
                    safety=json.dumps(summary["safety"], default=_json_default)))
            elif kind == "close":
                status = message[1]
                if not status["complete"]:
                    rec.send_recording_name(header["name"] + " (incomplete)")
                rec.send_property("status", rr.AnyValues(
                    **{key: value for key, value in status.items() if value != ""}))
                break
        rec.flush()
        rec.disconnect()
        outbox.send(("ok", ""))
    except Exception as exc:  # reported to the parent, which owns the user's terminal
        try:
            outbox.send(("error", f"{type(exc).__name__}: {exc}"))
        except OSError:
            pass
        raise SystemExit(1) from None


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


# --------------------------------------------------------------------------------------------
# The parent's handle.


class Recorder:
    """Writes ``path`` (recording.rrd) from trace rows, in a writer process.

    ``spawn`` starts a Rerun viewer that follows the run live; ``connect`` streams to a viewer
    already running at that URL (``rerun+http://host:port/proxy``). The file is written in
    either case.
    """

    def __init__(self, path: str | Path, name: str, run_names: list[str],
                 spawn: bool = False, connect: str | None = None, port: int = 9876):
        self.path = Path(path)
        self.sent: dict[str, int] = {}
        self.handoff_seconds = 0.0  # time the caller spent handing rows over
        self._error: str | None = None
        self._ready = False
        header = {"name": name, "runs": run_names, "recording_id": str(uuid.uuid4())}
        live = {"spawn": spawn, "connect": connect, "port": port, "viewer": None}
        if spawn:
            from .viewer import has_display, viewer_binary

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
            [sys.executable, "-m", "cosim.recording", str(from_parent), str(to_parent)],
            pass_fds=(from_parent, to_parent))
        os.close(from_parent)
        os.close(to_parent)
        self._outbox = Connection(to_child, readable=False)
        self._inbox = Connection(from_child, writable=False)
        self._send((str(self.path), header, live))

    def _send(self, message: tuple) -> None:
        if self._error is not None:
            return  # the writer is gone; close() reports why
        try:
            self._outbox.send(message)
        except OSError:
            kind, text = self._receive(5.0)
            self._error = text if kind == "error" else "the recording writer stopped"

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

    def send_rows(self, run: str, arrays: Mapping[str, np.ndarray], upto: int) -> None:
        """Send rows ``[already sent, upto)`` of the run's trace arrays. Completed rows are
        never written again, so the views are sent as they are, without a copy."""
        start = self.sent[run]
        if upto <= start:
            return
        self.wait_ready()  # the first call waits (the writer imports Rerun meanwhile)
        began = time.perf_counter()
        self._send(("rows", run, start, {k: a[start:upto] for k, a in arrays.items()}))
        self.sent[run] = upto
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


if __name__ == "__main__":  # the writer process, started by Recorder
    _writer_main(Connection(int(sys.argv[1]), writable=False),
                 Connection(int(sys.argv[2]), readable=False))
