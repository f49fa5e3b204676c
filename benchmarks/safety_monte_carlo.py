"""The safety filter's Monte Carlos (issue 30, item 6; docs/sweeps.md, "The safety filter's
Monte Carlos"): three distributions of starts and plants, each at the torque limits given,
run on Dask through cosim.sweep's own API (one cluster, explicit points), then a report per
run and limit with Wilson 95 % intervals.

    .venv/bin/python benchmarks/safety_monte_carlo.py --distribution project --unfiltered-only \\
        --samples 50 --out runs/peak                     # the unfiltered median peak τ1
    .venv/bin/python benchmarks/safety_monte_carlo.py --distribution near-boundary \\
        --samples 500 --torque-limits 1000 2000 --out runs/near
    .venv/bin/python benchmarks/safety_monte_carlo.py --results runs/near   # report only
    .venv/bin/python benchmarks/safety_monte_carlo.py --distribution near-boundary \
        --pipeline pipelines/near_boundary_drives.toml --torque-limits 1000 \
        --saturated-runs --unfiltered-runs --out runs/near_drives  # the arm behind its drives

Distributions (each pipeline's declared [uncertainty]):

- project (pipelines/monte_carlo.toml): benchmarks/monte_carlo.py's samples (q(0) = 0.1 ± 0.5
  rad, q̇(0) = 10 ± 5 rad/s, payload 0-1 kg, the noise's seed).
- near-boundary (pipelines/near_boundary.toml, 2 s): per sample one joint i and side s
  (cycled): q_i(0) = s·(β_q − d), d ~ U(0, 2) rad, moving outward q̇_i(0) = s·v,
  v ~ U(0, β_v), the safe centres pinned at 0; the other joints as in `project` (their
  velocity drawn within the bound unless --other-joints project); payload and noise seed as
  in `project`; x̂2(0) = q̇(0) + U(−e, e) per joint, e the declared initial observer error
  (0.5 rad/s; --observer-error). With --reference outward (default) joint i's reference is
  the issue's reproducer's, s·30 sin(ω_i t + 0.775) rad: it starts 1 rad past the bound,
  moving outward; the other joint's is the paper's.
- outside (pipelines/monte_carlo.toml, 5 s): `project` with one declared range exceeded per
  sample by up to 10 % (cycled): the payload (1.0-1.1 kg), the initial observer error (one
  joint's q̇(0) = 10 ± (5-5.5) rad/s) or the noise (σ = bound × U(1, 1.1) / 4: the largest
  draw of a run, ~4σ, about at or up to 10 % past the bound).

Every filtered run (--runs) runs at every --torque-limits value (N·m: a number, a per-joint
TOML list "[1000,500]", or none); the unfiltered runs (--unfiltered-runs) once per sample.
Each row keeps its sample's drawn values (sample.joint, sample.side, sample.d, sample.v,
sample.kind, sample.torque_limit). SI units, radians.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from monte_carlo import SAMPLES as PROJECT_SAMPLES

from cosim.config import load_pipeline
from cosim.evaluate.reports import wilson
from cosim.sweep import SweepError, SweepSpec, cluster_client, execute, parse_sample
from cosim.sweep.checks import family_kept, table_checks

PIPELINES = {"project": "pipelines/monte_carlo.toml",
             "near-boundary": "pipelines/near_boundary.toml",
             "outside": "pipelines/monte_carlo.toml"}
FILTERED = ("proposed_cbf", "baseline_cbf")
UNFILTERED = ("baseline", "proposed")
# the unfiltered controllers clipped at the limit (monte_carlo.toml): the actuator's share
SATURATED = ("proposed_saturated", "baseline_saturated")
NOMINAL_TIP_MASS = 2.3  # kg, m[2] of the paper's arm (monte_carlo.toml's payload adds to it)
DESIRED_START_VELOCITY = 10.0  # rad/s, q̇_d(0) of the paper's reference: x̂2(0) in `project`
OUTWARD_AMPLITUDE = 30.0  # rad, the reproducer's reference amplitude
OUTWARD_PHASE = 0.775  # rad, the reproducer's: 30 sin(0.775) = 21 rad, 1 rad past the bound
DEFAULT_DURATION = {"project": 20.0, "near-boundary": 2.0, "outside": 5.0}  # s per run
TRACKING = ("error", "error_rate", "error_rate_true")  # check families, every joint


@dataclass
class Sample:
    """One start and plant: the --set values of its point and what was drawn (for the
    report: which joint and side, d, v, which range was exceeded)."""

    point: dict
    drawn: dict = field(default_factory=dict)


@dataclass
class Bounds:
    """The declared quantities the distributions are drawn against (monte_carlo.toml)."""

    position: float  # β_q, rad
    velocity: float  # β_v, rad/s
    payload: tuple[float, float]  # kg
    noise_bound: float  # rad
    initial_velocity_error: float  # rad/s
    reference_amplitude: list[list[float]]  # the paper's, rad

    @property
    def links(self) -> int:
        return len(self.reference_amplitude)


def read_bounds(pipeline: str) -> Bounds:
    loaded = load_pipeline(pipeline, [], warn=None)
    u = loaded.uncertainty
    return Bounds(loaded.safety.position_bound, loaded.safety.velocity_bound,
                  tuple(u.payload), u.noise_bound, u.initial_velocity_error,
                  [list(row) for row in loaded.reference.amplitude])


def project_point(rng: np.random.Generator) -> dict:
    """A draw of benchmarks/monte_carlo.py's SAMPLES (the project's distribution)."""
    point = {}
    for item in PROJECT_SAMPLES:
        axis = parse_sample(item)
        kind, a, b = axis.distribution
        point[axis.key] = (float(rng.uniform(a, b)) if kind == "uniform"
                           else int(rng.integers(int(a), int(b) + 1)))
    return point


def q0(joint: int) -> str:
    return f'plant.parameters."q0[{joint}]"'


def qdot0(joint: int) -> str:
    return f'plant.parameters."qdot0[{joint}]"'


def project_samples(count: int, rng: np.random.Generator, bounds: Bounds,
                    args: argparse.Namespace) -> list[Sample]:
    return [Sample(project_point(rng), {"kind": "project"}) for _ in range(count)]


def near_boundary_sample(index: int, rng: np.random.Generator, bounds: Bounds,
                         args: argparse.Namespace) -> Sample:
    """Joint i, side s cycled with the index; d, v, the rest drawn (module docstring)."""
    n = bounds.links
    joint, side = index // 2 % n + 1, (1, -1)[index % 2]
    d, v = float(rng.uniform(0.0, 2.0)), float(rng.uniform(0.0, bounds.velocity))
    point = project_point(rng)
    if args.other_joints == "inside":  # the project's velocity range, within the box
        for j in range(1, n + 1):
            point[qdot0(j)] = float(rng.uniform(5.0, min(15.0, bounds.velocity)))
    point[q0(joint)] = side * (bounds.position - d)
    point[qdot0(joint)] = side * v
    bound = observer_error(args, bounds)
    error = rng.uniform(-bound, bound, n)
    point["observer.initial_velocity"] = [point[qdot0(j + 1)] + float(error[j])
                                          for j in range(n)]
    if args.reference == "outward":
        amplitude = [list(row) for row in bounds.reference_amplitude]
        phase = [[0.0] * len(row) for row in amplitude]
        amplitude[joint - 1] = [side * OUTWARD_AMPLITUDE]
        phase[joint - 1] = [OUTWARD_PHASE]
        point["reference.amplitude"], point["reference.phase"] = amplitude, phase
    drawn = {"kind": "near-boundary", "joint": joint, "side": side, "d": d, "v": v,
             "observer_error": float(np.max(np.abs(error)))}
    return Sample(point, drawn)


def near_boundary_samples(count: int, rng: np.random.Generator, bounds: Bounds,
                          args: argparse.Namespace) -> list[Sample]:
    return [near_boundary_sample(i, rng, bounds, args) for i in range(count)]


def outside_sample(index: int, rng: np.random.Generator, bounds: Bounds,
                   args: argparse.Namespace) -> Sample:
    """The project's distribution with one declared range exceeded by up to 10 %."""
    point = project_point(rng)
    kind = args.exceed[index % len(args.exceed)]
    low, high = bounds.payload
    width = high - low
    if kind == "payload":
        payload = float(rng.uniform(high, high + 0.1 * width))
        point['plant.parameters."m[2]"'] = NOMINAL_TIP_MASS + payload
        drawn = {"payload": payload}
    elif kind == "initial_velocity":
        joint, sign = int(rng.integers(1, bounds.links + 1)), float(rng.choice([-1.0, 1.0]))
        excess = float(rng.uniform(1.0, 1.1)) * bounds.initial_velocity_error
        point[qdot0(joint)] = DESIRED_START_VELOCITY + sign * excess
        drawn = {"joint": joint, "initial_velocity_error": excess}
    else:
        point["sensor.noise_std"] = bounds.noise_bound * float(rng.uniform(1.0, 1.1)) / 4.0
        drawn = {"noise_std": point["sensor.noise_std"]}
    return Sample(point, {"kind": f"outside: {kind}", **drawn})


