"""The filter's viable set against an independent computation, and the issue's reproducers.

The filter calls a state viable when its braking backup, rolled out in its nominal model
with a tube for the declared uncertainty, stops every joint inside its sets
(cosim/paper/cbf_filter/backup.py). Here the true arm (the paper's closed-form two-link arm,
tests/test_references.py, not the filter's recursive model) is braked apart by the same
policy recomputed with DAQP, held over each 1 ms control step and integrated by RK4 at
0.1 ms: from states the filter verifies it must stop inside the bound the check holds; from
states just past the filter's boundary it must not. SI units, radians."""

from __future__ import annotations

import numpy as np
import pytest
from test_references import two_link_closed_form

from cosim.paper.cbf_filter.backup import verified
from cosim.runner import run

LIMIT = 1000.0  # N·m, both joints
SAFETY = "pipelines/paper_safety.toml"
# The paper's arm, exactly the filter's model here: no payload, no noise declared
# (paper_safety.toml's [uncertainty]), the true velocity (baseline_cbf), so the tube is nil.
ARM = dict(a1=1.0, a2=1.0, m1=0.8, m2=2.3, g=9.8)
TAU_D = 0.01  # N·m, the plant's constant disturbance, which the filter's model assumes


@pytest.fixture(scope="module")
def filter_args():
    """The filter's arguments after a short run of baseline_cbf with a 1000 N·m limit (its
    model, its bounds; the rollout needs nothing of the run's state)."""
    from cosim.config import load_pipeline

    pipeline = load_pipeline(SAFETY, ["simulation.duration=0.01",
                                      f"cbf_filter.torque_limit={LIMIT}"])
    pipeline.runs = {"baseline_cbf": pipeline.runs["baseline_cbf"]}
    from cosim.assemble import assemble
    from cosim.engine import simulate

    scenario = assemble(pipeline)
    try:
        plan = scenario.runs["baseline_cbf"]
        simulate(scenario.plant, plan, plan.new_trace(scenario.steps))
    finally:
        scenario.close()
    return plan.block("cbf_filter").args


def is_verified(a, q, v) -> bool:
    zero = np.zeros(2)
    return bool(verified(0, a, np.array(q, float), np.array(v, float), zero, zero, False, 0))


def brake_apart(a, q, v, seconds: float = 1.0) -> tuple[float, float]:
    """The true arm braked by the backup's policy recomputed apart: the q̈ nearest
    −k_b v that |M q̈ + b + τ_d| ≤ LIMIT allows (DAQP), its torque held 1 ms, RK4 at
    0.1 ms. Returns (the largest |q_i| and |q̇_i| over the braking, rad and rad/s)."""
    import qpsolvers

    q, v = np.array(q, float), np.array(v, float)
    worst_q, worst_v = np.abs(q).max(), np.abs(v).max()

    def acceleration(q, v, tau):
        mass, bias = two_link_closed_form(q, v, **ARM)
        return np.linalg.solve(mass, tau - bias - TAU_D)

    for _ in range(int(seconds / 1e-3)):
        if np.abs(v).max() <= 0.05:
            break
        mass, bias = two_link_closed_form(q, v, **ARM)
        bias = bias + TAU_D
        desired = -a.backup_rate * v
        u = qpsolvers.solve_qp(np.eye(2), -desired, np.vstack([mass, -mass]),
                               np.concatenate([LIMIT - bias, LIMIT + bias]), solver="daqp")
        tau = np.clip(mass @ u + bias, -LIMIT, LIMIT)
        h = 1e-4
        for _ in range(10):
            k1q, k1v = v, acceleration(q, v, tau)
            k2q, k2v = v + h / 2 * k1v, acceleration(q + h / 2 * k1q, v + h / 2 * k1v, tau)
            k3q, k3v = v + h / 2 * k2v, acceleration(q + h / 2 * k2q, v + h / 2 * k2v, tau)
            k4q, k4v = v + h * k3v, acceleration(q + h * k3q, v + h * k3v, tau)
            q = q + h / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
            v = v + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
            worst_q, worst_v = max(worst_q, np.abs(q).max()), max(worst_v, np.abs(v).max())
    return worst_q, worst_v


# Joint 1 at distance d inside its upper bound moving outward; joint 2 somewhere else.
STARTS = [(0.3, (0.1, 5.0)), (0.6, (0.1, 5.0)), (0.3, (-0.7, 3.0))]


@pytest.mark.parametrize("distance, joint2", STARTS)
def test_the_viable_boundary_is_where_the_true_arm_can_just_stop(filter_args, distance,
                                                                 joint2):
    pytest.importorskip("qpsolvers")
    a = filter_args
    bound_q, bound_v = a.viable_bounds
    q = [bound_q - distance, joint2[0]]
    low, high = 0.0, 13.4  # rad/s: joint 1's outward speed, verified at low
    assert is_verified(a, q, [low, joint2[1]])
    if is_verified(a, q, [high, joint2[1]]):
        pytest.fail(f"every speed verified {distance} rad from the bound: no boundary")
    for _ in range(20):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if is_verified(a, q, [middle, joint2[1]]) else (low, middle)
    boundary = low
    worst_q, worst_v = brake_apart(a, q, [0.99 * boundary, joint2[1]])
    assert worst_q <= bound_q and worst_v <= bound_v, (boundary, worst_q, worst_v)
    # just past it the same braking overshoots the bound the check holds
    worst_q, _ = brake_apart(a, q, [1.03 * boundary, joint2[1]])
    assert worst_q > bound_q, (boundary, worst_q)
    # and the boundary is no smaller than the braking the limits give: v² = 2 d a̲ with
    # a̲ the deceleration this arm gets at least (joint 1 stretched out: ~50 rad/s²)
    assert boundary**2 >= 2 * distance * 40.0, boundary


@pytest.fixture(scope="module")
def reproducer():
    """The issue's broken guarantee: joint 1 0.1 rad from its 20 rad bound at 13 rad/s
    outward, the reference beyond the bound, with a 1000 N·m limit."""
    from cosim.config import load_pipeline

    pipeline = load_pipeline(SAFETY, [
        'plant.parameters."q0[1]"=19.9', 'plant.parameters."qdot0[1]"=13.0',
        "observer.initial_velocity=[13.0,10.0]", "uncertainty.initial_velocity_error=0.5",
        "reference.amplitude=[[30.0],[10.0]]", "reference.phase=[[0.775],[0.0]]",
        "reference.safe_centre=[0.0,0.0]", "reference.safe_velocity_centre=[0.0,0.0]",
        "simulation.duration=1.0", f"cbf_filter.torque_limit={LIMIT}"])
    pipeline.runs = {name: pipeline.runs[name] for name in ("proposed_cbf", "baseline_cbf")}
    return run(pipeline, None, progress=False)


@pytest.mark.parametrize("name", ["proposed_cbf", "baseline_cbf"])
def test_the_reproducer_is_reported_not_viable_never_covered_and_broken(reproducer, name):
    result = reproducer[name]
    g = result.metrics["guarantee"]
    assert g["starts_inside"] is True and g["starts_viable"] is False
    assert "not viable" in result_line(result) and g["covered"] is False
    assert g["broken"] is False and "BROKEN" not in result_line(result)
    # the limits hold at every step, the backup's torque included
    assert np.abs(result.trace["tau"]).max() <= LIMIT * (1 + 1e-12)
    # it overshoots (it could not stop) and the backup brings it back within the run
    assert g["returned"] is True and g["time_to_return_s"] < 1.0


def result_line(result) -> str:
    from cosim.paper.guarantee import Guarantee

    line, _ = Guarantee.report(None, result.metrics)
    return line
