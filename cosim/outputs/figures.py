"""PNG figures for reports, in the manner of the paper's Figs. 2-4: joint 1's position and
velocity (Fig. 2) and their errors (Fig. 3) for every run on one set of axes, with the safe
region shaded green and the unsafe region red and a zoom on the worst moment below; each
run's torques (Fig. 4), with the torque a filter was asked for beside what it applied; the
barriers (Fig. 5).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..evaluate import Check
from .recording.layout import FIGURE_CHECKS, JOINT_COLORS

# Run colours: the paper draws the classical controller in orange, then ours.
RUN_COLORS = ["tab:orange", "tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:olive"]
FIGURE_FILES = ("fig2_position_velocity.png", "fig3_errors.png", "fig4_torques.png",
                "fig5_barriers.png")
FIGURES = {
    "fig2_position_velocity.png": ("position_joint1", "velocity_estimated_joint1"),
    "fig3_errors.png": ("error_joint1", "error_rate_joint1"),
}


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
    the names written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    for filename, pair in FIGURES.items():
        # The runs evaluated with these checks (a run whose chain has no error signals has
        # none); a figure no run has is not drawn.
        runs = [run for run in checks if all(c in checks[run] for c in pair)]
        if not runs:
            continue
        # Top: the whole run. Bottom: ±1 s around the worst value of any run, where the
        # runs differ by fractions of the bound (the reference's peaks, for the position).
        fig, axes = plt.subplots(2, 2, figsize=(12, 7.6), constrained_layout=True,
                                 height_ratios=(1.2, 1))
        for column, check_name in enumerate(pair):
            first = checks[runs[0]][check_name]
            for ax in axes[:, column]:
                if first.reference is not None:
                    ax.plot(time[runs[0]], first.reference, color="black", lw=0.9, ls=":",
                            label="reference")
                for i, run in enumerate(runs):
                    ax.plot(time[run], checks[run][check_name].value, lw=1.0,
                            color=RUN_COLORS[i % len(RUN_COLORS)], label=run)
                ax.set_xlabel("time (s)")
                ax.set_ylabel(FIGURE_CHECKS[check_name])
            whole, zoom = axes[:, column]
            _shade(whole, first.lower, first.upper)
            whole.set_title(f"joint 1: {FIGURE_CHECKS[check_name].split(' (')[0]}")
            whole.legend(loc="lower right", fontsize=8)
            _zoom(zoom, time, {run: checks[run][check_name] for run in runs})
        _save(out, filename, fig)
        plt.close(fig)
        written.append(filename)

    runs = list(torques)
    fig, axes = plt.subplots(len(runs), 1, figsize=(10, 2.6 * len(runs)), sharex=True,
                             constrained_layout=True, squeeze=False)
    for ax, run in zip(axes[:, 0], runs, strict=True):
        tau = torques[run]
        before, kind = (asked or {}).get(run, (None, ""))
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
    _save(out, "fig4_torques.png", fig)
    plt.close(fig)
    written.append("fig4_torques.png")
    barriers = {run: h for run, h in (barriers or {}).items() if "H" in h}
    if barriers:  # only the runs evaluated with Theorem 1's barriers
        written.append(_barrier_figure(plt, out, time, barriers))
    return written


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


def _save(out, name: str, fig) -> None:
    if isinstance(out, Path | str):
        fig.savefig(Path(out) / name, dpi=110, format="png")
    else:
        out.write(name, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))


def _barrier_figure(plt, out, time, barriers) -> str:
    """Per run: H1 (28), H2 (29) and H, and the barrier condition Ḣ + αH (must stay ≥ 0),
    on symmetric-log axes (H1 is ~10⁴ where H2 is ~10²)."""
    runs = list(barriers)
    fig, axes = plt.subplots(len(runs), 2, figsize=(12, 2.6 * len(runs)), sharex=True,
                             constrained_layout=True, squeeze=False)
    for (left, right), run in zip(axes, runs, strict=True):
        h = barriers[run]
        for i, name in enumerate(("H1", "H2", "H")):
            left.plot(time[run], h[name], lw=0.8, label=name,
                      color=RUN_COLORS[(i + 1) % len(RUN_COLORS)])
        left.set_yscale("symlog", linthresh=10.0)
        left.axhline(0.0, color="darkred", lw=0.8, ls="--")
        left.set_title(f"{run}: barriers (H ≥ 0 inside)")
        left.set_ylabel("H1, H2, H (mixed units)")  # k0·ε², ‖Ŵ‖²/F, rᵀMr: no one unit
        left.legend(loc="upper right", fontsize=8)
        condition = h["condition"]
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
    _save(out, "fig5_barriers.png", fig)
    plt.close(fig)
    return "fig5_barriers.png"
