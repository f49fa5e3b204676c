"""The check that makes the filter's hard sets hold with bounded
torque: a torque is applied only if, after it, the backup can still stop every joint inside
its position set and keep its velocity set, for every state and plant the declared
uncertainty allows (a backup-controller safety filter in the manner of Chen, Jankovic,
Santillo and Ames, "Backup control barrier functions", 2021, checked by rolling the backup
out rather than by its sensitivities).

The check (:func:`verified`) rolls the nominal model out from the estimate (y, v), carrying
the middle of the declared payload range (:func:`.backup.rollout_payload`; the backup's torque
too): the candidate torque held over one step, then the backup, in steps of
``backup_step`` (of one control step where a torque limit binds in it; doubling up to
``backup_step_max`` where no joint's target moves over the step: :func:`.holds.may_grow`), until
every joint is stopped (|v − q̇_s − w| ≤ ``STOPPED``) or
``backup_horizon`` has passed (unverified). Around the nominal rollout a tube of
half-widths δq, δv holds the true state: δq(0) = n̄ (noise), δv(0) = the half-width of the
velocity's interval (:func:`.interval.velocity_interval`, at most ε), and per step, with D taken
TUBE_SAFETY (1.5) times, and δq advanced with δv before δv's update,

    δq_i ← δq_i + δv_i h + ½ (1.5 D_i) h²
    δv_i ← max(δv_i (1 − f_i) + f_i ε_i + 1.5 D_i h, ε_i)

where f_i = 1 − (1 − min(k_b dt, 1))^(h/dt) when joint i's torque is free (the backup's
feedback, applied and held at the control step dt, pulls its velocity towards its target:
:func:`.holds.feedback_contraction`) and f_i = 0 when its torque is at the limit or held (the
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
1.5 D_i its half-width (:func:`.holds.held_drift`), as the velocity's interval is predicted
(:func:`.interval.predict_interval`). Over a free backup's step of several holds the
backup is re-evaluated at each: its feedback on the departure is what f models, the
fall of its own q̈ is the holds' average (:func:`.holds.held_average`), its position the holds'
own (:func:`.holds.held_position`), and D the larger at the step's two ends
(:func:`.holds.later_deviation`). Without
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
step's configuration for the whole rollout, over a step of several holds the configuration
of its start for D and for the torque at its end, D inside such a step no more than at the
points it is taken (the start, the first hold's end, the end: measured, :func:`.holds.
later_deviation`), a torque limit binding at neither end of a grown step binding at none of
its holds, and the excursion between two rollout steps within half of ``bound_margin``:
the check holds the sets shrunk by half the margin the QP's rows keep (``viable_bounds``),
so that the QP's states leave the check that slack, and the check leaves the rest for what
happens between its points (with |q̈| ≤ Ā at most Ā h²/8: 5e-4 rad at Ā = 1000 rad/s²,
h = 2 ms, against 0.02 rad of a 20 rad bound). A grown step needs none of that room: its
nominal position moves one way over it (:func:`.holds.may_grow`), and its tube grows with
it, so its ends bound it.

"""

from __future__ import annotations

import numpy as np

from ...numba_compat import no_refcount_jit
from ..linalg import invert, product
from .backup import nominal_acceleration
from .deviation import deviation_bound, fixed_deviation
from .holds import (
    TUBE_SAFETY,
    feedback_contraction,
    free_at_end,
    held_average,
    held_drift,
    held_position,
    held_share,
    held_travel,
    later_deviation,
    may_grow,
)
from .model import nominal_model, robust_model
from .scratch import Flag, Matrix, Rollout, Tube, Vector

STOPPED = 0.05  # rad/s: a joint within this of its backup's target velocity has stopped


