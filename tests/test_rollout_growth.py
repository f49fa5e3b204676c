"""The check's rollout steps that grow (cosim/paper/cbf_filter/holds.py, ``may_grow``).

Where no torque limit binds at a step's start or end and no joint can reach the band near
its position bound where the backup steers it, the rollout's step doubles from
``backup_step`` (2 ms) up to ``backup_step_max`` (16 ms): the backup's velocity then falls by
the same factor at every hold, and the step takes its holds' own position
(``held_position``) and, as every free step of several holds does, the largest of D at its
start, its first hold's end and its end (``later_deviation``). Here the rollout is held
against the true arm braked apart (the paper's closed-form arm, DAQP, held 1 ms, RK4;
tests/test_viability.py), the torque at a grown step's end against the closed-form arm's,
and D along each free step against the widening the step took. Real filter arguments from
real runs; SI units, radians."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from test_references import two_link_closed_form
from test_viability import ARM, SAFETY, TAU_D, args_of, brake_apart, filter_args_of

from cosim.paper.cbf_filter.backup import HOLD, nominal_acceleration
from cosim.paper.cbf_filter.check import plan_box
from cosim.paper.cbf_filter.deviation import deviation_bound
from cosim.paper.cbf_filter.holds import TUBE_SAFETY, held_position, held_travel
from cosim.paper.cbf_filter.scratch import Rollout, Tube

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
from check_rollout import deviation_along_steps, planned  # noqa: E402


@pytest.fixture(scope="module")
def filter_args():
    return args_of(SAFETY)


def plan(a, q, v) -> list[tuple[np.ndarray, float]]:
    """The tube of the rollout the check verifies from (q, v): (segment, length) each."""
    segments = planned(a, np.array(q, float), np.array(v, float), 0.0)
    assert segments, "not verified"
    return segments


def test_a_grown_rollout_and_its_box_are_where_the_braked_arm_is(filter_args):
    """From 6 rad/s, free at the default 50 1/s, the rollout grows to 16 ms steps. At each of
    its points, and in the plan's box at every control step inside them, the true arm
    braked apart is within 6e-3 rad/s and 5e-4 rad of it: as close as with 2 ms steps alone
    (5.2e-3 rad/s, 1.9e-4 rad, the same start; the rest is the first steps, where a limit
    binds). The holds' average q̈ held over a 16 ms step (mutant cbf-grown-position-average)
    put the position ahead of the arm's by ~c dt² |q̈_0| m (m² − 1)/12."""
    pytest.importorskip("qpsolvers")
    a = filter_args
    q, v = np.array([0.1, 0.5]), np.array([6.0, -4.0])
    segments = plan(a, q, v)
    assert max(h for _, h in segments) == pytest.approx(a.backup_step_max)
    velocities: list = []
    positions: list = []
    brake_apart(a, q, v, seconds=0.3, velocities=velocities, positions=positions)
    start, points = 0.0, 0
    for segment, h in segments:
        row = int(round(start / a.dt))
        if row < len(velocities):
            assert np.abs(velocities[row] - segment[Tube.V]).max() <= 6e-3, (row, h)
            assert np.abs(positions[row] - segment[Tube.Q]).max() <= 5e-4, (row, h)
            points += 1
        start += h
    rows = 0
    plan(a, q, v)  # the plan in force again, at row 0
    for k in range(len(velocities) - 1):
        plan_box(k, a)  # the box at row k + 1
        box = a.work.rollout
        if np.isnan(box[Rollout.BOX_V]).any():
            break
        assert np.abs(box[Rollout.BOX_V] - velocities[k + 1]).max() <= 6e-3, k
        assert np.abs(box[Rollout.BOX_Q] - positions[k + 1]).max() <= 5e-4, k
        rows += 1
    assert points >= 10 and rows >= 60, (points, rows)


