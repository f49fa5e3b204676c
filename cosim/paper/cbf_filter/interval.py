"""The true velocity's interval the filter holds at each row: the observer's certified
interval, intersected with the one the step before predicted under the torque it applied
(the nominal model's q̈ ± TUBE_SAFETY D over the step, :mod:`.check`), and whether every
state it and the measured position allow lies inside the hard sets. The check
(:func:`.check.verified`) starts its tube from it; the run's classifier measures that the
true q̇ stays in it (docs/safety/filter.md, "The premises")."""

from __future__ import annotations

import numpy as np

from ...numba_compat import no_refcount_jit
from .backup import nominal_acceleration
from .deviation import deviation_bound, fixed_deviation
from .holds import TUBE_SAFETY, held_end
from .scratch import Flag, Rollout


@no_refcount_jit(cache=True)
def velocity_interval(k, a):
    """The true velocity's interval at row k (centre into Rollout.CENTRE, half-width into
    Rollout.HALF): the estimate's (the certified interval its ε is taken from, inside v ± ε),
    intersected with the one predicted at the step before
    (:func:`predict_interval`). Both hold the true q̇ under the declared bounds; the
    intersection keeps what the backup was verified from at the step before (the estimate
    alone may move by more than the model allows in one step, and a state verified a step
    ago would then look unverifiable). Where they do not meet, the declared bounds did not
    hold: the estimate's alone."""
    r = a.work.rollout
    v, eps, centre = a.velocity[k], a.velocity_bound[k], a.envelope_centre[k]
    consistent = k > 0
    for i in range(v.shape[0]):
        # the certified interval ε is taken from, c ± (ε − |v − c|): v ± ε's narrowest
        # part holding q̇ (ε bounds |q̇ − v| for every q̇ in it)
        half = max(eps[i] - abs(v[i] - centre[i]), 0.0)
        low, high = centre[i] - half, centre[i] + half
        if not (np.isfinite(low) and np.isfinite(high)):
            low, high = -np.inf, np.inf  # the observer confirmed no enclosure of q̇
        # a little room for rounding: a true velocity (ε = 0) may sit on the prediction's edge
        meets = r[Rollout.NEXT_LOW, i] <= high + 1e-9 and r[Rollout.NEXT_HIGH, i] >= low - 1e-9
        consistent = consistent and meets
        if k > 0 and meets:
            low, high = max(low, r[Rollout.NEXT_LOW, i]), min(high, r[Rollout.NEXT_HIGH, i])
            high = max(high, low)
        if np.isfinite(low) and np.isfinite(high):
            r[Rollout.CENTRE, i], r[Rollout.HALF, i] = 0.5 * (low + high), 0.5 * (high - low)
        else:  # nothing holds q̇: the estimate as the centre, the half-width infinite
            r[Rollout.CENTRE, i], r[Rollout.HALF, i] = v[i], np.inf
            consistent = False
        a.velocity_centre[k, i], a.velocity_spread[k, i] = r[Rollout.CENTRE, i], r[Rollout.HALF, i]
    a.work.flags[Flag.CONSISTENT] = 1.0 if consistent else 0.0


@no_refcount_jit(cache=True, inline="always")
def checked(k, a, tau):
    """Whether the last check's candidate step was τ held from row k's state (its position,
    the velocity's interval), with a hull of numbers: then the hull of q̈ it took
    (:func:`.holds.held_drift`) is the one :func:`predict_interval` takes, the same calls
    on the same numbers (both with the forms Γ the rows left). A NaN in it is taken afresh:
    the prediction's min and max drop a NaN at the step's start, the check's hull keeps it."""
    r = a.work.rollout
    if a.work.flags[Flag.CHECKED_ROW] != k + 1:
        return False
    y = a.position[k]
    for i in range(y.shape[0]):
        if (r[Rollout.CHECKED_TAU, i] != tau[i] or r[Rollout.CHECKED_Q, i] != y[i]
                or r[Rollout.CHECKED_V, i] != r[Rollout.CENTRE, i]
                or r[Rollout.CHECKED_HALF, i] != r[Rollout.HALF, i]
                or np.isnan(r[Rollout.CHECKED_LOW, i] + r[Rollout.CHECKED_HIGH, i])):
            return False
    return True


@no_refcount_jit(cache=True, inline="always")
def predict_interval(k, a, tau):
    """The interval of the true velocity at row k + 1 under τ held over the step (into
    Rollout.NEXT_LOW, Rollout.NEXT_HIGH): row k's moved by dt times the hull of q̈ ± D at the
    step's start and at its predicted end (q̈ drifts over the hold as q and q̇ move), D taken
    TUBE_SAFETY times as the check's tube takes it: a velocity outside a narrower prediction
    may still be in the tube the check verified. Where the check's last candidate step was
    τ from this state (:func:`checked`), its hull is taken as it stands: on the Panda that
    is two of its model's evaluations and two of D a step (~5.5 µs)."""
    r = a.work.rollout
    y = a.position[k]
    n = y.shape[0]
    low, high = r[Rollout.NEXT_LOW], r[Rollout.NEXT_HIGH]
    for i in range(n):
        r[Rollout.Q, i], r[Rollout.V, i] = y[i], r[Rollout.CENTRE, i]
        low[i], high[i] = np.inf, -np.inf
        r[Rollout.ACC_LOW, i] = r[Rollout.ACC_HIGH, i] = np.nan
    for i in range(n):
        if not r[Rollout.HALF, i] < np.inf:  # q̇ unknown now: nothing predicted
            for j in range(n):
                low[j], high[j] = -np.inf, np.inf
            return
    if checked(k, a, tau):  # the check took this hull already (most steps)
        for i in range(n):
            low[i], high[i] = r[Rollout.CHECKED_LOW, i], r[Rollout.CHECKED_HIGH, i]
    else:
        deviation, acceleration = r[Rollout.DEV], r[Rollout.ACC]
        fixed_deviation(a, r[Rollout.HALF])
        nominal_acceleration(k, a, tau, False, 0, a.torque_limit)
        deviation_bound(a, r[Rollout.V], r[Rollout.HALF], acceleration, deviation, False)
        for end in range(2):
            if end == 1:  # the step's predicted end
                held_end(k, a, tau, a.torque_limit, r[Rollout.HALF])
            for i in range(n):
                low[i] = min(low[i], acceleration[i] - TUBE_SAFETY * deviation[i])
                high[i] = max(high[i], acceleration[i] + TUBE_SAFETY * deviation[i])
    for i in range(n):
        r[Rollout.ACC_LOW, i], r[Rollout.ACC_HIGH, i] = low[i], high[i]  # the check's bound on q̈
        low[i] = r[Rollout.CENTRE, i] - r[Rollout.HALF, i] + a.dt * low[i]
        high[i] = r[Rollout.CENTRE, i] + r[Rollout.HALF, i] + a.dt * high[i]


@no_refcount_jit(cache=True, inline="always")
def inside(k, a):
    """Whether every state row k's bounds allow (|q − y| ≤ n̄, q̇ in its interval) is inside
    every hard set (as the check holds them): a state verified but not inside is one the
    backup brings back, not one it keeps."""
    r = a.work.rollout
    y = a.position[k]
    for i in range(y.shape[0]):
        if a.hard[0] and abs(y[i] - a.centres[0, i]) + a.noise_bound > a.viable_bounds[0, i]:
            return False
        if a.hard[1] and abs(r[Rollout.CENTRE, i] - a.centres[1, i]) + r[Rollout.HALF, i] \
                > a.viable_bounds[1, i]:
            return False
    return True
