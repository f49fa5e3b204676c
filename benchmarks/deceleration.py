"""The worst-case deceleration a̲ the safety filter's torque limits give, under the declared
uncertainty (issue 30's figure "every start with v² ≤ 2·d·a̲ is viable"): over a grid of
starts — each joint in turn d rad inside either position bound, moving outward; the other
joints' angles and velocities on a grid within their sets — the fastest outward speed v*
the filter's own check verifies (cosim/paper/cbf_filter/check.py's verified_from: the
model's forms at that start, as a step takes them; bisection), and
a = v*²/(2d). a̲ is the least over the grid; the payload, noise and disturbance as
declared, and the velocity known to within ε: 0 (a full-state filter) and the declared
initial observer error (an output-feedback filter at t = 0), both printed.

    .venv/bin/python benchmarks/deceleration.py --torque-limits 1000 2000
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from cosim.assemble import assemble
from cosim.config import load_pipeline
from cosim.engine import simulate
from cosim.paper.cbf_filter.check import verified_from


def filter_args(pipeline_path: str, limit: float, duration: float = 0.01):
    """The filter's arguments for a full-state filtered run at ``limit`` N·m, after
    ``duration`` s of it."""
    pipeline = load_pipeline(pipeline_path, [f"simulation.duration={duration}",
                                             f"cbf_filter.torque_limit={limit}"])
    pipeline.runs = {"baseline_cbf": pipeline.runs["baseline_cbf"]}
    scenario = assemble(pipeline)
    try:
        plan = scenario.runs["baseline_cbf"]
        simulate(scenario.plant, plan, plan.new_trace(scenario.steps))
    finally:
        scenario.close()
    return plan.block("cbf_filter").args


def fastest(a, q: np.ndarray, v: np.ndarray, joint: int, side: float, top: float,
            spread: float) -> float:
    """The fastest outward speed of ``joint`` the check verifies from (q, v ± spread),
    rad/s."""
    eps = np.full(len(q), spread)

    def ok(speed: float) -> bool:
        start = v.copy()
        start[joint] = side * speed
        return any(bool(verified_from(a, q, start, eps, policy)) for policy in range(2))

    if not ok(0.0):
        return 0.0
    if ok(top):
        return top
    low, high = 0.0, top
    for _ in range(16):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if ok(middle) else (low, middle)
    return low


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pipeline", default="pipelines/near_boundary.toml")
    parser.add_argument("--torque-limits", type=float, nargs="+", default=[1000.0, 2000.0],
                        help="N·m, every joint")
    parser.add_argument("--distances", type=float, nargs="+", default=[0.5, 1.0, 2.0],
                        help="rad inside the bound")
    args = parser.parse_args()
    for limit, spread in itertools.product(args.torque_limits, (0.0, None)):
        a = filter_args(args.pipeline, limit)
        if spread is None:
            spread = float(load_pipeline(args.pipeline).uncertainty.initial_velocity_error)
        worst = least_deceleration(a, args.distances, spread)
        print(f"torque limit {limit:g} N·m, velocity known to ±{spread:g} rad/s: a̲ = "
              f"{worst[0]:.3g} rad/s² (the least v*²/2d over the grid, at joint, side, d, "
              f"other angle, other speed, v* = {worst[1]})")


def least_deceleration(a, distances: list[float], spread: float) -> tuple[float, tuple]:
    """(a̲, where) over the grid (module docstring)."""
    bound_q, bound_v = a.viable_bounds[:, 0]
    n = a.position.shape[1]
    angles = np.linspace(-np.pi, np.pi, 9)
    speeds = np.array([-1.0, -0.5, 0.0, 0.5, 1.0]) * 0.95 * (bound_v - spread)
    top = 0.999 * (bound_v - spread)
    worst: tuple[float, tuple] = (np.inf, ())
    for joint, side, d in itertools.product(range(n), (1.0, -1.0), distances):
        others = [j for j in range(n) if j != joint]
        for angle, speed in itertools.product(angles, speeds):
            q, v = np.zeros(n), np.zeros(n)
            q[joint] = side * (bound_q - d)
            q[others], v[others] = angle, speed
            v_star = fastest(a, q, v, joint, side, top, spread)
            decel = v_star**2 / (2 * d)
            if v_star < top and decel < worst[0]:
                worst = (decel, (joint + 1, side, d, round(float(angle), 3),
                                 round(float(speed), 3), round(v_star, 3)))
    return worst

if __name__ == "__main__":
    main()
