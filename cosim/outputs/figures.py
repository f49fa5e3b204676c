"""PNG figures for reports, in the manner of the paper's Figs. 2-4: the checks whose
declarations name a figure (the paper's: position and velocity in Fig. 2, their errors in
Fig. 3), every joint, every run on one set of axes, with the safe region shaded green and
the unsafe region red, and a zoom on the worst moment below; each run's torques (Fig. 4),
with the torque a filter was asked for beside what it applied; and the series of each
evaluator that names a figure for them, beside their conditions (the paper's barriers,
Fig. 5). The file names are the evaluators' declarations (:func:`figure_files`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..evaluate import EVALUATORS, Check
from . import painter
from .recording.layout import JOINT_COLORS

# Run colours: the paper draws the classical controller in orange, then ours.
RUN_COLORS = ["tab:orange", "tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:olive"]
# Every run's torques, the framework's own figure (named as the paper's Fig. 4)
TORQUE_FIGURE = "fig4_torques.png"


def figure_files() -> tuple[str, ...]:
    """Every figure a run folder may hold: the registered evaluators' (their checks'
    declared figures and their series' figure) and the torques'."""
    from ..blocks.plugins import load_entry_points

    load_entry_points()  # the installed packages' evaluators (the paper's)
    names = [f"{d.figure}.png" for part in EVALUATORS.values() for d in part.declarations
             if d.figure]
    names += [TORQUE_FIGURE]
    names += [f"{part.series_figure}.png" for part in EVALUATORS.values() if part.series_figure]
    return tuple(dict.fromkeys(names))


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
                  series: Mapping[str, Mapping[str, np.ndarray]] | None = None,
                  asked: Mapping[str, tuple[np.ndarray, str]] | None = None) -> list[str]:
    """Write the figures into ``out``: a folder, or a :class:`~.run_folder.RunFolder`
    (which writes each to a temporary, verifies and renames it). ``time``, ``checks``,
    ``torques`` and ``series`` (the evaluators' series by name: the paper's H1, H2, H and
    condition) are per run name; ``asked``, for the
    runs whose torque a filter changed, the torque before it and the filter's kind. Returns
    the names written. With painters started (:func:`.painter.start_painters`) they draw the figures
    in parallel; otherwise, or for what a painter could not draw, this process does."""
    jobs = figure_jobs(time, checks, torques, series, asked)
    drawn = painter.paint(out, jobs, lambda into, name, drawn: save(into, name, None, drawn)) \
        if painter.started() else set()
    for name, kind, data in jobs:
        if name not in drawn:
            _draw_and_save(out, name, kind, data)
    return [name for name, _, _ in jobs]


def figure_jobs(time: Mapping[str, np.ndarray], checks: Mapping[str, Mapping[str, Check]],
                torques: Mapping[str, np.ndarray],
                series: Mapping[str, Mapping[str, np.ndarray]] | None = None,
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
    jobs.append((TORQUE_FIGURE, "torques", (dict(time), dict(torques), dict(asked or {}))))
    for part in EVALUATORS.values():  # each evaluator's series, where it names a figure
        shown = list(part.series_meanings)
        if not part.series_figure or not shown:
            continue
        # only the runs this evaluator gave its series for
        runs = {run: {name: h[name] for name in shown}
                for run, h in (series or {}).items() if all(name in h for name in shown)}
        if runs:
            jobs.append((f"{part.series_figure}.png", "series",
                         ({r: time[r] for r in runs}, runs, list(part.conditions))))
    return jobs


def _draw_and_save(out, name: str, kind: str, data: tuple) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = DRAW[kind](plt, *data)
    try:
        save(out, name, fig)
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
        for row in range(len(names), rows):
            axes[row, column].set_axis_off()
        nearest = max(names, key=lambda n: max(
            np.max(checks[r][n].magnitude, initial=-np.inf) / checks[r][n].upper for r in runs))
        zoom = axes[rows, column]
        _plot_runs(zoom, time, {run: checks[run][nearest] for run in runs})
        _zoom(zoom, time, {run: checks[run][nearest] for run in runs})
    # One legend for the figure, above the panels: inside one it covered data (5 runs).
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside upper center", fontsize=8,
               ncol=min(len(labels), 6))
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
    """Fig. 4: each run's torques, beside those its filter was asked for, on one torque
    scale for every run (panels compared at a glance), each legend beside its panel."""
    runs = list(torques)
    fig, axes = plt.subplots(len(runs), 1, figsize=(11, 2.6 * len(runs)), sharex=True,
                             sharey=True, constrained_layout=True, squeeze=False)
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
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7)
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


def save(out, name: str, fig, drawn: Path | None = None) -> None:
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


def _series_figure(plt, time, series, conditions):
    """An evaluator's series per run (the paper's Fig. 5: its barrier functions H1 (28),
    H2 (29) and H) on the left, and on the right its conditions (must stay ≥ 0: the paper's
    Ḣ + αH), their failing rows shaded; symmetric-log axes (H1 is ~10⁴ where H2 is ~10²)."""
    runs = list(series)
    fig, axes = plt.subplots(len(runs), 2, figsize=(12, 2.6 * len(runs)), sharex=True,
                             constrained_layout=True, squeeze=False)
    for (left, right), run in zip(axes, runs, strict=True):
        h = series[run]
        names = [name for name in h if name not in conditions]
        for i, name in enumerate(names):
            left.plot(time[run], h[name], lw=0.8, label=name,
                      color=RUN_COLORS[(i + 1) % len(RUN_COLORS)])
        left.set_yscale("symlog", linthresh=10.0)
        left.axhline(0.0, color="darkred", lw=0.8, ls="--")
        left.set_title(f"{run}: {', '.join(names)}")
        left.set_ylabel(", ".join(names))
        left.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
        failing = []
        for i, name in enumerate(conditions):
            condition = h[name]
            right.plot(time[run], condition, lw=0.6, label=name,
                       color=("tab:purple", "tab:brown", "tab:gray")[i % 3])
            right.fill_between(time[run], np.minimum(condition, 0.0), 0.0, color="tab:red",
                               alpha=0.3, lw=0)
            finite = condition[np.isfinite(condition)]
            failing.append(f"{name} (≥ 0 where it holds) fails in "
                           f"{100 * np.mean(finite < 0):.1f} % of steps"
                           if len(finite) else f"{name}: no rows")
        right.set_yscale("symlog", linthresh=10.0)
        right.axhline(0.0, color="darkred", lw=0.8, ls="--")
        right.set_title(f"{run}: " + "; ".join(failing))
        right.set_ylabel(", ".join(conditions))
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    return fig


DRAW = {"checks": _checks_figure, "torques": _torque_figure, "series": _series_figure}


def start_painters(cores: int | None = None) -> None:
    """Start the painter that draws the next :func:`write_figures` of this process in
    parallel (:mod:`.painter`)."""
    painter.start_painters(len(figure_files()), cores)


def paint_in_this_process(raw: bytes | None = None, forks: int = 0) -> int:
    """The painter process's work: :func:`.painter.painter_main` with these figures."""
    return painter.painter_main(DRAW, DPI, raw, forks)
