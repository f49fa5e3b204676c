"""A robust output-feedback CBF-QP safety filter: after any nominal controller, the torque
closest to the nominal one that keeps the *true* state in the physical sets, for every plant
and state the declared uncertainty allows (SPEC §7, README "The safety filter").

Sets, per joint i, each side of |x_i| ≤ β a barrier h = β − side·x_i:

    hard (physical, the true state)      position  x = q − q_s      degree 2
                                         velocity  x = q̇ − q̇_s     degree 1
    soft (tracking, weighted)            error     x = q_d − y      degree 2
                                         error rate x = q̇_d − v    degree 1

(and soft as norms, h = β² − ‖x‖²), with the conditions ḧ + 2p ḣ + p² h ≥ 0 (degree 2, an
exponential CBF, critically damped) and ḣ + k h ≥ 0 (degree 1).

What the filter knows: the measured y, the velocity v it is given (the observer's x̂2, or the
plant's q̇ for a full-state run), the observer's bound ε(t) on |q̇ − v| and the drift of x̂2,
the inertia model M̂, and the nominal chain (published by the inertia model) for
b̂ = C(y, v) v + G(y) + τ_d. The plant is q̈ = M⁻¹(τ − b − τ_d), and what is declared
(``[uncertainty]``) bounds the difference:

- |q − y| ≤ n̄ (noise bound) and |q̇ − v| ≤ ε(t): the hard rows take the worst case of
  each (p²·n̄, 2p·ε and k·ε), and a velocity row the worst case of the true barrier,
  max(h − ε, 0) (it is ≥ 0 until the set is first left);
- a payload Δm ∈ [low, high] at the last link's centre of mass c, Jacobian J (2×n):
  M = M̂ + Δm JᵀJ, b = b̂ + Δm Jᵀγ with γ = J̇q̇ + g ŷ. Then exactly
  q̈ = u − M̂⁻¹Jᵀ S (J u + γ), u = M̂⁻¹(τ − b̂), S = Δm (I + Δm K)⁻¹, K = J M̂⁻¹ Jᵀ;
  in K's eigenvectors S is diagonal with entries s_j(Δm) increasing in Δm, and a row is
  linear in (s_1, s_2). Split the range in ``payload_grid`` intervals: on each, (s_1, s_2)
  lies in the box of its end values, so the worst case is at a box corner: 3G + 1 linear
  rows in τ, never optimistic, exact as G grows. (When M̂ is the plant's own M, only b
  differs: q̈ = u − Δm M̂⁻¹Jᵀγ, the worst case at one end of the range.)
- b̂'s own error from the velocity error: b's velocity part is a quadratic form vᵀΓ_l v, so
  Δb = B δ + (δᵀΓ_l δ)_l with B_lj = 2 Σ_k Γ_l,jk v_k (Γ of the nominal chain plus the
  payload's); a row of joint i is tightened by Σ_j |(M̂⁻¹B)_ij| ε_j (its worst end of the
  payload range) + Σ_l |(M̂⁻¹)_il| (Σ_jk |Γ_l,jk| ε_j ε_k + d̄), d̄ the disturbance bound.

Solved as min ½‖τ − τ_nom‖² + ½ρ_s‖s‖² subject to G_hard τ ≤ h_hard and
G_soft τ ≤ h_soft + s (and |τ_i| ≤ τ_max, hard), every row scaled to unit norm (N·m). The
compiled semismooth Newton solves the penalty form with the hard rows at weight ρ_hard and
their limits lowered by ``hard_tolerance``; where a hard row still slips (tracking pulling
hard against it), it re-solves with the soft weights 1e-3 and 1e-6 times, then without the
soft rows; only if the hard rows alone are violated (as given) is the hard part infeasible
at that step (``cbf_infeasible`` =
1, counted), and the **backup** acts: by default the penalty form's answer itself (the
torque that violates the hard rows least), or braking, q̈ = −k (v − q̇_s) with the nominal
model, within the torque limit (``backup = "brake"``). Soft slack is reported apart
(``cbf_slack``): it says how much tracking gave way, never whether safety did.

Remaining assumptions (not covered by the margins): the sampled-data hold between steps
(``bound_margin`` keeps a fraction of each bound for it), and M̂, b̂ evaluated at y rather than
q (first order in n̄). The safe centres q_s, q̇_s must be constant (Remark 1, case ii): a
moving centre is refused.
"""

from __future__ import annotations

from typing import Annotated, Literal, NamedTuple

import numpy as np
from numba import njit
from pydantic import Field

from ..schema import FiniteFloat, PipelineError, PositiveFloat, Section
from ..signals import Signal
from .base import Block, BlockContext, Ports, register_block
from .inertia import planar_bias, planar_mass_matrix

SETS = ("position", "velocity", "error", "error_rate")
HardSet = Literal["position", "velocity"]
SoftSet = Literal["error", "error_rate"]


