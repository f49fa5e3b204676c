"""Two run folders side by side (`cosim compare A B`): every safety check's worst value and
verdict, and the numeric metrics that differ, with the difference; a gate a user's CI can
trust (exit status 1 on a regression):

- like with like: the folders must share the simulated duration and step, each compared
  run must have run to its end in both, and each check must have the same bound in both;
  otherwise :class:`CompareError` names what differs (nothing is judged);
- a regression is a check that held in A and fails in B, a check already violated in A
  whose worst value got worse in B (beyond ``tolerance``, a fraction of its bound), or a
  run of A missing from B. It is judged as the runs' verdicts are
  (:mod:`cosim.evaluate.checks`): a sufficient condition, or a set the reference itself
  leaves in B, is shown, not counted.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..evaluate.checks import VERDICT_KINDS, Kind, is_left, kind, unit
from ..evaluate.parts import metric_unit
from .compared_folder import CompareError, read_summary, verify_summary

# Metrics that measure the machine, not the controller: shown, never called a change.
TIMING = ("wall_time_s", "steps_per_second", "recording_handoff_s")


@dataclass
class Comparison:
    lines: list[str] = field(default_factory=list)
    regressions: list[str] = field(default_factory=list)
    document: dict = field(default_factory=dict)  # the same, for --json


def verdict(entry: dict | None) -> str:
    """A check's worst value and verdict in a dozen characters."""
    if entry is None:
        return "-"
    if entry.get("worst") is None:
        return "n/a"
    mark = "ok" if entry["satisfied"] else (
        "unattainable" if entry.get("attainable") is False else "VIOLATED")
    return f"{entry['worst']:.4g} {mark}"


def _metric_units(run: dict) -> dict[str, str]:
    """A run's declared metric units (summary.json's ``metric_units``); none where an older
    cosim wrote the folder or the entry is not a table of texts."""
    units = run.get("metric_units")
    if not isinstance(units, dict):
        return {}
    return {str(k): v for k, v in units.items() if isinstance(v, str)}


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


def _like_with_like(first: dict, second: dict, names: list[str]) -> list[str]:
    """What makes A and B not comparable: duration, step, a run cut short, a check's
    bound (each named with both values); empty when they compare like with like."""
    differs = []
    joints = [len(((s.get("plant") or {}).get("variables") or {}).get("q") or ())
              for s in (first, second)]
    if joints[0] != joints[1]:
        differs.append(f"the plant has {joints[0]} joints in A, {joints[1]} in B (a joint's "
                       "checks compare only with the same joint's, a norm only over the same "
                       "joints)")
    sims = [(s.get("pipeline") or {}).get("simulation") or {} for s in (first, second)]
    for key, unit_ in (("duration", "s"), ("step", "s")):
        va, vb = sims[0].get(key), sims[1].get(key)
        if va != vb:
            differs.append(f"simulation.{key} {va} {unit_} in A, {vb} {unit_} in B")
    # the bounds as the pipelines set them, then (a run's own override) check by check
    safety = [(s.get("pipeline") or {}).get("safety") or {} for s in (first, second)]
    differs += [f"safety.{key} {safety[0].get(key)} in A, {safety[1].get(key)} in B"
                for key in dict.fromkeys([*safety[0], *safety[1]])
                if safety[0].get(key) != safety[1].get(key)]
    bounds: list[str] = []
    for name in names:
        runs = [s["runs"].get(name) for s in (first, second)]
        if None in runs:
            continue
        for label, run, sim in zip("AB", runs, sims, strict=True):
            done = (run.get("metrics") or {}).get("simulated_time_s")
            duration = sim.get("duration")
            if run.get("complete") is False or (done is not None and duration is not None
                                                and done < duration - 1e-9):
                differs.append(f"run {name} stopped early in {label} (at {done:g} s of "
                               f"{duration:g} s: {run.get('error') or 'incomplete'})"
                               if done is not None and duration is not None else
                               f"run {name} is incomplete in {label}")
        checks_a, checks_b = (r.get("safety") or {} for r in runs)
        for check in [c for c in checks_a if c in checks_b]:
            ba, bb = checks_a[check].get("bound"), checks_b[check].get("bound")
            ua, ub = unit(checks_a[check]), unit(checks_b[check])
            if ua != ub:  # a revolute joint in one, a prismatic one in the other
                differs.append(f"{name}/{check} in {ua or 'no unit'} in A, {ub or 'no unit'} "
                               "in B")
            elif ba != bb:
                u = f" {ua}".rstrip()
                bounds.append(f"{name}/{check} bound {ba}{u} in A, {bb}{u} in B")
    if bounds and not any(d.startswith("safety.") for d in differs):
        differs += bounds[:3] + ([f"and {len(bounds) - 3} more bound(s)"]
                                 if len(bounds) > 3 else [])
    return differs