@pytest.mark.parametrize("distance, speed", [(0.26, 3.0), (0.3, 5.0), (0.35, 6.0)])
def test_no_step_grows_into_the_band_where_the_backup_steers_a_joint_in(
        filter_args, distance, speed):
    """Joint 1 ``distance`` inside its bound, moving outward at ``speed``, brakes towards
    the band within HOLD of its bound, where the backup's target moves with the position.
    Every step that grows keeps the joint out of the band from its start to its end (it
    moves one way over the step): the target w = 0 the step holds is the backup's
    throughout (with the band's guard dropped, mutant cbf-grown-band-guard, a step grew
    into it). Some steps do grow, and the arm braked apart is within 6e-3 rad/s of the
    rollout at its points."""
    pytest.importorskip("qpsolvers")
    a = filter_args
    band = a.viable_bounds[0, 0] - HOLD
    q = np.array([a.viable_bounds[0, 0] - distance, 0.5])
    v = np.array([speed, -1.0])
    segments = plan(a, q, v)
    grown = 0
    for segment, h in segments:
        if h > a.backup_step * (1.0 + 1e-9):
            grown += 1
            end = segment[Tube.Q] + h * segment[Tube.V] \
                + held_position(a, h, h) * segment[Tube.ACC_FIRST]
            for position in (segment[Tube.Q], end):
                assert np.all(np.abs(position - a.centres[0]) + a.noise_bound <= band), h
    assert grown >= 1
    velocities: list = []
    brake_apart(a, q, v, seconds=0.3, velocities=velocities)
    start = 0.0
    for segment, h in segments:
        row = int(round(start / a.dt))
        if row < len(velocities):
            assert np.abs(velocities[row] - segment[Tube.V]).max() <= 6e-3, row
        start += h


def torque_at_end(a, segment: np.ndarray, h: float) -> np.ndarray:
    """The backup's torque at a grown step's end on the closed-form arm: M q̈ + b + τ_d at the
    end's nominal velocity and q̈ (each hold's q̈ (1 − c) times the one before), the step's
    configuration, N·m."""
    c = min(a.backup_rate * a.dt, 1.0)
    first = segment[Tube.ACC_FIRST]
    velocity = segment[Tube.V] + first * held_travel(a, h, h)
    mass, bias = two_link_closed_form(segment[Tube.Q], velocity, **ARM)
    return mass @ (first * (1.0 - c) ** int(round(h / a.dt))) + bias + TAU_D


def test_a_grown_step_ends_with_the_backups_torque_within_the_limit():
    """At a 40 N·m limit, near the arm's own gravity torque, the braking torque falls with
    the backup's q̈ over a free step while the bias stays: a step may grow only where the
    backup's torque at its end is within the limit too, as at its start (mutant
    cbf-grown-end-torque: steps grew past where it bound). Every grown step of the plans
    verified from 60 sampled states: the torque at its end, M q̈ + b + τ_d on the
    closed-form arm (tests/test_references.py) at the end's nominal velocity and q̈, the
    step's configuration, within the limit."""
    a = filter_args_of(SAFETY, 40.0)
    rng = np.random.default_rng(3)
    grown = 0
    for _ in range(60):
        q = rng.uniform(-0.8, 0.8, 2) * a.viable_bounds[0]
        v = rng.uniform(-0.3, 0.3, 2) * a.viable_bounds[1]
        for segment, h in planned(a, q, v, 0.0):
            if h <= a.backup_step * (1.0 + 1e-9):
                continue
            grown += 1
            torque = torque_at_end(a, segment, h)
            assert np.all(np.abs(torque) <= 40.0 * (1.0 + 1e-6)), (h, torque)
    assert grown >= 20, grown


def test_no_step_grows_where_the_backups_torque_would_bind_at_its_end():
    """Joint 1 level (its gravity torque ~52 N·m), rising at 0.15 rad/s, braked at a 30 N·m
    limit: the braking q̈ lowers the torque the gravity asks at first, and as it falls the
    torque climbs back towards the gravity's. The rollout grows to 4 ms, then not to 8 ms,
    whose end would ask 31 N·m on the closed-form arm (mutant cbf-grown-end-torque: it
    grew): every grown step ends within the limit."""
    a = filter_args_of(SAFETY, 30.0)
    grown = 0
    for segment, h in planned(a, np.zeros(2), np.array([0.15, 0.0]), 0.0):
        if h <= a.backup_step * (1.0 + 1e-9):
            continue
        grown += 1
        torque = torque_at_end(a, segment, h)
        assert np.all(np.abs(torque) <= 30.0 * (1.0 + 1e-6)), (h, torque)
    assert grown >= 1


