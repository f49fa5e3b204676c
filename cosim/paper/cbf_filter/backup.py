"""The braking backup the filter falls back on, and whose rollout its check verifies
(:mod:`.check`): the torque that steers every joint to a stop inside its sets.

The backup: q̈_b = k_b (w − (v − q̇_s)) in the nominal model, τ_b = M̂ q̈_b + b̂ (the q̈
nearest that the torque limits allow, a small QP, or a lower braking_torque where the filter
asks for it), each τ_i clipped to that limit (so the torque limits hold whatever it asks);
w = 0 inside the position set away from its bound, inward at HOLD_RATE per rad within HOLD
of the bound (a persistent velocity error ε then holds the joint ε/HOLD_RATE deep in that
band instead of letting it drift out), and at up to ``recovery_speed`` past it (recovery).

The rollout's model carries the middle of the declared payload range
(:func:`rollout_payload`); :func:`nominal_acceleration` is one rollout step's torque and q̈.
"""

from __future__ import annotations

import numpy as np

from ...dynamics.model import model_bias, model_friction, model_geometry, model_mass
from ...numba_compat import no_refcount_jit
from ..linalg import invert, product
from .scratch import Matrix, Rollout, Solver
from .solver import newton

BACKUP_WEIGHT = 1e10  # the torque limits' weight in the backup's penalty form (then clipped)
# The backup's q̈ of a joint within NEAR (rad) of its position bound weighs up to 1 +
# NEAR_WEIGHT times another's, linearly in how near.
NEAR, NEAR_WEIGHT = 2.0, 1e3
# The backup holds a joint within HOLD (rad) of its position bound off it, steering it in at
# HOLD_RATE (1/s) per rad inside that band (and past the bound: recovery).
HOLD, HOLD_RATE = 0.2, 10.0


@no_refcount_jit(cache=True)
def backup_torque(k, a, q, v, mass, bias, out, policy, limit):
    """τ_b at (q, v) into ``out``: the q̈ closest to the backup's k_b (w − (v − q̇_s)) that
    the torques ``limit`` allow (the torque limits, or braking_torque:
    :func:`.policy.choose`), τ_b = M̂ q̈ + b̂ (a small QP in q̈: clipping each τ_i alone
    would turn the coupled arm's braking of one joint into accelerating another), w the
    recovery velocity of a joint outside its position set (into Rollout.TARGET, relative to
    q̇_s). ``policy`` 1 weighs the q̈ of joints near their position bound first
    (0: every joint alike). Returns whether a torque limit binds."""
    n = q.shape[0]
    w = a.work
    r = w.rollout
    target, desired = r[Rollout.TARGET], r[Rollout.SCRATCH]
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
    scale = r[Rollout.WEIGHT]
    for i in range(n):
        distance = a.viable_bounds[0, i] - abs(q[i] - a.centres[0, i]) - a.noise_bound
        scale[i] = np.sqrt(1.0 + NEAR_WEIGHT * policy * max(0.0, 1.0 - distance / NEAR))
        desired[i] *= scale[i]
    # The q̈ asked for, where it needs no torque beyond a limit, is the QP's answer as it
    # stands (every row slack): the QP is solved only where a limit binds.
    acceleration = w.backup_solver[Solver.TAU]
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
    ``limit``, into the backup solver's Solver.TAU: the small QP of :func:`backup_torque`."""
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
    acceleration = w.backup_solver[Solver.TAU]
    newton(desired, rows, limits, weights, count, 50, 1e-12, w.backup_solver,
           w.matrices[Matrix.BACKUP_FACTOR], w.backup_binding, False)
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
def nominal_acceleration(k, a, first, backup, policy, limit):
    """The rollout's torque (``first``, or the backup's within ``limit`` if ``backup``) into
    Rollout.TAU and the nominal model's q̈ under it into Rollout.ACC; the model's geometry
    left at the rollout's q. Returns whether the torque is held or limited (the backup's
    feedback does not act)."""
    w = a.work
    r, matrices = w.rollout, w.matrices
    q, vel, tau = r[Rollout.Q], r[Rollout.V], r[Rollout.TAU]
    acc, bias = r[Rollout.ACC], r[Rollout.BIAS]
    mass, minv = matrices[Matrix.ROLL_MASS], matrices[Matrix.ROLL_MINV]
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
    invert(mass, minv, matrices[Matrix.ROLL_LU])
    for i in range(n):
        bias[i] = tau[i] - bias[i]
    product(minv, bias, acc)
    return binds


@no_refcount_jit(cache=True)
def backup_at(k, a, policy, limit, out):
    """The backup's torque at row k (its position, the velocity interval's centre) with
    ``policy`` within the torques ``limit``, as the rollout computes it, into ``out``."""
    r = a.work.rollout
    y = a.position[k]
    for i in range(y.shape[0]):
        r[Rollout.Q, i], r[Rollout.V, i] = y[i], r[Rollout.CENTRE, i]
    nominal_acceleration(k, a, out, True, policy, limit)
    for i in range(y.shape[0]):
        out[i] = r[Rollout.TAU, i]