class CbfFilterParams(Section):
    hard: list[HardSet] = ["position", "velocity"]  # physical sets, per joint, guaranteed
    soft: list[SoftSet] = ["error", "error_rate"]  # tracking sets, per joint, weighted
    soft_norms: list[SoftSet] = ["error", "error_rate"]  # tracking sets as norms, weighted
    # p of the hard degree-2 (position) conditions (k1 = 2p, k0 = p²), 1/s. A model error D
    # (rad/s²) keeps the joint D/p² from its bound and the velocity error ε keeps it 2ε/p:
    # a fast p costs less tracking where the reference runs along a bound; p·step ≪ 1.
    position_rate: PositiveFloat = 30.0
    # p of the soft error rows (degree 2), 1/s. A slow p also caps how fast an error may
    # shrink (ḧ ≥ −2p ḣ − p² h on the far side of the set), which holds a fast tracking
    # controller back: the tracking rows are as fast as the controller they watch.
    tracking_rate: PositiveFloat = 100.0
    # k of degree-1 conditions, 1/s: under a model error D (rad/s²) a velocity set keeps a
    # margin D/k, so a fast rate costs little; k·step ≪ 1 for the 1 ms hold.
    velocity_rate: PositiveFloat = 100.0
    velocity: Literal["observer", "plant"] = "observer"  # x̂2 (with its ε), or the true q̇
    # A fraction of every bound kept for the sampled-data hold between steps (1 ms).
    bound_margin: Annotated[float, Field(ge=0, lt=1)] = 0.002
    torque_limit: PositiveFloat | None = None  # |τ_i| ≤ this, N·m (hard)
    # ρ_s: the cost of 1 N·m of soft violation, squared, against τ's: high, so that tracking
    # gives way only where it conflicts with a hard row (ρ_hard is 1e4 times more)
    tracking_weight: PositiveFloat = 1e6
    hard_weight: PositiveFloat = 1e10  # ρ_hard of the penalty form (then checked exactly)
    hard_tolerance: PositiveFloat = 1e-4  # N·m: the hard limits are lowered by this
    # When the hard part is infeasible: "least_violation", the penalty form's answer (the
    # torque that violates the hard rows least, in least squares, then tracks), or "brake",
    # q̈ = −k (v − q̇_s) with the nominal model and k = backup_rate, within the torque limit.
    backup: Literal["least_violation", "brake"] = "least_violation"
    backup_rate: PositiveFloat = 20.0  # 1/s
    # The payload's worst case is taken over the corners of `payload_grid` boxes that cover
    # the curve (s_1(Δm), s_2(Δm)): exact as it grows, conservative by a box's size.
    payload_grid: Annotated[int, Field(ge=1, le=32)] = 4
    tau_d: FiniteFloat | list[FiniteFloat] | None = None  # N·m; None: the observer's model
    solver: str = "newton"  # or a qpsolvers solver: daqp, osqp, clarabel, proxqp, quadprog
    iterations: Annotated[int, Field(ge=1, le=1000)] = 50  # Newton steps at most
    tolerance: PositiveFloat = 1e-12  # on the gradient, relative to ‖τ_nom‖


class CbfArgs(NamedTuple):
    hard: np.ndarray  # (4,) 1 where the set is a hard per-joint set, SETS order
    soft: np.ndarray  # (4,) 1 where it is a soft per-joint set
    soft_norms: np.ndarray  # (4,) 1 where it is a soft norm set
    bounds: np.ndarray  # (4,) β per set, bound_margin applied
    k1: float  # 2p
    k0: float  # p²
    tracking_k1: float  # 2p of the soft error rows
    tracking_k0: float  # p²
    k_velocity: float
    dt: float  # the hold, s
    torque_limit: float  # inf: none
    rho_soft: float
    rho_hard: float
    hard_tolerance: float
    brake: bool  # the backup: braking (else the least-violation answer)
    backup_rate: float
    payload_grid: int
    iterations: int
    tolerance: float
    noise_bound: float  # n̄, rad
    payload_low: float  # kg
    payload_high: float
    disturbance: float  # d̄, N·m
    inertia_is_plant: bool
    m: np.ndarray  # the nominal chain
    l: np.ndarray  # noqa: E741
    lc: np.ndarray
    inertia: np.ndarray
    gravity: float
    tau_d: np.ndarray
    rows: np.ndarray  # scratch: (rows, n) G, unit rows
    limits: np.ndarray  # scratch: (rows,) h
    weights: np.ndarray  # scratch: (rows,) ρ of each row
    is_hard: np.ndarray  # scratch: (rows,) 1 for hard rows
    kinds: np.ndarray  # (rows,) set index of each row (4 + set for norms, -1 torque)
    joints: np.ndarray  # (rows,) joint of each row (-1: a norm)
    multipliers: np.ndarray  # (rows,) nonzero where a row binds
    backup: np.ndarray  # (n,) the braking torque of this step
    position: np.ndarray
    velocity: np.ndarray
    velocity_bound: np.ndarray  # ε per row and joint (zeros for the plant's q̇)
    drift: np.ndarray  # dv/dt − M̂⁻¹τ per row and joint (NaN: use the nominal model)
    q_s: np.ndarray
    qdot_s: np.ndarray
    q_d: np.ndarray
    qdot_d: np.ndarray
    qddot_d: np.ndarray
    M_model: np.ndarray
    tau_nominal: np.ndarray
    tau: np.ndarray
    h_sets: np.ndarray  # (4, rows, n) robust h per set and joint
    active_sets: np.ndarray  # (4, rows, n)
    h_norms: np.ndarray  # (4, rows) β − ‖x‖
    active_norms: np.ndarray  # (4, rows)
    slack: np.ndarray
    active: np.ndarray
    correction: np.ndarray
    infeasible: np.ndarray


