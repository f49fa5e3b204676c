"""What the safety filter's check costs, and how long its rollout is, with its steps grown
(``backup_step_max``, the default) and with steps of ``backup_step`` alone, in one run.

Runs one filtered run of a pipeline, then, over every row of it, the check
(:func:`cosim.paper.cbf_filter.check.verified`) of the torque the run applied from the
row's estimate (its position, its velocity interval), in one compiled loop: µs per check,
and the rollout's steps per check (median, mean, 99th percentile).

    .venv/bin/python benchmarks/check_rollout.py [--pipeline pipelines/paper_safety.toml]
        [--run proposed_cbf] [--duration S] [--repeat 3]

With ``--premise``, also the premise of a free step's widening on sampled states of the
pipeline's arm (:func:`deviation_along_steps`): D at every hold inside each step against the
D its widening took (the larger of its ends'), and against its start's alone.

The last line is ``grown_us=X alone_us=Y steps_grown=M steps_alone=N`` (medians).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from cosim.assemble import assemble
from cosim.config import load_pipeline
from cosim.engine import simulate
from cosim.numba_compat import no_refcount_jit
from cosim.paper.cbf_filter.backup import nominal_acceleration
from cosim.paper.cbf_filter.check import verified, verified_from
from cosim.paper.cbf_filter.deviation import deviation_bound
from cosim.paper.cbf_filter.holds import TUBE_SAFETY, held_travel
from cosim.paper.cbf_filter.scratch import Flag, Rollout, Tube

ROOT = Path(__file__).resolve().parent.parent


@no_refcount_jit()
def checks(a, steps: int, lengths_out) -> float:
    """The check of row k's applied torque from row k's estimate, for every row; the
    rollout's steps of each into ``lengths_out`` (0 where not verified)."""
    r = a.work.rollout
    verified_rows = 0.0
    for k in range(steps):
        for i in range(r.shape[1]):
            r[Rollout.CENTRE, i] = a.velocity_centre[k, i]
            r[Rollout.HALF, i] = a.velocity_spread[k, i]
        ok = verified(k, a, a.position[k], r[Rollout.CENTRE], r[Rollout.HALF], a.tau[k],
                      True, 0, a.torque_limit)
        count = 0
        if ok:
            verified_rows += 1.0
            lengths = a.work.tube_steps[int(a.work.flags[Flag.PLAN_TUBE])]
            while count < lengths.shape[0] and lengths[count] > 0.0:
                count += 1
        lengths_out[k] = count
    return verified_rows


def timed(a, steps: int, repeat: int) -> tuple[float, np.ndarray, float]:
    """(µs per check, best of ``repeat``; the rollout's steps per row; rows verified)."""
    lengths = np.zeros(steps)
    checks(a, 2, lengths)  # compile outside the timing
    best = np.inf
    for _ in range(repeat):
        began = time.perf_counter()
        verified_rows = checks(a, steps, lengths)
        best = min(best, time.perf_counter() - began)
    return 1e6 * best / steps, lengths[lengths > 0], verified_rows


def planned(a, q: np.ndarray, v: np.ndarray, eps: float) -> list[tuple[np.ndarray, float]]:
    """The tube of the rollout the check verifies from (q, v ± eps), (segment, length) each;
    empty where it verifies none."""
    if not verified_from(a, q, v, np.full(len(q), eps), 0):
        return []
    buffer = int(a.work.flags[Flag.PLAN_TUBE])
    segments = []
    for segment, h in zip(a.work.tube[buffer], a.work.tube_steps[buffer], strict=True):
        if h <= 0.0:
            break
        segments.append((segment.copy(), float(h)))
    return segments


