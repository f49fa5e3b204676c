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
their limits lowered by ``hard_tolerance`` (each Newton step a least-squares solve in
square-root form, to ~1e-13 of τ; started from the rows that bound at the step before,
which is the answer at once at 99.9 % of the paper's steps); where a hard row still slips
(tracking pulling hard against it), it re-solves with the soft weights 1e-3 and 1e-6 times,
then without the soft rows; only if the hard rows alone are violated (as given) is the hard
part infeasible at that step (``cbf_infeasible`` = 1, counted), and the **backup** acts: by
default the penalty form's answer itself (the torque that violates the hard rows least), or
braking, q̈ = −k (v − q̇_s) with the nominal model, within the torque limit
(``backup = "brake"``). Soft slack is reported apart
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

# What a step runs is compiled without numba's reference counting (_nrt=False, an option
# numba's njit takes though it is underscored): it allocates nothing (every array it works
# in is made at reset, and the compiler refuses an allocation in such a function), and
# counting the references to the arrays it passes around cost more than its arithmetic
# (numba counts one per array each time a tuple of them is bound, and the filter's arguments
# hold ~70: measured ~1000 counting call sites in the step, and a helper taking two of a's
# arrays 44 ns a call against 4 ns without).
# Functions that take the arguments ``a`` are inlined, so that those are not copied per call,
# and so are the small helpers called in loops; the larger ones, called a few times a step,
# are not (compiling everything inlined took minutes).
_step_jit = njit(cache=True, _nrt=False)
_step_inline = njit(cache=True, inline="always", _nrt=False)

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


# The filter's scratch, made once at reset (a step allocates nothing), is a few arrays with
# named rows: the compiled loop passes a kernel's arguments by value at every step, and each
# array in them costs (measured: a call with these arguments took 0.67 µs with the scratch as
# 58 arrays, 0.11 µs as these 13, 80 ns without any).

# Rows of CbfWork.chain (11, n): the chain's geometry at one position, per link (m), the
# forces of the recursive Newton–Euler bias (N), and the polarisation's velocity and biases.
CX, CY, LX, LY, OX, OY, FX, FY, E, PLUS, MINUS = range(11)
# Of CbfWork.solver (5, n): the iterate (then the answer), the line search's point, the
# gradient, the step, a row being rotated into R.
TAU, TRIAL, GRADIENT, DIRECTION, ROTATED = range(5)
# Of CbfWork.vectors (n each): b̂ at (y, v) and at a predicted state; M̂⁻¹b̂ at (y, v), at the
# hold's end and at its midpoint; the nominal model's q̈ under the held torque; the states
# predicted at the hold's end and midpoint; dv/dt − M̂⁻¹τ; a row before its scaling; the bias
# error's quadratic part, and its bound on |M̂⁻¹(Δb + d)|; link masses of a unit payload (1 kg
# on the last link); M̂⁻¹Jᵀγ when M̂ is the plant's; from X, 4 rows: each set's x, SETS order.
(BIAS, MOVED_BIAS, BASE, BASE_END, BASE_MID, ACCELERATION, Y_END, V_END, Y_MID, V_MID, DRIFT,
 ROW, QUADRATIC, ROWS_ERROR, UNIT, PLANT_SHIFT, X) = range(17)
# Of CbfWork.matrices (n×n each): the nominal chain's M at y and at a predicted position, M̂
# moved there, M̂⁻¹ at y, at the hold's end and at its midpoint, elimination scratch, and R.
NOMINAL_NOW, NOMINAL, SHIFTED, MINV, MINV_END, MINV_MID, LU, FACTOR = range(8)
# The payload's structure: of CbfWork.planar (2×n each) J of its point, J M̂⁻¹ and α; of
# .pairs (2 each) γ = J̇v + g ŷ, J M̂⁻¹b̂, K's eigenvalues (ascending) and β; of .squares
# (2×2 each) K = J M̂⁻¹ Jᵀ and its eigenvectors (columns).
JAC, JM, ALPHA = range(3)
GAMMA, JB, LAM, BETA = range(4)
KMAT, VEC = range(2)


class CbfWork(NamedTuple):
    chain: np.ndarray  # (11, n) CX …
    solver: np.ndarray  # (5, n) TAU …
    vectors: np.ndarray  # (X + 4, n) BIAS …
    matrices: np.ndarray  # (8, n, n) NOMINAL_NOW …
    forms: np.ndarray  # (2, n, n, n) Γ of the nominal chain, of a unit payload (zero
    # without a payload range)
    linear: np.ndarray  # (2, n, n) B at each end of the payload range
    planar: np.ndarray  # (3, 2, n) JAC …
    pairs: np.ndarray  # (4, 2) GAMMA …
    squares: np.ndarray  # (2, 2, 2) KMAT, VEC
    s_grid: np.ndarray  # (grid + 1, 2) s_j(Δm) at Δm = low … high
    corner_index: np.ndarray  # (3 grid + 1, 2) the grid points of each box corner
    per_row: np.ndarray  # (2, rows) the limits and the weights the QP is solved with
    binding: np.ndarray  # (rows,) the rows violated at the solver's iterate


def payload_corners(grid: int) -> np.ndarray:
    """The grid points (of s_1, of s_2) of the box corners the payload's rows are taken at:
    s_j increases with Δm, so between two grid points (s_1, s_2) lies in their box, whose
    corners are (g, g), (g+1, g+1), (g, g+1), (g+1, g). 3 grid + 1 corners."""
    corner_index = np.zeros((3 * grid + 1, 2), np.int64)
    corners = 0
    for g in range(grid + 1):
        corner_index[corners, 0] = corner_index[corners, 1] = g
        corners += 1
        if g < grid:
            corner_index[corners, 0], corner_index[corners, 1] = g, g + 1
            corner_index[corners + 1, 0], corner_index[corners + 1, 1] = g + 1, g
            corners += 2
    return corner_index


def cbf_work(n: int, rows: int, grid: int) -> CbfWork:
    """The scratch of a filter on n joints with at most ``rows`` rows."""
    vectors = np.zeros((X + 4, n))
    vectors[UNIT, n - 1] = 1.0
    return CbfWork(
        chain=np.zeros((11, n)), solver=np.zeros((5, n)), vectors=vectors,
        matrices=np.zeros((8, n, n)), forms=np.zeros((2, n, n, n)), linear=np.zeros((2, n, n)),
        planar=np.zeros((3, 2, n)), pairs=np.zeros((4, 2)), squares=np.zeros((2, 2, 2)),
        s_grid=np.zeros((grid + 1, 2)), corner_index=payload_corners(grid),
        per_row=np.zeros((2, rows)), binding=np.zeros(rows, np.bool_))


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
    work: CbfWork


# The small linear algebra of a step, on n joints and 2-vectors, written out: numba's
# np.linalg and @ allocate their results and call LAPACK/BLAS, which costs more than the
# arithmetic at these sizes.


@_step_inline
def _dot(x, y):
    total = 0.0
    for i in range(x.shape[0]):
        total += x[i] * y[i]
    return total


@_step_inline
def _product(matrix, vector, out):
    """out = matrix @ vector."""
    for i in range(matrix.shape[0]):
        out[i] = _dot(matrix[i], vector)


@_step_inline
def _invert(matrix, out, lu):
    """out = matrix⁻¹ by Gauss–Jordan elimination with partial pivoting (``lu``: n×n
    scratch). A singular matrix gives non-finite entries, which the step reports."""
    n = matrix.shape[0]
    for i in range(n):
        for j in range(n):
            lu[i, j] = matrix[i, j]
            out[i, j] = 1.0 if i == j else 0.0
    for c in range(n):
        pivot_row = c
        for r in range(c + 1, n):
            if abs(lu[r, c]) > abs(lu[pivot_row, c]):
                pivot_row = r
        if pivot_row != c:
            for j in range(n):
                lu[c, j], lu[pivot_row, j] = lu[pivot_row, j], lu[c, j]
                out[c, j], out[pivot_row, j] = out[pivot_row, j], out[c, j]
        pivot = lu[c, c]
        for j in range(n):
            lu[c, j] /= pivot
            out[c, j] /= pivot
        for r in range(n):
            factor = lu[r, c]
            if r != c and factor != 0.0:
                for j in range(n):
                    lu[r, j] -= factor * lu[c, j]
                    out[r, j] -= factor * out[c, j]


@_step_inline
def _symmetric_eigen(kmat, lam, vec):
    """The eigenvalues (ascending, into ``lam``) and unit eigenvectors (columns of ``vec``)
    of a symmetric 2×2 matrix (its lower triangle), in closed form: with
    2θ = atan2(k10, (k00 − k11)/2), (cos θ, sin θ) belongs to the larger one."""
    mean = 0.5 * (kmat[0, 0] + kmat[1, 1])
    half = 0.5 * (kmat[0, 0] - kmat[1, 1])
    radius = np.hypot(half, kmat[1, 0])
    theta = 0.5 * np.arctan2(kmat[1, 0], half)
    c, s = np.cos(theta), np.sin(theta)
    lam[0], lam[1] = mean - radius, mean + radius
    vec[0, 0], vec[1, 0] = -s, c
    vec[0, 1], vec[1, 1] = c, s


# The nominal chain, as cosim.blocks.inertia's planar_mass_matrix and planar_bias compute it
# (the same operations in the same order, so the same numbers: tests/test_filter_speed.py),
# with the geometry computed once per position and no array allocated.


@_step_inline
def _geometry(q, l, lc, chain):  # noqa: E741
    """The chain's geometry at q into rows CX … OY of ``chain``."""
    theta, x, y = 0.0, 0.0, 0.0
    for k in range(q.shape[0]):
        theta += q[k]
        c, s = np.cos(theta), np.sin(theta)
        chain[CX, k], chain[CY, k] = lc[k] * c, lc[k] * s
        chain[LX, k], chain[LY, k] = l[k] * c, l[k] * s
        chain[OX, k], chain[OY, k] = x, y
        x += l[k] * c
        y += l[k] * s


@_step_inline
def _chain_mass(chain, m, inertia, out):
    """M of the chain whose geometry ``chain`` holds, into ``out``:
    M_ij = Σ_{k ≥ max(i, j)} [m_k (p_k − o_i)·(p_k − o_j) + I_k]."""
    n = m.shape[0]
    for i in range(n):
        for j in range(i, n):
            total = 0.0
            for k in range(j, n):
                px, py = chain[OX, k] + chain[CX, k], chain[OY, k] + chain[CY, k]
                total += (m[k] * ((px - chain[OX, i]) * (px - chain[OX, j])
                                  + (py - chain[OY, i]) * (py - chain[OY, j])) + inertia[k])
            out[i, j] = total
            out[j, i] = total


@_step_inline
def _chain_bias(chain, qdot, m, gravity, out):
    """b(q, q̇) = C(q, q̇) q̇ + G(q) of the chain whose geometry ``chain`` holds, into
    ``out``: recursive Newton–Euler with q̈ = 0 and the base accelerating upwards at
    ``gravity``."""
    n = qdot.shape[0]
    omega = 0.0
    ax, ay = 0.0, gravity  # acceleration of joint i's origin
    for i in range(n):
        omega += qdot[i]
        w2 = omega * omega  # no angular acceleration: q̈ = 0
        chain[FX, i] = m[i] * (ax - w2 * chain[CX, i])
        chain[FY, i] = m[i] * (ay - w2 * chain[CY, i])
        ax -= w2 * chain[LX, i]
        ay -= w2 * chain[LY, i]
    force_x, force_y, moment = 0.0, 0.0, 0.0  # what link i+1 exerts, about joint i+1
    for i in range(n - 1, -1, -1):
        moment += (chain[LX, i] * force_y - chain[LY, i] * force_x
                   + chain[CX, i] * chain[FY, i] - chain[CY, i] * chain[FX, i])
        force_x += chain[FX, i]
        force_y += chain[FY, i]
        out[i] = moment


@_step_jit
def _velocity_forms(q, m, l, lc, chain, out):  # noqa: E741
    """Γ of the chain at q into ``out`` (n, n, n), ``chain`` its scratch (11, n)."""
    n = q.shape[0]
    _geometry(q, l, lc, chain)
    e, plus, minus = chain[E], chain[PLUS], chain[MINUS]
    for j in range(n):
        for k in range(j, n):
            for i in range(n):
                e[i] = 0.0
            e[j] += 1.0
            e[k] += 1.0
            _chain_bias(chain, e, m, 0.0, plus)
            e[k] -= 2.0
            _chain_bias(chain, e, m, 0.0, minus)
            for i in range(n):
                # b_i(a + c) − b_i(a − c) = 4 aᵀΓ_i c (and e_j ± e_j = 2e_j, 0 for j = k)
                out[i, j, k] = out[i, k, j] = (plus[i] - minus[i]) / 4.0


@njit(cache=True)
def velocity_forms(q, m, l, lc, inertia):  # noqa: E741
    """Γ (n, n, n): b's velocity part b_i(v) = vᵀ Γ_i v of the chain (gravity 0), by
    polarisation of the recursive Newton–Euler bias. (A link's rotational ``inertia`` adds
    nothing to b in the plane: the argument keeps the chain's signature.)"""
    n = q.shape[0]
    out = np.zeros((n, n, n))
    _velocity_forms(q, m, l, lc, np.zeros((11, n)), out)
    return out


@_step_jit
def _com_kinematics(q, v, l, lc, gravity, jac, gamma):  # noqa: E741
    """The last link's centre of mass c: its Jacobian J (2×n, into ``jac``) and
    γ = J̇ v + g ŷ (into ``gamma``), the acceleration a point mass there needs beyond J q̈
    (gravity along −y)."""
    n = q.shape[0]
    jac[:] = 0.0
    gamma[0], gamma[1] = 0.0, gravity
    theta, omega = 0.0, 0.0
    for k in range(n):
        theta += q[k]
        omega += v[k]
        length = lc[k] if k == n - 1 else l[k]
        cx, cy = length * np.cos(theta), length * np.sin(theta)
        for j in range(k + 1):
            jac[0, j] -= cy
            jac[1, j] += cx
        gamma[0] -= omega**2 * cx
        gamma[1] -= omega**2 * cy


@_step_jit
def _acceleration_error_bound(v, eps, minv, low, high, disturbance, nominal, payload, linear,
                              quadratic, out):
    """acceleration_error_bound into ``out``, with Γ of a unit payload given (``payload``)
    and ``linear`` (2, n, n), ``quadratic`` (n,) as scratch."""
    n = v.shape[0]
    size = max(abs(low), abs(high))
    linear[:] = 0.0  # B for the nominal chain plus each end of the payload range
    quadratic[:] = disturbance
    for l in range(n):  # noqa: E741
        for j in range(n):
            for k in range(n):
                for end in range(2):
                    mass = low if end == 0 else high
                    linear[end, l, j] += 2.0 * (nominal[l, j, k] + mass * payload[l, j, k]) * v[k]
                quadratic[l] += (abs(nominal[l, j, k]) + size * abs(payload[l, j, k])) \
                    * eps[j] * eps[k]
    for i in range(n):
        out[i] = 0.0
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


@njit(cache=True)
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
    payload = np.zeros((n, n, n))
    _velocity_forms(q, unit, a.l, a.lc, np.zeros((11, n)), payload)
    out = np.zeros(n)
    _acceleration_error_bound(v, eps, minv, a.payload_low, a.payload_high, a.disturbance,
                              nominal, payload, np.zeros((2, n, n)), np.zeros(n), out)
    return out


@_step_inline
def _add_row(qp, count, row, limit, weight, hard, kind, joint):
    """Row ``count`` of the QP from ``row`` (scaled to unit norm, N·m), its limit, weight
    and labels, into ``qp`` = (a.rows, a.limits, a.weights, a.is_hard, a.kinds, a.joints);
    returns the next row's index. (Not ``a`` itself: binding a tuple to an argument counts a
    reference to each of its arrays, and a holds ~100.)"""
    G, limits, weights, is_hard, kinds, joints = qp
    n = row.shape[0]
    norm = 0.0
    for j in range(n):
        norm += row[j] * row[j]
    norm = np.sqrt(norm)
    if norm == 0.0:  # no τ in it: a row that holds or not whatever the filter does
        norm = 1.0
    for j in range(n):
        G[count, j] = row[j] / norm
    limits[count] = limit / norm
    weights[count] = weight
    is_hard[count] = 1.0 if hard else 0.0
    kinds[count] = kind
    joints[count] = joint
    return count + 1


@_step_inline
def _nominal_model(a, y, v, nominal, bias):
    """The nominal chain at (y, v): its M(y) into ``nominal`` and b̂ = C(y, v) v + G(y) + τ_d
    into ``bias``."""
    chain = a.work.chain
    _geometry(y, a.l, a.lc, chain)
    _chain_mass(chain, a.m, a.inertia, nominal)
    _chain_bias(chain, v, a.m, a.gravity, bias)
    for i in range(y.shape[0]):
        bias[i] += a.tau_d[i]


@_step_inline
def _moved_model(a, y, v, mass, minv, base):
    """At a predicted state (y, v): M̂⁻¹ into ``minv`` and M̂⁻¹b̂ into ``base`` (so that
    q̈ = M̂⁻¹τ − base), with M̂ moved from row k's by the nominal chain's change."""
    matrices, moved_bias = a.work.matrices, a.work.vectors[MOVED_BIAS]
    nominal, shifted = matrices[NOMINAL], matrices[SHIFTED]
    _nominal_model(a, y, v, nominal, moved_bias)
    n = y.shape[0]
    for i in range(n):
        for j in range(n):
            shifted[i, j] = mass[i, j] + nominal[i, j] - matrices[NOMINAL_NOW, i, j]
    _invert(shifted, minv, matrices[LU])
    _product(minv, moved_bias, base)


@_step_jit
def _payload_structure(low, high, minv, base, planar, pairs, squares, s_grid):
    """The payload's structure (see the module docstring) at one state, J and γ given (in
    ``planar`` and ``pairs``): K's eigenvalues and eigenvectors, s_j(Δm) on the grid, and the
    α_j = v_jᵀJM̂⁻¹ and β_j = v_jᵀ(γ − JM̂⁻¹b̂) a row is linear in."""
    n = minv.shape[0]
    jac, jm, alpha = planar[JAC], planar[JM], planar[ALPHA]
    gamma, jb, lam, beta = pairs[GAMMA], pairs[JB], pairs[LAM], pairs[BETA]
    kmat, vec = squares[KMAT], squares[VEC]
    for r in range(2):
        for col in range(n):
            total = 0.0
            for l in range(n):  # noqa: E741
                total += jac[r, l] * minv[l, col]
            jm[r, col] = total
        jb[r] = _dot(jac[r], base)
    for r in range(2):
        for c in range(2):
            kmat[r, c] = _dot(jm[r], jac[c])
    _symmetric_eigen(kmat, lam, vec)
    grid = s_grid.shape[0] - 1
    for g in range(grid + 1):
        payload = low + (high - low) * g / grid
        for j in range(2):
            s_grid[g, j] = payload / (1.0 + payload * lam[j])
    for j in range(2):
        for col in range(n):
            alpha[j, col] = vec[0, j] * jm[0, col] + vec[1, j] * jm[1, col]
        beta[j] = (-(vec[0, j] * jb[0] + vec[1, j] * jb[1])
                   + vec[0, j] * gamma[0] + vec[1, j] * gamma[1])


@_step_inline
def _hard_rows(a, count, k, y, v, eps, minv, base, at_end):
    """The hard rows of row k, with the model (M̂, b̂, the payload's structure, the bias
    error) evaluated at (y, v) and the barriers at row k's state. ``at_end``: the conditions
    at the end of the hold instead, at a predicted (y, v): a held τ must keep them there
    too, and q̈ drifts over a hold fast where M̂ is ill-conditioned and τ large. With
    q(dt) = q + dt q̇ + ½dt² q̈ and q̇(dt) = q̇ + dt q̈, a condition at the end weighs q̈ by
    1 + k dt (velocity) or 1 + 2p dt + ½p² dt² (position) and the position's by p² dt q̇."""
    n = y.shape[0]
    w = a.work
    vectors, forms = w.vectors, w.forms
    robust = a.payload_high != 0.0 or a.payload_low != 0.0
    _velocity_forms(y, a.m, a.l, a.lc, w.chain, forms[0])
    if robust:  # else the payload's forms stay zero, as its range is
        _velocity_forms(y, vectors[UNIT], a.l, a.lc, w.chain, forms[1])
    rows_error = vectors[ROWS_ERROR]  # |M̂⁻¹(Δb + d)|
    _acceleration_error_bound(v, eps, minv, a.payload_low, a.payload_high, a.disturbance,
                              forms[0], forms[1], w.linear, vectors[QUADRATIC], rows_error)
    # the payload's structure (see the module docstring)
    corners = 1
    s_grid, corner_index = w.s_grid, w.corner_index
    alpha, beta = w.planar[ALPHA], w.pairs[BETA]
    jac, gamma = w.planar[JAC], w.pairs[GAMMA]
    plant_shift = vectors[PLANT_SHIFT]
    plant_shift[:] = 0.0
    if robust:
        _com_kinematics(y, v, a.l, a.lc, a.gravity, jac, gamma)
    if robust and not a.inertia_is_plant:
        _payload_structure(a.payload_low, a.payload_high, minv, base, w.planar, w.pairs,
                           w.squares, s_grid)
        corners = corner_index.shape[0]
    elif robust:  # q̈ = u − Δm·M̂⁻¹Jᵀγ
        for i in range(n):
            for col in range(n):
                plant_shift[i] += minv[i, col] * (jac[0, col] * gamma[0]
                                                  + jac[1, col] * gamma[1])
    y0, v0, dt = a.position[k], a.velocity[k], a.dt
    row = vectors[ROW]
    qp = (a.rows, a.limits, a.weights, a.is_hard, a.kinds, a.joints)
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
                    count = _add_row(qp, count, row, limit + scale * offset, a.rho_hard, True,
                                     s, i)
    return count


@_step_jit
def cbf_rows(k, a):
    """Fill G (``a.rows``), h (``a.limits``), the weights and the hard flags of row k's QP,
    and the braking backup (``a.backup``); returns the number of rows."""
    return _rows(k, a)


@_step_inline
def _rows(k, a):
    """cbf_rows, inlined into the step: a's many fields are not copied per call."""
    n = a.position.shape[1]
    vectors, matrices = a.work.vectors, a.work.matrices
    y, v, eps = a.position[k], a.velocity[k], a.velocity_bound[k]
    mass = a.M_model[k]
    minv, bias, base = matrices[MINV], vectors[BIAS], vectors[BASE]  # u = M̂⁻¹τ − base
    _nominal_model(a, y, v, matrices[NOMINAL_NOW], bias)
    _invert(mass, minv, matrices[LU])
    _product(minv, bias, base)
    # the backup: brake every joint towards q̇_s
    for i in range(n):
        braking = 0.0
        for j in range(n):
            braking += mass[i, j] * (-a.backup_rate * (v[j] - a.qdot_s[k, j]))
        a.backup[i] = braking + bias[i]
        if np.isfinite(a.torque_limit):
            a.backup[i] = np.minimum(np.maximum(a.backup[i], -a.torque_limit), a.torque_limit)
    count = _hard_rows(a, 0, k, y, v, eps, minv, base, False)
    # the hold's end, predicted with the torque of the step before (the nominal model's q̈)
    held = a.tau[k - 1] if k > 0 else a.tau_nominal[k]
    acceleration = vectors[ACCELERATION]
    _product(minv, held, acceleration)
    y_end, v_end, y_mid, v_mid = vectors[Y_END], vectors[V_END], vectors[Y_MID], vectors[V_MID]
    for i in range(n):
        acceleration[i] -= base[i]
        y_end[i] = y[i] + a.dt * v[i] + 0.5 * a.dt * a.dt * acceleration[i]
        v_end[i] = v[i] + a.dt * acceleration[i]
        y_mid[i] = y[i] + 0.5 * a.dt * v[i] + 0.125 * a.dt * a.dt * acceleration[i]
        v_mid[i] = v[i] + 0.5 * a.dt * acceleration[i]
    minv_end, base_end = matrices[MINV_END], vectors[BASE_END]
    _moved_model(a, y_end, v_end, mass, minv_end, base_end)
    count = _hard_rows(a, count, k, y_end, v_end, eps, minv_end, base_end, True)
    # The soft rows take the plant's q̈ averaged over the hold (the midpoint rule: at the bound
    # of a set, q̈'s drift within one 1 ms hold is what would carry the state across), and
    # how v moves: the observer's drift + M̂⁻¹τ (the observer holds M̂ over the step), or the
    # plant's q̈ for the plant's q̇.
    minv_mid, base_mid = matrices[MINV_MID], vectors[BASE_MID]
    _moved_model(a, y_mid, v_mid, mass, minv_mid, base_mid)
    observed = np.isfinite(a.drift[k, 0])
    rate_minv = minv if observed else minv_mid
    drift, x, row = vectors[DRIFT], vectors[X:X + 4], vectors[ROW]
    qp = (a.rows, a.limits, a.weights, a.is_hard, a.kinds, a.joints)
    for i in range(n):
        drift[i] = a.drift[k, i] if observed else -base_mid[i]
        x[0, i] = y[i] - a.q_s[k, i]
        x[1, i] = v[i] - a.qdot_s[k, i]
        x[2, i] = a.q_d[k, i] - y[i]
        x[3, i] = a.qdot_d[k, i] - v[i]
    rate_error = x[3]  # q̇_d − v
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
        xs = x[s]
        norm = np.sqrt(_dot(xs, xs))
        a.h_norms[s, k] = beta_s - norm
        a.active_norms[s, k] = 0.0
        if a.soft[s]:
            for i in range(n):
                for side in (1.0, -1.0):
                    h = beta_s - side * x[s, i]
                    if s == 2:  # e = q_d − y: −side·q̈_i ≤ −side q̈_d − 2p side ė + p² h
                        for col in range(n):
                            row[col] = -side * minv_mid[i, col]
                        bound = (-side * a.qddot_d[k, i] - a.tracking_k1 * side * rate_error[i]
                                 + a.tracking_k0 * h - side * base_mid[i])
                    else:  # ė = q̇_d − v: −side·(M̂⁻¹τ)_i ≤ −side q̈_d + side drift_i + k h
                        for col in range(n):
                            row[col] = -side * rate_minv[i, col]
                        bound = -side * a.qddot_d[k, i] + side * drift[i] + a.k_velocity * h
                    count = _add_row(qp, count, row, bound, a.rho_soft, False, s, i)
        if a.soft_norms[s]:
            h = beta_s * beta_s - norm * norm
            if s == 2:  # ḧ = −2‖ė‖² − 2eᵀ(q̈_d − q̈), ḣ = −2eᵀė
                for col in range(n):
                    row[col] = -2.0 * _dot(xs, minv_mid[:, col])
                bound = (-2.0 * _dot(rate_error, rate_error) - 2.0 * _dot(xs, a.qddot_d[k])
                         - 2.0 * _dot(xs, base_mid) - 2.0 * a.tracking_k1 * _dot(xs, rate_error)
                         + a.tracking_k0 * h)
            else:  # ḣ = −2ėᵀ(q̈_d − dv/dt)
                for col in range(n):
                    row[col] = -2.0 * _dot(xs, rate_minv[:, col])
                bound = -2.0 * _dot(xs, a.qddot_d[k]) + 2.0 * _dot(xs, drift) + a.k_velocity * h
                # Over a hold h also loses ‖Δx‖² (the set is round, the step straight): a
                # state sliding along the bound would leave it by that much each step, so the
                # rate asked for is less by ‖Δx‖²/step, Δx taken from the step before.
                if k > 0:
                    change = 0.0
                    for i in range(n):
                        change += (xs[i] - (a.qdot_d[k - 1, i] - a.velocity[k - 1, i])) ** 2
                    bound -= change / a.dt
            count = _add_row(qp, count, row, bound, a.rho_soft, False, 4 + s, -1)
    if np.isfinite(a.torque_limit):
        for i in range(n):
            for side in (1.0, -1.0):
                for col in range(n):
                    row[col] = side if col == i else 0.0
                count = _add_row(qp, count, row, a.torque_limit, a.rho_hard, True, -1, i)
    return count


@_step_inline
def _penalty(tau, tau_nominal, G, h, weights, count):
    """½‖τ − τ_nom‖² + ½Σ ρ_j (g_j τ − h_j)₊² over the first ``count`` rows."""
    own = 0.0
    for i in range(tau.shape[0]):
        own += (tau[i] - tau_nominal[i]) ** 2
    rows = 0.0
    for j in range(count):
        rows += weights[j] * np.maximum(_dot(G[j], tau) - h[j], 0.0) ** 2
    return 0.5 * own + 0.5 * rows


@_step_inline
def _piece_minimiser(tau_nominal, G, h, weights, count, binding, factor, rotated, out):
    """The minimiser of ½‖τ − τ_nom‖² + ½Σ_A ρ_j (g_j τ − h_j)², A the rows flagged in
    ``binding``, into ``out``: the least-squares solution of [I; √ρ_A G_A] τ =
    [τ_nom; √ρ_A h_A], its R (``factor``) built from I by a Givens rotation per binding row
    entry (``rotated``: the row being rotated in). Its normal equations
    (I + Σ_A ρ_j g_jᵀ g_j) have a condition number up to 1 + ρ_hard (1e10, one binding row),
    which cost up to ~3e-5 of τ (measured against exact arithmetic); R's is the square root
    of that."""
    n = tau_nominal.shape[0]
    for i in range(n):
        for c in range(n):
            factor[i, c] = 1.0 if i == c else 0.0
        out[i] = tau_nominal[i]  # Qᵀ times the right-hand side, as R is built
    for j in range(count):
        if not binding[j]:
            continue
        root = np.sqrt(weights[j])
        for c in range(n):
            rotated[c] = root * G[j, c]
        side = root * h[j]
        for c in range(n):  # zero the row's entry c against R's row c
            if rotated[c] == 0.0:
                continue
            radius = np.hypot(factor[c, c], rotated[c])
            cs, sn = factor[c, c] / radius, rotated[c] / radius
            for col in range(c, n):
                upper = factor[c, col]
                factor[c, col] = cs * upper + sn * rotated[col]
                rotated[col] = cs * rotated[col] - sn * upper
            upper = out[c]
            out[c] = cs * upper + sn * side
            side = cs * side - sn * upper
    for c in range(n - 1, -1, -1):  # R τ = Qᵀ rhs
        total = out[c]
        for col in range(c + 1, n):
            total -= factor[c, col] * out[col]
        out[c] = total / factor[c, c]


@_step_jit
def _newton(tau_nominal, G, h, weights, count, iterations, tolerance, solver, factor,
            binding, warm):
    """solve_soft_qp on the first ``count`` rows of G, h and the weights, its vectors in
    ``solver`` (5, n: TAU …), R in ``factor`` and the rows violated in ``binding``: τ into
    ``solver[TAU]``; returns the iterations used. ``warm``: start from the minimiser of the
    piece the rows flagged in ``binding`` make (the step before's, as the rows keep their
    order), not from τ_nom; where the rows violated there are those, it is the answer (the
    convex function's gradient is that piece's, zero), at no iteration."""
    n = tau_nominal.shape[0]
    tau, trial, gradient, direction = solver[TAU], solver[TRIAL], solver[GRADIENT], \
        solver[DIRECTION]
    if warm:
        _piece_minimiser(tau_nominal, G, h, weights, count, binding, factor, solver[ROTATED],
                         tau)
    else:
        for i in range(n):
            tau[i] = tau_nominal[i]
        binding[:count] = False
    scale = 1.0 + np.sqrt(_dot(tau_nominal, tau_nominal))
    full_step = warm  # at τ, a minimiser of the piece ``binding`` flags
    for it in range(iterations):
        gradient[:] = 0.0
        same = True
        for j in range(count):
            excess = np.maximum(_dot(G[j], tau) - h[j], 0.0)
            now = excess > 0.0
            same = same and now == binding[j]
            binding[j] = now
            for i in range(n):
                gradient[i] += G[j, i] * (weights[j] * excess)
        for i in range(n):
            gradient[i] = tau[i] - tau_nominal[i] + gradient[i]
        # Exact once a piece's minimiser (a full Newton step) kept the same binding rows.
        if same and full_step:
            return it
        if np.sqrt(_dot(gradient, gradient)) <= tolerance * scale:
            return it
        # The piece is quadratic: the Newton step goes to its minimiser.
        _piece_minimiser(tau_nominal, G, h, weights, count, binding, factor, solver[ROTATED],
                         direction)
        for i in range(n):
            direction[i] -= tau[i]
        if not (np.isfinite(np.sum(direction)) and np.isfinite(np.sum(gradient))):
            for i in range(n):  # a diverging loop: the filter's step reports it
                tau[i] = np.nan
            return it
        value = _penalty(tau, tau_nominal, G, h, weights, count)
        slope = _dot(gradient, direction)
        step = 1.0
        while step > 1e-12:
            for i in range(n):
                trial[i] = tau[i] + step * direction[i]
            if _penalty(trial, tau_nominal, G, h, weights, count) \
                    <= value + 1e-4 * step * slope:
                break
            step *= 0.5
        full_step = step == 1.0
        for i in range(n):
            tau[i] = tau[i] + step * direction[i]
    return iterations


@njit(cache=True)
def solve_soft_qp(tau_nominal, G, h, weights, iterations, tolerance):
    """min ½‖τ − τ_nom‖² + ½Σ ρ_j s_j² s.t. Gτ − s ≤ h, by semismooth Newton on the
    equivalent ½‖τ − τ_nom‖² + ½Σ ρ_j (g_j τ − h_j)₊²: strictly convex and piecewise
    quadratic, so with the rows violated at τ fixed one linear solve (I + Σ_A ρ_j g_jᵀ g_j,
    in square-root form: _piece_minimiser) is exact; repeated until the set of violated rows
    no longer changes, with a backtracking line search. Its Hessian stays positive definite
    for opposing or conflicting rows, where a dual method stalls. Returns (τ, iterations
    used). From τ_nom (the filter's step starts from the step before's binding rows)."""
    n, m = tau_nominal.shape[0], G.shape[0]
    solver = np.zeros((5, n))
    used = _newton(tau_nominal, G, h, weights, m, iterations, tolerance, solver,
                   np.zeros((n, n)), np.zeros(m, np.bool_), False)
    return solver[TAU], used


@_step_inline
def _hard_violated(G, h, is_hard, count, tau):
    """Whether τ violates a hard row of the first ``count`` as given (h not lowered)."""
    for j in range(count):
        if is_hard[j] > 0.0 and _dot(G[j], tau) - h[j] > 0.0:
            return True
    return False


@_step_jit
def cbf_record(k, a, count, tau):
    """Row k's outputs for the torque τ the QP gave: the hard part checked against its
    limits as given (else the backup acts and the step is flagged infeasible), each
    constraint's activity, the largest soft slack."""
    return _record(k, a, count, tau)


@_step_inline
def _record(k, a, count, tau):
    """cbf_record, inlined into the step. ``tau`` may be ``a.tau[k]`` itself."""
    infeasible = _hard_violated(a.rows, a.limits, a.is_hard, count, tau)
    for i in range(tau.shape[0]):
        if infeasible and a.brake:  # the backup; a torque limit is honoured whatever else gives way
            a.tau[k, i] = a.backup[i]
        elif infeasible:
            a.tau[k, i] = np.minimum(np.maximum(tau[i], -a.torque_limit), a.torque_limit)
        else:
            a.tau[k, i] = tau[i]
    chosen = a.tau[k]
    a.infeasible[k] = 1.0 if infeasible else 0.0
    active = 0
    slack = 0.0
    for j in range(count):
        excess = _dot(a.rows[j], chosen) - a.limits[j]
        # a hard row binds within the tolerance it was solved with; a soft one when violated
        binds = excess > -2.0 * a.hard_tolerance if a.is_hard[j] > 0.0 else excess > 0.0
        a.multipliers[j] = 1.0 if binds else 0.0
        if a.is_hard[j] == 0.0:
            slack = max(slack, excess)
        if binds:
            active += 1
            s = a.kinds[j]
            if 0 <= s < 4:
                a.active_sets[s, k, a.joints[j]] = 1.0
            elif s >= 4:
                a.active_norms[s - 4, k] = 1.0
    a.active[k] = active
    a.slack[k] = slack
    correction = 0.0
    for i in range(chosen.shape[0]):
        correction += (chosen[i] - a.tau_nominal[k, i]) ** 2
    a.correction[k] = np.sqrt(correction)
    return np.isfinite(np.sum(chosen))


@_step_jit
def cbf_step(k, a):
    count = _rows(k, a)
    w = a.work
    h, weights, tau = w.per_row[0], w.per_row[1], w.solver[TAU]
    for j in range(count):  # solve with the hard limits lowered: checked as given after
        h[j] = a.limits[j] - a.hard_tolerance if a.is_hard[j] > 0.0 else a.limits[j]
        weights[j] = a.weights[j]
    # Warm: from the rows that bound at the step before (w.binding keeps them; a run's rows
    # keep their order), which most often still do.
    _newton(a.tau_nominal[k], a.rows, h, weights, count, a.iterations, a.tolerance, w.solver,
            w.matrices[FACTOR], w.binding, True)
    # A hard row may slip by ~ρ_soft·(soft excess)/ρ_hard where tracking pulls hard against
    # it: re-solve with tracking weighed less, down to the hard rows alone; only when those
    # alone cannot be met is the step infeasible (then cbf_record applies the backup).
    for _ in range(3):
        if not _hard_violated(a.rows, a.limits, a.is_hard, count, tau):
            break
        for j in range(count):
            if a.is_hard[j] == 0.0:
                weights[j] = weights[j] * 1e-3 if weights[j] > a.rho_soft * 1e-5 else 0.0
        _newton(a.tau_nominal[k], a.rows, h, weights, count, a.iterations, a.tolerance,
                w.solver, w.matrices[FACTOR], w.binding, True)
    return _record(k, a, count, tau)


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
            out["cbf_slack"], out["cbf_active"], out["cbf_correction"], out["cbf_infeasible"],
            cbf_work(n, rows, p.payload_grid))

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