@njit(cache=True)
def com_kinematics(q, v, l, lc, gravity):  # noqa: E741
    """The last link's centre of mass c: its Jacobian J (2×n) and γ = J̇ v + g ŷ, the
    acceleration a point mass there needs beyond J q̈ (gravity along −y)."""
    n = q.shape[0]
    theta = np.empty(n)
    omega = np.empty(n)
    t, w = 0.0, 0.0
    for i in range(n):
        t += q[i]
        w += v[i]
        theta[i], omega[i] = t, w
    jac = np.zeros((2, n))
    gamma = np.zeros(2)
    gamma[1] = gravity
    for k in range(n):
        length = lc[k] if k == n - 1 else l[k]
        cx, cy = length * np.cos(theta[k]), length * np.sin(theta[k])
        for j in range(k + 1):
            jac[0, j] -= cy
            jac[1, j] += cx
        gamma[0] -= omega[k] ** 2 * cx
        gamma[1] -= omega[k] ** 2 * cy
    return jac, gamma


@njit(cache=True)
def velocity_forms(q, m, l, lc, inertia):  # noqa: E741
    """Γ (n, n, n): b's velocity part b_i(v) = vᵀ Γ_i v of the chain (gravity 0), by
    polarisation of the recursive Newton–Euler bias."""
    n = q.shape[0]
    gamma = np.zeros((n, n, n))
    plus, minus = np.zeros(n), np.zeros(n)
    e = np.zeros(n)
    for j in range(n):
        for k in range(j, n):
            e[:] = 0.0
            e[j] += 1.0
            e[k] += 1.0
            planar_bias(q, e, m, l, lc, inertia, 0.0, plus)
            e[k] -= 2.0
            planar_bias(q, e, m, l, lc, inertia, 0.0, minus)
            for i in range(n):
                # b_i(a + c) − b_i(a − c) = 4 aᵀΓ_i c (and e_j ± e_j = 2e_j, 0 for j = k)
                gamma[i, j, k] = gamma[i, k, j] = (plus[i] - minus[i]) / 4.0
    return gamma


@njit(cache=True, inline="always")
def acceleration_error_bound(q, v, eps, minv, a, nominal):
    """Per joint i, a bound on |(M̂⁻¹(b(q, q̇) − b(q, v)))_i + (M̂⁻¹d)_i| for |q̇_j − v_j| ≤ ε_j
    and a disturbance |d_l| ≤ d̄. b's velocity part is b_l(v) = vᵀΓ_l v (``nominal``, plus
    Δm times a unit payload's), so b(v + δ) − b(v) = B δ + (δᵀΓ_l δ)_l with
    B_lj = 2 Σ_k Γ_l,jk v_k: the linear part through M̂⁻¹B keeps its cancellations (in a
    stretched arm most of the Coriolis force is radial: no torque), the quadratic part and
    d̄ are bounded row by row. Affine in Δm, so the worst case is at an end of its range."""
    n = q.shape[0]
    unit = np.zeros(n)
    unit[n - 1] = 1.0
    payload = velocity_forms(q, unit, a.l, a.lc, np.zeros(n))
    size = max(abs(a.payload_low), abs(a.payload_high))
    linear = np.zeros((2, n, n))  # B for the nominal chain plus each end of the payload range
    quadratic = np.full(n, a.disturbance)
    for l in range(n):  # noqa: E741
        for j in range(n):
            for k in range(n):
                for end in range(2):
                    mass = a.payload_low if end == 0 else a.payload_high
                    linear[end, l, j] += 2.0 * (nominal[l, j, k] + mass * payload[l, j, k]) * v[k]
                quadratic[l] += (abs(nominal[l, j, k]) + size * abs(payload[l, j, k])) \
                    * eps[j] * eps[k]
    out = np.zeros(n)
    for i in range(n):
        for j in range(n):
            worst = 0.0
            for end in range(2):
                value = 0.0
                for l in range(n):  # noqa: E741
                    value += minv[i, l] * linear[end, l, j]
                worst = max(worst, abs(value))
            out[i] += worst * eps[j]
        for l in range(n):  # noqa: E741
            out[i] += abs(minv[i, l]) * quadratic[l]
    return out


@njit(cache=True, inline="always")  # a's many fields are not copied per call
def _add_row(a, count, row, limit, weight, hard, kind, joint):
    _finish_row(a, count, limit, weight, hard, kind, joint, row)
    return count + 1


