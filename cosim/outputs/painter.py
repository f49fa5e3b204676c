"""The painter: a process that draws the run folder's figures in parallel with the runs.

Four figures take seconds to lay out and draw (matplotlib's text and layout work, in
Python), after the runs, when nothing else is left to do. `cosim run` starts a painter
before the runs: it waits a moment (the run's own process is loading its kernels and the
recording's writer importing Rerun: both on the critical path), then imports matplotlib and
draws a first small figure (fonts, the log axes' mathtext) while the runs go. Given the
figures, it forks once per further idle core, and the forks, warm already, draw their share
side by side with it. It pays only with idle cores: on a machine already busy none is
started, and this process draws them itself. A plain child interpreter (not
multiprocessing), as for the recording's writer, so that a script calling run() without a
__main__ guard works. A painter never given work reads the end of its input and exits; what
it could not draw, this process draws.
"""

from __future__ import annotations

import atexit
import os
import pickle
import subprocess
import sys
from pathlib import Path

_PAINTERS: list[subprocess.Popen] = []
PAINTER_DELAY_S = 1.0  # before the painter imports matplotlib, unless its work comes first
# The painter's first lines, before any import: wait, unless its input (work, or the end of
# it: not needed) comes first. One thread only, so that its forks are safe.
_LAUNCH = ("import select, sys\n"
           "ready = select.select([sys.stdin], [], [], {delay})[0]\n"
           "raw = sys.stdin.buffer.read() if ready else None\n"
           "if raw != b'':\n"
           "    from cosim.outputs.figures import paint_in_this_process\n"
           "    sys.exit(paint_in_this_process(raw, {forks}))\n")


def started() -> bool:
    """Whether a painter waits for this process's figures."""
    return bool(_PAINTERS)


