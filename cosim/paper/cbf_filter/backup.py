"""The braking backup and the check that makes the filter's hard sets hold with bounded
torque: a torque is applied only if, after it, the backup can still stop every joint inside
its position set and keep its velocity set, for every state and plant the declared
uncertainty allows (a backup-controller safety filter in the manner of Chen, Jankovic,
Santillo and Ames, "Backup control barrier functions", 2021, checked by rolling the backup
out rather than by its sensitivities).

The backup: q̈_b = k_b (w − (v − q̇_s)) in the nominal model, τ_b = M̂ q̈_b + b̂ (the q̈
nearest that the torque limits allow, a small QP, or a lower braking_torque where the filter
asks for it), each τ_i clipped to that limit (so the torque limits hold whatever it asks);
w = 0 inside the position set away from its bound, inward at HOLD_RATE per rad within HOLD
of the bound (a persistent velocity error ε then holds the joint ε/HOLD_RATE deep in that
band instead of letting it drift out), and at up to ``recovery_speed`` past it (recovery).

The check (:func:`verified`) rolls the nominal model out from the estimate (y, v), carrying
the middle of the declared payload range (:func:`rollout_payload`; the backup's torque
too): the candidate torque held over one step, then the backup, in steps of
``backup_step``, until every joint is stopped (|v − q̇_s − w| ≤ ``STOPPED``) or
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
by δv (docs/safety/filter.md, "The check"). Where the rollout's step is the control
step (``backup_step`` ≥ dt: from 2 ms at the default), every rollout step is a torque held
over the whole step, the candidate's and then the backup's, and q̈ drifts over it as the
state moves: its 1.5 D_i is widened to max(1.5 D_i, |q̈_i(end) − q̈_i| + 1.5 D_i(end))
(:func:`_held_drift`), the hull of q̈ ± 1.5 D at the step's start and its predicted end, as
the velocity's interval is predicted (:func:`.interval.predict_interval`). At shorter steps the
backup is re-evaluated within a rollout step (its feedback is what f models), and the
candidate's step is taken at its start: its drift taken too made the check brake
differently after start-up (docs/safety/measurements.md, "The tube premise"). D_i is the
bound on the true q̈_i's departure from the nominal model's: the bias error from the estimate's
velocity error ε, the friction and the disturbance (|M̂⁻¹(Δb + d)|, the hard rows' bound,
see :mod:`.model`, at the rollout's state), plus the payload's (:func:`_payload_deviation`):
with c the middle of the payload range, which the rollout's model carries, the largest
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

from ...dynamics.model import (
    model_bias,
    model_friction,
    model_geometry,
    model_mass,
    model_payload,
)
from ...numba_compat import no_refcount_jit
from ..linalg import dot, invert, product
from .model import (
    friction_error_into,
    linear_error_bound_into,
    nominal_model,
    payload_structure,
    quadratic_error_into,
    robust_model,
)
from .scratch import (
    ALPHA,
    BACKUP_FACTOR,
    BASE,
    BETA,
    BIAS,
    GAMMA,
    JAC,
    LU,
    MINV,
    NOMINAL_NOW,
    PLAN_STEP,
    PLAN_TUBE,
    R_ACC,
    R_BIAS,
    R_BOX_Q,
    R_BOX_Q_HALF,
    R_BOX_V,
    R_BOX_V_HALF,
    R_CENTRE,
    R_DEV,
    R_DQ,
    R_DV,
    R_FRICTION,
    R_HELD_ACC,
    R_HELD_Q,
    R_HELD_V,
    R_LIMIT_Q,
    R_LIMIT_V,
    R_Q,
    R_QUADRATIC,
    R_SCRATCH,
    R_TARGET,
    R_TAU,
    R_V,
    R_WEIGHT,
    R_WIDEN,
    ROLL_LU,
    ROLL_MASS,
    ROLL_MINV,
    T_ACC,
    T_DQ,
    T_DV,
    T_FEEDBACK,
    T_Q,
    T_V,
    T_WIDEN,
    TAU,
    TUBE_TRIAL,
    VEC,
)
from .solver import newton

STOPPED = 0.05  # rad/s: a joint within this of its backup's target velocity has stopped
BACKUP_WEIGHT = 1e10  # the torque limits' weight in the backup's penalty form (then clipped)
# The backup's q̈ of a joint within NEAR (rad) of its position bound weighs up to 1 +
# NEAR_WEIGHT times another's, linearly in how near.
NEAR, NEAR_WEIGHT = 2.0, 1e3
# The backup holds a joint within HOLD (rad) of its position bound off it, steering it in at
# HOLD_RATE (1/s) per rad inside that band (and past the bound: recovery).
HOLD, HOLD_RATE = 0.2, 10.0
# The tube's D is taken this many times: its linear model of the backup's feedback (each
# free joint pulled to its target at k_b, the torque recomputed from the true state) is first
# order; braked apart on the closed-form arm with 1 kg at the tip from the edge of the
# velocity's interval, D alone let joint 1 pass its bound by 0.015 rad
# (tests/test_viability.py), 1.5 D keeps it inside. An empirical factor, stated as such.
TUBE_SAFETY = 1.5


@no_refcount_jit(cache=True)
def backup_torque(k, a, q, v, mass, bias, out, policy, limit):
    """τ_b at (q, v) into ``out``: the q̈ closest to the backup's k_b (w − (v − q̇_s)) that
    the torques ``limit`` allow (the torque limits, or braking_torque:
    :func:`.policy.choose`), τ_b = M̂ q̈ + b̂ (a small QP in q̈: clipping each τ_i alone
    would turn the coupled arm's braking of one joint into accelerating another), w the
    recovery velocity of a joint outside its position set (into the rollout's R_TARGET row,
    relative to q̇_s). ``policy`` 1 weighs the q̈ of joints near their position bound first
    (0: every joint alike). Returns whether a torque limit binds."""
    n = q.shape[0]
    w = a.work
    r = w.rollout
    target, desired = r[R_TARGET], r[R_SCRATCH]
    for i in range(n):
        x = q[i] - a.centres[0, i]
        # within HOLD of the bound, or past it: back in at HOLD_RATE per rad of depth, up
        # to recovery_speed (a velocity the estimate gets wrong by ε then leaves the joint
        # ε/HOLD_RATE deep in that band, not drifting out)
        depth = abs(x) + a.noise_bound - (a.viable_bounds[0, i] - HOLD)
        speed = 0.0
        if a.hard[0] and depth > 0.0:
            speed = -np.sign(x) * min(a.recovery_speed, HOLD_RATE * depth)
        target[i] = speed
        desired[i] = a.backup_rate * (speed - (v[i] - a.centres[1, i]))
    # Weighted towards the joints near their position bound (what the limits cannot give
    # every joint, those get first): in z = √W q̈ the weights are the identity the solver
    # has, so q̈ = z/√W and a row's coefficients are divided by √W.
    scale = r[R_WEIGHT]
    for i in range(n):
        distance = a.viable_bounds[0, i] - abs(q[i] - a.centres[0, i]) - a.noise_bound
        scale[i] = np.sqrt(1.0 + NEAR_WEIGHT * policy * max(0.0, 1.0 - distance / NEAR))
        desired[i] *= scale[i]
    # The q̈ asked for, where it needs no torque beyond a limit, is the QP's answer as it
    # stands (every row slack): the QP is solved only where a limit binds.
    acceleration = w.backup_solver[TAU]
    for i in range(n):
        acceleration[i] = desired[i] / scale[i]
    product(mass, acceleration, out)
    within = True
    for i in range(n):
        within = within and abs(out[i] + bias[i]) <= limit[i]
    if not within:
        _limited_acceleration(n, limit, mass, bias, scale, desired, w)
        product(mass, acceleration, out)
    binds = False
    for i in range(n):
        torque = out[i] + bias[i]
        binds = binds or abs(torque) >= limit[i] * (1.0 - 1e-9)
        out[i] = min(max(torque, -limit[i]), limit[i])
    return binds


@no_refcount_jit(cache=True, inline="always")
def _limited_acceleration(n, limit, mass, bias, scale, desired, w):
    """The q̈ nearest ``desired`` (in z = √W q̈) whose torque M̂ q̈ + b̂ keeps every finite
    ``limit``, into the backup solver's TAU: the small QP of :func:`backup_torque`."""
    rows, limits, weights = w.backup_rows, w.backup_limits[0], w.backup_limits[1]
    count = 0
    for i in range(n):  # ±(M̂ q̈ + b̂)_i ≤ τ_max,i, scaled to unit rows
        if not np.isfinite(limit[i]):
            continue
        norm = 0.0
        for col in range(n):
            norm += (mass[i, col] / scale[col]) ** 2
        norm = np.sqrt(norm)
        for side in (1.0, -1.0):
            for col in range(n):
                rows[count, col] = side * mass[i, col] / scale[col] / norm
            limits[count] = (limit[i] - side * bias[i]) / norm
            weights[count] = BACKUP_WEIGHT
            count += 1
    acceleration = w.backup_solver[TAU]
    newton(desired, rows, limits, weights, count, 50, 1e-12, w.backup_solver,
           w.matrices[BACKUP_FACTOR], w.backup_binding, False)
    for i in range(n):
        acceleration[i] /= scale[i]


@no_refcount_jit(cache=True)
def rollout_payload(a):
    """The payload the rollout's model carries (kg): the middle of the declared range, so
    that the payload's departure in D spans half the range each way instead of all of it
    one way (on a fast arm the payload's largest share of D, its centripetal and Coriolis
    forces: 85 % of D for the paper's arm at 12 rad/s, 0.5 rad/s error, 0-1 kg; 40 % less D
    about the middle); none where M̂ is the plant's (its payload is in it)."""
    if a.inertia_is_plant:
        return 0.0
    return 0.5 * (a.payload_low + a.payload_high)


@no_refcount_jit(cache=True)
def _payload_deviation(a, q_dot, acceleration, deviation):
    """D_i += the largest |q̈(Δm)_i − q̈(0)_i| over the payload range under the rollout's
    torque (the model's geometry at the rollout's state, its M̂⁻¹ in ROLL_MINV and its q̈
    ``acceleration`` at the velocity ``q_dot``), Δm about the payload the rollout's model
    carries (:func:`rollout_payload`): from low − centre to high − centre.

    A point mass Δm at the payload point (Jacobian J, γ = J̇v − g) moves q̈ by
    −(M̂ + ΔmJᵀJ)⁻¹ΔmJᵀ(Jq̈(0) + γ) = −Σ_j α_j s_j(Δm) v_jᵀ(Jq̈(0) + γ), with
    K = JM̂⁻¹Jᵀ = Σ_j λ_j v_j v_jᵀ, α_j = v_jᵀJM̂⁻¹ and s_j = Δm/(1 + Δmλ_j) (Woodbury; the
    hard rows' structure, :func:`.model.payload_structure`). Linear in the s_j, which all
    increase with Δm: between two points of the payload grid the curve lies in their box,
    where a linear function's extremes are the sums of its terms' (each at one end). Not at
    the range's ends alone: the terms may cancel at both ends and not between (measured on
    the paper's arm braking near its bound: 0.75 rad/s² at the ends, 4.7 at Δm = 0.38 kg).
    Where M̂ is the plant's, the shift is −ΔmM̂⁻¹Jᵀγ: linear in Δm, largest at an end."""
    if a.payload_low == 0.0 and a.payload_high == 0.0:
        return
    w = a.work
    minv = w.matrices[ROLL_MINV]
    jac, gamma = w.point_rows[JAC], w.point_vectors[GAMMA]
    model_payload(a.model, q_dot, 1.0, jac, gamma)
    n, d = q_dot.shape[0], jac.shape[0]
    if a.inertia_is_plant:
        size = max(abs(a.payload_low), abs(a.payload_high))
        for i in range(n):
            shift = 0.0
            for col in range(n):
                for r in range(d):
                    shift += minv[i, col] * jac[r, col] * gamma[r]
            deviation[i] += size * abs(shift)
        return
    # γ + Jq̈(0) into γ: the point's acceleration the payload's force is proportional to
    for r in range(d):
        gamma[r] += dot(jac[r], acceleration)
    structure = w.point_vectors[BETA]  # v_jᵀ(Jq̈(0) + γ), per eigenvector j
    centre = rollout_payload(a)  # the rollout's model carries it: Δm is taken about it
    payload_structure(a.payload_low - centre, a.payload_high - centre, minv, acceleration,
                      w.point_rows, w.point_vectors, w.squares, w.s_grid)
    vec = w.squares[VEC]
    alpha, s_grid = w.point_rows[ALPHA], w.s_grid
    grid = s_grid.shape[0] - 1
    for j in range(d):
        structure[j] = 0.0
        for r in range(d):
            structure[j] += vec[r, j] * gamma[r]
    for i in range(n):
        worst = 0.0
        for g in range(grid):  # the box between grid points g and g + 1: its extremes
            largest = least = 0.0
            for j in range(d):
                weight = -alpha[j, i] * structure[j]
                start, end = weight * s_grid[g, j], weight * s_grid[g + 1, j]
                largest += max(start, end)
                least += min(start, end)
            worst = max(worst, largest, -least)
        deviation[i] += worst


@no_refcount_jit(cache=True)
def fixed_deviation(a, spread):
    """D's part that a rollout with the velocity error ``spread`` keeps at every step, into
    R_QUADRATIC (:func:`.model.quadratic_error_into`: Γ is the hard rows' for the whole
    rollout), so that :func:`deviation_bound` need not take it again."""
    w = a.work
    quadratic_error_into(spread, a.payload_low, a.payload_high, a.disturbance, w.forms[0],
                         w.forms[1], w.rollout[R_QUADRATIC])


@no_refcount_jit(cache=True)
def deviation_bound(a, q_dot, spread, acceleration, deviation):
    """D at the rollout's state into ``deviation``: the bound on |M̂⁻¹(Δb + d)| for a
    velocity error up to ``spread`` (its fixed part taken by :func:`fixed_deviation`) at
    the velocity ``q_dot`` (b's velocity forms Γ as the hard rows took them at row k: the
    configuration's drift over the rollout is left out), plus the payload's
    (:func:`_payload_deviation`): the velocity's and the payload's departures add up (a
    payload's true q̈ also carries the velocity error's)."""
    w = a.work
    friction_error_into(a.model, q_dot, spread, w.rollout[R_FRICTION])
    linear_error_bound_into(q_dot, spread, w.matrices[ROLL_MINV], a.payload_low,
                            a.payload_high, w.forms[0], w.forms[1], w.linear,
                            w.rollout[R_QUADRATIC], w.rollout[R_FRICTION], deviation)
    _payload_deviation(a, q_dot, acceleration, deviation)


@no_refcount_jit(cache=True)
def nominal_acceleration(k, a, first, backup, policy, limit):
    """The rollout's torque (``first``, or the backup's within ``limit`` if ``backup``) into
    R_TAU and the nominal model's q̈ under it into R_ACC; the model's geometry left at the
    rollout's q.
    Returns whether the torque is held or limited (the backup's feedback does not act)."""
    w = a.work
    r, matrices = w.rollout, w.matrices
    q, vel, tau, acc, bias = r[R_Q], r[R_V], r[R_TAU], r[R_ACC], r[R_BIAS]
    mass, minv = matrices[ROLL_MASS], matrices[ROLL_MINV]
    n = q.shape[0]
    model_geometry(a.model, q)
    centre = rollout_payload(a)
    model_mass(a.model, 1.0, centre, mass)
    model_bias(a.model, vel, 1.0, centre, 1.0, bias)
    model_friction(a.model, vel, bias)
    for i in range(n):
        bias[i] += a.tau_d[i]
    binds = True  # a held torque: no feedback over its step
    if backup:
        binds = backup_torque(k, a, q, vel, mass, bias, tau, policy, limit)
    else:
        for i in range(n):
            tau[i] = first[i]
    invert(mass, minv, matrices[ROLL_LU])
    for i in range(n):
        bias[i] = tau[i] - bias[i]
    product(minv, bias, acc)
    return binds


@no_refcount_jit(cache=True)
def _held_drift(k, a, first, limit, eps, widen):
    """Widen the held step's ``widen`` (1.5 D at its start, per joint) by q̈'s drift over
    the hold: the true q̈ over the step lies in the hull of q̈ ± 1.5 D at the step's start
    and at its predicted end (the premise :func:`.interval.predict_interval` takes too), so within
    max(1.5 D, |q̈(end) − q̈| + 1.5 D(end)) of the start's q̈, which the tube's centre
    follows. The rollout's row state (q, q̇, q̈) is the start's again on return."""
    r = a.work.rollout
    q, vel, acc, deviation = r[R_Q], r[R_V], r[R_ACC], r[R_DEV]
    held_q, held_v, held_acc = r[R_HELD_Q], r[R_HELD_V], r[R_HELD_ACC]
    n = q.shape[0]
    for i in range(n):
        held_q[i], held_v[i], held_acc[i] = q[i], vel[i], acc[i]
        q[i] += a.dt * vel[i] + 0.5 * a.dt * a.dt * acc[i]
        vel[i] += a.dt * acc[i]
    nominal_acceleration(k, a, first, False, 0, limit)
    deviation_bound(a, vel, eps, acc, deviation)
    for i in range(n):
        widen[i] = max(widen[i], abs(acc[i] - held_acc[i]) + TUBE_SAFETY * deviation[i])
        q[i], vel[i], acc[i] = held_q[i], held_v[i], held_acc[i]


@no_refcount_jit(cache=True)
def backup_at(k, a, policy, limit, out):
    """The backup's torque at row k (its position, the velocity interval's centre) with
    ``policy`` within the torques ``limit``, as the rollout computes it, into ``out``."""
    r = a.work.rollout
    y = a.position[k]
    for i in range(y.shape[0]):
        r[R_Q, i], r[R_V, i] = y[i], r[R_CENTRE, i]
    nominal_acceleration(k, a, out, True, policy, limit)
    for i in range(y.shape[0]):
        out[i] = r[R_TAU, i]


@no_refcount_jit(cache=True)
def plan_box(k, a):
    """The box the plan in force (the rollout of the last torque verified, at step k0) puts
    the true state in at row k + 1, into R_BOX_Q … R_BOX_V_HALF: its tube (k + 1 − k0)·dt
    after its start, within the segment holding that time (the nominal state exactly, q̈
    constant over a segment; δq, δv as the check grows them). NaN past the rollout's end.
    The classifier holds the true state to it (the tube measured along the run)."""
    w = a.work
    r = w.rollout
    n = r.shape[1]
    for i in range(n):
        r[R_BOX_Q, i] = r[R_BOX_Q_HALF, i] = r[R_BOX_V, i] = r[R_BOX_V_HALF, i] = np.nan
    plan = int(w.flags[PLAN_TUBE])
    tube, lengths, eps = w.tube[plan], w.tube_steps[plan], w.tube_eps[plan]
    offset = (k + 1 - w.flags[PLAN_STEP]) * a.dt
    start = 0.0
    for j in range(lengths.shape[0]):
        h = lengths[j]
        if h <= 0.0:
            return
        if offset <= start + h * (1.0 + 1e-9):
            s = offset - start
            segment = tube[j]
            for i in range(n):
                r[R_BOX_Q, i] = (segment[T_Q, i] + s * segment[T_V, i]
                                 + 0.5 * s * s * segment[T_ACC, i])
                r[R_BOX_Q_HALF, i] = (segment[T_DQ, i] + s * segment[T_DV, i]
                                      + 0.5 * s * s * segment[T_WIDEN, i])
                r[R_BOX_V, i] = segment[T_V, i] + s * segment[T_ACC, i]
                share = segment[T_FEEDBACK, i] * s / h
                r[R_BOX_V_HALF, i] = max(segment[T_DV, i] * (1.0 - share) + share * eps[i]
                                         + segment[T_WIDEN, i] * s, eps[i])
            return
        start += h


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
def verified(k, a, y, v, eps, first, hold, policy, limit):
    """Whether the backup keeps every hard set from the estimate (y, v) (|q − y| ≤ n̄,
    |q̇ − v| ≤ ε), after ``first`` is held for one step if ``hold`` (module docstring), with
    the backup's ``policy`` within the torques ``limit`` (the torque limits or less)."""
    w = a.work
    r = w.rollout
    q, vel, dq, dv, acc = r[R_Q], r[R_V], r[R_DQ], r[R_DV], r[R_ACC]
    limit_q, limit_v, deviation, widen = r[R_LIMIT_Q], r[R_LIMIT_V], r[R_DEV], r[R_WIDEN]
    n = y.shape[0]
    for i in range(n):
        if not eps[i] < np.inf:  # nothing known of the velocity: nothing is verified
            return False
    trial = int(w.flags[TUBE_TRIAL])  # the rollout is kept here; the plan, if verified
    tube, lengths = w.tube[trial], w.tube_steps[trial]
    for i in range(n):
        q[i], vel[i], dq[i], dv[i] = y[i], v[i], a.noise_bound, eps[i]
        # what each set allows: its bound, or the excess it starts with (recovery)
        limit_q[i] = max(a.viable_bounds[0, i], abs(y[i] - a.centres[0, i]) + a.noise_bound)
        limit_v[i] = max(a.viable_bounds[1, i], abs(v[i] - a.centres[1, i]) + eps[i])
        r[R_TARGET, i] = 0.0
        w.tube_eps[trial, i] = eps[i]
    fixed_deviation(a, eps)
    t = 0.0
    step = 0
    # where the rollout's step is the control step (backup_step is at least dt), each of its
    # steps is a torque the filter holds over the whole step: q̈'s drift over it is taken
    held = a.backup_step <= a.dt
    while t < a.backup_horizon and step < lengths.shape[0]:
        backup = not (hold and step == 0)
        h = a.backup_step if backup else a.dt
        clipped = nominal_acceleration(k, a, first, backup, policy, limit)
        # the bias error's velocity error is the estimate's, ε: the backup acts on the
        # state as measured, whatever the tube (the true state's spread about the rollout)
        deviation_bound(a, vel, eps, acc, deviation)
        for i in range(n):
            widen[i] = TUBE_SAFETY * deviation[i]
        if held:
            _held_drift(k, a, r[R_TAU], limit, eps, widen)
        decay = np.exp(-a.recovery_rate * (t + h))
        stopped = backup and not clipped
        segment = tube[step]
        for i in range(n):
            # the backup's feedback acts on a joint whose torque is free (the held torque:
            # on none): a limited joint brakes as hard as it can, the others still steer
            free = backup and abs(r[R_TAU, i]) < limit[i] * (1.0 - 1e-9)
            feedback = feedback_contraction(a.backup_rate, h, a.dt) if free else 0.0
            segment[T_Q, i], segment[T_V, i], segment[T_ACC, i] = q[i], vel[i], acc[i]
            segment[T_DQ, i], segment[T_DV, i] = dq[i], dv[i]
            segment[T_WIDEN, i], segment[T_FEEDBACK, i] = widen[i], feedback
            # exact for q̈ constant over the step (the position's error would be ~v·h/2),
            # with its turning point inside the step checked too
            turn = q[i]
            if vel[i] * acc[i] < 0.0 and abs(vel[i]) < abs(acc[i]) * h:
                turn = q[i] - 0.5 * vel[i] * vel[i] / acc[i]
            q[i] += h * vel[i] + 0.5 * h * h * acc[i]
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
                return False
            if a.hard[1] and abs(vel[i] - a.centres[1, i]) + dv[i] > allowed_v:
                return False
            stopped = stopped and abs(vel[i] - a.centres[1, i] - r[R_TARGET, i]) <= STOPPED
        lengths[step] = h
        t += h
        step += 1
        if stopped:
            if step < lengths.shape[0]:
                lengths[step] = 0.0  # the rollout's end
            # verified: this rollout is the plan (the next check writes the other buffer)
            w.flags[PLAN_TUBE], w.flags[TUBE_TRIAL] = trial, 1 - trial
            w.flags[PLAN_STEP] = k
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
    minv, bias, base = matrices[MINV], vectors[BIAS], vectors[BASE]
    nominal_model(a, y, v, matrices[NOMINAL_NOW], bias)
    invert(matrices[NOMINAL_NOW], minv, matrices[LU])
    product(minv, bias, base)
    robust_model(a, y, v, eps, minv, base)
    # nothing held: bias unread
    return verified(0, a, y, v, eps, bias, False, policy, a.torque_limit)
