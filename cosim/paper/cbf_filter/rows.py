"""The rows of one step's QP: G τ ≤ h, each scaled to unit norm, with its weight, kind and
joint; the hard rows robust to the declared uncertainty (see the package docstring), kept in
groups (a joint's side of a set, a row per payload corner, unscaled: :mod:`.groups`) that the
solve takes rows from as it needs them (cutting planes), the soft (tracking) rows, and the
torque limits; and the barrier values the step reports."""

from __future__ import annotations

import numpy as np

from ...numba_compat import no_refcount_jit
from ..linalg import dot, invert, product
from .groups import add_corner, hard_groups
from .interval import velocity_interval
from .model import moved_model, nominal_model
from .scratch import Flag, GroupLabel, Matrix, Vector
from .solver import add_row


@no_refcount_jit(cache=True)
def cbf_rows(k, a):
    """Fill G (``a.rows``), h (``a.limits``), the weights and the hard flags of row k's whole
    QP, every hard row of the groups first (each payload corner's, in the groups' order),
    and the true velocity's interval; returns the number of rows."""
    return step_rows(k, a, True)


@no_refcount_jit(cache=True, inline="always")
def step_rows(k, a, every):
    """Row k's QP: the hard rows in groups (:func:`.groups.hard_groups`), each of their
    rows first if ``every`` (:func:`cbf_rows`), else none (the step's solve adds those it
    needs: :func:`.groups.add_cuts`); then the soft rows and the torque limits as rows; the barrier
    values and the true velocity's interval. Returns the number of rows."""
    vectors, matrices = a.work.vectors, a.work.matrices
    y, v, eps = a.position[k], a.velocity[k], a.velocity_bound[k]
    mass = a.M_model[k]
    # u = M̂⁻¹τ − base
    minv, bias, base = matrices[Matrix.MINV], vectors[Vector.BIAS], vectors[Vector.BASE]
    nominal_model(a, y, v, matrices[Matrix.NOMINAL_NOW], bias)
    invert(mass, minv, matrices[Matrix.LU])
    product(minv, bias, base)
    velocity_interval(k, a)
    a.work.flags[Flag.GROUPS] = 0.0
    a.work.flags[Flag.CHECKED_ROW] = 0.0  # no check's hull is this row's yet
    # ε infinite (the observer confirmed no enclosure of q̇): no hard row holds for every
    # velocity, and none is made; the check verifies nothing from such a state either
    known = True
    for i in range(y.shape[0]):
        known = known and eps[i] < np.inf
    if known:
        hard_groups(a, k, y, v, eps, minv, base, False)
    _predict_hold(k, a, y, v, minv, base)
    y_end, v_end = vectors[Vector.Y_END], vectors[Vector.V_END]
    minv_end, base_end = matrices[Matrix.MINV_END], vectors[Vector.BASE_END]
    moved_model(a, y_end, v_end, mass, minv_end, base_end)
    if known:
        hard_groups(a, k, y_end, v_end, eps, minv_end, base_end, True)
    # The soft rows take the plant's q̈ averaged over the hold (the midpoint rule: at the bound
    # of a set, q̈'s drift within one 1 ms hold is what would carry the state across), and
    # how v moves: the observer's drift + M̂⁻¹τ (the observer holds M̂ over the step), or the
    # plant's q̈ for the plant's q̇.
    minv_mid, base_mid = matrices[Matrix.MINV_MID], vectors[Vector.BASE_MID]
    moved_model(a, vectors[Vector.Y_MID], vectors[Vector.V_MID], mass, minv_mid, base_mid)
    observed = np.isfinite(a.drift[k, 0])
    rate_minv = minv if observed else minv_mid
    _set_states(k, a, y, v, observed, base_mid)
    _barrier_values(k, a, eps)
    count = 0
    if every:
        for g in range(int(a.work.flags[Flag.GROUPS])):
            for c in range(a.work.group_labels[g, GroupLabel.CORNERS]):
                count = add_corner(a, count, g, c)
    for s in range(4):
        count = _soft_rows(k, a, count, s, rate_minv, minv_mid, base_mid)
    return _torque_rows(a, count)


@no_refcount_jit(cache=True)
def _predict_hold(k, a, y, v, minv, base):
    """The states at the hold's end and midpoint (Vector.Y_END … Vector.V_MID),
    predicted with the torque of the step before (the nominal model's q̈)."""
    vectors = a.work.vectors
    held = a.tau[k - 1] if k > 0 else a.tau_nominal[k]
    acceleration = vectors[Vector.ACCELERATION]
    product(minv, held, acceleration)
    y_end, v_end = vectors[Vector.Y_END], vectors[Vector.V_END]
    y_mid, v_mid = vectors[Vector.Y_MID], vectors[Vector.V_MID]
    for i in range(y.shape[0]):
        acceleration[i] -= base[i]
        y_end[i] = y[i] + a.dt * v[i] + 0.5 * a.dt * a.dt * acceleration[i]
        v_end[i] = v[i] + a.dt * acceleration[i]
        y_mid[i] = y[i] + 0.5 * a.dt * v[i] + 0.125 * a.dt * a.dt * acceleration[i]
        v_mid[i] = v[i] + 0.5 * a.dt * acceleration[i]


