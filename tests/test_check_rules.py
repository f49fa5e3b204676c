"""The filter's check rule by rule, in both directions and at either joint: the state
inside the hard sets as the check holds them (cosim/paper/cbf_filter/interval.py,
``inside``), a braking rollout that stops whichever way a joint moves, and the tube's
half-widths growing by the recurrence the check states (cosim/paper/cbf_filter/check.py,
``_advance``). Each catches a bug an outside audit planted that the viability tests let
through. SI units, radians."""

from __future__ import annotations

import numpy as np
import pytest
from test_viability import args_of, is_verified

from cosim.paper.cbf_filter.check import STOPPED
from cosim.paper.cbf_filter.interval import inside
from cosim.paper.cbf_filter.scratch import Flag, Rollout, Tube


@pytest.fixture(scope="module")
def paper_args():
    return args_of("pipelines/paper_safety.toml")


@pytest.fixture(scope="module")
def uncertain_args():
    """near_boundary.toml: a payload of 0-1 kg at the tip, noise 6e-4 rad declared."""
    return args_of("pipelines/near_boundary.toml")


def plan(a) -> tuple[np.ndarray, np.ndarray]:
    """The rollout just verified, segment by segment, and each segment's length, s (up to
    the first of length 0, its end: an earlier, longer rollout's may follow)."""
    buffer = int(a.work.flags[Flag.PLAN_TUBE])
    lengths = a.work.tube_steps[buffer]
    ends = np.flatnonzero(lengths == 0.0)
    count = int(ends[0]) if len(ends) else len(lengths)
    return a.work.tube[buffer, :count], lengths[:count]


@pytest.mark.parametrize("joint", (0, 1))
@pytest.mark.parametrize("side", (1.0, -1.0))
def test_the_state_is_inside_only_within_both_bounds_at_either_joint(uncertain_args, joint,
                                                                     side):
    """``inside`` on the velocity interval and the measured position: 0.1 within a bound
    (the check's own, viable_bounds) inside, 0.1 past it not, on either side of either
    joint."""
    a = uncertain_args
    rollout, position = a.work.rollout, a.position[0]
    kept = rollout[Rollout.CENTRE].copy(), rollout[Rollout.HALF].copy(), position.copy()
    try:
        rollout[Rollout.HALF] = 0.0
        rollout[Rollout.CENTRE] = a.centres[1]
        position[:] = a.centres[0]
        for quantity, bound in ((1, a.viable_bounds[1, joint]),
                                (0, a.viable_bounds[0, joint] - a.noise_bound)):
            values = rollout[Rollout.CENTRE] if quantity else position
            for offset, expected in ((-0.1, True), (0.1, False)):
                values[joint] = a.centres[quantity, joint] + side * (bound + offset)
                assert inside(0, a) is expected, (quantity, offset)
            values[joint] = a.centres[quantity, joint]
    finally:
        rollout[Rollout.CENTRE], rollout[Rollout.HALF], position[:] = kept


@pytest.mark.parametrize("joint", (0, 1))
def test_a_joint_moving_either_way_is_braked_to_its_target_and_stops(paper_args, joint):
    """From rest but one joint at ±1 rad/s, the verified rollout takes as many segments
    either way, and ends with every joint within STOPPED of its backup's target."""
    a = paper_args
    segments = {}
    for side in (1.0, -1.0):
        v = np.zeros(2)
        v[joint] = side
        assert is_verified(a, [0.0, 0.0], v)
        tube, _ = plan(a)
        segments[side] = len(tube)
        rollout = a.work.rollout
        moving = rollout[Rollout.V] - a.centres[1] - rollout[Rollout.TARGET]
        assert np.all(np.abs(moving) <= STOPPED)
    assert segments[1.0] == segments[-1.0] > 1, segments


