"""The safety table people read at a glance: one verdict per run, one row per check with its
bound stated once, marks instead of sentences in the cells, as text that fits the terminal
(runs paged into column groups) and as Markdown for the run folder's summary.md.

It reads the runs' summaries (``summary.json``'s ``runs``), so a finished folder can be
shown again the same way.
"""

from __future__ import annotations

from ..evaluate.checks import Kind, kind, left_sets, unit

KEPT, LEFT, UNATTAINABLE = "✓", "✗", "~"
LEGEND = (f"{KEPT} kept, {LEFT} left, {UNATTAINABLE} unattainable (the reference itself leaves "
          "the set: none can keep it)")


def _mark(entry: dict) -> str:
    if entry["satisfied"]:
        return KEPT
    return UNATTAINABLE if entry.get("attainable") is False else LEFT


def verdict(summary: dict) -> str:
    """One short line, the robot's limits (the hard sets: position, velocity, effort) apart
    from tracking (the soft sets): whether the run kept them, or which it left first, when,
    for how long and how many more. Unattainable sets and sufficient conditions are the
    table's to show."""
    safety = summary.get("safety", {})
    tail = "" if summary.get("complete", True) else " (the run did not finish)"
    hard = left_sets(safety, [Kind.HARD])
    soft = left_sets(safety, [Kind.SOFT])
    tracking = f"tracking: left {_first(soft)}" if soft else "tracking kept"
    if hard:
        return f"limits LEFT: {_first(hard)}; {tracking}{tail}"
    families = list(dict.fromkeys(e["family"].removesuffix("_true").replace("_", " ")
                                  for e in safety.values()
                                  if kind(e) == Kind.HARD and "family" in e))
    limits = (f"limits kept (every joint's {', '.join(families)})" if families
              else "no limits (no hard set)")
    return f"{limits}; {tracking}{tail}"


def _first(left: list[tuple[str, dict]]) -> str:
    """The first set a run left, when and for how long, and how many more."""
    name, entry = left[0]
    more = f", +{len(left) - 1} more" if len(left) > 1 else ""
    return (f"{name} at {entry['first_violation_s']:.2f} s "
            f"({entry['time_outside_s']:.2f} s out){more}")


def _bounds(runs: dict[str, dict], check: str) -> list[float]:
    return sorted({e["bound"] for r in runs.values()
                   if (e := r.get("safety", {}).get(check)) is not None})


def _limits(runs: dict[str, dict], check: str) -> list[tuple[float, float]]:
    """The distinct [lower, upper] limits a check has in the runs (none: not a limit)."""
    return sorted({tuple(e["limits"]) for r in runs.values()
                   if (e := r.get("safety", {}).get(check)) is not None and "limits" in e})


def _rows(runs: dict[str, dict]) -> tuple[list[str], list[list[str]]]:
    """(check labels with their bound, cells per check and run)."""
    checks = list(dict.fromkeys(c for r in runs.values() for c in r.get("safety", {})))
    labels, cells = [], []
    for check in checks:
        bounds = _bounds(runs, check)
        shared = len(bounds) == 1
        first = next(r["safety"][check] for r in runs.values() if check in r.get("safety", {}))
        limits = _limits(runs, check)
        if limits:  # a robot's limits: the quantity itself between them
            shared = len(limits) == 1
            label = (f"{check} in [{limits[0][0]:g}, {limits[0][1]:g}] {unit(first)}".rstrip()
                     if shared else check)
        else:
            label = f"{check} ≤ {bounds[0]:g} {unit(first)}".rstrip() if shared else check
        labels.append(f"{label} (*)" if kind(first) == Kind.SUFFICIENT else label)
        row = []
        for summary in runs.values():
            entry = summary.get("safety", {}).get(check)
            if entry is None:
                row.append("-")
            elif entry.get("worst") is None:
                row.append("n/a")
            elif "range" in entry:
                low, high = entry["range"]
                own = "" if shared else " (in [{:g}, {:g}])".format(*entry["limits"])
                row.append(f"[{low:.3f}, {high:.3f}] {_mark(entry)}{own}")
            else:
                own = "" if shared else f" (≤ {entry['bound']:g})"
                row.append(f"{entry['worst']:.3f} {_mark(entry)}{own}")
        cells.append(row)
    return labels, cells


def text_table(runs: dict[str, dict], width: int = 100) -> str:
    """The table as text no wider than ``width``: the runs in as many column groups as
    needed, then one verdict line per run."""
    labels, cells = _rows(runs)
    names = list(runs)
    first = max([len("check (bound, SI units)"), *map(len, labels)])
    widths = [max([len(n), *(len(row[i]) for row in cells)]) for i, n in enumerate(names)]
    groups, current, used = [], [], first
    for i, w in enumerate(widths):
        if current and used + 2 + w > width:
            groups.append(current)
            current, used = [], first
        current.append(i)
        used += 2 + w
    groups.append(current)
    lines = ["safety: each check's worst value against its bound", f"  {LEGEND}"]
    if any(label.endswith("(*)") for label in labels):
        lines.append(f"  (*) {_footnote()}")
    for group in groups:
        lines.append("  ".join(["check (bound, SI units)".ljust(first),
                                *(names[i].ljust(widths[i]) for i in group)]).rstrip())
        for label, row in zip(labels, cells, strict=True):
            lines.append("  ".join([label.ljust(first),
                                    *(row[i].ljust(widths[i]) for i in group)]).rstrip())
    lines.append("verdict:")
    pad = max(map(len, names))
    for name in names:
        lines.extend(_verdict_lines(f"  {name.ljust(pad)}  ", verdict(runs[name]), width))
    return "\n".join(lines)


def _verdict_lines(head: str, text: str, width: int) -> list[str]:
    """A verdict after ``head``, its tracking part on a line of its own, aligned, where the
    whole would be wider than ``width``."""
    if len(head) + len(text) <= width or "; " not in text:
        return [head + text]
    limits, tracking = text.split("; ", 1)
    return [f"{head}{limits};", " " * len(head) + tracking]


def markdown_table(runs: dict[str, dict], title: str, not_run: list[str] = ()) -> str:
    """summary.md: the verdicts (and the runs a failure left without a result), then the
    checks with the first exit and time outside."""
    names = list(runs)
    lines = [f"# {title}", "", "## Verdict", ""]
    lines.extend(f"- **{name}**: {verdict(runs[name])}" for name in names)
    lines.extend(f"- **{name}**: no result (the runs stopped before it finished)"
                 for name in not_run)
    lines += ["", "## Safety checks", "", f"Worst value against its bound: {LEGEND}. "
              f"(*) {_footnote()}.", "",
              "| check | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    labels, cells = _rows(runs)
    checks = list(dict.fromkeys(c for r in runs.values() for c in r.get("safety", {})))
    for check, label, row in zip(checks, labels, cells, strict=True):
        out = []
        for name, cell in zip(names, row, strict=True):
            entry = runs[name].get("safety", {}).get(check)
            if entry and entry.get("worst") is not None and _mark(entry) == LEFT:
                cell += (f" from {entry['first_violation_s']:.2f} s, "
                         f"{entry['time_outside_s']:.2f} s out")
            elif entry and _mark(entry) == UNATTAINABLE:
                cell += f" (reference reaches {entry['reference_worst']:.3f})"
            out.append(cell)
        lines.append(f"| {label} | " + " | ".join(out) + " |")
    lines.append("")
    return "\n".join(lines)


def _footnote() -> str:
    return "a sufficient condition for other sets, not a safe set: not in the verdict"
