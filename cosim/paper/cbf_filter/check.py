"""The check that makes the filter's hard sets hold with bounded
torque: a torque is applied only if, after it, the backup can still stop every joint inside
its position set and keep its velocity set, for every state and plant the declared
uncertainty allows (a backup-controller safety filter in the manner of Chen, Jankovic,
Santillo and Ames, "Backup control barrier functions", 2021, checked by rolling the backup
out rather than by its sensitivities).

The check (:func:`verified`) rolls the nominal model out from the estimate (y, v), carrying
the middle of the declared payload range (:func:`.backup.rollout_payload`; the backup's torque
too): the candidate torque held over one step, then the backup, in steps of
``backup_step`` (of one control step where a torque limit binds in it), until every joint
is stopped (|v − q̇_s − w| ≤ ``STOPPED``) or
``backup_horizon`` has passed (unverified). Around the nominal rollout a tube of
half-widths δq, δv holds the true state: δq(0) = n̄ (noise), δv(0) = the half-width of the
velocity's interval (:func:`.interval.velocity_interval`, at most ε), and per step, with D taken
TUBE_SAFETY (1.5) times, and δq advanced with δv before δv's update,

    δq_i ← δq_i + δv_i h + ½ (1.5 D_i) h²
    δv_i ← max(δv_i (1 − f_i) + f_i ε_i + 1.5 D_i h, ε_i)

where f_i = 1 − (1 − min(k_b dt, 1))^(h/dt) when joint i's torque is free (the backup's
feedback, applied and held at the control step dt, pulls its velocity towards its target:
:func:`feedback_contraction`) and f_i = 0 when its torque is at the limit or held (the
candidate's step). The f_i ε_i is derived: the feedback acts on an estimate within ε of the
true velocity, so the true velocity's departure u from the rollout's obeys
u̇ = −k_b (u + e) + Δ, |e| ≤ ε, |Δ| ≤ D. The factor 1.5 is empirical: D is taken at the
rollout's state with the spread ε, while over a held step the true state departs from it
by δv (docs/safety/filter.md, "The check"). A torque held over a whole step drifts in q̈
as the state moves: the candidate's step always, every step where a limit binds in the
backup (whose q̈ is then the small QP's, moving with the bias as a held torque's does),
and, where the rollout's step is the control step (``backup_step`` ≥ dt: from 2 ms at the
default), every step of the backup too. Over such a step the tube's centre takes the
middle of the hull of q̈ ± 1.5 D at the step's start and at its predicted end, and
1.5 D_i its half-width (:func:`_held_drift`), as the velocity's interval is predicted
(:func:`.interval.predict_interval`). Over a free backup's step of several holds the
backup is re-evaluated at each: its feedback on the departure is what f models, and the
fall of its own q̈ is the holds' average (:func:`held_average`). Without
the candidate's drift at 1 ms, 22 of 73 covered full-state runs on the project's
distribution left the tube at start-up braking (docs/safety/measurements.md, "The tube
premise"). D_i is the
bound on the true q̈_i's departure from the nominal model's (:mod:`.deviation`): the bias
error from the estimate's velocity error ε, the friction and the disturbance (|M̂⁻¹(Δb + d)|,
the hard rows' bound, see :mod:`.model`, at the rollout's state), plus the payload's: with
c the middle of the payload range, which the rollout's model carries, the largest
|q̈(c + Δm) − q̈(c)| under the rollout's torque for Δm from low − c to high − c (where M̂ is
the plant's, c = 0 and Δm over the range itself). Every joint's
|q − q_s| + δq and |v − q̇_s| + δv must stay within its bound at every rollout step: for a
set already left, within the excess it started with, decaying at ``recovery_rate``
(h < 0 must grow back at that rate).

What it assumes, besides the declared bounds: the tube's linear feedback model of the
backup (exact for a joint the backup does not clip), b's velocity forms Γ taken at the
step's configuration for the whole rollout, and the
excursion between two rollout steps within half of ``bound_margin``: the check holds the
sets shrunk by half the margin the QP's rows keep (``viable_bounds``), so that the QP's
states leave the check that slack, and the check leaves the rest for what happens between
its points (with |q̈| ≤ Ā at most Ā h²/8: 5e-4 rad at Ā = 1000 rad/s², h = 2 ms, against
0.02 rad of a 20 rad bound).

"""

from __future__ import annotations

import numpy as np