def test_the_tubes_half_widths_grow_by_the_recurrence_the_check_states(uncertain_args):
    """A rollout of steps of 1 and 2 ms (and longer, grown) near the position bound with the
    payload and an estimate within 0.5 rad/s: segment by segment, a joint held or at its
    limit, or over one hold, δq' = δq + h δv + ½h²·widen and δv' = max(δv (1 − f) + f ε
    + h·widen, ε), f the feedback's share; a free joint over m > 1 holds, each removing the
    share c = k_b dt of its departure u, hold by hold: with |u_j| ≤ U_j = (1 − c)^j δv
    + (1 − (1 − c)^j) ε + widen dt Σ_{k<j} (1 − c)^k and inside hold j
    (1 − cτ/dt) U_j + (cτ/dt) ε + widen τ, δq' = δq + Σ_j ∫ over hold j and
    δv' = max(U_m, ε); to rounding."""
    a = uncertain_args
    bound = a.viable_bounds[0, 0]
    eps = 0.5
    assert is_verified(a, [bound - 0.3, 0.1], [3.0, 5.0], eps)
    tube, lengths = plan(a)
    assert len(tube) > 10 and len(set(np.round(lengths, 9))) > 1, lengths
    c = min(a.backup_rate * a.dt, 1.0)
    several = 0
    for j in range(len(tube) - 1):
        h, now, then = lengths[j], tube[j], tube[j + 1]
        f = now[Tube.FEEDBACK]
        holds = int(round(h / a.dt))
        dq = now[Tube.DQ] + h * now[Tube.DV] + 0.5 * h * h * now[Tube.WIDEN]
        dv = now[Tube.DV] * (1.0 - f) + f * eps + now[Tube.WIDEN] * h
        if holds > 1 and (f > 0.0).any():
            several += 1
            bounds = [now[Tube.DV] * (1.0 - c) ** k + (1.0 - (1.0 - c) ** k) * eps
                      + now[Tube.WIDEN] * a.dt * sum((1.0 - c) ** i for i in range(k))
                      for k in range(holds + 1)]
            inside = sum(a.dt * ((1.0 - 0.5 * c) * bounds[k] + 0.5 * c * eps)
                         + 0.5 * now[Tube.WIDEN] * a.dt * a.dt for k in range(holds))
            dq = np.where(f > 0.0, now[Tube.DQ] + inside, dq)
            dv = np.where(f > 0.0, bounds[holds], dv)
        np.testing.assert_allclose(then[Tube.DQ], dq, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(then[Tube.DV], np.maximum(dv, eps), rtol=1e-12, atol=1e-15)
    assert several > 3, several


def test_the_plans_box_inside_a_step_of_several_holds_contracts_no_faster_than_the_holds(
        uncertain_args):
    """At a 0.5 ms control step and 200 1/s the rollout's steps span several holds of the
    backup, each removing the share c = k_b dt of a free joint's δv. The plan's box after J
    holds into a segment keeps at least δv (1 − c)^J + (1 − (1 − c)^J) ε + J dt·widen: the
    feedback has had J holds to act, not the whole segment's (the payload's D > 0, so the
    tube is not nil)."""
    from cosim.paper.cbf_filter.check import plan_box
    from cosim.paper.cbf_filter.scratch import Rollout

    a = uncertain_args._replace(backup_rate=200.0, dt=5e-4)
    eps, c = 0.3, 200.0 * 5e-4
    assert is_verified(a, [0.1, 0.5], [2.0, 1.0], eps)
    tube, lengths = plan(a)
    starts = np.concatenate(([0.0], np.cumsum(lengths)))
    inside_steps = 0
    for k in range(int(round(starts[-1] / a.dt)) - 1):
        plan_box(k, a)
        offset = (k + 1) * a.dt
        j = int(np.searchsorted(starts, offset - 1e-12)) - 1
        holds = int(round((offset - starts[j]) / a.dt))
        if not 0 < holds < round(lengths[j] / a.dt):
            continue  # at a segment's edge, where the box is the segment's own
        segment = tube[j]
        free = segment[Tube.FEEDBACK] > 0.0
        kept = (1.0 - c) ** holds
        least = segment[Tube.DV] * kept + (1.0 - kept) * eps + holds * a.dt * segment[Tube.WIDEN]
        box = a.work.rollout[Rollout.BOX_V_HALF]
        assert np.all(box[free] >= least[free] - 1e-12), (k, box, least)
        inside_steps += int(free.any())
    assert inside_steps >= 10, inside_steps
