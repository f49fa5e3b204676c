"""What `cosim run` prints once its runs are done: the summary table, then per run what its
guarantee covers and its metrics, within 100 columns."""

from __future__ import annotations


def print_summary(results) -> None:
    import shutil

    from ..outputs.table import text_table

    width = max(60, min(100, shutil.get_terminal_size((100, 24)).columns))
    print(text_table({name: r.summary() for name, r in results.items()}, width))
    for name, r in results.items():
        m = r.metrics
        g = m.get("guarantee") or {}
        if g.get("feasible") is not None:  # a filtered run: what its guarantee covers
            covered = g["starts_inside"] and g["feasible"] and g["within_bounds"]
            exit_text = (f"left {g['first_exit']['set']} at {g['first_exit']['t']:.3f} s"
                         if g["first_exit"] else "kept every hard set")
            _wrapped(f"{name}: {exit_text}; guarantee "
                     + ("covers this run" if covered else "does not cover this run: "
                        + "; ".join([*(["started outside"] if not g["starts_inside"] else []),
                                     *([f"{g['infeasible_steps']} infeasible step(s)"]
                                       if not g["feasible"] else []), *g["outside"]]))
                     + (" — BROKEN" if g["broken"] else ""))
        lines = []
        if "peak_torque" in m:
            tau = ", ".join(f"{x:.1f}" for x in m["peak_torque"])
            gain = m.get("feedback_gain")
            lines.append(f"peak torque [{tau}] N·m" + (
                f"; effective gain on r̂ (median) {gain['median']:.1f} N·m·s/rad"
                if gain else ""))
        obs = m.get("observer_velocity_error_rms_after_1s")
        if obs:
            lines.append("observer velocity RMS error after 1 s "
                         f"[{', '.join(f'{x:.3f}' for x in obs)}] rad/s")
        if "barrier_condition" in m:
            condition = m["barrier_condition"]
            lines.append(f"min H {m['min_barrier_H']:.3g} (H1 {m['min_barrier_H1']:.3g}, "
                         f"H2 {m['min_barrier_H2']:.3g}); dH/dt + {condition['alpha']:g} H < 0 "
                         f"in {100 * (condition['fraction_failing'] or 0):.1f} % of steps")
        not_run = [n for n, said in r.evaluation.evaluators.items() if said != "ran"]
        if not_run:
            lines.append(f"not evaluated (inputs missing, see summary.json): "
                         f"{', '.join(not_run)}")
        sps = m["steps_per_second"]
        lines.append(f"{m['wall_time_s']:.2f} s wall, {sps or 0:,.0f} steps/s")
        _wrapped(f"{name}: {lines[0]}")
        for line in lines[1:]:
            _wrapped(line, indent=1)


def _wrapped(line: str, indent: int = 0) -> None:
    """A summary line within 100 columns, indented by ``indent`` levels, its continuations
    by one more."""
    import textwrap

    print(textwrap.fill(line, width=100, initial_indent="    " * indent,
                        subsequent_indent="    " * (indent + 1), break_long_words=False,
                        break_on_hyphens=False))