def outside_samples(count: int, rng: np.random.Generator, bounds: Bounds,
                    args: argparse.Namespace) -> list[Sample]:
    return [outside_sample(i, rng, bounds, args) for i in range(count)]


DISTRIBUTIONS: dict[str, Callable[..., list[Sample]]] = {
    "project": project_samples, "near-boundary": near_boundary_samples,
    "outside": outside_samples}


def observer_error(args: argparse.Namespace, bounds: Bounds) -> float:
    """The near-boundary starts' bound on |q̇(0) − x̂2(0)|, rad/s: --observer-error, else the
    pipeline's declared one."""
    return bounds.initial_velocity_error if args.observer_error is None else args.observer_error


def base_sets(args: argparse.Namespace) -> list[str]:
    """The --set assignments of every point of the distribution (near_boundary.toml pins
    the safe centres and declares the observer's initial error itself)."""
    sets = [f"simulation.duration={args.duration}"]
    if args.distribution == "near-boundary" and args.observer_error is not None:
        sets.append(f"uncertainty.initial_velocity_error={args.observer_error}")
    return sets + list(args.set)


def parse_limit(text: str) -> float | list[float] | None:
    """A --torque-limits value: a number, a per-joint TOML list, or none."""
    if text.strip().lower() in ("none", "inf"):
        return None
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        raise SystemExit(f"--torque-limits {text!r}: expected a number (N·m), a per-joint "
                         "list like [1000,500], or none") from None


def limit_label(limit: float | list[float] | None) -> str:
    return "none" if limit is None else json.dumps(limit, separators=(",", ":"))


@dataclass
class Job:
    """One call of cosim.sweep's execute: its runs, points and each point's drawn values."""

    runs: list[str]
    points: list[dict]
    drawn: list[dict]


