"""The filter's step, as a kernel: the QP's rows (:mod:`.rows`), its solve with the hard
rows the payload's corners add as cuts, tracking scaled back where it asks a joint for more
than the controller has, the torque chosen (:mod:`.policy`), and the record of what it
chose: every output of the row, and what the run's classifier measures the check's premises
with."""

from __future__ import annotations

import numpy as np

from ...numba_compat import no_refcount_jit
from ..linalg import dot
from .check import plan_box
from .groups import add_cuts, groups_record
from .interval import predict_interval
from .policy import choose
from .rows import step_rows
from .scratch import Authority, Flag, Matrix, Rollout, Solver
from .solver import newton


@no_refcount_jit(cache=True, inline="always")
def hard_violated(G, h, is_hard, count, tau):
    """Whether τ violates a hard row of the first ``count`` as given (h not lowered)."""
    for j in range(count):
        if is_hard[j] > 0.0 and dot(G[j], tau) - h[j] > 0.0:
            return True
    return False


@no_refcount_jit(cache=True)
def solve_with_cuts(k, a, count):
    """The QP's answer over every row (the groups' included) into Solver.TAU, by
    Newton over the first ``count`` rows, then again with the hard rows it violates (or
    comes within hard_tolerance of) added, until there are none (:func:`.groups.add_cuts`):
    the same minimiser, over the few rows that can bind instead of every payload corner's.
    Returns the number of rows the QP then has."""
    w = a.work
    h, weights, tau = w.per_row[0], w.per_row[1], w.solver[Solver.TAU]
    while True:
        newton(a.tau_nominal[k], a.rows, h, weights, count, a.iterations, a.tolerance,
               w.solver, w.matrices[Matrix.FACTOR], w.binding, True)
        more = add_cuts(a, count, tau)
        if more == count:
            return count
        count = more


@no_refcount_jit(cache=True)
def cbf_record(k, a, count, tau):
    """Row k's outputs for the torque τ the QP gave (:func:`.policy.choose`, then each
    constraint's activity, the largest soft slack)."""
    return step_record(k, a, count, tau)


@no_refcount_jit(cache=True, inline="always")
def step_record(k, a, count, tau):
    """cbf_record, as the step calls it. ``tau`` is the solver's, changed in place. Also
    what the run's classifier measures the check's premises with: the box the plan of the
    step before put this row's state in, and the check's bound on q̈ over this step."""
    r = a.work.rollout
    for i in range(tau.shape[0]):
        a.tube_position[k, i] = r[Rollout.BOX_Q, i] if k > 0 else np.nan
        a.tube_position_spread[k, i] = r[Rollout.BOX_Q_HALF, i] if k > 0 else np.nan
        a.tube_velocity[k, i] = r[Rollout.BOX_V, i] if k > 0 else np.nan
        a.tube_velocity_spread[k, i] = r[Rollout.BOX_V_HALF, i] if k > 0 else np.nan
    viable, share = choose(k, a, tau)
    for i in range(tau.shape[0]):
        a.tau[k, i] = tau[i]
    predict_interval(k, a, tau)
    for i in range(tau.shape[0]):
        a.acceleration_low[k, i] = r[Rollout.ACC_LOW, i]
        a.acceleration_high[k, i] = r[Rollout.ACC_HIGH, i]
    if viable:  # the plan in force (verified now, or followed) says where the state goes
        plan_box(k, a)
    else:
        for i in range(tau.shape[0]):
            r[Rollout.BOX_Q, i] = r[Rollout.BOX_Q_HALF, i] = np.nan
            r[Rollout.BOX_V, i] = r[Rollout.BOX_V_HALF, i] = np.nan
    chosen = a.tau[k]
    a.viable[k] = 1.0 if viable else 0.0
    if viable:
        a.work.flags[Flag.VIABLE_ONCE] = 1.0
    a.infeasible[k] = 0.0 if viable else 1.0
    a.backup_share[k] = share
    # the hard rows of the groups, every payload corner's (those among the QP's rows too)
    met, active = groups_record(k, a, chosen)
    slack = 0.0
    for j in range(count):
        if a.is_hard[j] > 0.0 and 0 <= a.kinds[j] < 2:
            continue  # a group's row: counted above
        excess = dot(a.rows[j], chosen) - a.limits[j]
        met = met and not (a.is_hard[j] > 0.0 and excess > 0.0)
        # a hard row binds within the tolerance it was solved with; a soft one when violated
        binds = excess > -2.0 * a.hard_tolerance if a.is_hard[j] > 0.0 else excess > 0.0
        if a.is_hard[j] == 0.0:
            slack = max(slack, excess)
        if binds:
            active += 1
            s = a.kinds[j]
            if 0 <= s < 4:
                a.active_sets[s, k, a.joints[j]] = 1.0
            elif s >= 4:
                a.active_norms[s - 4, k] = 1.0
    a.rows_met[k] = 1.0 if met else 0.0
    a.active[k] = active
    a.slack[k] = slack
    correction = 0.0
    for i in range(chosen.shape[0]):
        correction += (chosen[i] - a.tau_nominal[k, i]) ** 2
    a.correction[k] = np.sqrt(correction)
    return np.isfinite(np.sum(chosen))