def _judge(ca: dict | None, cb: dict | None, tolerance: float) -> tuple[str, bool]:
    """A check's change from A to B and whether it is a regression. A check of one side
    only counts as the runs' verdicts count one: gone from B (B no longer checks it), or
    new in B and left there."""
    if ca is None or cb is None:
        side, entry = ("A", ca) if cb is None else ("B", cb)
        counted = kind(entry) in VERDICT_KINDS and (side == "A" or is_left(entry))
        return f"only in {side}", counted
    held_a, held_b = bool(ca.get("satisfied")), bool(cb.get("satisfied"))
    # a regression as the runs' verdicts count one: left in B
    counts = kind(ca) in VERDICT_KINDS and is_left(cb)
    if held_a and not held_b:
        if counts:
            return "REGRESSED", True
        return ("not held (not a safe set)" if kind(ca) == Kind.SUFFICIENT
                else "unknown in B" if cb.get("satisfied") is None
                else "not counted"), False
    if held_b and not held_a:
        return "now holds", False
    if counts and is_left(ca) and ca.get("worst") is not None:
        allowed = tolerance * abs(ca.get("bound") or 0.0)
        if cb["worst"] - ca["worst"] > allowed:
            return "WORSE", True
    return "", False


def _compare_checks(name: str, run_a: dict, run_b: dict, tolerance: float,
                    result: Comparison, entries: dict) -> None:
    """One run's safety checks in A and B: a table row each, its entry for --json, and a
    regression where :func:`_judge` finds one."""
    rows = [["check", "A", "B", "B - A", ""]]
    safety_a, safety_b = run_a.get("safety") or {}, run_b.get("safety") or {}
    for check in dict.fromkeys([*safety_a, *safety_b]):
        ca, cb = safety_a.get(check), safety_b.get(check)
        change, regressed = _judge(ca, cb, tolerance)
        if regressed:
            result.regressions.append(
                f"{name}/{check}: violated in A ({verdict(ca)}) and worse in B "
                f"({verdict(cb)})" if change == "WORSE" else
                f"{name}/{check}: not in A, {verdict(cb)} in B" if ca is None else
                f"{name}/{check}: {'held' if ca.get('satisfied') else 'checked'} in A "
                f"({verdict(ca)}), not in B ({verdict(cb)})")
        both = ca and cb and ca.get("worst") is not None and cb.get("worst") is not None
        delta = cb["worst"] - ca["worst"] if both else None
        declared = unit(cb or ca)
        rows.append([f"{check} ({declared})" if declared else check, verdict(ca),
                     verdict(cb), f"{delta:+.4g}" if delta is not None else "", change])
        entries[check] = {
            "unit": declared, "bound": (cb or ca).get("bound"),
            "a": ca and ca.get("worst"), "b": cb and cb.get("worst"), "b_minus_a": delta,
            "a_verdict": verdict(ca), "b_verdict": verdict(cb),
            "change": change.lower() or None, "regression": regressed}
    result.lines.extend(_table(rows))


