"""PNG figures for reports, in the manner of the paper's Figs. 2-4: the checks whose
declarations name a figure (the paper's: position and velocity in Fig. 2, their errors in
Fig. 3), every joint, every run on one set of axes, with the safe region shaded green and
the unsafe region red, and a zoom on the worst moment below; each
run's torques (Fig. 4), with the torque a filter was asked for beside what it applied; the
barriers (Fig. 5).
"""

from __future__ import annotations

import atexit
import os
import pickle
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .. import interface as io
from ..evaluate import Check
from .recording.layout import JOINT_COLORS

# Run colours: the paper draws the classical controller in orange, then ours.
RUN_COLORS = ["tab:orange", "tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:olive"]
FIGURE_FILES = ("fig2_position_velocity.png", "fig3_errors.png", "fig4_torques.png",
                "fig5_barriers.png")


def _shade(ax, lower: float, upper: float) -> None:
    """Green inside [lower, upper], red outside, over whatever the data's y-range is."""
    low, high = ax.get_ylim()
    span = max(high - low, upper - lower)
    low, high = min(low, lower - 0.1 * span), max(high, upper + 0.1 * span)
    ax.axhspan(lower, upper, color="tab:green", alpha=0.12, lw=0)
    ax.axhspan(upper, high, color="tab:red", alpha=0.10, lw=0)
    ax.axhspan(low, lower, color="tab:red", alpha=0.10, lw=0)
    for bound in (lower, upper):
        ax.axhline(bound, color="darkgreen", lw=0.8, ls="--")
    ax.set_ylim(low, high)


def write_figures(out, time: Mapping[str, np.ndarray],
                  checks: Mapping[str, Mapping[str, Check]],
                  torques: Mapping[str, np.ndarray],
                  barriers: Mapping[str, Mapping[str, np.ndarray]] | None = None,
                  asked: Mapping[str, tuple[np.ndarray, str]] | None = None) -> list[str]:
    """Write the figures into ``out``: a folder, or a :class:`~.run_folder.RunFolder`
    (which writes each to a temporary, verifies and renames it). ``time``, ``checks``,
    ``torques`` and ``barriers`` (H1, H2, H, condition) are per run name; ``asked``, for the
    runs whose torque a filter changed, the torque before it and the filter's kind. Returns
    the names written. With painters started (:func:`start_painters`) they draw the figures
    in parallel; otherwise, or for what a painter could not draw, this process does."""
    jobs = figure_jobs(time, checks, torques, barriers, asked)
    drawn = _paint(out, jobs) if _PAINTERS else set()
    for name, kind, data in jobs:
        if name not in drawn:
            _draw_and_save(out, name, kind, data)
    return [name for name, _, _ in jobs]


def figure_jobs(time: Mapping[str, np.ndarray], checks: Mapping[str, Mapping[str, Check]],
                torques: Mapping[str, np.ndarray],
                barriers: Mapping[str, Mapping[str, np.ndarray]] | None = None,
                asked: Mapping[str, tuple[np.ndarray, str]] | None = None
                ) -> list[tuple[str, str, tuple]]:
    """(file name, kind, data) of each figure to draw (the arguments of
    :func:`write_figures`): only the arrays it shows, so that a painter process is sent
    megabytes, not the whole evaluation."""
    jobs = []
    for filename, columns in check_figures(checks).items():
        shown = [name for names in columns for name in names]
        # The runs evaluated with these checks (a run whose chain has no error signals has
        # none); a figure no run has is not drawn.
        runs = [run for run in checks if all(c in checks[run] for c in shown)]
        if runs:
            jobs.append((filename, "checks", (columns, {r: time[r] for r in runs},
                                              {r: {c: checks[r][c] for c in shown}
                                               for r in runs})))
    jobs.append(("fig4_torques.png", "torques", (dict(time), dict(torques), dict(asked or {}))))
    barriers = {run: h for run, h in (barriers or {}).items() if io.BARRIER_CONDITION in h}
    if barriers:  # only the runs evaluated with Theorem 1's barriers
        jobs.append(("fig5_barriers.png", "barriers", ({r: time[r] for r in barriers},
                                                       barriers)))
    return jobs