def jobs_of(samples: list[Sample], args: argparse.Namespace) -> list[Job]:
    """The unfiltered runs once per sample; the filtered ones at every torque limit."""
    jobs = []
    if args.unfiltered_runs:
        jobs.append(Job(list(args.unfiltered_runs), [s.point for s in samples],
                        [{**s.drawn, "index": i, "torque_limit": "none"}
                         for i, s in enumerate(samples)]))
    if args.runs and not args.unfiltered_only:
        points, drawn = [], []
        for limit in (parse_limit(text) for text in args.torque_limits):
            for i, s in enumerate(samples):
                points.append(s.point if limit is None
                              else {**s.point, "cbf_filter.torque_limit": limit})
                drawn.append({**s.drawn, "index": i, "torque_limit": limit_label(limit)})
        jobs.append(Job([*args.runs, *args.saturated_runs], points, drawn))
    return jobs


def check_job(pipeline: str, job: Job, base: list[str]) -> None:
    """Refuse before any work, as `cosim sweep` does, a point that does not load (a key, a
    value): the first points, and the first of every torque limit and kind of sample (the
    first one assembled too). :class:`SweepError` names the point."""
    from cosim.sweep.spec import validate

    firsts: dict[tuple, int] = {}
    for index, drawn in enumerate(job.drawn):
        firsts.setdefault((drawn.get("torque_limit"), drawn.get("kind")), index)
    chosen = sorted({*range(min(4, len(job.points))), *firsts.values()})
    validate(SweepSpec(pipeline, runs=job.runs, base=base), [job.points[i] for i in chosen])


def run_jobs(pipeline: str, jobs: list[Job], base: list[str], workers: int
             ) -> tuple[list[dict], list[dict]]:
    """Every job on one local Dask cluster: (rows, timings). A row gains its sample's drawn
    values as ``sample.*``. Ctrl-C keeps the finished rows (a timing says interrupted)."""
    for job in jobs:
        check_job(pipeline, job, base)
    rows: list[dict] = []
    timings: list[dict] = []
    client, cluster = cluster_client(workers, None)
    try:
        for job in jobs:
            spec = SweepSpec(pipeline, runs=job.runs, base=base)
            start = time.perf_counter()
            found, interrupted = execute(spec, job.points, client)
            seconds = time.perf_counter() - start
            for row in found:
                row.update({f"sample.{k}": v for k, v in job.drawn[row["point"]].items()})
            rows += found
            timings.append({"runs": job.runs, "points": len(job.points), "rows": len(found),
                            "seconds": seconds, "workers": workers,
                            "s_per_point": seconds / max(1, len(job.points)),
                            "interrupted": interrupted})
            print(f"{', '.join(job.runs)}: {len(job.points)} point(s), {len(found)} row(s) in "
                  f"{seconds:.1f} s on {workers} worker(s): {timings[-1]['s_per_point']:.3f} "
                  "s per point", file=sys.stderr)
            if interrupted:
                break
    finally:
        client.close()
        cluster.close()
    return rows, timings


def write_outputs(out: Path, rows: list[dict], meta: dict) -> None:
    """results.parquet, results.csv (one row per sample, run and limit) and meta.json (the
    command's options, the --set of every point, the timings)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    out.mkdir(parents=True, exist_ok=True)
    columns = list(dict.fromkeys(k for r in rows for k in r))
    table = pa.table({c: _column([_cell(r.get(c)) for r in rows]) for c in columns})
    pq.write_table(table, out / "results.parquet")
    pacsv.write_csv(table, out / "results.csv")
    (out / "meta.json").write_text(json.dumps(meta, indent=2, default=str) + "\n")


def _column(values: list) -> list:
    """A column Arrow can store: values of mixed kinds (a limit given as a number in some
    rows and as a per-joint list in others) as text."""
    kinds = {bool if isinstance(v, bool) else float if isinstance(v, int | float) else type(v)
             for v in values if v is not None}
    if len(kinds) <= 1:
        return values
    return [None if v is None else json.dumps(v) if not isinstance(v, str) else v
            for v in values]


def _cell(value: object) -> object:
    """A value Arrow can store in a column of mixed rows (lists and dicts as JSON)."""
    if isinstance(value, list | dict):
        return json.dumps(value)
    if isinstance(value, np.generic):
        return value.item()
    return value


# The report. Keys the classifier may or may not publish yet are looked up, never assumed:
# a missing one prints "-".

def share(kept: int, total: int) -> str:
    """k/n, the share and its Wilson 95 % interval."""
    if not total:
        return f"{kept}/0: -"
    low, high = wilson(kept, total)
    return f"{kept}/{total}: {100 * kept / total:.1f} % [{100 * low:.1f}, {100 * high:.1f}]"


def has(rows: list[dict], key: str) -> bool:
    return any(r.get(key) is not None for r in rows)


def viable_key(rows: list[dict]) -> str:
    """The classifier's viable-start flag when it publishes one, else "starts inside"."""
    return ("guarantee.starts_viable" if has(rows, "guarantee.starts_viable")
            else "guarantee.starts_inside")


def is_filtered(rows: list[dict]) -> bool:
    """Whether these are a filtered run's rows (the classifier's flag, else its
    feasibility, which only a filter has)."""
    if any("guarantee.filtered" in r for r in rows):
        return any(r.get("guarantee.filtered") is True for r in rows)
    return any(r.get("guarantee.feasible") is not None for r in rows)


def is_covered(row: dict) -> bool:
    if row.get("guarantee.covered") is not None:
        return bool(row["guarantee.covered"])
    return bool(row.get("guarantee.starts_inside") and row.get("guarantee.feasible")
                and row.get("guarantee.within_bounds"))


OBSERVER_STEPS = "guarantee.observer_bound_exceeded_steps"
OBSERVER_TEXT = r"above (?:its bound )?ε\(t\) at (\d+) steps"
NUMBER = r"-?\d+(\.\d+)?(e[-+]?\d+)?"  # a value in a reason, for grouping reasons


