"""`cosim run` under a supervisor: the run goes on in a child process, and a plant binary
that crashes it, or never lets it answer Ctrl-C, is reported and its summary marked."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from .common import print_error
from .parser import build_parser

SUPERVISED = "COSIM_SUPERVISED"  # set in the run process's environment by its supervisor

# Seconds the run process has to answer Ctrl-C or SIGTERM (its handler acknowledges at once
# when Python runs it) before it is killed: only a plant binary that never returns control
# (a foreign FMU blocking in doStep) keeps Python from running it.
STOP_GRACE_S = float(os.environ.get("COSIM_STOP_GRACE_S", "10"))


def supervise(args: list[str]) -> int:
    """Run ``cosim run`` in a child process and wait: if it dies by a signal (a plant
    binary that crashes takes the process with it), say so and mark its summary. The child
    has its own process group, so Ctrl-C and SIGTERM reach it once, through here; if it does
    not acknowledge one within STOP_GRACE_S, it is killed (and its summary marked)."""
    import threading

    child = subprocess.Popen([sys.executable, "-m", "cosim.cli", *args],
                             env=dict(os.environ, **{SUPERVISED: "1"}), process_group=0)
    stopping: dict = {"timer": None, "acknowledged": False, "killed": None}

    def end_unanswered(name: str) -> None:
        if not stopping["acknowledged"] and child.poll() is None:
            stopping["killed"] = name
            child.kill()

    def forward(signum, frame) -> None:
        child.send_signal(signum)
        if stopping["timer"] is None:
            stopping["timer"] = threading.Timer(STOP_GRACE_S, end_unanswered,
                                                (signal.Signals(signum).name,))
            stopping["timer"].daemon = True
            stopping["timer"].start()

    def acknowledged(signum, frame) -> None:
        stopping["acknowledged"] = True

    signal.signal(signal.SIGUSR1, acknowledged)
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, forward)
    status = child.wait()
    if stopping["timer"] is not None:
        stopping["timer"].cancel()
    if status >= 0:
        return status
    name = signal.Signals(-status).name
    out, plant = _crashed_run(args)
    where = f" in {plant}" if plant else ""
    if stopping["killed"]:
        print_error(f"the run process did not answer {stopping['killed']} within "
                    f"{STOP_GRACE_S:g} s (most likely blocked inside the plant FMU's "
                    f"doStep{where}) and was killed; what was written before is kept in {out} "
                    "(summary.json marked crashed)")
        _mark_crashed(out, f"killed: the run process did not answer {stopping['killed']} "
                      f"within {STOP_GRACE_S:g} s{where}")
        return 2
    print_error(f"the run process was killed by {name}, most likely inside the plant FMU's "
                f"binary{where}; what was computed is kept in {out} (summary.json marked "
                "crashed)")
    _mark_crashed(out, f"the run process was killed by {name}{where}")
    return 2


def _crashed_run(args: list[str]) -> tuple[Path, str]:
    """The run folder and plant of the run that crashed, from its arguments."""
    from ..config import load_pipeline
    from ..schema import PipelineError

    ns = build_parser().parse_args(args)
    try:
        pipeline = load_pipeline(ns.pipeline, ns.set)
    except PipelineError:
        return Path(ns.out or "runs"), ""
    plant = (Path(pipeline.plant.fmu).name if pipeline.plant.fmu else
             Path(pipeline.plant.urdf.file).name if pipeline.plant.urdf else "the built-in plant")
    # without --out, the run made runs/NAME/TIME and pointed runs/NAME/latest at it
    return Path(ns.out or (Path("runs") / pipeline.name / "latest").resolve()), plant


def _mark_crashed(out: Path, reason: str) -> None:
    import json

    summary = out / "summary.json"
    try:
        data = json.loads(summary.read_text())
        data.update(complete=False, status="crashed", error=reason)
        tmp = out / ".summary.json.crashed"
        tmp.write_text(json.dumps(data, indent=2) + "\n")
        tmp.replace(summary)
    except (OSError, ValueError):
        pass