@njit(cache=True, inline="always")
def _finish_row(a, count, limit, weight, hard, kind, joint, row):
    """Row ``count`` of the QP from ``row`` (written into ``a.rows[count]`` scaled to unit
    norm, N·m), its limit, weight and labels; no allocation (the filter adds ~200 a step)."""
    n = row.shape[0]
    norm = 0.0
    for j in range(n):
        norm += row[j] * row[j]
    norm = np.sqrt(norm)
    if norm == 0.0:  # no τ in it: a row that holds or not whatever the filter does
        norm = 1.0
    for j in range(n):
        a.rows[count, j] = row[j] / norm
    a.limits[count] = limit / norm
    a.weights[count] = weight
    a.is_hard[count] = 1.0 if hard else 0.0
    a.kinds[count] = kind
    a.joints[count] = joint


@njit(cache=True, inline="always")
def _nominal_model(a, y, v, mass):
    """(M̂⁻¹, b̂ = C(y, v) v + G(y) + τ_d, M̂⁻¹b̂) at (y, v), so that q̈ = M̂⁻¹τ − M̂⁻¹b̂."""
    minv = np.linalg.inv(mass)
    bias = np.zeros(y.shape[0])
    planar_bias(y, v, a.m, a.l, a.lc, a.inertia, a.gravity, bias)
    bias += a.tau_d
    return minv, bias, minv @ bias


@njit(cache=True, inline="always")
def _hard_rows(a, count, k, y, v, eps, minv, base, at_end):
    """The hard rows of row k, with the model (M̂, b̂, the payload's structure, the bias
    error) evaluated at (y, v) and the barriers at row k's state. ``at_end``: the conditions
    at the end of the hold instead, at a predicted (y, v): a held τ must keep them there
    too, and q̈ drifts over a hold fast where M̂ is ill-conditioned and τ large. With
    q(dt) = q + dt q̇ + ½dt² q̈ and q̇(dt) = q̇ + dt q̈, a condition at the end weighs q̈ by
    1 + k dt (velocity) or 1 + 2p dt + ½p² dt² (position) and the position's by p² dt q̇."""
    n = y.shape[0]
    forms = velocity_forms(y, a.m, a.l, a.lc, a.inertia)
    rows_error = acceleration_error_bound(y, v, eps, minv, a, forms)  # |M̂⁻¹(Δb + d)|
    # the payload's structure (see the module docstring)
    robust = a.payload_high != 0.0 or a.payload_low != 0.0
    jac, gamma = com_kinematics(y, v, a.l, a.lc, a.gravity)
    corners = 1
    grid = a.payload_grid
    s_grid = np.zeros((grid + 1, 2))  # s_j(Δm) at Δm = low … high
    corner_index = np.zeros((3 * grid + 1, 2), np.int64)  # grid points of each corner
    alpha = np.zeros((2, n))
    beta = np.zeros(2)
    plant_shift = np.zeros(n)
    if robust and not a.inertia_is_plant:
        kmat = jac @ minv @ jac.T
        lam, vec = np.linalg.eigh(kmat)
        for g in range(grid + 1):
            payload = a.payload_low + (a.payload_high - a.payload_low) * g / grid
            for j in range(2):
                s_grid[g, j] = payload / (1.0 + payload * lam[j])
        for j in range(2):
            alpha[j] = vec[:, j] @ jac @ minv
            beta[j] = -(vec[:, j] @ (jac @ base)) + vec[:, j] @ gamma
        # s_j increases with Δm, so between two grid points (s_1, s_2) lies in their box,
        # whose corners are (g, g), (g+1, g+1), (g, g+1), (g+1, g)
        corners = 0
        for g in range(grid + 1):
            corner_index[corners, 0] = corner_index[corners, 1] = g
            corners += 1
            if g < grid:
                corner_index[corners, 0], corner_index[corners, 1] = g, g + 1
                corner_index[corners + 1, 0], corner_index[corners + 1, 1] = g + 1, g
                corners += 2
    elif robust:
        plant_shift = minv @ (jac.T @ gamma)  # q̈ = u − Δm·this
    y0, v0, dt = a.position[k], a.velocity[k], a.dt
    row = np.empty(n)
    for s in range(2):
        if not a.hard[s]:
            continue
        for i in range(n):
            for side in (1.0, -1.0):
                # side·q̈_i ≤ limit for every q, q̇ within the bounds
                if s == 0:
                    h = a.bounds[0] - side * (y0[i] - a.q_s[k, i])
                    limit = a.k0 * (h - a.noise_bound) - a.k1 * (side * v0[i] + eps[i])
                    scale = 1.0 + a.k1 * dt + 0.5 * a.k0 * dt * dt if at_end else 1.0
                    if at_end:
                        limit -= a.k0 * dt * side * v0[i]
                else:
                    # The true h is ≥ 0 until the set is first left (by induction) and at
                    # least h − ε: its worst case is max(h − ε, 0), not h − ε. So an estimate
                    # that may lie outside asks only "do not approach", not recovery at rate
                    # k from a state the plant may not be in.
                    h = a.bounds[1] - side * (v0[i] - a.qdot_s[k, i])
                    limit = a.k_velocity * max(h - eps[i], 0.0)
                    scale = 1.0 + a.k_velocity * dt if at_end else 1.0
                limit -= scale * rows_error[i]
                if corners == 1:
                    limit -= scale * max(-a.payload_low * side * plant_shift[i],
                                         -a.payload_high * side * plant_shift[i])
                for corner in range(corners):
                    offset = side * base[i]
                    for col in range(n):
                        row[col] = side * minv[i, col]
                    if corners > 1:
                        for j in range(2):
                            weight = s_grid[corner_index[corner, j], j] * side * alpha[j, i]
                            for col in range(n):
                                row[col] -= weight * alpha[j, col]
                            offset += weight * beta[j]
                    for col in range(n):
                        row[col] *= scale
                    _finish_row(a, count, limit + scale * offset, a.rho_hard, True, s, i, row)
                    count += 1
    return count


