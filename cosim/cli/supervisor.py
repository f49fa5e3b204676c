"""`cosim run` under a supervisor: the run goes on in a child process, and a plant binary
that crashes it, or never lets it answer Ctrl-C, is reported and its summary marked."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import sysconfig
from pathlib import Path

from ..environment import seconds_from_environment
from ..run_note import NOTE, NOTE_PREFIX, SUPERVISED, read_note
from .common import print_error

# Seconds the run process has to answer Ctrl-C or SIGTERM (its handler acknowledges at once
# when Python runs it) before it is killed: only a plant binary that never returns control
# (a foreign FMU blocking in doStep) keeps Python from running it. COSIM_STOP_GRACE_S
# changes it.
STOP_GRACE_VARIABLE, STOP_GRACE_S = "COSIM_STOP_GRACE_S", 10.0


def stop_grace() -> float:
    """COSIM_STOP_GRACE_S (seconds, > 0), else the default; a bad value is the user's
    mistake, said before anything runs."""
    return seconds_from_environment(STOP_GRACE_VARIABLE, STOP_GRACE_S)


def supervise(args: list[str]) -> int:
    """Run ``cosim run`` in a child process and wait: if it dies by a signal (a plant
    binary that crashes takes the process with it), say so and mark its summary. The child
    has its own process group, so Ctrl-C and SIGTERM reach it once, through here; if it does
    not acknowledge one within the grace (COSIM_STOP_GRACE_S), it is killed (and its summary
    marked). The child tells which run folder it made through a note file (cosim.run_note):
    nothing of the pipeline is loaded here, so a plugin that crashes cannot crash this too."""
    import tempfile
    import threading

    try:
        grace = stop_grace()
    except ValueError as exc:
        print_error(str(exc))
        return 2
    _remove_stale_notes(Path(tempfile.gettempdir()))
    handle, note_file = tempfile.mkstemp(prefix=f"{NOTE_PREFIX}{os.getpid()}-", suffix=".json")
    os.close(handle)
    try:
        return _supervise(args, grace, Path(note_file), threading)
    finally:
        Path(note_file).unlink(missing_ok=True)
        fault_file(Path(note_file)).unlink(missing_ok=True)


def _remove_stale_notes(folder: Path) -> None:
    """Note and fault files of supervisors that no longer run (killed before cleaning up)."""
    for path in folder.glob(f"{NOTE_PREFIX}*-*.*"):
        pid = path.name[len(NOTE_PREFIX):].partition("-")[0]
        if pid.isdigit() and not _alive(int(pid)) and path.suffix in (".json", ".fault"):
            path.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def fault_file(note_file: Path) -> Path:
    """Where the run process's faulthandler writes the Python stack of a fatal signal."""
    return note_file.with_suffix(".fault")


# Frames that are not a user's code: cosim's own and installed packages' (FMPy's calls into
# the plant binary); the standard library's are passed over (a plugin's ctypes call).
UNPACKED = "cosim_fmu_"  # cosim.plant.unpack.PREFIX: where an FMU is unpacked to run
_STDLIB = str(Path(sysconfig.get_paths()["stdlib"]).resolve())
_NOT_USERS = (str(Path(__file__).resolve().parents[1]), *{
    str(Path(sysconfig.get_paths()[key]).resolve()) for key in ("purelib", "platlib")})


def users_frame(note_file: Path) -> str | None:
    """``"my_blocks.py, line 12, in step"``: where the fatal signal's stack (faulthandler's
    dump, the crashing thread's) leaves the standard library, when that is a user's code (a
    plugin), else None (cosim's or an installed package's: the plant's binary)."""
    try:
        dump = fault_file(note_file).read_text(errors="replace")
    except OSError:
        return None
    current = dump.split("Current thread", 1)[-1]
    for path, line, function in re.findall(r'File "([^"]+)", line (\d+) in (\S+)', current):
        resolved = str(Path(path).resolve()) if not path.startswith("<") else path
        # before the stdlib (site-packages may be inside it); an unpacked FMU's own Python
        # (a PythonFMU plant) is the plant's
        if resolved.startswith(_NOT_USERS) or any(part.startswith(UNPACKED)
                                                  for part in Path(resolved).parts):
            return None
        if not (path.startswith("<") or resolved.startswith(_STDLIB)):
            return f"{path}, line {line}, in {function}"  # faulthandler: the innermost first
    return None