def deviation_along_steps(a, samples: int, seed: int,
                          grown: bool = True) -> tuple[int, float, float]:
    """On ``samples`` states drawn within 0.8 of each position bound and 0.6 of each velocity
    bound (ε one of 0, 0.02, 0.1, 0.5 rad/s), of every verified rollout's free steps of
    several holds, longer than ``backup_step`` (``grown``) or of it: (the steps; the
    largest ratio of D inside a step, each hold's q̈ at the nominal velocity at its start
    and at its end, the step's configuration, to the D the step's widening took,
    WIDEN / TUBE_SAFETY; and the largest to D at the step's start alone)."""
    n = a.viable_bounds.shape[1]
    rng = np.random.default_rng(seed)
    c = min(a.backup_rate * a.dt, 1.0)
    deviation, steps = np.zeros(n), 0
    worst = {"widening": 0.0, "start": 0.0}
    for _ in range(samples):
        q = a.centres[0] + rng.uniform(-0.8, 0.8, n) * a.viable_bounds[0]
        v = a.centres[1] + rng.uniform(-0.6, 0.6, n) * a.viable_bounds[1]
        eps = float(rng.choice([0.0, 0.02, 0.1, 0.5]))
        for segment, h in planned(a, q, v, eps):
            longer = h > a.backup_step * (1.0 + 1e-9)
            if longer != grown or h <= a.dt * (1.0 + 1e-9):
                continue
            steps += 1
            rollout = a.work.rollout
            rollout[Rollout.Q], rollout[Rollout.V] = segment[Tube.Q], segment[Tube.V]
            # the model at the step's start, as the check took it there
            nominal_acceleration(0, a, np.zeros(n), True, 0, a.torque_limit)
            covered = {"widening": np.maximum(segment[Tube.WIDEN] / TUBE_SAFETY, 1e-300)}
            # hold j's q̈ at its start's velocity and at its end's (the states inside it)
            for j in range(int(round(h / a.dt))):
                for at in (j, j + 1):
                    velocity = segment[Tube.V] \
                        + segment[Tube.ACC_FIRST] * held_travel(a, h, at * a.dt)
                    deviation_bound(a, velocity, np.full(n, eps),
                                    segment[Tube.ACC_FIRST] * (1.0 - c) ** j, deviation, False)
                    if at == 0:
                        covered["start"] = np.maximum(deviation.copy(), 1e-300)
                    for name, taken in covered.items():
                        worst[name] = max(worst[name], float(np.max(deviation / taken)))
    return steps, worst["widening"], worst["start"]


def filter_args(path: str, run: str, sets: list[str]):
    """(the filter's arguments after ``run`` of the pipeline at ``path``, its rows, its
    name)."""
    pipeline = load_pipeline(path, sets)
    pipeline.runs = {run: pipeline.runs[run]}
    scenario = assemble(pipeline)
    try:
        plan = scenario.runs[run]
        simulate(scenario.plant, plan, plan.new_trace(scenario.steps))
    finally:
        scenario.close()
    return plan.block("cbf_filter").args, scenario.steps, pipeline.name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pipeline", default=str(ROOT / "pipelines" / "paper_safety.toml"))
    parser.add_argument("--run", default="proposed_cbf", help="a filtered run of it")
    parser.add_argument("--duration", type=float, help="simulated seconds (default: its own)")
    parser.add_argument("--repeat", type=int, default=3, help="repetitions (best is kept)")
    parser.add_argument("--premise", type=int, metavar="SAMPLES", default=0,
                        help="also D along the steps on this many sampled states")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a pipeline override, as cosim run's (repeatable)")
    args = parser.parse_args()
    sets = list(args.set)
    if args.duration is not None:
        sets.append(f"simulation.duration={args.duration}")
    grown, steps, name = filter_args(args.pipeline, args.run, sets)
    # steps of backup_step alone: the same run with no step longer (not the record changed
    # by _replace: a type of its own to numba, whose loop measured 4x slower here)
    alone = filter_args(args.pipeline, args.run,
                        [*sets, f"cbf_filter.backup_step_max={grown.backup_step}"])[0]
    print(f"{name}: {args.run}, {steps} rows, the check of each row's torque "
          f"(best of {args.repeat}):")
    figures = {}
    for variant, a in (("grown", grown), ("alone", alone)):
        us, lengths, verified_rows = timed(a, steps, args.repeat)
        figures[variant] = us, float(np.median(lengths))
        label = (f"steps grown to {1e3 * a.backup_step_max:g} ms" if variant == "grown"
                 else f"steps of {1e3 * a.backup_step:g} ms alone")
        print(f"  {label:<26} {us:7.2f} us a check, rollout steps median "
              f"{np.median(lengths):.0f}, mean {lengths.mean():.1f}, 99th percentile "
              f"{np.percentile(lengths, 99):.0f} ({verified_rows:.0f} rows verified)")
    for grown_steps in (True, False) if args.premise else ():
        steps, widening, start = deviation_along_steps(grown, args.premise, 7, grown_steps)
        what = "steps grown" if grown_steps else f"free {1e3 * grown.backup_step:g} ms steps"
        print(f"  {what:<18} D at a hold inside within {widening:.3f} times the larger of "
              f"its ends', {start:.2f} times its start's ({steps} steps, {args.premise} "
              "sampled states)")
    print(f"grown_us={figures['grown'][0]:.2f} alone_us={figures['alone'][0]:.2f} "
          f"steps_grown={figures['grown'][1]:.0f} steps_alone={figures['alone'][1]:.0f}")


if __name__ == "__main__":
    main()