@njit(cache=True)
def cbf_rows(k, a):
    """Fill G (``a.rows``), h (``a.limits``), the weights and the hard flags of row k's QP,
    and the braking backup (``a.backup``); returns the number of rows."""
    n = a.position.shape[1]
    y, v, eps = a.position[k], a.velocity[k], a.velocity_bound[k]
    mass = a.M_model[k]
    minv, bias, base = _nominal_model(a, y, v, mass)  # u = M̂⁻¹τ − base
    # the backup: brake every joint towards q̇_s
    a.backup[:] = mass @ (-a.backup_rate * (v - a.qdot_s[k])) + bias
    if np.isfinite(a.torque_limit):
        a.backup[:] = np.minimum(np.maximum(a.backup, -a.torque_limit), a.torque_limit)
    count = _hard_rows(a, 0, k, y, v, eps, minv, base, False)
    # the hold's end, predicted with the torque of the step before (the nominal model's q̈)
    held = a.tau[k - 1] if k > 0 else a.tau_nominal[k]
    acceleration = minv @ held - base
    y_end = y + a.dt * v + 0.5 * a.dt * a.dt * acceleration
    v_end = v + a.dt * acceleration
    nominal_now, nominal_end = np.empty((n, n)), np.empty((n, n))
    planar_mass_matrix(y, a.m, a.l, a.lc, a.inertia, nominal_now)
    planar_mass_matrix(y_end, a.m, a.l, a.lc, a.inertia, nominal_end)
    minv_end, _, base_end = _nominal_model(a, y_end, v_end, mass + nominal_end - nominal_now)
    count = _hard_rows(a, count, k, y_end, v_end, eps, minv_end, base_end, True)
    # The soft rows take the plant's q̈ averaged over the hold (the midpoint rule: at the bound
    # of a set, q̈'s drift within one 1 ms hold is what would carry the state across), and
    # how v moves: the observer's drift + M̂⁻¹τ (the observer holds M̂ over the step), or the
    # plant's q̈ for the plant's q̇.
    nominal_mid = np.empty((n, n))
    y_mid = y + 0.5 * a.dt * v + 0.125 * a.dt * a.dt * acceleration
    planar_mass_matrix(y_mid, a.m, a.l, a.lc, a.inertia, nominal_mid)
    minv_mid, _, base_mid = _nominal_model(a, y_mid, v + 0.5 * a.dt * acceleration,
                                           mass + nominal_mid - nominal_now)
    if np.isfinite(a.drift[k, 0]):
        rate_minv, drift = minv, a.drift[k]
    else:
        rate_minv, drift = minv_mid, -base_mid
    x = np.empty((4, n))
    x[0] = y - a.q_s[k]
    x[1] = v - a.qdot_s[k]
    x[2] = a.q_d[k] - y
    x[3] = a.qdot_d[k] - v
    rate_error = a.qdot_d[k] - v
    for s in range(4):
        beta_s = a.bounds[s]
        tight = 0.0  # the worst case of the true state within the declared bounds
        for i in range(n):
            if s == 0:
                tight = a.noise_bound
            elif s == 1:
                tight = eps[i]
            a.h_sets[s, k, i] = beta_s - abs(x[s, i]) - tight
            a.active_sets[s, k, i] = 0.0
        norm = np.sqrt(np.sum(x[s] ** 2))
        a.h_norms[s, k] = beta_s - norm
        a.active_norms[s, k] = 0.0
        if a.soft[s]:
            for i in range(n):
                for side in (1.0, -1.0):
                    h = beta_s - side * x[s, i]
                    if s == 2:  # e = q_d − y: −side·q̈_i ≤ −side q̈_d − 2p side ė + p² h
                        row = -side * minv_mid[i]
                        bound = (-side * a.qddot_d[k, i] - a.tracking_k1 * side * rate_error[i]
                                 + a.tracking_k0 * h - side * base_mid[i])
                    else:  # ė = q̇_d − v: −side·(M̂⁻¹τ)_i ≤ −side q̈_d + side drift_i + k h
                        row = -side * rate_minv[i]
                        bound = -side * a.qddot_d[k, i] + side * drift[i] + a.k_velocity * h
                    count = _add_row(a, count, row, bound, a.rho_soft, False, s, i)
        if a.soft_norms[s]:
            xs = x[s]
            h = beta_s * beta_s - norm * norm
            if s == 2:  # ḧ = −2‖ė‖² − 2eᵀ(q̈_d − q̈), ḣ = −2eᵀė
                row = -2.0 * (xs @ minv_mid)
                bound = (-2.0 * np.sum(rate_error**2) - 2.0 * (xs @ a.qddot_d[k])
                         - 2.0 * (xs @ base_mid) - 2.0 * a.tracking_k1 * (xs @ rate_error)
                         + a.tracking_k0 * h)
            else:  # ḣ = −2ėᵀ(q̈_d − dv/dt)
                row = -2.0 * (xs @ rate_minv)
                bound = -2.0 * (xs @ a.qddot_d[k]) + 2.0 * (xs @ drift) + a.k_velocity * h
                # Over a hold h also loses ‖Δx‖² (the set is round, the step straight): a
                # state sliding along the bound would leave it by that much each step, so the
                # rate asked for is less by ‖Δx‖²/step, Δx taken from the step before.
                if k > 0:
                    change = xs - (a.qdot_d[k - 1] - a.velocity[k - 1])
                    bound -= np.sum(change**2) / a.dt
            count = _add_row(a, count, row, bound, a.rho_soft, False, 4 + s, -1)
    if np.isfinite(a.torque_limit):
        for i in range(n):
            for side in (1.0, -1.0):
                row = np.zeros(n)
                row[i] = side
                count = _add_row(a, count, row, a.torque_limit, a.rho_hard, True, -1, i)
    return count