from ...numba_compat import no_refcount_jit
from ..linalg import invert, product
from .backup import HOLD, nominal_acceleration
from .deviation import deviation_bound, fixed_deviation
from .model import nominal_model, robust_model
from .scratch import Flag, Matrix, Rollout, Tube, Vector

STOPPED = 0.05  # rad/s: a joint within this of its backup's target velocity has stopped
# The tube's D is taken this many times: its linear model of the backup's feedback (each
# free joint pulled to its target at k_b, the torque recomputed from the true state) is first
# order; braked apart on the closed-form arm with 1 kg at the tip from the edge of the
# velocity's interval, D alone let joint 1 pass its bound by 0.015 rad
# (tests/test_viability.py), 1.5 D keeps it inside. An empirical factor, stated as such.
TUBE_SAFETY = 1.5
# rad/s: a velocity set's centre this small is a 0 (filtered) to the rollout's steps
TINY_CENTRE = 1e-6


@no_refcount_jit(cache=True)
def feedback_contraction(rate, h, dt):
    """f: the share of the true velocity's departure u from the rollout's that the backup's
    feedback removes over a rollout step of h. The filter applies the backup at the control
    step dt and holds it, so per hold u ← (1 − c) u − c e + ∫Δ with c = min(k_b dt, 1), and
    over the h/dt holds of a rollout step (``backup_step`` is a whole number of control
    steps) (1 − c)^(h/dt) of u remains. Within a step, the share after s is at least
    f s/h (1 − (1 − c)^j is concave in j), as :func:`plan_box` takes it. The first-order
    k_b h claimed more than the holds give: 0.4 against 0.36 at k_b = 200 1/s, h = 2 dt =
    2 ms (docs/safety/filter.md, "The check")."""
    holds = max(1, round(h / dt))
    held = min(rate * dt, 1.0)
    if holds == 1:
        return held
    return 1.0 - (1.0 - held) ** holds


@no_refcount_jit(cache=True)
def held_end(k, a, tau, limit, spread):
    """A held step's predicted end: the rollout's row state (Rollout.Q, Rollout.V) moved by
    dt under its q̈ (Rollout.ACC), and there the nominal q̈ under τ held (Rollout.ACC) and D
    for the velocity error ``spread`` (Rollout.DEV). The true q̈ over the step lies in the
    hull of q̈ ± 1.5 D at the step's start and at this end (:func:`_held_drift`,
    :func:`.interval.predict_interval`)."""
    r = a.work.rollout
    q, vel, acc = r[Rollout.Q], r[Rollout.V], r[Rollout.ACC]
    for i in range(q.shape[0]):
        q[i] += a.dt * vel[i] + 0.5 * a.dt * a.dt * acc[i]
        vel[i] += a.dt * acc[i]
    nominal_acceleration(k, a, tau, False, 0, limit)
    deviation_bound(a, vel, spread, acc, r[Rollout.DEV])


@no_refcount_jit(cache=True)
def _held_drift(k, a, first, limit, eps, widen):
    """Take q̈'s drift over a held step (``first`` held for dt) into the tube: the true q̈
    over the step lies in the hull of q̈ ± ``widen`` at the step's start (1.5 D there, per
    joint) and q̈ ± 1.5 D at its predicted end (the premise :func:`.interval.predict_interval`
    takes too). The rollout's q̈ (the tube's centre over the step) becomes the hull's
    middle and ``widen`` its half-width; q and q̇ are the start's again on return. (The
    start's q̈ as the centre, widened to max(1.5 D, |q̈(end) − q̈| + 1.5 D(end)), is as sound
    and wider by up to half the drift.)"""
    r = a.work.rollout
    q, vel, acc, deviation = r[Rollout.Q], r[Rollout.V], r[Rollout.ACC], r[Rollout.DEV]
    held_q, held_v, held_acc = r[Rollout.HELD_Q], r[Rollout.HELD_V], r[Rollout.HELD_ACC]
    n = q.shape[0]
    for i in range(n):
        held_q[i], held_v[i], held_acc[i] = q[i], vel[i], acc[i]
    held_end(k, a, first, limit, eps)
    for i in range(n):
        # the hull of q̈ ± W at the start and q̈ ± W at the end: its middle and half-width
        low = min(held_acc[i] - widen[i], acc[i] - TUBE_SAFETY * deviation[i])
        high = max(held_acc[i] + widen[i], acc[i] + TUBE_SAFETY * deviation[i])
        widen[i] = 0.5 * (high - low)
        q[i], vel[i], acc[i] = held_q[i], held_v[i], 0.5 * (low + high)