def _compare_metrics(run_a: dict, run_b: dict, result: Comparison, entries: dict) -> None:
    """One run's numeric metrics in A and B: a table row for each that differs (with its
    unit; units that differ are not subtracted), an entry each for --json."""
    ma, mb = _numbers(run_a.get("metrics", {})), _numbers(run_b.get("metrics", {}))
    units_a, units_b = _metric_units(run_a), _metric_units(run_b)
    if not units_a and not units_b and (ma or mb):
        result.lines.append("  (neither folder declares its metrics' units: written by "
                            "an older cosim; the metrics are shown bare)")
    rows = [["metric (unit)", "A", "B", "B - A", ""]]
    same = 0
    for metric in dict.fromkeys([*ma, *mb]):
        va, vb = ma.get(metric), mb.get(metric)
        unit_a, unit_b = metric_unit(units_a, metric), metric_unit(units_b, metric)
        clash = unit_a is not None and unit_b is not None and unit_a != unit_b
        delta = vb - va if va is not None and vb is not None and not clash else None
        declared = f"A {unit_a}, B {unit_b}" if clash else unit_b or unit_a
        entries[metric] = {"unit": declared, "a": va, "b": vb, "b_minus_a": delta,
                           "timing": metric in TIMING}
        if clash:
            entries[metric].update(unit=None, unit_a=unit_a, unit_b=unit_b)
        if va == vb and not clash:
            same += 1
            continue
        cells = [f"{v:.6g}" if v is not None else "-" for v in (va, vb)]
        note = ("units differ: not subtracted" if clash
                else "timing" if metric in TIMING else "")
        rows.append([f"{metric} ({declared})" if declared else metric, *cells,
                     f"{delta:+.4g}" if delta is not None else "", note])
    if len(rows) > 1:
        result.lines.extend(_table(rows))
    result.lines.append(f"  {same} metric(s) equal in A and B (--json lists every one)")


def compare(a: str | Path, b: str | Path, runs: list[str] | None = None,
            tolerance: float = 0.0) -> Comparison:
    """Compare the runs the two folders share (or ``runs``, each once); a run of A missing
    from B is a regression (its checks cannot hold there). ``tolerance``: how much worse
    (a fraction of the check's bound) an already violated check may get in B before it
    counts. Raises :class:`CompareError` when A and B do not compare like with like."""
    a, b = Path(a), Path(b)
    first, second = read_summary(a, "A"), read_summary(b, "B")
    verify_summary(a, "A", first)
    verify_summary(b, "B", second)
    runs = list(dict.fromkeys(runs)) if runs else None
    for name in runs or []:
        if name not in first["runs"] and name not in second["runs"]:
            raise CompareError(f"--run {name}: in neither folder; A has "
                               f"{', '.join(first['runs'])}, B has {', '.join(second['runs'])}")
    names = runs or list(dict.fromkeys([*first["runs"], *second["runs"]]))
    differs = _like_with_like(first, second, names)
    if differs:
        raise CompareError(f"A {a} and B {b} do not compare like with like, so no verdict: "
                           f"{'; '.join(differs)}; compare runs of the same duration and "
                           "bounds that both ran to their end")
    result = Comparison()
    result.document = {"a": str(a), "b": str(b), "tolerance": tolerance, "runs": {}}
    result.lines += [f"A: {a} ({first.get('status', '?')})",
                     f"B: {b} ({second.get('status', '?')})",
                     "per run: each check's worst value and verdict, then the metrics that "
                     "differ; each with its unit"]
    plants = [(s.get("plant") or {}) for s in (first, second)]
    if plants[0].get("guid") != plants[1].get("guid"):  # judged, but say it: not the change
        labels = [f"{p.get('model_name', '?')} ({Path(p.get('path') or '?').name})"
                  for p in plants]
        result.lines.append(f"note: the plants differ: A {labels[0]}, B {labels[1]}")
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
        entries: dict = {"checks": {}, "metrics": {}}
        result.document["runs"][name] = entries
        _compare_checks(name, run_a, run_b, tolerance, result, entries["checks"])
        _compare_metrics(run_a, run_b, result, entries["metrics"])
    if result.regressions:
        result.lines.append(f"\n{len(result.regressions)} regression(s):")
        result.lines.extend(f"  {r}" for r in result.regressions)
    else:
        result.lines.append("\nno regression: every check that held in A holds in B, and "
                            "none already violated in A got worse")
    result.document["regressions"] = list(result.regressions)
    return result