@pytest.mark.parametrize("path", ["pipelines/near_boundary.toml", SAFETY])
@pytest.mark.parametrize("grown", [True, False])
def test_a_free_steps_widening_covers_d_at_every_hold_inside_it(path, grown):
    """The premise of a free step's widening, measured: D inside a step of several holds
    (each hold's q̈ at the nominal velocity at its start and at its end, the step's
    configuration) within 1.1 times the largest of D at the step's start, its first hold's
    end and its end, the D that 1.5 D widens the tube by; for the steps that grow and for
    those of ``backup_step``. On 60 sampled states of each arm: at most 1.041
    (near_boundary.toml, its payload's part; 1.104 with the step's ends alone). D at the
    step's start alone (mutant cbf-end-deviation-dropped) fell short by up to 26 times in a
    grown step, and 4.3 times at a 2 ms step's end. Printed by benchmarks/check_rollout.py
    --premise."""
    steps, worst, _ = deviation_along_steps(args_of(path), 60, 7, grown)
    assert steps >= 50, steps
    assert worst <= 1.1, worst


def test_d_later_in_a_step_is_d_taken_afresh_there():
    """D later in a free step of several holds takes the payload's structure (K's
    eigenvectors, α, the s_j on the grid) from the D at the step's start, the same
    configuration and M̂⁻¹, rather than again. With a payload of 0-1 kg declared
    (near_boundary.toml), every such step of the plans verified from 40 sampled states
    widened its tube by 1.5 times the largest of D at its start, its first hold's
    end and its end, each taken afresh at the step's configuration, to 1e-12 (mutant
    cbf-structure-stale: the start's D took the structure of the step before's end)."""
    a = args_of("pipelines/near_boundary.toml")
    n = a.viable_bounds.shape[1]
    rng = np.random.default_rng(5)
    c = min(a.backup_rate * a.dt, 1.0)
    steps = 0
    deviation = np.zeros(n)
    for _ in range(40):
        q = a.centres[0] + rng.uniform(-0.8, 0.8, n) * a.viable_bounds[0]
        v = a.centres[1] + rng.uniform(-0.6, 0.6, n) * a.viable_bounds[1]
        eps = np.full(n, float(rng.choice([0.0, 0.1, 0.5])))
        for segment, h in planned(a, q, v, eps[0]):
            if h <= a.dt * (1.0 + 1e-9) or not np.all(segment[Tube.FEEDBACK] > 0.0):
                continue  # a held step, or one where a limit binds
            steps += 1
            rollout = a.work.rollout
            rollout[Rollout.Q], rollout[Rollout.V] = segment[Tube.Q], segment[Tube.V]
            nominal_acceleration(0, a, np.zeros(n), True, 0, a.torque_limit)
            first, holds = segment[Tube.ACC_FIRST], int(round(h / a.dt))
            largest = np.zeros(n)
            for reached in (0, 1, holds):
                velocity = segment[Tube.V] + first * held_travel(a, h, reached * a.dt)
                deviation_bound(a, velocity, eps, first * (1.0 - c) ** max(reached - 1, 0),
                                deviation, False)
                largest = np.maximum(largest, deviation)
            # to rounding: the velocities and q̈ are recomputed here in NumPy (its power
            # of (1 − c) is not numba's by an ulp)
            assert np.allclose(segment[Tube.WIDEN], TUBE_SAFETY * largest, rtol=1e-12,
                               atol=0.0), (h, segment[Tube.WIDEN], TUBE_SAFETY * largest)
    assert steps >= 100, steps