@no_refcount_jit(cache=True, inline="always")
def held_average(a, h, contraction):
    """The rollout's q̈ over a step of h = m dt, m > 1 holds of a backup no torque limit
    binds: its q̈ at each hold, averaged (into Rollout.ACC; the first hold's into
    Rollout.HOLD_ACC).
    The filter re-evaluates the backup at every control step dt and holds it, so over the
    step its q̈ = k_b (w − (v − q̇_s)) falls as it acts: (1 − c)^k q̈_0 at hold k,
    c = min(k_b dt, 1). Taken at the first hold's q̈ for the whole step, the rollout braked
    faster than the filter does, by c dt |q̈_0| m (m − 1)/2 in velocity after a step to first
    order: 0.2 dt |q̈_0| at 200 1/s and m = 2, up to 0.24 rad/s along a rollout
    (docs/safety/filter.md, "The check"). With the average, Σ_k (1 − c)^k / m = f / (m c),
    the rollout's velocity after the step is the holds'. Its position is ahead of theirs in
    the direction of motion (conservative) by c dt² |q̈_0| m (m² − 1)/12 a step to first
    order (½ dt² c |q̈_0| at m = 2; over a braking from 13 rad/s at 1 ms, 1.7e-4 rad at
    50 1/s and 7.2e-4 rad at 200 1/s, in the room ``bound_margin`` leaves between the
    check's points). Inside the step, the plan's box takes the holds' own velocities
    (:func:`held_travel`). A step where a limit binds is one hold (:func:`verified`).
    ``contraction``: the step's f (:func:`feedback_contraction`)."""
    r = a.work.rollout
    acc, first = r[Rollout.ACC], r[Rollout.HOLD_ACC]
    c = min(a.backup_rate * a.dt, 1.0)
    share = 1.0
    if c > 0.0:
        share = contraction / (max(1, round(h / a.dt)) * c)
    for i in range(acc.shape[0]):
        first[i] = acc[i]
        acc[i] *= share


@no_refcount_jit(cache=True, inline="always")
def held_travel(a, h, s):
    """The velocity a step of h moves by after s, per unit of its first hold's q̈: s where
    the step is one hold (its q̈ constant), else the holds' Σ_{k<J} (1 − c)^k dt (J = s/dt,
    c = k_b dt: :func:`held_average`) and the next hold's share of the rest."""
    c = min(a.backup_rate * a.dt, 1.0)
    if h <= a.dt * (1.0 + 1e-9) or c <= 0.0:
        return s
    holds = np.floor(s / a.dt + 1e-9)
    remains = (1.0 - c) ** holds
    return a.dt * (1.0 - remains) / c + (s - holds * a.dt) * remains


@no_refcount_jit(cache=True, inline="always")
def held_position(a, h, s):
    """The position a step of h moves by after s beyond s times its start's velocity, per
    unit of its first hold's q̈: ½ s² where the step is one hold (its q̈ constant), else
    the holds' own sum, their q̈ falling by (1 − c) at each (:func:`held_average`). The
    holds' average q̈ held over the step put the position ahead of theirs in the direction
    of motion, by c dt² |q̈_0| m (m² − 1)/12 to first order: 2e-3 rad from 13 rad/s over a
    step of 16 holds at 50 1/s."""
    c = min(a.backup_rate * a.dt, 1.0)
    if h <= a.dt * (1.0 + 1e-9) or c <= 0.0:
        return 0.5 * s * s
    holds = int(np.floor(s / a.dt + 1e-9))
    position = travel = 0.0  # per unit of q̈_0: so far, and the velocity gained so far
    share = 1.0  # (1 − c)^j: hold j's q̈ per unit of the first's
    for _ in range(holds):
        position += a.dt * travel + 0.5 * a.dt * a.dt * share
        travel += a.dt * share
        share *= 1.0 - c
    rest = s - holds * a.dt
    return position + rest * travel + 0.5 * rest * rest * share