def observer_exceedances(row: dict) -> int | None:
    """Steps where |q̇ − x̂2| > ε(t). The classifier's count when it publishes one
    (guarantee.observer_bound_exceeded_steps: None where it does not judge the observer, a
    filter that reads the true velocity); else the count its text gives (a violation, or a
    reason for "outside"); None: not said, or said without a count."""
    if OBSERVER_STEPS in row:
        value = row[OBSERVER_STEPS]
        return None if value is None or value != value else int(value)
    texts = [row.get(key) for key in ("guarantee.violations", "guarantee.outside")]
    texts = [t for t in texts if isinstance(t, str)]
    for text in texts:
        match = re.search(OBSERVER_TEXT, text)
        if match:
            return int(match[1])
        if "ε(t)" in text:  # said, but not how often
            return None
    return 0 if texts else None


def limit_values(label: str, links: int) -> np.ndarray:
    """A row's torque limit per joint, N·m (inf: none)."""
    value = None if label in (None, "none") else json.loads(label)
    if value is None:
        return np.full(links, np.inf)
    return np.broadcast_to(np.asarray(value, float), (links,))


def peaks(rows: list[dict], links: int) -> np.ndarray:
    """Each row's peak |τ_j|, (rows, joints), N·m."""
    return np.array([[r.get(f"peak_torque.{j}") or math.nan for j in range(1, links + 1)]
                     for r in rows], float)


def links_of(rows: list[dict]) -> int:
    return max((int(k.split(".")[1]) for r in rows[:1] for k in r
                if k.startswith("peak_torque.")), default=2)


def declared_kept_but_observer(row: dict) -> bool:
    """Whether the run stayed within the declared ranges, the observer bound ε(t) apart (a
    run that exceeds ε(t) inside them is what the ε figure counts)."""
    text = row.get("guarantee.outside") or ""
    return not [reason for reason in text.split("; ") if reason
                and not reason.startswith("observer error above")]


def viability_lines(rows: list[dict], key: str, a_min: float | None) -> list[str]:
    """Starts inside the box but not viable (and why, when said), and the starts that
    v² ≤ 2·d·a̲ says must be viable."""
    box = [r for r in rows if r.get("guarantee.starts_inside") is True]
    if key == "guarantee.starts_inside":
        lines = ["  inside the box, not viable      - (no guarantee.starts_viable yet)"]
    else:
        apart = [r for r in box if r.get(key) is False]
        lines = [f"  inside the box, not viable      {share(len(apart), len(box))} of the box"]
        reasons: dict[str, int] = {}
        for r in apart:
            for k, v in r.items():
                if "viab" in k and isinstance(v, str) and v:
                    reasons[v.split(" (")[0]] = reasons.get(v.split(" (")[0], 0) + 1
        lines += [f"    {count} × {reason}" for reason, count in sorted(reasons.items())]
    drawn = [r for r in rows if r.get("sample.d") is not None]
    need = [r["sample.v"] ** 2 / (2 * r["sample.d"]) for r in drawn if r.get(key) is False]
    if need:  # the easiest start filed not viable: an a̲ above this fails the figure
        lines.append(f"  {'least v²/(2d), not viable':<32}{min(need):.3g} rad/s² (median "
                     f"{np.median(need):.3g}): a stated a̲ must stay below it")
    if drawn and a_min is not None:
        must = [r for r in drawn if r["sample.v"] ** 2 <= 2 * r["sample.d"] * a_min]
        wrong = [r for r in must if r.get(key) is False]
        # not viable only because the velocity the filter holds at t = 0 (x̂2 ± ε(0)) reaches
        # past a velocity bound: the declared initial observer error, not the braking
        blind = [r for r in wrong if "reaches past the velocity bound"
                 in (r.get("guarantee.not_viable") or "")]
        lines.append(f"  {'v² ≤ 2·d·a̲':<33}{len(must)} of {len(drawn)} starts (a̲ = {a_min:g} "
                     f"rad/s²); not viable among them: {len(wrong)} (must be 0), of which "
                     f"{len(blind)} for the velocity's interval at t = 0 alone")
    elif drawn:
        lines.append("  v² ≤ 2·d·a̲                      - (give --decel a̲, rad/s²)")
    return lines


def broken_why(row: dict) -> str:
    """What broke a run: the classifier's violations, else the hard set it left."""
    if isinstance(row.get("guarantee.violations"), str) and row["guarantee.violations"]:
        return row["guarantee.violations"]
    return (f"left {row.get('guarantee.first_exit.set')} at "
            f"{row.get('guarantee.first_exit.t') or math.nan:.3f} s "
            f"(|value| {row.get('guarantee.first_exit.value') or math.nan:.4f})")


def drawn_lines(rows: list[dict], key: str, shown: int = 8) -> list[str]:
    """Near-boundary: the hard sets kept among viable starts per joint and side, and the
    broken runs' starts (sample, joint, side, d, v, the set left)."""
    drawn = [r for r in rows if r.get("sample.d") is not None]
    if not drawn:
        return []
    cells = []
    for joint, side in sorted({(r["sample.joint"], r["sample.side"]) for r in drawn}):
        viable = [r for r in rows if r.get("sample.joint") == joint
                  and r.get("sample.side") == side and r.get(key) is True]
        kept = sum(bool(r.get("hard_sets_kept")) for r in viable)
        cells.append(f"joint {joint} {'+' if side > 0 else '−'}: {kept}/{len(viable)}")
    lines = ["  kept per joint and side         " + ", ".join(cells)]
    broken = [r for r in drawn if r.get("guarantee.broken")]
    lines += [f"    broken: sample {r['sample.index']}, joint {r['sample.joint']}, side "
              f"{r['sample.side']:+d}, d {r['sample.d']:.3f} rad, v {r['sample.v']:.2f} rad/s: "
              + broken_why(r) for r in broken[:shown]]
    if len(broken) > shown:
        lines.append(f"    … and {len(broken) - shown} more broken")
    return lines