def _supervise(args: list[str], grace: float, note_file: Path, threading) -> int:
    # -P: the working folder is not put first on the module path, so a random.py or
    # json.py there cannot shadow the standard library in the run process; the folder
    # holding cosim itself is (a source tree run without installing).
    package_root = str(Path(__file__).resolve().parents[2])
    path = os.pathsep.join(filter(None, [package_root, os.environ.get("PYTHONPATH")]))
    child = subprocess.Popen([sys.executable, "-P", "-m", "cosim.cli", *args],
                             env=dict(os.environ, PYTHONPATH=path,
                                      **{SUPERVISED: str(os.getpid()), NOTE: str(note_file)}),
                             process_group=0)
    stopping: dict = {"timer": None, "acknowledged": False, "killed": None}

    def end_unanswered(name: str) -> None:
        if not stopping["acknowledged"] and child.poll() is None:
            stopping["killed"] = name
            child.kill()

    def forward(signum, frame) -> None:
        child.send_signal(signum)
        if stopping["timer"] is None:
            stopping["timer"] = threading.Timer(grace, end_unanswered,
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
    # The run process's unpacked FMU, where it had no chance to remove it (killed, or
    # signalled as the folder was being made): it has ended, so its folder is stale.
    from ..plant.unpack import remove_stale

    remove_stale()
    if status >= 0:
        return status
    name = signal.Signals(-status).name
    note = read_note(note_file)
    plant, out = note.get("plant"), note.get("out")
    where = f" in {plant}" if plant else ""
    users = None if stopping["killed"] else users_frame(note_file)
    if not out:  # it died before making its run folder: loading the pipeline
        culprit = (f"in a plugin's code ({users})" if users
                   else f"while importing the plugin {note['importing']}"
                   if note.get("importing")
                   else "while loading the pipeline")
        cause = (f"did not answer {stopping['killed']} within {grace:g} s and was killed"
                 if stopping["killed"] else f"was killed by {name}")
        print_error(f"the run process {cause} {culprit}, before any run folder was made; "
                    "nothing was run or written")
        return 2
    out = Path(out)
    started = (out / "summary.json").is_file()
    _settle(note, started)
    kept = (f"what was written before is kept in {out} (summary.json marked crashed)"
            if started else "nothing was written (the run had not started)")
    if stopping["killed"]:
        print_error(f"the run process did not answer {stopping['killed']} within "
                    f"{grace:g} s (most likely blocked inside the plant FMU's "
                    f"doStep{where}) and was killed; {kept}")
        _mark_crashed(out, f"killed: the run process did not answer {stopping['killed']} "
                      f"within {grace:g} s{where}")
        return 2
    inside = (f"in a plugin's code ({users})" if users
              else f"most likely inside the plant FMU's binary{where}")
    print_error(f"the run process was killed by {name}, {inside}; "
                + kept.replace("written before", "computed"))
    _mark_crashed(out, f"the run process was killed by {name}"
                  + (f" in a plugin's code ({users})" if users else where))
    return 2


def _settle(note: dict, started: bool) -> None:
    """A run folder cosim named (no --out), as the run itself would have left it: latest →
    it once it holds a run; removed if still empty (the run had not started)."""
    if not note.get("named"):
        return
    if started:
        from ..outputs.run_folder import point_latest

        point_latest(Path(note["out"]))
        return
    try:
        Path(note["out"]).rmdir()  # only if empty
    except OSError:
        pass


def _mark_crashed(out: Path, reason: str) -> None:
    """The crashed run's own summary.json (never another folder's): marked crashed, if
    cosim wrote it."""
    import json

    summary = out / "summary.json"
    try:
        data = json.loads(summary.read_text())
        if not isinstance(data, dict) or "complete" not in data:
            return
        runs = (data.get("pipeline") or {}).get("runs") or {}
        data.update(complete=False, status="crashed", error=reason,
                    not_run=[name for name in runs if name not in (data.get("runs") or {})])
        tmp = out / ".summary.json.crashed"
        tmp.write_text(json.dumps(data, indent=2) + "\n")
        tmp.replace(summary)
    except (OSError, ValueError):
        pass