def _draw_and_save(out, name: str, kind: str, data: tuple) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = _DRAW[kind](plt, *data)
    try:
        _save(out, name, fig)
    finally:
        plt.close(fig)


def check_figures(checks: Mapping[str, Mapping[str, Check]]) -> dict[str, list[list[str]]]:
    """File name → its columns: per family declared with that figure (in declaration
    order), every joint's check, over the runs' checks."""
    figures: dict[str, dict[str, list[str]]] = {}
    for run_checks in checks.values():
        for name, check in run_checks.items():
            declared = check.declared
            if declared is None or not declared.figure or check.joint is None:
                continue
            names = figures.setdefault(f"{declared.figure}.png", {}).setdefault(
                declared.family, [])
            if name not in names:
                names.append(name)
    return {name: list(columns.values()) for name, columns in figures.items()}


def _checks_figure(plt, columns: list[list[str]], time, checks):
    """Figs. 2 and 3: a column per family, a row per joint with every run over the whole
    run, and below each column a zoom on the joint nearest its bound."""
    runs = list(checks)
    rows = max(map(len, columns))
    fig, axes = plt.subplots(rows + 1, len(columns), figsize=(6 * len(columns), 2.6 * rows + 3),
                             constrained_layout=True, squeeze=False)
    for column, names in enumerate(columns):
        for row, name in enumerate(names):
            whole = axes[row, column]
            _plot_runs(whole, time, {run: checks[run][name] for run in runs})
            first = checks[runs[0]][name]
            _shade(whole, first.lower, first.upper)
            whole.set_title(f"joint {first.joint}: {first.declared.quantity}")
            if row == 0:
                whole.legend(loc="lower right", fontsize=8)
        for row in range(len(names), rows):
            axes[row, column].set_axis_off()
        nearest = max(names, key=lambda n: max(
            np.max(checks[r][n].magnitude, initial=-np.inf) / checks[r][n].upper for r in runs))
        zoom = axes[rows, column]
        _plot_runs(zoom, time, {run: checks[run][nearest] for run in runs})
        _zoom(zoom, time, {run: checks[run][nearest] for run in runs})
    return fig


def _plot_runs(ax, time, checks: Mapping[str, Check]) -> None:
    """Every run's values of one check (and the reference's, dotted), labelled."""
    runs = list(checks)
    first = checks[runs[0]]
    if first.reference is not None:
        ax.plot(time[runs[0]], first.reference, color="black", lw=0.9, ls=":",
                label="reference")
    for i, run in enumerate(runs):
        ax.plot(time[run], checks[run].value, lw=1.0, color=RUN_COLORS[i % len(RUN_COLORS)],
                label=run)
    ax.set_xlabel("time (s)")
    where = "norm" if first.joint is None else f"joint {first.joint}"
    ax.set_ylabel(f"{where} ({first.declared.unit})" if first.declared else "")


def _torque_figure(plt, time, torques, asked):
    """Fig. 4: each run's torques, beside those its filter was asked for."""
    runs = list(torques)
    fig, axes = plt.subplots(len(runs), 1, figsize=(10, 2.6 * len(runs)), sharex=True,
                             constrained_layout=True, squeeze=False)
    for ax, run in zip(axes[:, 0], runs, strict=True):
        tau = torques[run]
        before, kind = asked.get(run, (None, ""))
        for j in range(tau.shape[1]):
            color = np.array(JOINT_COLORS[j % len(JOINT_COLORS)]) / 255
            ax.plot(time[run], tau[:, j], lw=0.8, color=color, label=f"τ{j + 1}")
            if before is not None:
                ax.plot(time[run], before[:, j], lw=0.7, ls=(0, (2, 2)), color=color,
                        alpha=0.8, label=f"τ{j + 1} asked (before the {kind})")
        ax.set_ylabel("torque (N·m)")
        title = f"{run}: joint torques"
        if before is not None and len(tau):
            changed = np.any(tau != before, axis=1)
            title += (f"; the {kind} changed them in {100 * changed.mean():.1f} % of steps, "
                      f"by up to {np.max(np.abs(tau - before)):.3g} N·m")
        ax.set_title(title, fontsize=10)
        ax.legend(loc="upper right", fontsize=7, ncol=2 if before is not None else 1)
    axes[-1, 0].set_xlabel("time (s)")
    return fig