def guarantee_lines(rows: list[dict], a_min: float | None) -> list[str]:
    """Hard sets kept among viable starts, the box, covered, broken, ε(t) exceeded."""
    key = viable_key(rows)
    viable = [r for r in rows if r.get(key) is True]
    kept = sum(bool(r.get("hard_sets_kept")) for r in viable)
    covered = sum(map(is_covered, viable))
    broken = (str(sum(bool(r.get("guarantee.broken")) for r in rows))
              if has(rows, "guarantee.broken") else "-")
    lines = [f"  hard sets kept, viable starts   {share(kept, len(viable))}  "
             f"(viable: {key})", *viability_lines(rows, key, a_min),
             f"  covered, of viable starts       {share(covered, len(viable))}",
             f"  broken                          {broken}", *drawn_lines(rows, key)]
    counts = [(observer_exceedances(r), declared_kept_but_observer(r)) for r in rows]
    known = [(c, inside) for c, inside in counts if c is not None]
    if known:
        inside = [c for c, kept_ranges in known if kept_ranges]
        lines.append(f"  ε(t) exceeded (steps)           {sum(inside)} in "
                     f"{sum(c > 0 for c in inside)} of {len(inside)} runs within the declared "
                     f"ranges; {sum(c for c, _ in known)} in all {len(known)}")
    else:
        lines.append("  ε(t) exceeded (steps)           -")
    return lines


def recovery_lines(rows: list[dict]) -> list[str]:
    """Runs that left a hard set: the share back within 1 s, the time to return."""
    left = [r for r in rows if r.get("hard_sets_kept") is False]
    if not left:
        return ["  left a hard set                 0"]
    back = [r.get("guarantee.back_within_1s") for r in left]
    known = [bool(b) for b in back if b is not None]
    times = [r["guarantee.time_to_return_s"] for r in left
             if isinstance(r.get("guarantee.time_to_return_s"), int | float)]
    time_text = (f"; time to return median {np.median(times):.3f} s, max {np.max(times):.3f} s"
                 if times else "")
    return [f"  left a hard set                 {len(left)}; back within 1 s "
            + (share(sum(known), len(known)) if known else "-") + time_text]


def torque_lines(rows: list[dict], compared: list[dict], compared_name: str) -> list[str]:
    """Peak |τ| against the limit (every joint), and the median peak τ1 against the
    unfiltered controller's."""
    links = links_of(rows)
    peak = peaks(rows, links)
    limits = np.array([limit_values(r.get("sample.torque_limit"), links) for r in rows])
    above = int(np.sum(np.any(peak > limits * (1 + 1e-9) + 1e-9, axis=1)))
    worst = ", ".join(f"{v:.0f}" for v in np.nanmax(peak, axis=0))
    limit_text = rows[0].get("sample.torque_limit") or "none"
    median = float(np.nanmedian(peak[:, 0]))
    lines = [f"  peak |τ| (max over runs)        [{worst}] N·m, limit {limit_text}: "
             f"{above} run(s) above it"]
    steps = [r["guarantee.torque_over_limit_steps"] for r in rows
             if isinstance(r.get("guarantee.torque_over_limit_steps"), int | float)]
    if steps:
        lines.append(f"  steps with |τ| above the limit  {int(np.nansum(steps))} (the "
                     "classifier's count, every step)")
    quartiles = np.nanpercentile(peak[:, 0], [0, 25, 75, 100])
    text = f"  median peak τ1                  {median:.0f} N·m"
    if compared:
        theirs = float(np.nanmedian(peaks(compared, links)[:, 0]))
        text += f" against {compared_name}'s {theirs:.0f} N·m: ratio {median / theirs:.2f}"
    lines += [text, f"  peak τ1 spread                  min {quartiles[0]:.0f}, quartiles "
                    f"{quartiles[1]:.0f}-{quartiles[2]:.0f}, max {quartiles[3]:.0f} N·m"]
    return lines + startup_lines(rows, compared, compared_name)


def startup_lines(rows: list[dict], compared: list[dict] = (),
                  compared_name: str = "") -> list[str]:
    """Where the peak τ1 comes from (the guarantee's ``torque`` metrics, rows of a cosim
    that records them): in how many runs it falls before the filter first found the state
    viable (start-up), the median peak τ1 from then on, and each run's start-up peak τ1
    against the same sample's peak τ1 in ``compared`` (the unfiltered run), their median."""
    timed = [r for r in rows if isinstance(r.get("guarantee.torque.peak_at_startup.1"), bool)]
    if not timed:
        return []
    at_startup = [r for r in timed if r["guarantee.torque.peak_at_startup.1"]]
    after = [r["guarantee.torque.peak_after_startup.1"] for r in timed
             if isinstance(r.get("guarantee.torque.peak_after_startup.1"), float)]
    backup = [r["guarantee.torque.peak_backup_share.1"] for r in at_startup
              if isinstance(r.get("guarantee.torque.peak_backup_share.1"), float)]
    theirs = {r.get("sample.index"): r.get("peak_torque.1") for r in compared}
    ratios = [r["guarantee.torque.peak_during_startup.1"] / theirs[r.get("sample.index")]
              for r in timed if isinstance(r.get("guarantee.torque.peak_during_startup.1"), float)
              and theirs.get(r.get("sample.index"))]
    lines = [f"  peak τ1 at start-up             {len(at_startup)} of {len(timed)} runs (before "
             "the first viable step)"
             + (f"; the backup's share of those peaks: median {np.median(backup):.2f}"
                if backup else ""),
             "  median peak τ1 after start-up   "
             + (f"{np.median(after):.0f} N·m ({len(after)} runs ever viable)" if after else "-")]
    if ratios:
        quartiles = np.percentile(ratios, [25, 75])
        lines.append(f"  start-up peak τ1 / {compared_name}'s peak τ1, per sample: median "
                     f"{np.median(ratios):.2f} (quartiles {quartiles[0]:.2f}-{quartiles[1]:.2f}, "
                     f"max {max(ratios):.2f}; {len(ratios)} runs with a start-up)")
    return lines


