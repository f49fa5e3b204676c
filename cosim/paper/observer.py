"""FLNN velocity observer, eqs. (5)–(10), gain k0 from (8), weight law (24) or error-driven.

The observer is integrated in its z form (7)/(9), which needs only the measured position y:

    x̂1' = x̂2 + kD x̃1,   ẑ2' = Ŵoᵀ σo(x̂) + M⁻¹(τ − τ_d) + k0 x̃1,   x̂2 = ẑ2 + kp x̃1,

with x̃1 = y − x̂1. When ν is small k0 exceeds 10⁴ and the output injection is stiff, so each
sub-step treats the linear part (x̂1, ẑ2) by backward Euler, which is L-stable for every k0
(it cannot blow up, it only damps), and the NN and torque terms explicitly. y is interpolated
linearly between the two samples that bound the master step; a sub-step's σo, k0 and the
error-driven weight law are evaluated with the old x̂1 and the sub-step's *end* measurement
y_{j+1} (consistent first order; tests/test_references.py checks the scheme as written and
its convergence to the continuous law).

Basis choices for the printed σo = [q̂; q̂̇; q̂̈; |q̂|; |q̂̇|], whose q̂̈ closes an algebraic
loop: "lagged" uses q̂̈ from the previous sub-step; "no_acceleration" drops it.
Weight laws: "paper" is (24) as printed, Ŵo' = Fo(κo·1 − Ŵo), which has no error signal;
"error_driven" is Kim & Lewis's Ŵo' = Fo σo x̃1ᵀ − κo Fo ‖x̃1‖ Ŵo.

**The bound ε(t) on |q̇ − x̂2| (``qdot_hat_bound``), certified beside the FLNN.** The FLNN's
error dynamics give no bound the closed loop cannot break: their forcing is the plant's
acceleration, which the safety filter's braking (kilo-newton-metres) drives, so a bound
resting on a *declared* rate of it (the former J̄, ``uncertainty.observer_residual_rate``)
failed in near-boundary runs (issue 30, by up to 2.7×). Instead the observer keeps an
interval q̇(t_k) ∈ [lo_k, hi_k] per joint, proven from what is declared and what the loop
knows, and publishes

    ε_i(t_k) = |x̂2,i − c_i| + r_i,   c, r the interval's centre and half-width,

which holds whatever x̂2 does. The interval:

1. starts at x̂2(0) ± the declared initial error (ε(0) is that error);
2. is propagated over each step [t_k−1, t_k] by a bound q̈ ∈ [a_lo, a_hi] on the true
   acceleration: the torque τ applied over the step is known (the input ``tau``), and the
   plant is the nominal model (inertia_model's ``nominal_model``: the planar chain or a
   URDF's spatial chain, cosim.dynamics) plus a payload Δm in the declared range at its
   payload point (the planar chain's last centre of mass, a URDF's tip frame) plus a
   disturbance |d| ≤ d̄, so
   q̈ = M(Δm)⁻¹(τ − τ_d − d − b(q, q̇, Δm)). With J the payload point's Jacobian,
   K = J M̂⁻¹ Jᵀ = VΛVᵀ and s_j(Δm) = Δm/(1 + Δm λ_j) (each increasing in Δm), at a velocity c
   q̈ = u − Σ_j s_j R_j v_jᵀ(J u + γ), u = M̂⁻¹(τ − τ_d − b̂(c)), R = M̂⁻¹JᵀV, γ = J̇c − g:
   linear in each s_j, so exact at the ends of their ranges. For the true q̇ = c + δ,
   |δ_j| ≤ r_j: b's velocity part is a quadratic form (Γ, affine in Δm), and
   M(Δm)⁻¹ = M̂⁻¹ − R diag(s) Rᵀ, so the linear part M(Δm)⁻¹B(Δm)δ is bounded at the
   vertices of (s_1 … s_d, Δm) (multilinear; d = 2 in the plane, 3 in space), the
   quadratic part and d̄ through max |M(Δm)⁻¹| entrywise. The velocity box itself is an
   a-priori enclosure of q̇ over the step (the interval widened by ρ) that the resulting
   bound must confirm
   (dt·max(−a_lo, a_hi, 0) ≤ ρ), widened until it does;
3. is intersected with the estimates from the measured positions over the last N = 1 …
   ``window`` steps: q̇(t_k) = (q(t_k) − q(t_k−N))/T + (1/T)∫(s − t_k−N) q̈(s) ds with
   T = N dt, the noise |q_meas − q| ≤ n̄ contributing ±2n̄/T and q̈ the bounds of 2. (These
   bring the interval back within a few steps whatever happened before, and keep it
   ~2√(n̄ Δa) wide for an acceleration band Δa; without noise or payload it follows q̇ to
   ~0.03 rad/s.)
4. The payload dominates Δa (the Monte Carlo's 0–1 kg at the tip of a 2.3 kg link), and
   it is constant: the declared range is split into ``payload_cells`` cells, each with its
   own interval (1.–3. with the cell's range). A cell whose interval empties (no q̇ fits
   its payloads and the measurements) is dropped; ε(t) uses the hull of the live cells'.
   On the near-boundary runs only the true payload's cell is left after the first braking,
   which takes the median ε from ~0.67 to ~0.48 rad/s (4 cells). Were every live cell to
   fail at once (outside what is assumed), all restart from their hull.

*Assumption* (the one approximation, beside rounding): over a step, q̈ is bounded by its
bounds at the step's two measured positions y_k−1 and y_k (M and b taken at the measured
position, not at the true q between them: first order in n̄ and in the ≤ 0.015 rad a joint
moves in a step, the approximation the safety filter declares too, docs/safety/filter.md). Every
other quantity is declared (payload range, n̄, initial error, d̄) or known (τ, the nominal
chain, τ_d's model). A plant outside these (an undeclared payload, friction, disturbance)
may break ε(t): tests/test_observer_bound.py checks it on every step of near-boundary
runs inside the declared ranges and shows it failing outside them. The windows' best N was
≤ 8 steps on those runs and on the paper's: ``window`` = 16 keeps the cost small. Cost
(measured, this machine): the observer's kernel 0.98 → 4.39 µs a step on the paper's arm
with one payload cell (benchmarks/bench_cosim.py --profile; the fused closed loop 5.6 →
9.2 µs), ~+4.3 µs a step with the Monte Carlo's four cells.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal, NamedTuple

import numpy as np
from numba import njit
from pydantic import Field

from ..blocks.base import Block, BlockContext, Ports, register_block
from ..blocks.binding import master_step, parameter, reads, scratch, uncertainty, writes
from ..dynamics.model import (
    RigidBodyModel,
    model_bias,
    model_friction,
    model_friction_spread,
    model_geometry,
    model_mass,
    model_payload,
    model_point_forms,
    model_velocity_forms,
    own_scratch,
    payload_dim,
    planar_model,
)
from ..numba_compat import no_refcount_jit
from ..records import kernel_record
from ..schema import (
    FiniteFloat,
    NonNegativeFloat,
    PerJoint,
    PositiveFloat,
    Section,
    per_joint_array,
)
from ..signals import Signal
from .inertia import InertiaModel, default_links
from .linalg import invert, linear_part, small_symmetric_eigen, solve
from .sampled_loop import check_friction_step

LAWS = {"paper": 0, "error_driven": 1}
BASES = {"lagged": 0, "no_acceleration": 1}


class ObserverParams(Section):
    """Gains of (5)–(10) and (24); see the module docstring for ``law`` and ``basis``."""

    # gain kp of the output injection into the velocity estimate, x̂2 = ẑ2 + kp x̃1, 1/s
    kp: PositiveFloat = 100.0
    # gain kD of the output injection into the position estimate, x̂1' = x̂2 + kD x̃1, 1/s
    kd: PositiveFloat = 100.0
    # ν in the denominator of the gain k0 of (8), beside ‖x̃1‖²: the smaller, the larger k0
    # near x̃1 = 0, rad²
    nu: PositiveFloat = 5e-4
    # bound Z_Wo on the FLNN's ideal weights ‖Wo‖ (Assumption 4), in k0 of (8), mixed units
    z_wo: NonNegativeFloat = 10.0
    # bound ε_oM on the FLNN's approximation error, in k0 of (8), rad/s²
    eps_om: NonNegativeFloat = 1.0
    zeta_om: NonNegativeFloat = 1.0  # bound ζ_oM on the disturbance, in k0 of (8), rad/s²
    # learning rate Fo of the observer's weight law (24), a scalar times I, mixed units
    fo: PositiveFloat = 1.0
    # κo of the weight law: the value (24) draws Ŵo's entries to, or the factor of the
    # error-driven law's decay rate κo Fo ‖x̃1‖, mixed units
    kappa_o: NonNegativeFloat = 6.0
    # the weight law (a name): "paper", (24) as printed, or "error_driven", Kim & Lewis's
    law: Literal["paper", "error_driven"] = "error_driven"
    # the basis σo's acceleration q̂̈ (a name): "lagged", from the previous sub-step, or
    # "no_acceleration", dropped
    basis: Literal["lagged", "no_acceleration"] = "no_acceleration"
    # sub-steps of the observer's integration per master step, dimensionless (a count)
    substeps: Annotated[int, Field(ge=1, le=1000)] = 10
    # the disturbance torque τ_d that (7) assumes known, per joint or one for all, N·m
    tau_d: PerJoint[FiniteFloat] = 0.01
    # the initial velocity estimate x̂2(0): "desired", the reference's q̇_d(0), "zero", or
    # one value per joint, rad/s
    initial_velocity: Annotated[Literal["desired", "zero"] | list[FiniteFloat],
                                PerJoint.marker] = "desired"
    # longest window of the certified envelope's position-difference estimates of q̇ (ε(t),
    # module docstring), dimensionless (a count of steps)
    window: Annotated[int, Field(ge=1, le=10000)] = 16
    # cells of the declared payload range the envelope tracks apart, each dropped once the
    # measurements rule its payloads out (ε(t), module docstring), dimensionless (a count)
    payload_cells: Annotated[int, Field(ge=1, le=64)] = 4


def basis_size(links: int, basis: str) -> int:
    return (5 if basis == "lagged" else 4) * links


@kernel_record
class ObserverArgs(NamedTuple):
    dt: master_step()  # s
    substeps: parameter()
    law: int  # LAWS
    basis: int  # BASES
    kp: parameter()
    kd: parameter()
    nu: parameter()
    z_wo: parameter()
    eps_sum: float  # ε_oM + ζ_oM
    kp_kd: float  # kp kD, √No and 2√(kp kD): (8)'s constant factors, once
    sqrt_basis: float
    den_scale: float
    fo: parameter()
    kappa_o: parameter()
    n_basis: int
    tau_d: parameter()  # (n,) N·m
    initial_velocity: np.ndarray  # (n,) x̂2(0)
    noise_bound: uncertainty()  # declared |q_meas − q|, rad
    initial_error: uncertainty("initial_velocity_error")  # declared |q̇(0) − x̂2(0)|, rad/s
    state: scratch("3 * n + n_basis * n")  # x̂1, ẑ2, q̂̈, Ŵo (n_basis × n), flat; Ŵo from 0
    q_meas: reads()
    tau: reads()
    M_model: reads()
    q_d: reads()
    q_hat: writes()
    qdot_hat: writes()
    k0: writes()
    W_o_norm: writes()
    error_bound: writes("qdot_hat_bound")  # ε(t) per joint
    envelope_centre: writes("qdot_envelope_centre")  # the certified interval's centre c
    drift: writes("qdot_hat_drift")  # dx̂2/dt − M̂⁻¹τ
    # scratch, so that a step allocates nothing
    sigma: scratch("n_basis")  # σo
    y: scratch("n")
    x1_err: scratch("n")  # x̃1
    x2: scratch("n")  # x̂2
    g: scratch("n")  # Ŵoᵀσo (+ M̂⁻¹τ)
    torque_term: scratch("n, 1")  # M̂⁻¹(τ − τ_d), the solve's right-hand side
    lu: scratch("n, n")  # M̂'s elimination
    env: Envelope  # the certified velocity envelope behind ε(t)


@njit(cache=True)
def error_envelope(kp, kd, k0):
    """The frozen-time error dynamics of (12), x̃1' = w, w' = −k0 x̃1 − (kp + kD) w + f̃, with
    w = x̃1' = x̃2 − kD x̃1: (decay rate of the slowest mode (1/s), peak factor of w's free
    response to w(0) (≥ 1), L1 norm of the impulse response from f̃' to w (s²)).
    Not what ε(t) rests on any more (module docstring): a frozen-time envelope is no proof
    while k0 moves, and its forcing's rate is the closed loop's; kept as the analysis
    docs/safety/filter.md describes."""
    sigma = 0.5 * (kp + kd)
    if k0 > sigma * sigma:  # complex poles −σ ± jω: |w| ≤ w0·√k0/ω·e^{−σt}
        omega = np.sqrt(k0 - sigma * sigma)
        ratio = sigma * np.pi / (2.0 * omega)  # ∫|e^{−σt} sin ωt/ω| dt = coth(σπ/2ω)/k0
        return sigma, np.sqrt(k0) / omega, 1.0 / (np.tanh(ratio) * k0)
    root = np.sqrt(sigma * sigma - k0)  # real poles −σ ± root: a positive impulse response
    slow, fast = sigma - root, sigma + root
    peak = (slow + fast) / max(fast - slow, 1e-12)
    return slow, max(peak, 1.0), 1.0 / max(k0, 1e-300)


# ----------------------------------------------------------------------------------------
# The certified velocity envelope: ε(t) = |x̂2 − c| + r with q̇ ∈ [c − r, c + r] proven
# (see the module docstring).

@kernel_record
class Envelope(NamedTuple):
    """The certified envelope's constants, its state, its per-position cache (two slots: the
    step's two ends, slot k % 2 for y_k) and its scratch. d is the payload point's
    dimension (the model's: 2 for the planar chain, 3 for a spatial one)."""

    model: RigidBodyModel  # the nominal model (inertia_model's nominal_model)
    zeros: scratch("n")  # stays 0
    payload_low: float  # declared payload range, kg
    payload_high: float
    cells: np.ndarray  # (P + 1,) the payload cells' edges, low … high, kg
    disturbance: uncertainty()  # declared d̄, N·m
    window: parameter()  # longest window of the position-difference estimates, steps
    interval: scratch("P, 2, n")  # per payload cell, q̇(t_k) ∈ [lo, hi], the state
    alive: np.ndarray  # (P,) 1 while the cell is consistent with the measurements, else 0
    since: scratch("P", int)  # the first step whose acc row the cell has (revived cells)
    hull: scratch("2, n")  # the hull of the live cells' intervals: what ε(t) uses
    rho: scratch("P, n")  # the a-priori enclosure's widening of the last step, rad/s
    acc: scratch("P, steps, 2, n")  # q̈ ∈ [lo, hi] over [t_j, t_j+1], rad/s²
    minv: scratch("2, n, n")  # M̂⁻¹ at the slot's position
    pabs: scratch("2, P, n, n")  # max over the corners of |M(Δm)⁻¹|, entrywise
    rmat: scratch("2, n, d")  # M̂⁻¹JᵀV
    vec: scratch("2, d, d")  # V, K = J M̂⁻¹ Jᵀ = V Λ Vᵀ
    s: scratch("2, P, 2, d")  # s_j(Δm) = Δm/(1 + Δm λ_j) at [slot, cell, end, j]
    forms: scratch("2, 2, n, n, n")  # Γ of the nominal model [0] and of a unit payload [1]
    grav: scratch("2, n")  # the nominal model's gravity torque G(y)
    jac: scratch("2, d, n")  # the payload point's Jacobian J
    point_forms: scratch("2, d, n, n")  # J̇v = (vᵀP_r v)_r, the point's velocity part
    lift: scratch("2, d")  # −g at the point: γ = J̇v − g
    # scratch
    mass: scratch("n, n")
    lu: scratch("n, n")
    kmat: scratch("d, d")
    lam: scratch("d")
    eigen_work: scratch("d, d")
    work: scratch("8, n")  # e, plus, minus, u, centre, radius, acc lo, acc hi
    bmat: scratch("2, n, n")  # B(Δm) at the payload cell's ends
    linear: scratch("2, n, n")  # M̂⁻¹B(Δm) at the cell's ends
    projected: scratch("2, d, n")  # RᵀB(Δm) at the cell's ends
    point: scratch("d")  # J u + γ
    jac_work: scratch("d, n")


E_, PLUS_, MINUS_, U_, CENTRE_, RADIUS_, ALO_, AHI_ = range(8)


@no_refcount_jit(cache=True)
def envelope_position(env, y, slot):
    """What the acceleration bound needs of the position y, into cache ``slot``: M̂⁻¹, the
    payload point's J and the quadratic form of J̇v, K = J M̂⁻¹ Jᵀ = VΛVᵀ, s_j at the ends of
    the payload range, the entrywise largest magnitude of M(Δm)⁻¹ = M̂⁻¹ − R diag(s) Rᵀ
    (R = M̂⁻¹JᵀV) over the corners of (s_1 … s_d), the Γ forms and the gravity torque."""
    n = y.shape[0]
    model = env.model
    d = payload_dim(model)
    model_geometry(model, y)
    model_mass(model, 1.0, 0.0, env.mass)
    minv = env.minv[slot]
    invert(env.mass, minv, env.lu)
    jac = env.jac[slot]
    model_payload(model, env.zeros, 0.0, jac, env.point)
    kmat = env.kmat
    for r in range(d):
        for c in range(d):
            total = 0.0
            for i in range(n):
                for j in range(n):
                    total += jac[r, i] * minv[i, j] * jac[c, j]
            kmat[r, c] = total
    vec = env.vec[slot]
    small_symmetric_eigen(kmat, env.lam, vec, env.eigen_work)
    rmat = env.rmat[slot]
    for i in range(n):
        for j in range(d):
            total = 0.0
            for col in range(n):
                direction = 0.0
                for r in range(d):
                    direction += jac[r, col] * vec[r, j]
                total += minv[i, col] * direction
            rmat[i, j] = total
    for cell in range(env.cells.shape[0] - 1):
        s = env.s[slot, cell]
        for end in range(2):
            payload = env.cells[cell + end]
            for j in range(d):
                s[end, j] = payload / (1.0 + payload * max(env.lam[j], 0.0))
        pabs = env.pabs[slot, cell]
        for i in range(n):
            for col in range(n):
                # M(Δm)⁻¹ is separable in the s_j: its extremes over the corners are the
                # sums of each term's
                low = high = minv[i, col]
                for j in range(d):
                    term = rmat[i, j] * rmat[col, j]
                    low -= max(s[0, j] * term, s[1, j] * term)
                    high -= min(s[0, j] * term, s[1, j] * term)
                pabs[i, col] = max(abs(low), abs(high))
    e, plus = env.work[E_], env.work[PLUS_]
    model_velocity_forms(model, 1.0, 0.0, e, plus, env.forms[slot, 0])
    model_velocity_forms(model, 0.0, 1.0, e, plus, env.forms[slot, 1])
    model_point_forms(model, e, env.jac_work, env.point, env.point_forms[slot], env.lift[slot])
    model_bias(model, env.zeros, 1.0, 0.0, 1.0, env.grav[slot])


@no_refcount_jit(cache=True)
def envelope_acceleration(env, slot, cell, tau, tau_d, centre, radius, lo, hi):
    """Widen [lo, hi] (per joint) to hold q̈ = M(Δm)⁻¹(τ − τ_d − d − b(y, q̇, Δm)) at the
    cached position ``slot`` for every q̇ with |q̇ − centre| ≤ radius, Δm in the payload
    ``cell`` and |d| ≤ d̄ (per joint): the payload exactly at q̇ = centre (q̈ = u − R diag(s)
    Rᵀ... linear in each s_j), the velocity's linear part through M(Δm)⁻¹B(Δm) =
    M̂⁻¹B(Δm) − Σ_j s_j R_j (R_jᵀB(Δm)) at the cell's ends (B is affine in Δm) and over the
    box of (s_1 … s_d) (a sum of terms each linear in one s_j: its extremes are the sums of
    the terms'), its quadratic part and d̄ through max |M(Δm)⁻¹| row by row."""
    n = centre.shape[0]
    d = payload_dim(env.model)
    minv, rmat, vec, s = env.minv[slot], env.rmat[slot], env.vec[slot], env.s[slot, cell]
    forms, jac = env.forms[slot], env.jac[slot]
    point_forms, lift = env.point_forms[slot], env.lift[slot]
    pabs = env.pabs[slot, cell]
    payload_low, payload_high = env.cells[cell], env.cells[cell + 1]
    u, work = env.work[U_], env.work[E_]
    bmat, linear, projected = env.bmat, env.linear, env.projected
    for l in range(n):  # noqa: E741
        bias = env.grav[slot, l] + tau_d[l]
        for j in range(n):
            for k in range(n):
                bias += forms[0, l, j, k] * centre[j] * centre[k]
        work[l] = tau[l] - bias
    friction, spread_of_friction = env.work[PLUS_], env.work[MINUS_]
    friction[:] = 0.0
    model_friction(env.model, centre, friction)
    spread_of_friction[:] = 0.0
    model_friction_spread(env.model, centre, radius, spread_of_friction)
    for l in range(n):  # noqa: E741
        work[l] -= friction[l]
        for j in range(n):
            bmat[0, l, j], bmat[1, l, j] = linear_part(forms[0], forms[1], centre, payload_low,
                                                       payload_high, l, j)
    linear[:] = 0.0  # M̂⁻¹B and RᵀB at each end of the cell, B's column j row by row
    projected[:] = 0.0
    for end in range(2):
        for j in range(n):
            for l in range(n):  # noqa: E741
                entry = bmat[end, l, j]
                for i in range(n):
                    linear[end, i, j] += minv[i, l] * entry
                for r in range(d):
                    projected[end, r, j] += rmat[l, r] * entry
    for i in range(n):
        total = 0.0
        for l in range(n):  # noqa: E741
            total += minv[i, l] * work[l]
        u[i] = total
    # J u + γ, γ = J̇q̇ − g
    point = env.point
    for r in range(d):
        total = lift[r]
        for k in range(n):
            total += jac[r, k] * u[k]
            for j in range(n):
                total += point_forms[r, j, k] * centre[j] * centre[k]
        point[r] = total
    size = 0.0
    for l in range(n):  # noqa: E741 — the quadratic part plus d̄, per equation l
        worst = 0.0
        for end in range(2):
            mass = payload_low if end == 0 else payload_high
            total = 0.0
            for j in range(n):
                for k in range(n):
                    total += abs(forms[0, l, j, k] + mass * forms[1, l, j, k]) \
                        * radius[j] * radius[k]
            worst = max(worst, total)
        work[l] = worst + env.disturbance + spread_of_friction[l]
    for i in range(n):
        low, high = u[i], u[i]
        for j in range(d):  # −s_j R_ij (v_jᵀ(J u + γ)), s_j over its range
            along = 0.0
            for r in range(d):
                along += vec[r, j] * point[r]
            z = rmat[i, j] * along
            a, b = -s[0, j] * z, -s[1, j] * z
            low += min(a, b)
            high += max(a, b)
        spread = 0.0
        for j in range(n):
            worst = 0.0
            for end in range(2):
                least = most = linear[end, i, j]
                for r in range(d):
                    term = rmat[i, r] * projected[end, r, j]
                    least -= max(s[0, r] * term, s[1, r] * term)
                    most -= min(s[0, r] * term, s[1, r] * term)
                worst = max(worst, -least, most)
            spread += worst * radius[j]
        for l in range(n):  # noqa: E741
            spread += pabs[i, l] * work[l]
        size = spread
        lo[i] = min(lo[i], low - size)
        hi[i] = max(hi[i], high + size)


@no_refcount_jit(cache=True)
def envelope_windows(k, dt, noise, window, y, acc, interval):
    """Intersect q̇(t_k) ∈ ``interval`` with the estimates from the position differences over
    the last N = 1 … ``window`` steps: q̇(t_k) = (q(t_k) − q(t_k−N))/T + (1/T)∫(s − t_k−N)q̈ ds,
    T = N dt, the measurements within ±``noise`` (±2 noise/T) and q̈ within acc[j] (lo, hi)
    over step j, whose weight ∫(s − t_k−N) ds over the step is dt²(j − k + N + ½). False
    when no q̇ fits every estimate (then the interval is the hull of the crossing ends)."""
    n = y.shape[1]
    consistent = True
    for i in range(n):
        sum_lo, sum_hi, moment_lo, moment_hi = 0.0, 0.0, 0.0, 0.0
        lo, hi = interval[0, i], interval[1, i]
        for length in range(1, min(k, window) + 1):
            j = k - length
            if not (np.isfinite(acc[j, 0, i]) and np.isfinite(acc[j, 1, i])):
                break  # a step whose q̈ no bound held: no window over it says anything
            sum_lo += acc[j, 0, i]
            sum_hi += acc[j, 1, i]
            moment_lo += (j - k + 0.5) * acc[j, 0, i]
            moment_hi += (j - k + 0.5) * acc[j, 1, i]
            span = length * dt
            base = (y[k, i] - y[j, i]) / span
            spread = 2.0 * noise / span
            lo = max(lo, base - spread + (moment_lo + length * sum_lo) * dt / length)
            hi = min(hi, base + spread + (moment_hi + length * sum_hi) * dt / length)
        if lo > hi:  # no q̇ fits: outside what is assumed; the hull of the two, never less
            lo, hi = hi, lo
            consistent = False
        interval[0, i], interval[1, i] = lo, hi
    return consistent


@no_refcount_jit(cache=True)
def envelope_cell(k, dt, y, tau, tau_d, noise, env, cell):
    """One payload cell from t_k−1 to t_k: q̈'s bound over the step on an a-priori enclosure
    of q̇ that the bound itself must confirm (widened until it does), the interval
    propagated by it, then intersected with the windows. False when the cell's payloads
    cannot explain the measurements."""
    n = y.shape[1]
    centre, radius = env.work[CENTRE_], env.work[RADIUS_]
    alo, ahi = env.work[ALO_], env.work[AHI_]
    interval, rho, acc = env.interval[cell], env.rho[cell], env.acc[cell]
    for i in range(n):
        centre[i] = 0.5 * (interval[0, i] + interval[1, i])
    for _ in range(60):
        for i in range(n):
            radius[i] = 0.5 * (interval[1, i] - interval[0, i]) + rho[i]
            alo[i], ahi[i] = np.inf, -np.inf
        envelope_acceleration(env, (k - 1) % 2, cell, tau, tau_d, centre, radius, alo, ahi)
        envelope_acceleration(env, k % 2, cell, tau, tau_d, centre, radius, alo, ahi)
        confirmed = True
        for i in range(n):  # q̇ over the step stays within [lo + dt·min(0, alo), hi + …]
            need = dt * max(-alo[i], ahi[i], 0.0)
            if need > rho[i]:
                confirmed = False
                rho[i] = max(1.5 * need, 2.0 * rho[i])
        if confirmed:
            break
    for i in range(n):
        if not confirmed or not (alo[i] > -np.inf and ahi[i] < np.inf):
            alo[i], ahi[i] = -np.inf, np.inf
        rho[i] = 1.2 * dt * max(-alo[i], ahi[i], 0.0) + 1e-9  # next step's first guess
        acc[k - 1, 0, i] = alo[i]
        acc[k - 1, 1, i] = ahi[i]
        interval[0, i] += dt * alo[i]
        interval[1, i] += dt * ahi[i]
    return envelope_windows(k, dt, noise, min(env.window, k - env.since[cell]), y, acc,
                            interval)


@no_refcount_jit(cache=True)
def envelope_step(k, dt, y, tau, tau_d, noise, env):
    """The envelope from t_k−1 to t_k: each live payload cell (envelope_cell); a cell no
    q̇ fits is dropped (the payload is constant: it is not in that cell), unless every live
    cell fails at once (then outside what is assumed: every cell restarts from the hull of
    the failed ones, its windows from then on). The published interval (``hull``) is the
    hull of the live cells'."""
    n = y.shape[1]
    envelope_position(env, y[k], k % 2)
    cells = env.alive.shape[0]
    live = 0
    for cell in range(cells):
        if env.alive[cell] == 0.0:
            continue
        if envelope_cell(k, dt, y, tau, tau_d, noise, env, cell):
            live += 1
        else:
            env.alive[cell] = -1.0  # failed this step
    hull = env.hull
    for i in range(n):
        hull[0, i], hull[1, i] = np.inf, -np.inf
        for cell in range(cells):
            if env.alive[cell] != 0.0:
                hull[0, i] = min(hull[0, i], env.interval[cell, 0, i])
                hull[1, i] = max(hull[1, i], env.interval[cell, 1, i])
    for cell in range(cells):
        if live == 0:  # outside what is assumed: every cell again, from the failed hull
            if env.alive[cell] == 0.0:
                env.since[cell] = k
                for i in range(n):
                    env.rho[cell, i] = 0.0
            env.alive[cell] = 1.0
            for i in range(n):
                env.interval[cell, 0, i] = hull[0, i]
                env.interval[cell, 1, i] = hull[1, i]
        elif env.alive[cell] == -1.0:
            env.alive[cell] = 0.0


@njit(cache=True)
def _basis(x1, x2, qdd, basis, out):
    """σo = [x̂1; x̂2; q̂̈ (basis "lagged" only); |x̂1|; |x̂2|] into ``out``."""
    n = x1.shape[0]
    k = 3 * n if basis == 0 else 2 * n  # where |x̂1| starts
    for i in range(n):
        out[i] = x1[i]
        out[n + i] = x2[i]
        if basis == 0:
            out[2 * n + i] = qdd[i]
        out[k + i] = abs(x1[i])
        out[k + n + i] = abs(x2[i])


@njit(cache=True)
def _gain(a, x1_err_norm, w_norm, e_norm):
    """k0 of eq. (8)."""
    num = a.kp_kd * x1_err_norm + a.sqrt_basis * (a.z_wo + w_norm) + a.eps_sum + e_norm
    den = a.den_scale * (x1_err_norm * x1_err_norm + a.nu)
    return (num / den) ** 2


@njit(cache=True)
def _distance(u, v):
    """‖u − v‖, summed in index order (as np.sum would)."""
    total = 0.0
    for i in range(u.shape[0]):
        d = u[i] - v[i]
        total += d * d
    return np.sqrt(total)


@njit(cache=True)
def _weights_times(W, sigma, out):
    """out = Ŵoᵀσo, as loops: a BLAS call per sub-step costs more than its 2·No·n flops."""
    for i in range(out.shape[0]):
        total = 0.0
        for b in range(sigma.shape[0]):
            total += W[b, i] * sigma[b]
        out[i] = total


@njit(cache=True)
def observer_step(k, a):
    """One step of the observer (5)–(10), (24): its sub-steps, gain and weight law in one
    body, which its speed needs (the sub-step loop shares its scratch and hoisted
    constants; split, numba would pass them through the calls)."""
    n = a.q_meas.shape[1]
    n_basis = a.n_basis
    kp = a.kp
    c = kp + a.kd
    s = a.state
    x1 = s[0:n]
    z2 = s[n:2 * n]
    qdd = s[2 * n:3 * n]
    W = s[3 * n:3 * n + n_basis * n].reshape((n_basis, n))
    sigma, y, x1_err, x2, g = a.sigma, a.y, a.x1_err, a.x2, a.g  # scratch
    w_sq = 0.0  # ‖Ŵo‖², kept up to date by the weight law's loop below
    for b in range(n_basis):
        for i in range(n):
            w_sq += W[b, i] * W[b, i]
    if k == 0:  # x̂1(0) = y(0): x̃1(0) = 0; x̂2(0) as configured
        x1[:] = a.q_meas[0]
        z2[:] = a.initial_velocity
    else:  # integrate over [t_{k-1}, t_k] under the torque held over that interval
        y0 = a.q_meas[k - 1]
        y1 = a.q_meas[k]
        torque_term = a.torque_term
        for i in range(n):
            torque_term[i, 0] = a.tau[k - 1, i] - a.tau_d[i]
        solve(a.M_model[k - 1], torque_term, a.lu)  # M̂⁻¹(τ − τ_d), held over the step
        e_norm = _distance(a.q_d[k - 1], y0)
        h = a.dt / a.substeps
        # What no sub-step changes, once: the implicit part's coefficients h(kp + kD), h², and
        # the weight law's decay factor e^{−Fo h} (24) or its gains h Fo, h κo Fo.
        hc = h * c
        hh = h * h
        w_decay = np.exp(-a.fo * h)
        h_fo = h * a.fo
        h_kappa_fo = h * a.kappa_o * a.fo
        for j in range(a.substeps):
            frac = (j + 1) / a.substeps
            err_sq = 0.0
            for i in range(n):
                y[i] = y0[i] + (y1[i] - y0[i]) * frac
                x1_err[i] = y[i] - x1[i]
                err_sq += x1_err[i] * x1_err[i]
                x2[i] = z2[i] + kp * x1_err[i]
            x1_err_norm = np.sqrt(err_sq)
            k0 = _gain(a, x1_err_norm, np.sqrt(w_sq), e_norm)
            _basis(x1, x2, qdd, a.basis, sigma)
            _weights_times(W, sigma, g)
            # backward Euler of the linear part: (1 + h(kp + kD) + h²k0) x̂1⁺ = x̂1 + h ẑ2
            # + h² g + (h(kp + kD) + h²k0) y, then ẑ2⁺ = ẑ2 + h(g + k0 (y − x̂1⁺))
            denom = 1.0 + hc + hh * k0
            gain_y = hc + hh * k0
            for i in range(n):
                g[i] += torque_term[i, 0]
                x1_new = (x1[i] + h * z2[i] + hh * g[i] + gain_y * y[i]) / denom
                z2_new = z2[i] + h * (g[i] + k0 * (y[i] - x1_new))
                qdd[i] = (z2_new + kp * (y[i] - x1_new) - x2[i]) / h
                x1[i] = x1_new
                z2[i] = z2_new
            w_sq = 0.0
            if a.law == 0:  # (24): exact solution of Ŵo' = Fo(κo·1 − Ŵo) over h
                for b in range(n_basis):
                    for i in range(n):
                        W[b, i] = a.kappa_o + (W[b, i] - a.kappa_o) * w_decay
                        w_sq += W[b, i] * W[b, i]
            else:  # error-driven, decay term implicit so it never overshoots
                shrink = 1.0 + h_kappa_fo * x1_err_norm
                for b in range(n_basis):
                    for i in range(n):
                        W[b, i] = (W[b, i] + h_fo * (sigma[b] * x1_err[i])) / shrink
                        w_sq += W[b, i] * W[b, i]
    y_k = a.q_meas[k]
    err_sq = 0.0
    for i in range(n):
        x1_err[i] = y_k[i] - x1[i]
        err_sq += x1_err[i] * x1_err[i]
    w_norm = np.sqrt(w_sq)
    k0 = _gain(a, np.sqrt(err_sq), w_norm, _distance(a.q_d[k], y_k))
    qdot_hat = a.qdot_hat[k]
    for i in range(n):
        a.q_hat[k, i] = x1[i]
        qdot_hat[i] = z2[i] + kp * x1_err[i]
    a.k0[k] = k0
    a.W_o_norm[k] = w_norm
    # ε(t) from the certified envelope q̇(t_k) ∈ [lo, hi] (module docstring): whatever x̂2
    # is, |q̇ − x̂2| ≤ |x̂2 − c| + r with c, r the interval's centre and half-width.
    env = a.env
    interval = env.hull
    if k == 0:  # the declared initial error around x̂2(0), every payload cell alive
        envelope_position(env, y_k, 0)
        for i in range(n):
            interval[0, i] = qdot_hat[i] - a.initial_error
            interval[1, i] = qdot_hat[i] + a.initial_error
        for cell in range(env.alive.shape[0]):
            env.alive[cell] = 1.0
            env.since[cell] = 0
            for i in range(n):
                env.interval[cell, 0, i] = interval[0, i]
                env.interval[cell, 1, i] = interval[1, i]
                env.rho[cell, i] = 0.0
    else:
        envelope_step(k, a.dt, a.q_meas, a.tau[k - 1], a.tau_d, a.noise_bound, env)
    for i in range(n):
        low, high = interval[0, i], interval[1, i]
        if np.isfinite(low) and np.isfinite(high):
            centre = 0.5 * (low + high)
            a.error_bound[k, i] = abs(qdot_hat[i] - centre) + 0.5 * (high - low)
        else:  # no enclosure confirmed: nothing is known of q̇ (ε infinite, never NaN)
            centre = qdot_hat[i]
            a.error_bound[k, i] = np.inf
        a.envelope_centre[k, i] = centre
    # dx̂2/dt = Ŵoᵀσo + M̂⁻¹(τ − τ_d) + (k0 − kp kD) x̃1 + kp x̃2: all but M̂⁻¹τ and the
    # unknown kp x̃2 (|·| ≤ kp ε) is the drift the filter's rows on x̂2 need.
    _basis(x1, qdot_hat, qdd, a.basis, sigma)
    _weights_times(W, sigma, g)
    disturbance = a.torque_term  # the step's M̂⁻¹(τ − τ_d) is spent: its array is free
    for i in range(n):
        disturbance[i, 0] = a.tau_d[i]
    solve(a.M_model[k], disturbance, a.lu)  # M̂⁻¹τ_d
    finite = 0.0
    for i in range(n):
        a.drift[k, i] = g[i] - disturbance[i, 0] + (k0 - kp * a.kd) * x1_err[i]
        finite += qdot_hat[i] + x1[i]
    return np.isfinite(finite + w_norm)


@register_block
class FlnnObserver(Block):
    kind = "observer"
    Params = ObserverParams
    kernel = observer_step
    # tau_d_model: the disturbance bound τ_d (N·m per joint); observer_gain: Fo of (10),
    # for H1 (28).
    # tau_d_model: τ_d per joint (N·m), the disturbance (7) assumes; observer_gain: Fo
    PUBLISHES = {"tau_d_model": np.ndarray, "observer_gain": float}

    def __init__(self, params: ObserverParams, context: BlockContext):
        super().__init__(params, context)
        self.inputs = ("q_meas", "M_model", "q_d", "qdot_d")
        self.delayed = ("tau",)  # τ held over the previous step
        self.requires = ("nominal_model",)  # the certified envelope's model (ε(t))
        self.outputs = {
            "q_hat": Signal("n", "rad", "position estimate x̂1", "observer/q_hat",
                            estimates="q"),
            "qdot_hat": Signal("n", "rad/s", "velocity estimate x̂2", "observer/qdot_hat",
                               estimates="qdot"),
            "k0": Signal("1", "1/s²", "observer gain k0 of (8)", "observer/k0"),
            "W_o_norm": Signal("1", "-", "FLNN weight norm ‖Ŵo‖", "observer/W_norm", "‖Ŵo‖"),
            # For the safety filter and the evaluation; in the trace files, not recorded
            # (the recording shows ε(t) as the observer-error check's band).
            "qdot_hat_bound": Signal("n", "rad/s", "bound ε(t) on |q̇ − x̂2| per joint, from "
                                     "the declared uncertainty", kept=True),
            "qdot_hat_drift": Signal("n", "rad/s²", "dx̂2/dt − M̂⁻¹τ (its kp x̃2 term "
                                     "left out: unknown, |·| ≤ kp ε)", kept=True),
            # q̇ ∈ c ± (ε − |x̂2 − c|): the interval ε(t) is taken from, narrower than x̂2 ± ε
            # by 2|x̂2 − c| (the filter's backup check holds the velocity in it)
            "qdot_envelope_centre": Signal("n", "rad/s", "centre c of the certified velocity "
                                           "envelope (q̇ within ε − |x̂2 − c| of it)",
                                           kept=True),
        }
        self.publishes = {"tau_d_model": per_joint_array(params.tau_d, context.links),
                          "observer_gain": float(params.fo)}

    def check(self, published) -> None:
        check_friction_step(self, published)

    def reset(self, ports: Ports) -> None:
        p, n = self.params, self.context.links
        n_basis = basis_size(n, p.basis)
        if isinstance(p.initial_velocity, str):
            v0 = (ports.inputs["qdot_d"][0] if p.initial_velocity == "desired"
                  else np.zeros(n))
        else:
            v0 = np.asarray(p.initial_velocity, float)
        self.args = self.bind(
            ObserverArgs, ports, sizes={"n_basis": n_basis}, law=LAWS[p.law],
            basis=BASES[p.basis], eps_sum=p.eps_om + p.zeta_om, kp_kd=p.kp * p.kd,
            sqrt_basis=math.sqrt(n_basis), den_scale=2.0 * math.sqrt(p.kp * p.kd),
            n_basis=n_basis, initial_velocity=np.array(v0, float),
            env=self._envelope(ports, len(ports.inputs["q_meas"])))

    def _envelope(self, ports: Ports, steps: int) -> Envelope:
        """The envelope's constants (the nominal model the inertia model publishes, or the
        default chain when none is given, as in a unit test), state and scratch."""
        n, u = self.context.links, self.context.uncertainty
        model = ports.constants.get("nominal_model")
        if model is None:
            links = InertiaModel.chain_arrays(default_links(n))
            model = planar_model(**links, gravity=9.8)
        d = payload_dim(model)
        low, high = map(float, u.payload)
        cells = self.params.payload_cells if high > low else 1
        return self.bind(
            Envelope, ports, sizes={"P": cells, "steps": max(steps, 1), "d": d},
            model=own_scratch(model), payload_low=low, payload_high=high,
            cells=np.linspace(low, high, cells + 1), alive=np.ones(cells))
