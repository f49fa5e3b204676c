"""What `cosim run` prints once its runs are done: the summary table, then per run what
its evaluators report (their headlines, then their lines), within 100 columns."""

from __future__ import annotations


def print_summary(results) -> None:
    import shutil

    from ..outputs.table import text_table

    width = max(60, min(100, shutil.get_terminal_size((100, 24)).columns))
    print(text_table({name: r.summary() for name, r in results.items()}, width))
    for name, r in results.items():
        m = r.metrics
        for headline in r.evaluation.headlines:  # e.g. what a filter's guarantee covers
            _wrapped(f"{name}: {headline}")
        lines = list(r.evaluation.lines)
        not_run = [f"{n} ({said.removeprefix('not run: ')})"
                   for n, said in r.evaluation.evaluators.items() if said != "ran"]
        if not_run:
            lines.append(f"not evaluated: {'; '.join(not_run)}")
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