def start_painters(figures: int, cores: int | None = None) -> None:
    """Start the painter for the next figures of this process (at most ``figures`` of them),
    to draw on ``cores`` cores (default: the idle ones, at most one per figure); none when
    fewer than two are idle, where drawing here costs the same, without the painter's
    import."""
    if _PAINTERS:
        return
    cores = min(figures, cores or idle_cores())
    if cores < 2:
        return
    atexit.register(stop_painters)  # once per process: it ends whatever is left
    forks = cores - 1 if hasattr(os, "fork") else 0
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}  # no BLAS threads: a fork copies only the one
    try:
        _PAINTERS.append(subprocess.Popen(
            [sys.executable, "-c", _LAUNCH.format(delay=PAINTER_DELAY_S, forks=forks)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
            env=env))
    except OSError:
        pass  # no process to be had: the figures are drawn here


def idle_cores() -> int:
    """The cores nothing else is running on now: the processes runnable this instant
    besides this one (Linux's /proc/loadavg; not the load average, which a warm-up or a
    build that just ended keeps up for a minute), else the 1-minute load average."""
    cores = os.cpu_count() or 1
    try:
        runnable = int(Path("/proc/loadavg").read_text().split()[3].split("/")[0])
        busy = float(max(0, runnable - 1))
    except (OSError, ValueError, IndexError):
        try:
            busy = os.getloadavg()[0]
        except OSError:
            busy = 0.0
    return max(0, int(cores - busy + 0.5))


def stop_painters() -> None:
    """End the painter if not (or no longer) needed: closing its input ends it."""
    while _PAINTERS:
        painter = _PAINTERS.pop()
        try:
            if painter.stdin and not painter.stdin.closed:
                painter.stdin.close()
        except OSError:
            pass
        if painter.poll() is None:
            try:
                painter.wait(5.0)
            except subprocess.TimeoutExpired:
                painter.kill()
                painter.wait()
        if painter.stdout:
            painter.stdout.close()


def paint(out, jobs: list[tuple[str, str, tuple]], save) -> set[str]:
    """Hand ``jobs`` to the painter, each figure drawn to a temporary in the folder and
    then written as ours by ``save(out, name, drawn)``; returns the names written. An
    interrupt (Ctrl-C) ends the painter and goes on up."""
    folder = Path(out) if isinstance(out, Path | str) else out.path
    painter, done = _PAINTERS.pop(), set()
    work = [(name, kind, data, str(folder / f".{name}.painter.tmp"))
            for name, kind, data in jobs]
    try:
        try:
            painter.stdin.write(pickle.dumps(work, protocol=pickle.HIGHEST_PROTOCOL))
            painter.stdin.close()
            answer = pickle.loads(painter.stdout.read())
        except (OSError, EOFError, pickle.UnpicklingError):
            answer = []  # the painter is gone: its figures are drawn here
        for name, error in answer:
            drawn = folder / f".{name}.painter.tmp"
            if error is None and drawn.is_file():
                save(out, name, drawn)
                done.add(name)
    except BaseException:  # Ctrl-C, a full disk: the painter's work is of no more use
        painter.kill()
        raise
    finally:
        _PAINTERS.append(painter)
        stop_painters()
        for name, _, _ in jobs:
            (folder / f".{name}.painter.tmp").unlink(missing_ok=True)
    return done


# Rough relative cost of each kind of figure, measured (0.9, 0.6 and 0.25 s on 2 cores):
# the barriers' symlog axes and the two-by-two figures lay out many more labels.
_COST = {"series": 3.5, "checks": 2.4, "torques": 1.0}


def _shares(work: list, count: int) -> list[list]:
    """``work`` in ``count`` shares of about equal cost: the costliest first, each to the
    least loaded share."""
    shares: list[list] = [[] for _ in range(max(1, count))]
    loads = [0.0] * len(shares)
    for item in sorted(work, key=lambda job: -_COST.get(job[1], 1.0)):
        least = loads.index(min(loads))
        loads[least] += _COST.get(item[1], 1.0)
        shares[least].append(item)
    return [share for share in shares if share]


def _draw_share(plt, share: list, draw: dict, dpi: int) -> list[tuple[str, str | None]]:
    answer = []
    for name, kind, data, path in share:
        try:
            fig = draw[kind](plt, *data)
            fig.savefig(path, dpi=dpi, format="png")
            plt.close(fig)
            answer.append((name, None))
        except Exception as exc:  # noqa: BLE001 (drawn again by the parent, which reports)
            answer.append((name, f"{type(exc).__name__}: {exc}"))
    return answer


def painter_main(draw: dict, dpi: int, raw: bytes | None = None, forks: int = 0) -> int:
    """The painter: import matplotlib and load what its first figure would (fonts, the
    mathtext parser of the log axes' labels), then draw the figures it is sent (``raw``,
    or what it reads), in itself and ``forks`` forks of itself, each kind by ``draw[kind]``
    at ``dpi``."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(2, 2), constrained_layout=True)
    ax.plot([0.0, 1.0], [1.0, 1e4], label="x")
    ax.set_yscale("symlog", linthresh=10.0)
    ax.set_title("τ Ḣ")
    ax.legend()
    fig.savefig(io.BytesIO(), dpi=dpi, format="png")
    plt.close(fig)
    if raw is None:
        raw = sys.stdin.buffer.read()
    if not raw:
        return 0  # never given work
    mine, *theirs = _shares(pickle.loads(raw), forks + 1)
    children = []
    for share in theirs:
        read, write = os.pipe()
        pid = os.fork()
        if pid == 0:  # a fork: its share, its answer, and out without the parent's exit
            try:
                os.close(read)
                with os.fdopen(write, "wb") as pipe:
                    pipe.write(pickle.dumps(_draw_share(plt, share, draw, dpi)))
            finally:
                os._exit(0)
        os.close(write)
        children.append((pid, read, share))
    answer = _draw_share(plt, mine, draw, dpi)
    for pid, read, share in children:
        with os.fdopen(read, "rb") as pipe:
            data = pipe.read()
        os.waitpid(pid, 0)
        answer += pickle.loads(data) if data else [(item[0], "its painter died")
                                                   for item in share]
    sys.stdout.buffer.write(pickle.dumps(answer))
    return 0