def kept_share(rows: list[dict], checks: list[str]) -> str:
    """The share of the rows that have ``checks`` keeping every one ("-": none has them,
    e.g. the true error rate of a full-state run)."""
    judged = [r for r in rows if any(r.get(f"{c}.satisfied") is not None for c in checks)]
    return share(sum(family_kept(r, checks) for r in judged), len(judged)) if judged else "-"


def tracking_lines(rows: list[dict], comparisons: list[tuple[str, list[dict]]]) -> list[str]:
    """The tracking sets kept, every joint, against each (name, rows) compared: the
    unfiltered controller's, and the same controller clipped at the run's limit (Wilson)."""
    comparisons = [(name, theirs) for name, theirs in comparisons if theirs]
    families = dict(table_checks(rows + [r for _, theirs in comparisons for r in theirs]))
    lines = []
    for family in TRACKING:
        if family not in families:
            continue
        checks = families[family]
        lines.append(f"  {family + ' kept':<32}{kept_share(rows, checks)}" + "".join(
            f"  ({name}: {kept_share(theirs, checks)})" for name, theirs in comparisons))

    def rms(of: list[dict]) -> list[float]:
        return [r["rms_error.1"] for r in of if r.get("rms_error.1") is not None]

    if rms(rows):
        lines.append(f"  RMS |e1| (mean over runs)       {np.mean(rms(rows)):.4f} rad" + "".join(
            f" ({name}: {np.mean(rms(theirs)):.4f} rad)" for name, theirs in comparisons
            if rms(theirs)))
    return lines


def kind_lines(rows: list[dict]) -> list[str]:
    """Per kind of sample (which declared range it exceeds, say): how many runs the
    classifier files outside the declared ranges, and why."""
    kinds = sorted({r.get("sample.kind") for r in rows} - {None})
    if len(kinds) < 2 and not any(k.startswith("outside") for k in kinds):
        return []
    lines = []
    for kind in kinds:
        mine = [r for r in rows if r.get("sample.kind") == kind]
        outside = [r for r in mine if r.get("guarantee.within_bounds") is False]
        reasons: dict[str, int] = {}
        for r in outside:
            for reason in filter(None, (r.get("guarantee.outside") or "").split("; ")):
                short = re.sub(NUMBER, "#", reason.split(" (")[0])
                reasons[short] = reasons.get(short, 0) + 1
        why = ", ".join(f"{n} × {text}" for text, n in sorted(reasons.items()))
        lines.append(f"  {kind + ':':<32}{len(outside)} of {len(mine)} filed outside the "
                     f"declared ranges" + (f" ({why})" if why else ""))
    return lines


def coverage_lines(ok: list[dict], rows: list[dict], limit: str) -> list[str]:
    """An output-feedback filtered run (covered from its first viable step, not from t = 0
    alone): how many are covered, from when; and, where baseline_cbf ran on the same
    samples at this limit, the starts truly inside (its filter, which reads the true
    state, finds the start viable at t = 0) and how many of those are covered."""
    later = [r for r in ok if r.get("guarantee.covered") is True
             and r.get("guarantee.starts_viable") is False]
    if not later:
        return []
    covered = [r for r in ok if r.get("guarantee.covered") is True]
    start = np.array([r["guarantee.covered_from_s"] for r in covered
                      if isinstance(r.get("guarantee.covered_from_s"), float)]) * 1e3
    lines = [f"  covered (from a later step)     {share(len(covered), len(ok))}, "
             f"{len(later)} of them not viable at t = 0; covered from median "
             f"{np.median(start):.1f} ms, max {np.max(start):.1f} ms"]
    full = {r["point"]: r for r in rows if r["run"] == "baseline_cbf" and r["status"] == "ok"
            and (r.get("sample.torque_limit") or "none") == limit}
    inside = [r for r in ok if full.get(r["point"], {}).get("guarantee.starts_viable") is True]
    if full and inside:
        mine = [r for r in inside if r.get("guarantee.covered") is True]
        start = np.array([r["guarantee.covered_from_s"] for r in mine
                          if isinstance(r.get("guarantee.covered_from_s"), float)]) * 1e3
        since = f"; covered from median {np.median(start):.1f} ms" if len(start) else ""
        lines.append(f"  covered, truly inside starts    {share(len(mine), len(inside))} "
                     "(truly inside: baseline_cbf's check, on the true state, viable at "
                     f"t = 0){since}")
        kept = sum(bool(r.get("hard_sets_kept")) for r in inside)
        lines.append(f"  hard sets kept, truly inside    {share(kept, len(inside))}")
    return lines


def counterpart(run: str) -> str:
    """The unfiltered run a filtered one is compared with: proposed_cbf -> proposed."""
    return run.removesuffix("_cbf")


def percent_low(kept: int, total: int) -> str:
    """"k/n p % (≥ Wilson lower bound)", compact for the summary."""
    if not total:
        return "-"
    return f"{kept}/{total} {100 * kept / total:.1f}% (≥{100 * wilson(kept, total)[0]:.1f})"