@njit(cache=True)
def _penalty(tau, tau_nominal, G, h, weights):
    """½‖τ − τ_nom‖² + ½Σ ρ_j (g_j τ − h_j)₊²."""
    excess = np.maximum(G @ tau - h, 0.0)
    return 0.5 * np.sum((tau - tau_nominal) ** 2) + 0.5 * np.sum(weights * excess**2)


@njit(cache=True)
def solve_soft_qp(tau_nominal, G, h, weights, iterations, tolerance):
    """min ½‖τ − τ_nom‖² + ½Σ ρ_j s_j² s.t. Gτ − s ≤ h, by semismooth Newton on the
    equivalent ½‖τ − τ_nom‖² + ½Σ ρ_j (g_j τ − h_j)₊²: strictly convex and piecewise
    quadratic, so with the rows violated at τ fixed one linear solve (I + Σ_A ρ_j g_jᵀ g_j)
    is exact; repeated until the set of violated rows no longer changes, with a backtracking
    line search. Its Hessian stays positive definite for opposing or conflicting rows, where
    a dual method stalls. Returns (τ, iterations used)."""
    n, m = tau_nominal.shape[0], G.shape[0]
    tau = tau_nominal.copy()
    scale = 1.0 + np.sqrt(np.sum(tau_nominal**2))
    binding = np.zeros(m, np.bool_)
    full_step = False
    for it in range(iterations):
        excess = np.maximum(G @ tau - h, 0.0)
        now = excess > 0.0
        gradient = tau - tau_nominal + G.T @ (weights * excess)
        # Exact for this piece once a full Newton step kept the same binding rows.
        if it > 0 and np.array_equal(now, binding) and full_step:
            return tau, it
        if np.sqrt(np.sum(gradient**2)) <= tolerance * scale:
            return tau, it
        binding = now
        hessian = np.eye(n)
        for j in range(m):
            if binding[j]:
                hessian += weights[j] * np.outer(G[j], G[j])
        if not (np.isfinite(np.sum(hessian)) and np.isfinite(np.sum(gradient))):
            return tau + np.nan, it  # a diverging loop: the filter's step reports it
        direction = -np.linalg.solve(hessian, gradient)
        value = _penalty(tau, tau_nominal, G, h, weights)
        slope = gradient @ direction
        step = 1.0
        while step > 1e-12:
            trial = tau + step * direction
            if _penalty(trial, tau_nominal, G, h, weights) <= value + 1e-4 * step * slope:
                break
            step *= 0.5
        full_step = step == 1.0
        tau = tau + step * direction
    return tau, iterations


@njit(cache=True)
def _hard_violated(G, h, is_hard, tau):
    """Whether τ violates a hard row as given (h not lowered)."""
    excess = G @ tau - h
    for j in range(G.shape[0]):
        if is_hard[j] > 0.0 and excess[j] > 0.0:
            return True
    return False