@no_refcount_jit(cache=True, inline="always")
def plan_box(k, a):
    """The box the plan in force (the rollout of the last torque verified, at step k0) puts
    the true state in at row k + 1, into Rollout.BOX_Q … Rollout.BOX_V_HALF: its tube
    (k + 1 − k0)·dt after its start, within the segment holding that time (the nominal state
    exactly, q̈ constant over a segment; δq, δv as the check grows them). NaN past the rollout's end.
    The classifier holds the true state to it (the tube measured along the run)."""
    w = a.work
    r = w.rollout
    n = r.shape[1]
    for i in range(n):
        r[Rollout.BOX_Q, i] = r[Rollout.BOX_Q_HALF, i] = np.nan
        r[Rollout.BOX_V, i] = r[Rollout.BOX_V_HALF, i] = np.nan
    plan = int(w.flags[Flag.PLAN_TUBE])
    tube, lengths, eps = w.tube[plan], w.tube_steps[plan], w.tube_eps[plan]
    offset = (k + 1 - w.flags[Flag.PLAN_STEP]) * a.dt
    start = 0.0
    for j in range(lengths.shape[0]):
        h = lengths[j]
        if h <= 0.0:
            return
        if offset <= start + h * (1.0 + 1e-9):
            s = offset - start
            segment = tube[j]
            for i in range(n):
                r[Rollout.BOX_Q, i] = (segment[Tube.Q, i] + s * segment[Tube.V, i]
                                       + held_position(a, h, s) * segment[Tube.ACC_FIRST, i])
                r[Rollout.BOX_Q_HALF, i] = (segment[Tube.DQ, i] + s * segment[Tube.DV, i]
                                            + 0.5 * s * s * segment[Tube.WIDEN, i])
                r[Rollout.BOX_V, i] = segment[Tube.V, i] \
                    + segment[Tube.ACC_FIRST, i] * held_travel(a, h, s)
                share = segment[Tube.FEEDBACK, i] * s / h
                r[Rollout.BOX_V_HALF, i] = max(segment[Tube.DV, i] * (1.0 - share)
                                               + share * eps[i] + segment[Tube.WIDEN, i] * s,
                                               eps[i])
            return
        start += h


@no_refcount_jit(cache=True, inline="always")
def _advance(a, segment, h, eps, backup, stopped, limit, decay, contraction):
    """One step h of the rollout and its tube (module docstring), kept in ``segment``, the
    state's excess over a set it started outside of allowed to shrink by ``decay``, the
    feedback removing the share ``contraction`` of a free joint's δv: −1 if a hard set is
    left, else 1 if every joint has stopped (``stopped``: the step's backup is free of its
    limits), else 0."""
    r = a.work.rollout
    q, vel, dq, dv = r[Rollout.Q], r[Rollout.V], r[Rollout.DQ], r[Rollout.DV]
    acc, widen = r[Rollout.ACC], r[Rollout.WIDEN]
    limit_q, limit_v = r[Rollout.LIMIT_Q], r[Rollout.LIMIT_V]
    n = q.shape[0]
    travel = held_position(a, h, h)  # the nominal's, per unit of its first hold's q̈
    for i in range(n):
        # the backup's feedback acts on a joint whose torque is free (the held torque:
        # on none): a limited joint brakes as hard as it can, the others still steer
        free = backup and abs(r[Rollout.TAU, i]) < limit[i] * (1.0 - 1e-9)
        feedback = contraction if free else 0.0
        segment[Tube.Q, i], segment[Tube.V, i] = q[i], vel[i]
        segment[Tube.ACC_FIRST, i] = r[Rollout.HOLD_ACC, i]
        segment[Tube.DQ, i], segment[Tube.DV, i] = dq[i], dv[i]
        segment[Tube.WIDEN, i], segment[Tube.FEEDBACK, i] = widen[i], feedback
        # exact for q̈ constant over the step (the position's error would be ~v·h/2), and
        # for a free backup's over several holds (held_position), with its turning point
        # inside the step checked too (the holds' average q̈ taken for it)
        turn = q[i]
        if vel[i] * acc[i] < 0.0 and abs(vel[i]) < abs(acc[i]) * h:
            turn = q[i] - 0.5 * vel[i] * vel[i] / acc[i]
        q[i] += h * vel[i] + travel * r[Rollout.HOLD_ACC, i]
        vel[i] += h * acc[i]
        dq[i] += h * dv[i] + 0.5 * h * h * widen[i]
        # the feedback acts on the estimate e within ε of the true velocity: the true
        # velocity's departure u from the rollout's obeys u̇ = −k_b (u + e) + Δ, |Δ| ≤ D,
        # so |u| grows by at most f ε + D h a step as the feedback f contracts it
        dv[i] = max(dv[i] * (1.0 - feedback) + feedback * eps[i] + widen[i] * h, eps[i])
        allowed_q = a.viable_bounds[0, i] + (limit_q[i] - a.viable_bounds[0, i]) * decay
        allowed_v = a.viable_bounds[1, i] + (limit_v[i] - a.viable_bounds[1, i]) * decay
        if a.hard[0] and max(abs(q[i] - a.centres[0, i]), abs(turn - a.centres[0, i])) + dq[i] \
                > allowed_q:
            return -1
        if a.hard[1] and abs(vel[i] - a.centres[1, i]) + dv[i] > allowed_v:
            return -1
        stopped = stopped and abs(vel[i] - a.centres[1, i] - r[Rollout.TARGET, i]) <= STOPPED
    return 1 if stopped else 0


