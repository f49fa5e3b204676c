"""The worst-case deceleration a̲ the safety filter's torque limits give, under the declared
uncertainty (issue 30's figure "every start with v² ≤ 2·d·a̲ is viable"): over a grid of
starts — each joint in turn d rad inside either position bound, moving outward; the other
joints' angles and velocities on a grid within their sets — the fastest outward speed v*
the filter's own check verifies (cosim/paper/cbf_filter/backup.py, bisection), and
a = v*²/(2d). a̲ is the least over the grid; the velocity is taken as known (ε = 0: what
the observer adds is reported apart by the Monte Carlo), the payload, noise and disturbance
as declared.

    .venv/bin/python benchmarks/deceleration.py --torque-limits 1000 2000
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from cosim.assemble import assemble
from cosim.config import load_pipeline
from cosim.engine import simulate
from cosim.paper.cbf_filter.backup import verified


def filter_args(pipeline_path: str, limit: float):
    """The filter's arguments for a full-state filtered run at ``limit`` N·m."""
    pipeline = load_pipeline(pipeline_path, ["simulation.duration=0.01",
                                             f"cbf_filter.torque_limit={limit}"])
    pipeline.runs = {"baseline_cbf": pipeline.runs["baseline_cbf"]}
    scenario = assemble(pipeline)
    try:
        plan = scenario.runs["baseline_cbf"]
        simulate(scenario.plant, plan, plan.new_trace(scenario.steps))
    finally:
        scenario.close()
    return plan.block("cbf_filter").args


def fastest(a, q: np.ndarray, v: np.ndarray, joint: int, side: float, top: float) -> float:
    """The fastest outward speed of ``joint`` the check verifies from (q, v), rad/s."""
    zero = np.zeros(len(q))

    def ok(speed: float) -> bool:
        start = v.copy()
        start[joint] = side * speed
        return any(bool(verified(0, a, q, start, zero, zero, False, policy))
                   for policy in range(2))

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
    for limit in args.torque_limits:
        a = filter_args(args.pipeline, limit)
        bound_q, bound_v = a.viable_bounds
        n = len(a.m)
        angles = np.linspace(-np.pi, np.pi, 9)
        speeds = np.array([-1.0, -0.5, 0.0, 0.5, 1.0]) * 0.95 * bound_v
        worst = (np.inf, None)
        for joint, side, d in itertools.product(range(n), (1.0, -1.0), args.distances):
            others = [j for j in range(n) if j != joint]
            for angle, speed in itertools.product(angles, speeds):
                q, v = np.zeros(n), np.zeros(n)
                q[joint] = side * (bound_q - d)
                q[others], v[others] = angle, speed
                v_star = fastest(a, q, v, joint, side, 0.999 * bound_v)
                decel = v_star**2 / (2 * d)
                if v_star < 0.999 * bound_v and decel < worst[0]:
                    worst = (decel, (joint + 1, side, d, angle, speed, v_star))
        print(f"torque limit {limit:g} N·m: a̲ = {worst[0]:.3g} rad/s² (the least v*²/2d over "
              f"the grid, at joint, side, d, other angle, other speed, v* = {worst[1]})")


if __name__ == "__main__":
    main()