@njit(cache=True)
def cbf_record(k, a, count, tau):
    """Row k's outputs for the torque τ the QP gave: the hard part checked against its
    limits as given (else the backup acts and the step is flagged infeasible), each
    constraint's activity, the largest soft slack."""
    G, h = a.rows[:count], a.limits[:count]
    infeasible = _hard_violated(G, h, a.is_hard[:count], tau)
    if infeasible:  # the backup; a torque limit is honoured whatever else gives way
        tau = a.backup.copy() if a.brake else np.minimum(np.maximum(
            tau, -a.torque_limit), a.torque_limit)
    excess = G @ tau - h
    a.tau[k] = tau
    a.infeasible[k] = 1.0 if infeasible else 0.0
    active = 0
    slack = 0.0
    for j in range(count):
        # a hard row binds within the tolerance it was solved with; a soft one when violated
        binds = excess[j] > -2.0 * a.hard_tolerance if a.is_hard[j] > 0.0 else excess[j] > 0.0
        a.multipliers[j] = 1.0 if binds else 0.0
        if a.is_hard[j] == 0.0:
            slack = max(slack, excess[j])
        if binds:
            active += 1
            s = a.kinds[j]
            if 0 <= s < 4:
                a.active_sets[s, k, a.joints[j]] = 1.0
            elif s >= 4:
                a.active_norms[s - 4, k] = 1.0
    a.active[k] = active
    a.slack[k] = slack
    a.correction[k] = np.sqrt(np.sum((tau - a.tau_nominal[k]) ** 2))
    return np.isfinite(np.sum(tau))


@njit(cache=True)
def cbf_step(k, a):
    count = cbf_rows(k, a)
    G, given, hard = a.rows[:count], a.limits[:count], a.is_hard[:count]
    h = given.copy()
    for j in range(count):  # solve with the hard limits lowered: checked as given after
        if hard[j] > 0.0:
            h[j] -= a.hard_tolerance
    weights = a.weights[:count].copy()
    tau, _ = solve_soft_qp(a.tau_nominal[k], G, h, weights, a.iterations, a.tolerance)
    # A hard row may slip by ~ρ_soft·(soft excess)/ρ_hard where tracking pulls hard against
    # it: re-solve with tracking weighed less, down to the hard rows alone; only when those
    # alone cannot be met is the step infeasible (then cbf_record applies the backup).
    for _ in range(3):
        if not _hard_violated(G, given, hard, tau):
            break
        for j in range(count):
            if hard[j] == 0.0:
                weights[j] = weights[j] * 1e-3 if weights[j] > a.rho_soft * 1e-5 else 0.0
        tau, _ = solve_soft_qp(a.tau_nominal[k], G, h, weights, a.iterations, a.tolerance)
    return cbf_record(k, a, count, tau)