def _zoom(ax, time: Mapping[str, np.ndarray], checks: Mapping[str, Check]) -> None:
    """Limit ``ax`` to ±1 s around the worst value of any run, the bound it nears drawn."""
    worst_run = max(checks, key=lambda r: np.max(checks[r].magnitude, initial=-np.inf))
    check = checks[worst_run]
    if not len(check.value):
        ax.set_title("zoom: no rows")
        return
    k = int(np.argmax(check.magnitude))
    t0 = float(time[worst_run][k])
    window = [(time[r] >= t0 - 1.0) & (time[r] <= t0 + 1.0) for r in checks]
    values = np.concatenate([c.value[w] for c, w in zip(checks.values(), window, strict=True)]
                            + [c.reference[w] for c, w in zip(checks.values(), window,
                                                              strict=True)
                               if c.reference is not None])
    bound = check.upper if check.value[k] >= 0 else check.lower
    low, high = min(values.min(), bound), max(values.max(), bound)
    pad = 0.08 * (high - low or 1.0)
    ax.set_xlim(t0 - 1.0, t0 + 1.0)
    ax.set_ylim(low - pad, high + pad)
    ax.axhline(bound, color="darkred", lw=0.9, ls="--")
    ax.axhspan(bound, high + pad if bound == check.upper else low - pad, color="tab:red",
               alpha=0.10, lw=0)
    ax.set_title(f"zoom: ±1 s around the worst value ({worst_run}, {check.value[k]:.4g} at "
                 f"t = {t0:.3g} s; bound {bound:g})", fontsize=9)


DPI = 110


def _save(out, name: str, fig, drawn: Path | None = None) -> None:
    """``fig`` (or the PNG a painter ``drawn``) as ``name`` in ``out``: a folder, or a
    RunFolder, which verifies and renames it."""
    def produce(tmp: Path) -> None:
        if drawn is not None:
            os.replace(drawn, tmp)
        else:
            fig.savefig(tmp, dpi=DPI, format="png")

    if isinstance(out, Path | str):
        produce(Path(out) / name)
    else:
        out.write(name, produce)


def _barrier_figure(plt, time, barriers):
    """Fig. 5, per run: the evaluators' barrier functions (the paper's H1 (28), H2 (29) and
    H), and their condition (Ḣ + αH, must stay ≥ 0), on symmetric-log axes (H1 is ~10⁴ where
    H2 is ~10²)."""
    runs = list(barriers)
    fig, axes = plt.subplots(len(runs), 2, figsize=(12, 2.6 * len(runs)), sharex=True,
                             constrained_layout=True, squeeze=False)
    for (left, right), run in zip(axes, runs, strict=True):
        h = barriers[run]
        names = [name for name in h if name != io.BARRIER_CONDITION]
        for i, name in enumerate(names):
            left.plot(time[run], h[name], lw=0.8, label=name,
                      color=RUN_COLORS[(i + 1) % len(RUN_COLORS)])
        left.set_yscale("symlog", linthresh=10.0)
        left.axhline(0.0, color="darkred", lw=0.8, ls="--")
        left.set_title(f"{run}: barrier functions (≥ 0 inside)")
        left.set_ylabel(f"{', '.join(names)} (mixed units)")  # k0·ε², ‖Ŵ‖²/F, rᵀMr
        left.legend(loc="upper right", fontsize=8)
        condition = h[io.BARRIER_CONDITION]
        right.plot(time[run], condition, lw=0.6, color="tab:purple")
        right.fill_between(time[run], np.minimum(condition, 0.0), 0.0, color="tab:red",
                           alpha=0.3, lw=0)
        right.set_yscale("symlog", linthresh=10.0)
        right.axhline(0.0, color="darkred", lw=0.8, ls="--")
        finite = condition[np.isfinite(condition)]
        failing = f"{100 * np.mean(finite < 0):.1f} %" if len(finite) else "none (no rows)"
        right.set_title(f"{run}: Ḣ + αH ≥ 0 fails in {failing} of steps")
        right.set_ylabel("Ḣ + αH (H per second)")
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    return fig