@no_refcount_jit(cache=True)
def beyond_authority(k, a, tau):
    """Whether τ asks a joint for more torque than the controller has so far (the largest
    |τ_nom,i| up to row k, kept up to date here: tracking_torque = "controller")."""
    peak = a.work.authority[Authority.PEAK]
    beyond = False
    for i in range(tau.shape[0]):
        peak[i] = max(peak[i], abs(a.tau_nominal[k, i]))
        beyond = beyond or abs(tau[i]) > peak[i]
    return beyond


@no_refcount_jit(cache=True)
def within_authority(a, tau, tau_hard):
    """τ_h + μ(τ − τ_h) into ``tau``, μ ∈ [0, 1] the largest that keeps every |τ_i| within
    the controller's peak (or within |τ_h,i| where the hard rows alone ask more): the
    tracking rows' share of the correction scaled back. Both ends meet the hard rows, which
    are linear, so the blend does too."""
    peak = a.work.authority[Authority.PEAK]
    mu = 1.0
    for i in range(tau.shape[0]):
        cap = max(peak[i], abs(tau_hard[i]))
        if abs(tau[i]) > cap:  # then τ_i ≠ τ_h,i: the crossing is in [0, 1)
            mu = min(mu, (np.sign(tau[i]) * cap - tau_hard[i]) / (tau[i] - tau_hard[i]))
    for i in range(tau.shape[0]):
        tau[i] = tau_hard[i] + mu * (tau[i] - tau_hard[i])


@no_refcount_jit(cache=True)
def cbf_step(k, a):
    count = step_rows(k, a, False)
    w = a.work
    h, weights, tau = w.per_row[0], w.per_row[1], w.solver[Solver.TAU]
    for j in range(count):  # solve with the hard limits lowered: checked as given after
        h[j] = a.limits[j] - a.hard_tolerance if a.is_hard[j] > 0.0 else a.limits[j]
        weights[j] = a.weights[j]
    # Warm: from the rows that bound at the step before (w.binding keeps them), which most
    # often still do: the soft rows and the torque limits, in the same order at every step;
    # the hard rows the solve adds are flagged as they come. A warm start from other rows
    # costs iterations, never the answer (the solver checks the piece it starts from).
    count = solve_with_cuts(k, a, count)
    # A hard row may slip by ~ρ_soft·(soft excess)/ρ_hard where tracking pulls hard against
    # it: re-solve with tracking weighed less, down to the hard rows alone (what remains is
    # the backup's check, in step_record). The rows left out are met (solve_with_cuts).
    for _ in range(3):
        if not hard_violated(a.rows, a.limits, a.is_hard, count, tau):
            break
        for j in range(count):
            if a.is_hard[j] == 0.0:
                weights[j] = weights[j] * 1e-3 if weights[j] > a.rho_soft * 1e-5 else 0.0
        count = solve_with_cuts(k, a, count)
    if a.tracking_authority and beyond_authority(k, a, tau):
        # the hard rows' answer alone, then the tracking rows' share scaled back to it
        answer = w.authority[Authority.ANSWER]
        for i in range(tau.shape[0]):
            answer[i] = tau[i]
        for j in range(count):
            if a.is_hard[j] == 0.0:
                weights[j] = 0.0
        count = solve_with_cuts(k, a, count)
        for i in range(tau.shape[0]):
            answer[i], tau[i] = tau[i], answer[i]
        if np.isfinite(np.sum(answer)):  # else the answer with the tracking rows stands
            within_authority(a, tau, answer)
    return step_record(k, a, count, tau)