@register_block
class CbfFilter(Block):
    kind = "cbf_filter"
    Params = CbfFilterParams
    per_joint = ("tau_d",)
    views = (("h", "CBF barrier values β − |x| (≥ 0 inside)"),
             ("correction", "‖τ − τ_nom‖ (N·m)"))

    def __init__(self, params: CbfFilterParams, context: BlockContext):
        super().__init__(params, context)
        observer = params.velocity == "observer"
        self.position = "q_meas" if observer else "q"
        self.velocity = "qdot_hat" if observer else "qdot"
        extra = ("qdot_hat_bound", "qdot_hat_drift") if observer else ()
        self.inputs = (self.position, self.velocity, *extra, "q_s", "qdot_s", "q_d", "qdot_d",
                       "qddot_d", "M_model", "tau")
        self.requires = ("nominal_chain", "inertia_is_plant",
                         *(("tau_d_model",) if params.tau_d is None else ()))
        self.outputs = {"tau": Signal("n", "N·m", "filtered torque τ", "cbf_filter/tau")}
        for name in SETS:
            self.outputs[f"cbf_{name}"] = Signal(
                "n", "SI", f"{name} set: β − |x_i| − its uncertainty (≥ 0 inside for every "
                "state the declared bounds allow)", f"cbf_filter/h/{name}", f"h_{name}")
            self.outputs[f"cbf_{name}_active"] = Signal(
                "n", "-", f"{name} set: a constraint of joint i active (1)",
                f"cbf_filter/active/{name}", f"active_{name}")
            self.outputs[f"cbf_{name}_norm"] = Signal(
                "1", "SI", f"{name} set as a norm: β − ‖x‖", f"cbf_filter/h/{name}_norm",
                f"h_{name}_norm")
            self.outputs[f"cbf_{name}_norm_active"] = Signal(
                "1", "-", f"{name} norm constraint active (1)",
                f"cbf_filter/active/{name}_norm", f"active_{name}_norm")
        self.outputs.update({
            "cbf_slack": Signal("1", "N·m", "largest slack of a soft (tracking) row",
                                "cbf_filter/slack"),
            "cbf_active": Signal("1", "-", "number of active constraints",
                                 "cbf_filter/active_count"),
            "cbf_correction": Signal("1", "N·m", "‖τ − τ_nom‖", "cbf_filter/correction"),
            "cbf_infeasible": Signal("1", "-", "1 where the hard part was infeasible and the "
                                     "braking backup acted", "cbf_filter/infeasible"),
        })
        if params.solver == "newton":
            self.kernel = cbf_step
        else:
            self._check_solver(params.solver)

    @staticmethod
    def _check_solver(name: str) -> None:
        try:
            import qpsolvers
        except ImportError:
            raise PipelineError(f"cbf_filter.solver = {name!r} needs qpsolvers (pip install "
                                "'qpsolvers[daqp]'); or use solver = \"newton\"") from None
        if name not in qpsolvers.available_solvers:
            raise PipelineError(f"cbf_filter.solver = {name!r} is not an installed QP solver "
                                f"(installed: newton, {', '.join(qpsolvers.available_solvers)})")

    def reset(self, ports: Ports) -> None:
        p, n = self.params, self.context.links
        safety, uncertainty = self.context.safety, self.context.uncertainty
        inp, out, const = ports.inputs, ports.outputs, ports.constants
        for centre in ("q_s", "qdot_s"):
            moving = np.ptp(inp[centre], axis=0) if len(inp[centre]) else np.zeros(1)
            if np.any(moving > 0.0):
                raise PipelineError(
                    f"run '{self.context.run}': the cbf_filter block needs constant safe-set "
                    f"centres, but {centre} moves (by up to {float(np.max(moving)):.3g}); use "
                    "reference.safe_case = \"midpoint\" or drop the filter")
        chain = const["nominal_chain"]
        tau_d = const["tau_d_model"] if p.tau_d is None else p.tau_d
        bounds = np.array([safety.position_bound, safety.velocity_bound, safety.error_bound,
                           safety.error_rate_bound]) * (1.0 - p.bound_margin)
        corners = 3 * p.payload_grid + 1 if any(uncertainty.payload) else 1
        rows = 2 * (2 * n * 2 * corners) + 2 * n * 2 + 4 + 2 * n
        steps = len(ports.trace.time)
        if p.velocity == "observer":
            velocity_bound, drift = inp["qdot_hat_bound"], inp["qdot_hat_drift"]
        else:
            velocity_bound, drift = np.zeros((steps, n)), np.full((steps, n), np.nan)
        flags = [np.array([float(s in chosen) for s in SETS])
                 for chosen in (p.hard, p.soft, p.soft_norms)]
        self.args = CbfArgs(
            *flags, bounds,
            2.0 * p.position_rate, p.position_rate**2, 2.0 * p.tracking_rate,
            p.tracking_rate**2, p.velocity_rate, self.context.dt,
            p.torque_limit or np.inf, p.tracking_weight, p.hard_weight, p.hard_tolerance,
            p.backup == "brake", p.backup_rate, p.payload_grid, p.iterations, p.tolerance,
            uncertainty.noise_bound, *map(float, uncertainty.payload), uncertainty.disturbance,
            bool(const["inertia_is_plant"]),
            chain.m, chain.l, chain.lc, chain.inertia, float(chain.gravity),
            np.broadcast_to(np.asarray(tau_d, float), (n,)).copy(),
            np.zeros((rows, n)), np.zeros(rows), np.zeros(rows), np.zeros(rows),
            np.zeros(rows, np.int64), np.zeros(rows, np.int64), np.zeros(rows), np.zeros(n),
            inp[self.position], inp[self.velocity], velocity_bound, drift,
            inp["q_s"], inp["qdot_s"], inp["q_d"], inp["qdot_d"], inp["qddot_d"],
            inp["M_model"], inp["tau"], out["tau"],
            *(_per_set(ports.trace, f"cbf_{{}}{suffix}", shape) for suffix, shape in
              (("", (steps, n)), ("_active", (steps, n)), ("_norm", (steps,)),
               ("_norm_active", (steps,)))),
            out["cbf_slack"], out["cbf_active"], out["cbf_correction"], out["cbf_infeasible"])

    def step(self, k: int) -> bool:
        """With a qpsolvers solver (no kernel): the same rows, the hard ones as hard
        constraints and the soft ones with an explicit slack, solved in Python."""
        import qpsolvers

        a = self.args
        count = cbf_rows(k, a)
        G, h = a.rows[:count], a.limits[:count]
        hard = a.is_hard[:count] > 0
        soft = ~hard
        n, m = G.shape[1], int(soft.sum())
        # variables [τ, s]: ½‖τ − τ_nom‖² + ½ρ_s‖s‖²; G_h τ ≤ h_h; G_s τ − s ≤ h_s; s ≥ 0
        P = np.diag(np.concatenate([np.ones(n), a.weights[:count][soft]]))
        q = np.concatenate([-a.tau_nominal[k], np.zeros(m)])
        G_full = np.block([[G[hard], np.zeros((int(hard.sum()), m))],
                           [G[soft], -np.eye(m)], [np.zeros((m, n)), -np.eye(m)]])
        h_full = np.concatenate([h[hard] - a.hard_tolerance, h[soft], np.zeros(m)])
        x = qpsolvers.solve_qp(P, q, G_full, h_full, solver=self.params.solver)
        tau = a.backup.copy() if x is None else x[:n]
        return cbf_record(k, a, count, tau)


def _per_set(trace, pattern: str, shape: tuple[int, ...]) -> np.ndarray:
    """One array (4, *shape) for the four sets' outputs named ``pattern.format(set)``, the
    kernel's to index by set; the trace's arrays become views of it."""
    stacked = np.full((len(SETS), *shape), np.nan)
    for i, name in enumerate(SETS):
        trace.arrays[pattern.format(name)] = stacked[i]
    return stacked