@no_refcount_jit(cache=True, inline="always")
def _may_grow(a, h):
    """Whether a free backup's step may take h (longer than ``backup_step``): its target
    stays w = 0 over it for every joint, as the rollout holds it. No joint is steered
    (Rollout.TARGET 0), and none can reach the band within HOLD of its position bound
    where the backup steers it, at its speed, which only falls over a free step (towards
    q̇_s, on the same side of 0: else the velocity crosses 0 and the position turns, by
    up to |q̇_s| h, left to the room ``bound_margin`` leaves between the check's points
    only where |q̇_s| ≤ TINY_CENTRE, a filtered 0). Then every joint's velocity and q̈
    fall by the same factor at each hold, and its position moves one way."""
    r = a.work.rollout
    if a.backup_rate * a.dt >= 1.0:
        return False
    for i in range(r.shape[1]):
        speed, centre = r[Rollout.V, i], a.centres[1, i]
        if r[Rollout.TARGET, i] != 0.0 or (speed * centre < 0.0 and abs(centre) > TINY_CENTRE):
            return False
        reach = abs(r[Rollout.Q, i] - a.centres[0, i]) + a.noise_bound \
            + (abs(speed - centre) + abs(centre)) * h
        if a.hard[0] and reach > a.viable_bounds[0, i] - HOLD:
            return False
    return True


@no_refcount_jit(cache=True, inline="always")
def _grown_deviation(a, h, eps, widen):
    """Over a step longer than ``backup_step`` (:func:`_may_grow`), D at its end too: the
    tube's widening the larger of 1.5 D at the step's start and at its end, the nominal
    velocity and q̈ there (Rollout.HELD_V, Rollout.HELD_ACC) at the start's configuration.
    Along the step every joint's velocity departs from q̇_s by the same falling factor: the
    bias error's part linear in it is largest at an end; the friction's and the payload's
    need not be (docs/safety/filter.md, "Steps that grow")."""
    r = a.work.rollout
    vel, acc, first = r[Rollout.V], r[Rollout.ACC], r[Rollout.HOLD_ACC]
    end_v, end_acc, deviation = r[Rollout.HELD_V], r[Rollout.HELD_ACC], r[Rollout.DEV]
    remains = (1.0 - min(a.backup_rate * a.dt, 1.0)) ** max(1, round(h / a.dt))
    for i in range(vel.shape[0]):
        end_v[i] = vel[i] + h * acc[i]
        end_acc[i] = first[i] * remains
    deviation_bound(a, end_v, eps, end_acc, deviation)
    for i in range(vel.shape[0]):
        widen[i] = max(widen[i], TUBE_SAFETY * deviation[i])