def summary_cells(ok: list[dict], compared: list[dict]) -> list[str]:
    """A filtered run's figures at one limit, one cell each (see SUMMARY_COLUMNS)."""
    key = viable_key(ok)
    viable = [r for r in ok if r.get(key) is True]
    box = [r for r in ok if r.get("guarantee.starts_inside") is True]
    apart = (str(sum(r.get(key) is False for r in box))
             if key != "guarantee.starts_inside" else "-")
    links = links_of(ok)
    limits = np.array([limit_values(r.get("sample.torque_limit"), links) for r in ok])
    above = int(np.sum(np.any(peaks(ok, links) > limits * (1 + 1e-9) + 1e-9, axis=1)))
    inside = [c for r in ok if (c := observer_exceedances(r)) is not None
              and declared_kept_but_observer(r)]
    median_peak = [float(np.nanmedian(peaks(group, links)[:, 0])) for group in (ok, compared)
                   if group]
    ratio = f"{median_peak[0] / median_peak[1]:.2f}" if compared else "-"
    left = [r.get("guarantee.back_within_1s") for r in ok if r.get("hard_sets_kept") is False]
    known = [bool(b) for b in left if b is not None]
    return [percent_low(sum(bool(r.get("hard_sets_kept")) for r in viable), len(viable)),
            apart, percent_low(sum(map(is_covered, viable)), len(viable)),
            str(sum(bool(r.get("guarantee.broken")) for r in ok)),
            str(sum(inside)) if inside else "-", str(above), ratio,
            f"{sum(known)}/{len(known)}" if known else f"-/{len(left)}", tube_cell(ok),
            tube_cell(ok, "plan_tube")]


def tube_cell(ok: list[dict], tube: str = "tube") -> str:
    """How many covered runs left the check's tube by more than the room it leaves to the
    bounds (the guarantee's ``tube_exceeded_steps``, measured from the step a run is
    covered from; ``tube`` "plan_tube": on the rows where the filter followed the plan in
    force), and the largest velocity excess past that room, rad/s."""
    judged = [r for r in ok if r.get("guarantee.covered") is True
              and isinstance(r.get(f"guarantee.{tube}_exceeded_steps"), int | float)
              and not math.isnan(r[f"guarantee.{tube}_exceeded_steps"])]
    if not judged:
        return "-"
    left = [r for r in judged if r[f"guarantee.{tube}_exceeded_steps"] > 0]
    slack = [r.get(f"guarantee.{tube}_slack.velocity") for r in left]
    worst = max((-x for x in slack if isinstance(x, float) and math.isfinite(x)), default=0.0)
    return f"{len(left)}/{len(judged)}" + (f" {worst:.3g}" if left and worst > 0 else "")


SUMMARY_COLUMNS = (("run", 14), ("limit", 11), ("kept, viable", 24), ("¬viable", 8),
                   ("covered, viable", 24), ("broken", 7), ("ε steps", 8), ("τ>lim", 6),
                   ("τ1 ratio", 9), ("back≤1s", 9), ("tube left", 14), ("plan tube", 12))


def summary(groups: dict[tuple[str, str], list[dict]], rows: list[dict]) -> list[str]:
    """One line per filtered run and limit: the issue's figures side by side."""
    lines = ["", "summary of the filtered runs: kept = every joint's hard sets (true state);",
             "≥ = Wilson 95 % lower bound; ε steps = within the declared ranges; τ1 ratio =",
             "median peak τ1 against the unfiltered run's; back≤1s = of the runs that left",
             "a set, back within 1 s; tube left = covered runs past the check's tube by",
             "more than its room (of those covered), and the largest velocity excess, rad/s;",
             "plan tube = the same on the rows where the filter followed the plan in force",
             "".join(f"{name:<{width}}" for name, width in SUMMARY_COLUMNS)]
    for (run, limit), group in groups.items():
        ok = [r for r in group if r["status"] == "ok"]
        if not is_filtered(ok):
            continue
        compared = [r for r in rows if r["run"] == counterpart(run) and r["status"] == "ok"]
        cells = [run, limit, *summary_cells(ok, compared if counterpart(run) != run else [])]
        lines.append("".join(f"{c:<{w}}" for c, (_, w) in zip(cells, SUMMARY_COLUMNS,
                                                               strict=True)))
    return lines


def reproducer(row: dict, meta: dict) -> str:
    """The `cosim run` command that runs a row's sample and run again (its recording, its
    verdict)."""
    import shlex

    sets = [*meta.get("base_sets", []),
            *(f"{k.removeprefix('set:')}={v}" for k, v in row.items()
              if k.startswith("set:") and v is not None)]
    return shlex.join(["cosim", "run", meta["pipeline"], "--run", row["run"],
                       *(word for s in sets for word in ("--set", s))])