@no_refcount_jit(cache=True, inline="always")
def plan_box(k, a):
    """The box the plan in force (the rollout of the last torque verified, at step k0) puts
    the true state in at row k + 1, into Rollout.BOX_Q … Rollout.BOX_V_HALF: its tube
    (k + 1 − k0)·dt after its start, within the segment holding that time (the nominal state
    as the segment moves it, hold by hold: :func:`.holds.held_position`,
    :func:`.holds.held_travel`; δq, δv as the check grows them). NaN past the rollout's end.
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
            # the same for every joint: the nominal's position and velocity after s per unit
            # of its first hold's q̈, and over several holds the share of a free joint's
            # δv − ε left and its integral (holds.held_share)
            position, travel = held_position(a, h, s), held_travel(a, h, s)
            several = h > a.dt * (1.0 + 1e-9)
            remains, contracted = 1.0, 0.0
            if several:
                remains, contracted = held_share(a, s)[:2]
            for i in range(n):
                r[Rollout.BOX_Q, i] = (segment[Tube.Q, i] + s * segment[Tube.V, i]
                                       + position * segment[Tube.ACC_FIRST, i])
                r[Rollout.BOX_V, i] = segment[Tube.V, i] + segment[Tube.ACC_FIRST, i] * travel
                spread, widen = segment[Tube.DV, i], segment[Tube.WIDEN, i]
                if segment[Tube.FEEDBACK, i] > 0.0 and several:
                    # a free joint over several holds, δv's excess over ε contracted hold by
                    # hold as the check grew its tube; the D gathered taken whole, W s, at
                    # least the holds' (test_check_rules)
                    r[Rollout.BOX_Q_HALF, i] = (segment[Tube.DQ, i] + eps[i] * s
                                                + (spread - eps[i]) * contracted
                                                + 0.5 * s * s * widen)
                    r[Rollout.BOX_V_HALF, i] = max(eps[i] + remains * (spread - eps[i])
                                                   + widen * s, eps[i])
                    continue
                r[Rollout.BOX_Q_HALF, i] = segment[Tube.DQ, i] + s * spread + 0.5 * s * s * widen
                share = segment[Tube.FEEDBACK, i] * s / h
                r[Rollout.BOX_V_HALF, i] = max(spread * (1.0 - share) + share * eps[i]
                                               + widen * s, eps[i])
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
    several = h > a.dt * (1.0 + 1e-9)
    contracted = gathered = gathered_integral = 0.0
    if several:  # a free joint's δv − ε left, its integral, the D gathered and its integral
        _, contracted, gathered, gathered_integral = held_share(a, h)
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
        # the feedback acts on the estimate e within ε of the true velocity: the true
        # velocity's departure u from the rollout's obeys u̇ = −k_b (u + e) + Δ, |Δ| ≤ D,
        # so |u| grows by at most f ε + D h a step as the feedback f contracts it; over a
        # free step of several holds it contracts u hold by hold (holds.held_share)
        if free and several:
            dq[i] += eps[i] * h + (dv[i] - eps[i]) * contracted + widen[i] * gathered_integral
            dv[i] = max(dv[i] * (1.0 - feedback) + feedback * eps[i] + widen[i] * gathered,
                        eps[i])
        else:
            dq[i] += h * dv[i] + 0.5 * h * h * widen[i]
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
    stride = a.backup_step  # the next free step's length: doubles while it may (may_grow)
    while t < a.backup_horizon and step < lengths.shape[0]:
        backup = not (hold and step == 0)
        clipped = nominal_acceleration(k, a, first, backup, policy, limit)
        # a step where a torque limit binds (or the candidate's) is one hold, whose drift is
        # taken: under a limit the backup's q̈ is no longer its linear feedback's, and moves
        # with the state's bias as a held torque's does
        h = a.backup_step if backup and not clipped else a.dt
        if h > a.dt and stride > h and may_grow(a, stride) and free_at_end(a, stride, limit):
            h = stride
        stride = min(2.0 * h, a.backup_step_max) if h > a.dt else a.backup_step
        # the bias error's velocity error is the estimate's, ε: the backup acts on the
        # state as measured, whatever the tube (the true state's spread about the rollout)
        deviation_bound(a, vel, eps, acc, deviation, False)
        for i in range(n):
            widen[i] = TUBE_SAFETY * deviation[i]
        contraction = feedback_contraction(a.backup_rate, h, a.dt)  # the step's, every joint's
        if held or clipped:
            held_drift(k, a, r[Rollout.TAU], limit, eps, widen, hold and step == 0)
            for i in range(n):
                r[Rollout.HOLD_ACC, i] = acc[i]
        else:  # a step of several holds, the backup re-evaluated at each
            held_average(a, h, contraction)
            later_deviation(a, h, eps, widen)
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