@no_refcount_jit(cache=True)
def verified(k, a, y, v, eps, first, hold, policy, limit):
    """Whether the backup keeps every hard set from the estimate (y, v) (|q − y| ≤ n̄,
    |q̇ − v| ≤ ε), after ``first`` is held for one step if ``hold`` (module docstring), with
    the backup's ``policy`` within the torques ``limit`` (the torque limits or less)."""
    w = a.work
    r = w.rollout
    q, vel, dq, dv, acc = r[Rollout.Q], r[Rollout.V], r[Rollout.DQ], r[Rollout.DV], r[Rollout.ACC]
    limit_q, limit_v = r[Rollout.LIMIT_Q], r[Rollout.LIMIT_V]
    deviation, widen = r[Rollout.DEV], r[Rollout.WIDEN]
    n = y.shape[0]
    for i in range(n):
        if not eps[i] < np.inf:  # nothing known of the velocity: nothing is verified
            return False
    trial = int(w.flags[Flag.TUBE_TRIAL])  # the rollout is kept here; the plan, if verified
    tube, lengths = w.tube[trial], w.tube_steps[trial]
    for i in range(n):
        q[i], vel[i], dq[i], dv[i] = y[i], v[i], a.noise_bound, eps[i]
        # what each set allows: its bound, or the excess it starts with (recovery)
        limit_q[i] = max(a.viable_bounds[0, i], abs(y[i] - a.centres[0, i]) + a.noise_bound)
        limit_v[i] = max(a.viable_bounds[1, i], abs(v[i] - a.centres[1, i]) + eps[i])
        r[Rollout.TARGET, i] = 0.0
        w.tube_eps[trial, i] = eps[i]
    fixed_deviation(a, eps)
    t = 0.0
    step = 0
    # where the rollout's step is the control step (backup_step is at least dt), each of its
    # steps is a torque the filter holds over the whole step, as the candidate's always is:
    # q̈'s drift over it is taken
    held = a.backup_step <= a.dt
    stride = a.backup_step  # the next free step's length: doubles while it may (_may_grow)
    while t < a.backup_horizon and step < lengths.shape[0]:
        backup = not (hold and step == 0)
        clipped = nominal_acceleration(k, a, first, backup, policy, limit)
        # a step where a torque limit binds (or the candidate's) is one hold, whose drift is
        # taken: under a limit the backup's q̈ is no longer its linear feedback's, and moves
        # with the state's bias as a held torque's does
        h = a.backup_step if backup and not clipped else a.dt
        if h > a.dt and stride > h and _may_grow(a, stride):
            h = stride
        stride = min(2.0 * h, a.backup_step_max) if h > a.dt else a.backup_step
        # the bias error's velocity error is the estimate's, ε: the backup acts on the
        # state as measured, whatever the tube (the true state's spread about the rollout)
        deviation_bound(a, vel, eps, acc, deviation)
        for i in range(n):
            widen[i] = TUBE_SAFETY * deviation[i]
        contraction = feedback_contraction(a.backup_rate, h, a.dt)  # the step's, every joint's
        if held or clipped:
            _held_drift(k, a, r[Rollout.TAU], limit, eps, widen)
            for i in range(n):
                r[Rollout.HOLD_ACC, i] = acc[i]
        else:  # a step of several holds, the backup re-evaluated at each
            held_average(a, h, contraction)
            if h > a.backup_step * (1.0 + 1e-9):
                _grown_deviation(a, h, eps, widen)
        decay = np.exp(-a.recovery_rate * (t + h))
        state = _advance(a, tube[step], h, eps, backup, backup and not clipped, limit, decay,
                         contraction)
        if state < 0:
            return False
        lengths[step] = h
        t += h
        step += 1
        if state > 0:  # every joint stopped
            if step < lengths.shape[0]:
                lengths[step] = 0.0  # the rollout's end
            # verified: this rollout is the plan (the next check writes the other buffer)
            w.flags[Flag.PLAN_TUBE], w.flags[Flag.TUBE_TRIAL] = trial, 1 - trial
            w.flags[Flag.PLAN_STEP] = k
            return True
    return False


@no_refcount_jit(cache=True)
def verified_from(a, y, v, eps, policy):
    """Whether the backup with ``policy`` keeps every hard set from the estimate (y, v),
    |q̇ − v| ≤ ε, with nothing held first: :func:`verified` for a check made apart from a
    run (benchmarks/deceleration.py, the viability tests). The bias error's velocity forms
    Γ and the payload's structure are taken at (y, v) with the nominal M̂(y), as the hard
    rows take them in a step; :func:`verified` alone would use whatever state the filter's
    work space last held. Overwrites that work space (not for use inside a step)."""
    matrices, vectors = a.work.matrices, a.work.vectors
    minv, bias, base = matrices[Matrix.MINV], vectors[Vector.BIAS], vectors[Vector.BASE]
    nominal_model(a, y, v, matrices[Matrix.NOMINAL_NOW], bias)
    invert(matrices[Matrix.NOMINAL_NOW], minv, matrices[Matrix.LU])
    product(minv, bias, base)
    robust_model(a, y, v, eps, minv, base)
    # nothing held: bias unread
    return verified(0, a, y, v, eps, bias, False, policy, a.torque_limit)