_DRAW = {"checks": _checks_figure, "torques": _torque_figure, "barriers": _barrier_figure}


# The painter: a process that draws the figures in parallel ----------------------------------
#
# Four figures take seconds to lay out and draw (matplotlib's text and layout work, in
# Python), after the runs, when nothing else is left to do. `cosim run` starts a painter
# before the runs: it waits a moment (the run's own process is loading its kernels and the
# recording's writer importing Rerun: both on the critical path), then imports matplotlib
# and draws a first small figure (fonts, the log axes' mathtext) while the runs go. Given
# the figures, it forks once per further idle core, and the forks, warm already, draw their
# share side by side with it. It pays only with idle cores: on a machine already busy none
# is started, and this process draws them itself. A plain child interpreter (not
# multiprocessing), as for the recording's writer, so that a script calling run() without a
# __main__ guard works. A painter never given work reads the end of its input and exits;
# what it could not draw, this process draws.

_PAINTERS: list[subprocess.Popen] = []
PAINTER_DELAY_S = 1.0  # before the painter imports matplotlib, unless its work comes first
# The painter's first lines, before any import: wait, unless its input (work, or the end of
# it: not needed) comes first. One thread only, so that its forks are safe.
_LAUNCH = ("import select, sys\n"
           "ready = select.select([sys.stdin], [], [], {delay})[0]\n"
           "raw = sys.stdin.buffer.read() if ready else None\n"
           "if raw != b'':\n"
           "    from cosim.outputs.figures import _painter_main\n"
           "    sys.exit(_painter_main(raw, {forks}))\n")


def start_painters(cores: int | None = None) -> None:
    """Start the painter for the next :func:`write_figures` of this process, to draw on
    ``cores`` cores (default: the idle ones, at most one per figure); none when fewer than
    two are idle, where drawing here costs the same, without the painter's import."""
    if _PAINTERS:
        return
    cores = min(len(FIGURE_FILES), cores or idle_cores())
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


def _paint(out, jobs: list[tuple[str, str, tuple]]) -> set[str]:
    """Hand ``jobs`` to the painter, each figure drawn to a temporary in the folder and
    then written as ours; returns the names written. An interrupt (Ctrl-C) ends the painter
    and goes on up."""
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
                _save(out, name, None, drawn)
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
_COST = {"barriers": 3.5, "checks": 2.4, "torques": 1.0}


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


def _draw_share(plt, share: list) -> list[tuple[str, str | None]]:
    answer = []
    for name, kind, data, path in share:
        try:
            fig = _DRAW[kind](plt, *data)
            fig.savefig(path, dpi=DPI, format="png")
            plt.close(fig)
            answer.append((name, None))
        except Exception as exc:  # noqa: BLE001 (drawn again by the parent, which reports)
            answer.append((name, f"{type(exc).__name__}: {exc}"))
    return answer


def _painter_main(raw: bytes | None = None, forks: int = 0) -> int:
    """The painter: import matplotlib and load what its first figure would (fonts, the
    mathtext parser of the log axes' labels), then draw the figures it is sent (``raw``,
    or what it reads), in itself and ``forks`` forks of itself."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(2, 2), constrained_layout=True)
    ax.plot([0.0, 1.0], [1.0, 1e4], label="x")
    ax.set_yscale("symlog", linthresh=10.0)
    ax.set_title("τ Ḣ")
    ax.legend()
    fig.savefig(io.BytesIO(), dpi=DPI, format="png")
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
                    pipe.write(pickle.dumps(_draw_share(plt, share)))
            finally:
                os._exit(0)
        os.close(write)
        children.append((pid, read, share))
    answer = _draw_share(plt, mine)
    for pid, read, share in children:
        with os.fdopen(read, "rb") as pipe:
            data = pipe.read()
        os.waitpid(pid, 0)
        answer += pickle.loads(data) if data else [(item[0], "its painter died")
                                                   for item in share]
    sys.stdout.buffer.write(pickle.dumps(answer))
    return 0