def report(rows: list[dict], a_min: float | None, meta: dict | None = None) -> str:
    """One block per run and torque limit (module docstring)."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["run"], r.get("sample.torque_limit") or "none"), []).append(r)
    lines = []
    for (run, limit), group in groups.items():
        ok = [r for r in group if r["status"] == "ok"]
        lines.append(f"{run}, torque limit {limit}{' N·m' * (limit != 'none')}: "
                     f"{len(group)} run(s), "
                     f"{len(group) - len(ok)} failed")
        if not ok:
            continue
        other = counterpart(run)
        compared = ([r for r in rows if r["run"] == other and r["status"] == "ok"]
                    if other != run else [])
        if is_filtered(ok):
            lines += guarantee_lines(ok, a_min)
            lines += coverage_lines(ok, rows, limit)
            lines += kind_lines(ok)
        else:
            inside = [r for r in ok if r.get("guarantee.starts_inside") is True]
            lines.append("  hard sets kept, starts inside   "
                         + share(sum(bool(r.get("hard_sets_kept")) for r in inside),
                                 len(inside)))
        lines += recovery_lines(ok)
        lines += torque_lines(ok, compared, other)
        saturated = run.removesuffix("_cbf") + "_saturated"
        clipped = [r for r in rows if r["run"] == saturated and r["status"] == "ok"
                   and (r.get("sample.torque_limit") or "none") == limit]
        lines += tracking_lines(ok, [(other, compared), (f"{saturated}, same limit", clipped)])
    broken = [r for r in rows if r.get("guarantee.broken")]
    if broken and meta:
        lines += ["", f"the first broken run again ({broken[0]['run']}, sample "
                  f"{broken[0].get('sample.index')}):", "  " + reproducer(broken[0], meta)]
    return "\n".join(lines + summary(groups, rows))


def timing_text(meta: dict) -> str:
    return "\n".join(f"timing: {', '.join(t['runs'])}: {t['points']} point(s) in "
                     f"{t['seconds']:.1f} s on {t['workers']} worker(s), "
                     f"{t['s_per_point']:.3f} s per point"
                     + (" (interrupted)" if t.get("interrupted") else "")
                     for t in meta.get("timings", []))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    parser.add_argument("--distribution", choices=list(DISTRIBUTIONS), default="near-boundary")
    parser.add_argument("--samples", type=int, default=500, help="starts drawn")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--workers", type=int, default=2, help="local Dask worker processes")
    parser.add_argument("--duration", type=float,
                        help="s per run (default: project 20, near-boundary 2, outside 5)")
    parser.add_argument("--torque-limits", nargs="+", default=["1000", "2000"],
                        help="cbf_filter.torque_limit values, N·m: a number, a per-joint "
                        "list [1000,500], or none (default: 1000 2000)")
    parser.add_argument("--runs", nargs="*", default=list(FILTERED),
                        help="filtered runs, at every limit")
    parser.add_argument("--saturated-runs", nargs="*", default=list(SATURATED),
                        help="the unfiltered controllers clipped at every limit, for "
                        "tracking (none: give the option alone)")
    parser.add_argument("--unfiltered-runs", nargs="*", default=list(UNFILTERED),
                        help="unfiltered runs, once per sample (none: give the option alone)")
    parser.add_argument("--unfiltered-only", action="store_true",
                        help="only the unfiltered runs: their peak |τ1| sets the limits")
    parser.add_argument("--observer-error", type=float,
                        help="near-boundary: the |q̇(0) − x̂2(0)| bound, rad/s, drawn within and "
                        "declared (default: near_boundary.toml's, 0.5)")
    parser.add_argument("--reference", choices=("outward", "paper"), default="outward",
                        help="near-boundary: the sampled joint's reference")
    parser.add_argument("--other-joints", choices=("inside", "project"), default="inside",
                        help="near-boundary: the other joints' q̇(0) from the project's "
                        "range within the velocity bound (inside), or all of it")
    parser.add_argument("--exceed", nargs="+", default=["payload", "initial_velocity", "noise"],
                        choices=("payload", "initial_velocity", "noise"),
                        help="outside: the declared ranges exceeded, one per sample, cycled")
    parser.add_argument("--decel", type=float,
                        help="a̲, rad/s²: the worst-case deceleration the limits give under the "
                        "declared uncertainty; starts with v² ≤ 2·d·a̲ must be viable")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a pipeline value for every run, as `cosim run --set` (repeat)")
    parser.add_argument("--pipeline", default=None,
                        help="the pipeline the distribution's samples run on, one with its "
                        "declared uncertainty (default: the distribution's own, above; "
                        "pipelines/near_boundary_drives.toml: the arm behind its drives)")
    parser.add_argument("--out", type=Path, default=Path("runs/safety_mc"))
    parser.add_argument("--force", action="store_true", help="write into a non-empty --out")
    parser.add_argument("--results", type=Path, help="an existing output folder: report only")
    args = parser.parse_args(argv)
    if args.duration is None:
        args.duration = DEFAULT_DURATION[args.distribution]
    return args


def main(argv: list[str] | None = None) -> int:
    import pyarrow.parquet as pq

    args = parse_args(argv)
    folder = args.results
    if folder is None:
        if args.out.exists() and any(args.out.iterdir()) and not args.force:
            print(f"{args.out} holds files: give another --out, or --force", file=sys.stderr)
            return 2
        pipeline = args.pipeline or PIPELINES[args.distribution]
        bounds = read_bounds(pipeline)
        rng = np.random.default_rng(args.seed)
        samples = DISTRIBUTIONS[args.distribution](args.samples, rng, bounds, args)
        base = base_sets(args)
        try:
            rows, timings = run_jobs(pipeline, jobs_of(samples, args), base, args.workers)
        except SweepError as exc:
            print(f"safety_monte_carlo: {exc}", file=sys.stderr)
            return 2
        meta = {"pipeline": pipeline, "options": vars(args), "base_sets": base,
                "timings": timings, "command": " ".join(sys.argv)}
        write_outputs(args.out, rows, meta)
        folder = args.out
    rows = pq.read_table(folder / "results.parquet").to_pylist()
    meta = json.loads((folder / "meta.json").read_text())
    print(f"{meta['options']['distribution']} distribution, {meta['options']['samples']} "
          f"sample(s), {meta['options']['duration']:g} s per run ({folder})")
    a_min = args.decel if args.decel is not None else meta["options"].get("decel")
    print(report(rows, a_min, meta))
    print(timing_text(meta))
    return 0


if __name__ == "__main__":
    sys.exit(main())