@no_refcount_jit(cache=True)
def _set_states(k, a, y, v, observed, base_mid):
    """Each set's x (Vector.X …, SETS order) and how v moves (Vector.DRIFT):
    the observer's drift, else the plant's q̈ less M̂⁻¹τ at the hold's midpoint."""
    vectors = a.work.vectors
    drift, x = vectors[Vector.DRIFT], vectors[Vector.X:Vector.X + 4]
    for i in range(y.shape[0]):
        drift[i] = a.drift[k, i] if observed else -base_mid[i]
        x[0, i] = y[i] - a.centres[0, i]
        x[1, i] = v[i] - a.centres[1, i]
        x[2, i] = a.q_d[k, i] - y[i]
        x[3, i] = a.qdot_d[k, i] - v[i]


@no_refcount_jit(cache=True)
def _barrier_values(k, a, eps):
    """Row k's barrier values per set and joint (robust: the worst case of the true state
    within the declared bounds) and as norms, their activity cleared for the record."""
    x = a.work.vectors[Vector.X:Vector.X + 4]
    for s in range(4):
        beta_s = a.bounds[s]
        tight = 0.0  # the worst case of the true state within the declared bounds
        for i in range(x.shape[1]):
            if s == 0:
                tight = a.noise_bound
            elif s == 1:
                tight = eps[i]
            beta_i = a.joint_bounds[s, i] if s < 2 else beta_s
            a.h_sets[s, k, i] = beta_i - abs(x[s, i]) - tight
            a.active_sets[s, k, i] = 0.0
        xs = x[s]
        a.h_norms[s, k] = beta_s - np.sqrt(dot(xs, xs))
        a.active_norms[s, k] = 0.0


@no_refcount_jit(cache=True)
def _soft_rows(k, a, count, s, rate_minv, minv_mid, base_mid):
    """The soft rows of set s: per joint and side (if ``a.soft[s]``), then as a norm,
    h = β² − ‖x‖² (if ``a.soft_norms[s]``); returns the next row's index."""
    vectors = a.work.vectors
    drift, x, row = vectors[Vector.DRIFT], vectors[Vector.X:Vector.X + 4], vectors[Vector.ROW]
    qp = (a.rows, a.limits, a.weights, a.is_hard, a.kinds, a.joints)
    rate_error = x[3]  # q̇_d − v
    beta_s = a.bounds[s]
    n = row.shape[0]
    if a.soft[s]:
        for i in range(n):
            beta_i = a.joint_bounds[s, i] if s < 2 else beta_s
            for side in (1.0, -1.0):
                h = beta_i - side * x[s, i]
                if s == 2:  # e = q_d − y: −side·q̈_i ≤ −side q̈_d − 2p side ė + p² h
                    for col in range(n):
                        row[col] = -side * minv_mid[i, col]
                    bound = (-side * a.qddot_d[k, i] - a.tracking_k1 * side * rate_error[i]
                             + a.tracking_k0 * h - side * base_mid[i])
                else:  # ė = q̇_d − v: −side·(M̂⁻¹τ)_i ≤ −side q̈_d + side drift_i + k h
                    for col in range(n):
                        row[col] = -side * rate_minv[i, col]
                    bound = -side * a.qddot_d[k, i] + side * drift[i] + a.k_velocity * h
                count = add_row(qp, count, row, bound, a.rho_soft, False, s, i)
    if not a.soft_norms[s]:
        return count
    xs = x[s]
    norm = np.sqrt(dot(xs, xs))
    h = beta_s * beta_s - norm * norm
    if s == 2:  # ḧ = −2‖ė‖² − 2eᵀ(q̈_d − q̈), ḣ = −2eᵀė
        for col in range(n):
            row[col] = -2.0 * dot(xs, minv_mid[:, col])
        bound = (-2.0 * dot(rate_error, rate_error) - 2.0 * dot(xs, a.qddot_d[k])
                 - 2.0 * dot(xs, base_mid) - 2.0 * a.tracking_k1 * dot(xs, rate_error)
                 + a.tracking_k0 * h)
    else:  # ḣ = −2ėᵀ(q̈_d − dv/dt)
        for col in range(n):
            row[col] = -2.0 * dot(xs, rate_minv[:, col])
        bound = -2.0 * dot(xs, a.qddot_d[k]) + 2.0 * dot(xs, drift) + a.k_velocity * h
        # Over a hold h also loses ‖Δx‖² (the set is round, the step straight): a
        # state sliding along the bound would leave it by that much each step, so the
        # rate asked for is less by ‖Δx‖²/step, Δx taken from the step before.
        if k > 0:
            change = 0.0
            for i in range(n):
                change += (xs[i] - (a.qdot_d[k - 1, i] - a.velocity[k - 1, i])) ** 2
            bound -= change / a.dt
    return add_row(qp, count, row, bound, a.rho_soft, False, 4 + s, -1)


@no_refcount_jit(cache=True)
def _torque_rows(a, count):
    """The finite torque limits |τ_i| ≤ τ_max,i as hard rows; returns the next row's
    index."""
    row = a.work.vectors[Vector.ROW]
    qp = (a.rows, a.limits, a.weights, a.is_hard, a.kinds, a.joints)
    n = row.shape[0]
    for i in range(n):
        if not np.isfinite(a.torque_limit[i]):
            continue
        for side in (1.0, -1.0):
            for col in range(n):
                row[col] = side if col == i else 0.0
            count = add_row(qp, count, row, a.torque_limit[i], a.rho_hard, True, -1, i)
    return count
