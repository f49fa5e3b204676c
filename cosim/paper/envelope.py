"""The certified velocity envelope behind the observer's bound ε(t) on |q̇ − x̂2|
(``qdot_hat_bound``, :mod:`cosim.paper.observer`).

The FLNN's error dynamics give no bound the closed loop cannot break: their forcing is the
plant's acceleration, which the safety filter's braking (kilo-newton-metres) drives, so a bound
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

from enum import auto
from typing import NamedTuple

import numpy as np

from ..blocks.binding import parameter, scratch, uncertainty
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
    payload_dim,
)
from ..numba_compat import no_refcount_jit
from ..records import Rows, kernel_record
from .linalg import invert, linear_part, small_symmetric_eigen
from .position_windows import envelope_windows


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
    work: scratch("EnvelopeRow, n")
    bmat: scratch("2, n, n")  # B(Δm) at the payload cell's ends
    linear: scratch("2, n, n")  # M̂⁻¹B(Δm) at the cell's ends
    projected: scratch("2, d, n")  # RᵀB(Δm) at the cell's ends
    point: scratch("d")  # J u + γ
    jac_work: scratch("d, n")


class EnvelopeRow(Rows):
    """Rows of Envelope.work (n each), each a stage's scratch, some reused by the next."""

    # the polarisation's unit vector and its scratch (the velocity forms at a position);
    # then τ less the bias at the enclosure's centre (E), the nominal friction there (PLUS)
    # and its spread over the enclosure (MINUS)
    E = auto()
    PLUS = auto()
    MINUS = auto()
    U = auto()  # M̂⁻¹ applied to that torque
    CENTRE = auto()  # the a-priori enclosure of q̇ over the step: its centre
    RADIUS = auto()  # … and half-width
    ACC_LOW = auto()  # q̈'s bound over the step: its low end
    ACC_HIGH = auto()  # … and its high end


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
    e, plus = env.work[EnvelopeRow.E], env.work[EnvelopeRow.PLUS]
    model_velocity_forms(model, 1.0, 0.0, e, plus, env.forms[slot, 0])
    model_velocity_forms(model, 0.0, 1.0, e, plus, env.forms[slot, 1])
    model_point_forms(model, e, env.jac_work, env.point, env.point_forms[slot], env.lift[slot])
    model_bias(model, env.zeros, 1.0, 0.0, 1.0, env.grav[slot])


@no_refcount_jit(cache=True, inline="always")
def _linear_part_at_ends(env, slot, centre, payload_low, payload_high):
    """b's part linear in q̇ − centre, B(Δm), at each end of the payload cell (into
    ``env.bmat``), and M̂⁻¹B and RᵀB there (``env.linear``, ``env.projected``), B's column j
    row by row."""
    n = centre.shape[0]
    d = payload_dim(env.model)
    minv, rmat, forms = env.minv[slot], env.rmat[slot], env.forms[slot]
    bmat, linear, projected = env.bmat, env.linear, env.projected
    for l in range(n):  # noqa: E741
        for j in range(n):
            bmat[0, l, j], bmat[1, l, j] = linear_part(forms[0], forms[1], centre, payload_low,
                                                       payload_high, l, j)
    linear[:] = 0.0
    projected[:] = 0.0
    for end in range(2):
        for j in range(n):
            for l in range(n):  # noqa: E741
                entry = bmat[end, l, j]
                for i in range(n):
                    linear[end, i, j] += minv[i, l] * entry
                for r in range(d):
                    projected[end, r, j] += rmat[l, r] * entry


@no_refcount_jit(cache=True, inline="always")
def _quadratic_part(env, slot, radius, payload_low, payload_high, spread_of_friction, work):
    """Per equation l, the most b's part quadratic in q̇ − centre reaches over the box of
    half-widths ``radius`` and the payload cell's ends, plus d̄ and the friction's spread,
    into ``work``."""
    n = radius.shape[0]
    forms = env.forms[slot]
    for l in range(n):  # noqa: E741
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
    u, work = env.work[EnvelopeRow.U], env.work[EnvelopeRow.E]
    linear, projected = env.linear, env.projected
    for l in range(n):  # noqa: E741
        bias = env.grav[slot, l] + tau_d[l]
        for j in range(n):
            for k in range(n):
                bias += forms[0, l, j, k] * centre[j] * centre[k]
        work[l] = tau[l] - bias
    friction, spread_of_friction = env.work[EnvelopeRow.PLUS], env.work[EnvelopeRow.MINUS]
    friction[:] = 0.0
    model_friction(env.model, centre, friction)
    spread_of_friction[:] = 0.0
    model_friction_spread(env.model, centre, radius, spread_of_friction)
    for l in range(n):  # noqa: E741
        work[l] -= friction[l]
    _linear_part_at_ends(env, slot, centre, payload_low, payload_high)
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
    _quadratic_part(env, slot, radius, payload_low, payload_high, spread_of_friction, work)
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


@no_refcount_jit(cache=True, inline="always")
def envelope_cell(k, dt, y, tau, tau_d, noise, env, cell):
    """One payload cell from t_k−1 to t_k: q̈'s bound over the step on an a-priori enclosure
    of q̇ that the bound itself must confirm (widened until it does), the interval
    propagated by it, then intersected with the windows. False when the cell's payloads
    cannot explain the measurements."""
    n = y.shape[1]
    centre, radius = env.work[EnvelopeRow.CENTRE], env.work[EnvelopeRow.RADIUS]
    alo, ahi = env.work[EnvelopeRow.ACC_LOW], env.work[EnvelopeRow.ACC_HIGH]
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


@no_refcount_jit(cache=True, inline="always")
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
