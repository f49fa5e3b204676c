"""The recording's writer process: Rerun sinks, styles, and the rows as they arrive.

Rerun's Python side costs about 0.2 ms per ``send_columns`` call, and a run needs about 40
calls per simulated second, which would be a third of the control loop's own time. So the
recording is written by a separate process: the loop hands it each completed second of
rows (the declared signals and their evaluated checks and barriers) over a pipe and carries
on, while the writer talks to Rerun on the other core. It computes nothing but layout.
"""

from __future__ import annotations

import json
import os
import signal
import sys
from dataclasses import dataclass, field
from multiprocessing.connection import Connection

import numpy as np

from ... import interface as io
from . import arm3d
from .layout import (
    ARM_RATE_HZ,
    BOUND_COLOR,
    JOINT_COLORS,
    REFERENCE_COLOR,
    VIOLATION_COLOR,
    VIOLATION_RATE_HZ,
    RunSpec,
    arm_points,
    blueprint,
    series_names,
    violations,
)


@dataclass
class _Writer:
    """``batch_s``: seconds of rows gathered into one chunk per entity (each chunk carries
    ~1 KB of schema: 5 s instead of 1 s saves ~1.7 MB on the paper's recording); 0 when a
    viewer watches live, so that it follows every second."""

    rec: object
    batch_s: float = 5.0
    runs: dict[str, RunSpec] = field(default_factory=dict)
    pending: dict[str, list] = field(default_factory=dict)
    trees: dict[str, tuple] = field(default_factory=dict)  # run -> its URDF trees (3-D arm)

    def begin(self, spec: RunSpec) -> None:
        """Static styles: series names and joint colours, the checks' bounds, the arm."""
        import rerun as rr

        self.runs[spec.name] = spec
        root, n = f"/{spec.name}", spec.links
        colors = (JOINT_COLORS * n)[:n]
        for entity, (_, stem, width) in spec.entities.items():
            self.rec.log(f"{root}/{entity}", rr.SeriesLines(
                names=series_names(stem, width), colors=colors[:width]), static=True)
        for entity, (_, _, stem) in spec.derived.items():
            self.rec.log(f"{root}/{entity}", rr.SeriesLines(names=series_names(stem, n),
                                                              colors=colors), static=True)
        for i, name in enumerate(spec.barriers):
            self.rec.log(f"{root}/barrier/{name}", rr.SeriesLines(
                names=[name], colors=[JOINT_COLORS[i]]), static=True)
        if spec.barriers:
            self.rec.log(f"{root}/barrier_condition", rr.SeriesPoints(
                names=["condition < 0"], colors=[VIOLATION_COLOR], markers=["cross"],
                marker_sizes=[3.0]), static=True)
        ends = rr.TimeColumn("sim_time", duration=[0.0, spec.duration])
        for family, names in spec.families().items():
            base = f"{root}/safety/{family}"
            self.rec.log(f"{base}/value", rr.SeriesLines(
                names=names, colors=[spec.color(name) for name in names]), static=True)
            for side, index in (("upper", 1), ("lower", 0)):
                self.rec.log(f"{base}/{side}", rr.SeriesLines(
                    names=[f"{side} bound"] * len(names), colors=[BOUND_COLOR] * len(names),
                    widths=[2.0] * len(names)), static=True)
                bound = [spec.bounds[name][index] for name in names]
                self.rec.send_columns(f"{base}/{side}", indexes=[ends],
                                      columns=rr.Scalars.columns(scalars=[bound, bound]))
            for name in names:
                self.rec.log(f"{base}/violation/{name}", rr.SeriesPoints(
                    names=["violation"], colors=[VIOLATION_COLOR], markers=["cross"],
                    marker_sizes=[3.0]), static=True)
        if spec.urdf is not None:
            self.trees[spec.name] = arm3d.log_model(self.rec, spec.name, spec.urdf)
            return
        # Only colours and radii are static: a static strip or point would hide the
        # animated ones.
        reach = float(np.sum(spec.link_lengths))
        self.rec.log(f"{root}/arm/links", rr.LineStrips2D.from_fields(
            colors=[(40, 40, 40)], radii=[0.03 * reach]), static=True)
        self.rec.log(f"{root}/arm/desired", rr.LineStrips2D.from_fields(
            colors=[REFERENCE_COLOR], radii=[0.012 * reach]), static=True)
        self.rec.log(f"{root}/arm/joints", rr.Points2D.from_fields(
            colors=[JOINT_COLORS[0]], radii=[0.05 * reach]), static=True)

    def rows(self, run: str, start: int, stop: int, rows: dict[str, np.ndarray],
             checks: dict[str, np.ndarray], barrier_values: dict[str, np.ndarray]) -> None:
        """Gather a chunk of rows [start, stop); write once ``batch_s`` seconds of them are
        here."""
        pending = self.pending.setdefault(run, [])
        pending.append((start, stop, rows, checks, barrier_values))
        if (stop - pending[0][0]) * self.runs[run].dt >= self.batch_s:
            self.flush(run)

    def flush(self, run: str | None = None) -> None:
        """Write what is gathered (of ``run``, or of every run)."""
        for name in [run] if run is not None else list(self.pending):
            pending = self.pending.pop(name, [])
            if not pending:
                continue
            start, stop = pending[0][0], pending[-1][1]
            joined = [{key: np.concatenate([p[i][key] for p in pending]) for key in pending[0][i]}
                      for i in (2, 3, 4)]
            self._write(name, start, stop - start, *joined)

    def _write(self, run: str, start: int, count: int, rows: dict[str, np.ndarray],
               checks: dict[str, np.ndarray], barrier_values: dict[str, np.ndarray]) -> None:
        import rerun as rr

        spec = self.runs[run]
        root = f"/{run}"
        times = (start + np.arange(count)) * spec.dt
        index = [rr.TimeColumn("sim_time", duration=times)]
        columns = [(entity, rows[key]) for entity, (key, _, _) in spec.entities.items()]
        columns += [(entity, rows[true] - rows[estimate])
                    for entity, (true, estimate, _) in spec.derived.items()]
        columns += [(f"safety/{family}/value", np.column_stack([checks[n] for n in names]))
                    for family, names in spec.families().items()]
        columns += [(f"barrier/{name}", value) for name, value in barrier_values.items()
                    if name != io.BARRIER_CONDITION]
        for entity, values in columns:
            self.rec.send_columns(f"{root}/{entity}", indexes=index,
                                  columns=rr.Scalars.columns(scalars=values))
        stride = max(1, int(round(1.0 / (VIOLATION_RATE_HZ * spec.dt))))
        for name, where, values in violations(checks, spec.bounds, start, stride):
            family = spec.family(name)
            self.rec.send_columns(f"{root}/safety/{family}/violation/{name}",
                                  indexes=[rr.TimeColumn("sim_time", duration=times[where])],
                                  columns=rr.Scalars.columns(scalars=values))
        # The barrier condition where it fails, like a violation (dense in the trace file).
        condition = io.BARRIER_CONDITION
        failing = ({condition: barrier_values[condition]}
                   if spec.barriers and condition in barrier_values else {})
        for _, where, values in violations(failing, {condition: (0.0, np.inf)}, start,
                                           stride):
            self.rec.send_columns(f"{root}/barrier_condition",
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
        if spec.urdf is not None:
            arm3d.log_pose(self.rec, spec.name, spec.urdf, self.trees[spec.name], times[pick],
                           rows["q"][pick], rows["q_d"][pick])
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
        layout = blueprint(header["runs"], header.get("views"), header.get("error_views"),
                           header.get("check_views"), header.get("spatial", ()))
        rec.set_sinks(*sinks, default_blueprint=layout)
        rec.send_recording_name(header["name"])
        outbox.send(("ready", ""))
        writer = _Writer(rec, batch_s=0.0 if live.get("spawn") or live.get("connect")
                         else 5.0)
        while True:
            try:
                message = inbox.recv()
            except EOFError:
                writer.flush()
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
                writer.flush(run)
                rec.send_property(f"run_{run}", rr.AnyValues(
                    complete=summary["complete"], error=summary.get("error"),
                    metrics=json.dumps(summary["metrics"], default=_json_default),
                    safety=json.dumps(summary["safety"], default=_json_default)))
            elif kind == "close":
                writer.flush()
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



if __name__ == "__main__":  # the writer process, started by Recorder
    _writer_main(Connection(int(sys.argv[1]), writable=False),
                 Connection(int(sys.argv[2]), readable=False))
