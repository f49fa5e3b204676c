"""Two run folders side by side (`cosim compare A B`): every safety check's worst value and
verdict, and every numeric metric, with the difference; a check that held in A and fails in
B is a regression, so a controller change can be gated in a user's CI (exit status 1).
A regression is judged as the runs' verdicts are (:mod:`cosim.evaluate.checks`): a
sufficient condition, or a set the reference itself leaves in B, is shown, not counted."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..evaluate.checks import VERDICT_KINDS, Kind, is_left, kind, unit
from .run_folder import _ours_summary

# Metrics that measure the machine, not the controller: shown, never called a change.
TIMING = ("wall_time_s", "steps_per_second", "recording_handoff_s")


class CompareError(Exception):
    """A folder that cannot be compared: one line naming it."""


@dataclass
class Comparison:
    lines: list[str] = field(default_factory=list)
    regressions: list[str] = field(default_factory=list)


def _summary(folder: Path, label: str) -> dict:
    summary = _ours_summary(folder) if folder.is_dir() else None
    if summary is None or not isinstance(summary.get("runs"), dict):
        raise CompareError(f"{label} {folder}: not a cosim run folder (no summary.json with "
                           "runs); give folders `cosim run --out` wrote")
    return summary


def verdict(entry: dict | None) -> str:
    """A check's worst value and verdict in a dozen characters."""
    if entry is None:
        return "-"
    if entry.get("worst") is None:
        return "n/a"
    mark = "ok" if entry["satisfied"] else (
        "unattainable" if entry.get("attainable") is False else "VIOLATED")
    return f"{entry['worst']:.4g} {mark}"


def _numbers(metrics: dict, prefix: str = "") -> dict[str, float]:
    """The numeric leaves of a metrics tree, by dotted name (lists per joint: name[1])."""
    out: dict[str, float] = {}
    for key, value in metrics.items():
        name = f"{prefix}{key}"
        if isinstance(value, bool) or value is None:
            continue
        if isinstance(value, int | float):
            out[name] = float(value)
        elif isinstance(value, dict):
            out.update(_numbers(value, f"{name}."))
        elif isinstance(value, list) and all(isinstance(v, int | float)
                                             and not isinstance(v, bool) for v in value):
            out.update({f"{name}[{i + 1}]": float(v) for i, v in enumerate(value)})
    return out


def _table(rows: list[list[str]]) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
            for r in rows]


def compare(a: str | Path, b: str | Path, runs: list[str] | None = None) -> Comparison:
    """Compare the runs the two folders share (or ``runs``); a run of A missing from B is a
    regression (its checks cannot hold there)."""
    a, b = Path(a), Path(b)
    first, second = _summary(a, "A"), _summary(b, "B")
    result = Comparison()
    result.lines += [f"A: {a} ({first.get('status', '?')})",
                     f"B: {b} ({second.get('status', '?')})",
                     "per run: each check's worst value and verdict, then the metrics; SI units"]
    for label, summary in (("A", first), ("B", second)):
        if not summary.get("complete"):
            result.lines.append(f"note: {label} is not complete (status "
                                f"{summary.get('status', '?')}): its values cover what ran")
    names = runs or list(dict.fromkeys([*first["runs"], *second["runs"]]))
    for name in runs or []:
        if name not in first["runs"] and name not in second["runs"]:
            raise CompareError(f"--run {name}: in neither folder; A has "
                               f"{', '.join(first['runs'])}, B has {', '.join(second['runs'])}")
    for name in names:
        run_a, run_b = first["runs"].get(name), second["runs"].get(name)
        if run_a is None:
            result.lines.append(f"\nrun {name}: only in B")
            continue
        if run_b is None:
            result.lines.append(f"\nrun {name}: only in A")
            result.regressions.append(f"{name}: in A, missing from B")
            continue
        result.lines.append(f"\nrun {name}")
        rows = [["check", "A", "B", "B - A", ""]]
        checks = list(dict.fromkeys([*run_a.get("safety", {}), *run_b.get("safety", {})]))
        for check in checks:
            ca, cb = run_a.get("safety", {}).get(check), run_b.get("safety", {}).get(check)
            held_a = bool(ca and ca.get("satisfied"))
            held_b = bool(cb and cb.get("satisfied"))
            change = ""
            # a regression as the runs' verdicts count one: left in B (or gone from it)
            counts = held_a and kind(ca) in VERDICT_KINDS and (cb is None or is_left(cb))
            if held_a and not held_b and not counts:
                change = ("not held (not a safe set)" if kind(ca) == Kind.SUFFICIENT
                          else "unknown in B" if cb.get("satisfied") is None
                          else "unattainable in B")
            elif held_a and not held_b:
                change = "REGRESSED"
                result.regressions.append(f"{name}/{check}: held in A ({verdict(ca)}), not in "
                                          f"B ({verdict(cb)})")
            elif held_b and not held_a:
                change = "now holds"
            both = ca and cb and ca.get("worst") is not None and cb.get("worst") is not None
            delta = f"{cb['worst'] - ca['worst']:+.4g}" if both else ""
            declared = unit(cb or ca)
            rows.append([f"{check} ({declared})" if declared else check, verdict(ca),
                         verdict(cb), delta, change])
        result.lines.extend(_table(rows))
        ma, mb = _numbers(run_a.get("metrics", {})), _numbers(run_b.get("metrics", {}))
        rows = [["metric", "A", "B", "B - A", ""]]
        for metric in dict.fromkeys([*ma, *mb]):
            va, vb = ma.get(metric), mb.get(metric)
            cells = [f"{v:.6g}" if v is not None else "-" for v in (va, vb)]
            delta = f"{vb - va:+.4g}" if va is not None and vb is not None else ""
            note = "timing" if metric in TIMING else ""
            rows.append([metric, *cells, delta, note])
        result.lines.extend(_table(rows))
    if result.regressions:
        result.lines.append(f"\n{len(result.regressions)} regression(s):")
        result.lines.extend(f"  {r}" for r in result.regressions)
    else:
        result.lines.append("\nno regression: every check that held in A holds in B")
    return result
