"""The filter's model of the plant at one state: the nominal chain's M̂ and b̂ (by
cosim.paper.inertia's chain kernels), b's velocity part and the bound on its error, the
payload's Jacobian and structure (see the package docstring)."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...dynamics.planar import com_kinematics
from ...numba_compat import no_refcount_jit
from ..inertia import chain_bias, chain_geometry, chain_mass
from ..linalg import dot, invert, product, symmetric_eigen
from .scratch import (
    ALPHA,
    BETA,
    CHAIN_SCRATCH_ROWS,
    GAMMA,
    JAC,
    JB,
    JM,
    KMAT,
    LAM,
    LU,
    MINUS,
    MOVED_BIAS,
    NOMINAL,
    NOMINAL_NOW,
    PLANT_SHIFT,
    PLUS,
    QUADRATIC,
    ROWS_ERROR,
    SHIFTED,
    UNIT,
    VEC,
    E,
)


@no_refcount_jit(cache=True)
def velocity_forms_into(q, m, l, lc, chain, out):  # noqa: E741
    """Γ of the chain at q into ``out`` (n, n, n), ``chain`` its scratch
    (CHAIN_SCRATCH_ROWS, n)."""
    n = q.shape[0]
    chain_geometry(q, l, lc, chain)
    e, plus, minus = chain[E], chain[PLUS], chain[MINUS]
    for j in range(n):
        for k in range(j, n):
            for i in range(n):
                e[i] = 0.0
            e[j] += 1.0
            e[k] += 1.0
            chain_bias(chain, e, m, 0.0, plus)
            e[k] -= 2.0
            chain_bias(chain, e, m, 0.0, minus)
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
    velocity_forms_into(q, m, l, lc, np.zeros((CHAIN_SCRATCH_ROWS, n)), out)
    return out


@no_refcount_jit(cache=True)
def acceleration_error_bound_into(v, eps, minv, low, high, disturbance, nominal, payload,
                                  linear, quadratic, out):
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
    velocity_forms_into(q, unit, a.l, a.lc, np.zeros((CHAIN_SCRATCH_ROWS, n)), payload)
    out = np.zeros(n)
    acceleration_error_bound_into(v, eps, minv, a.payload_low, a.payload_high, a.disturbance,
                                  nominal, payload, np.zeros((2, n, n)), np.zeros(n), out)
    return out


@no_refcount_jit(cache=True, inline="always")
def nominal_model(a, y, v, nominal, bias):
    """The nominal chain at (y, v): its M(y) into ``nominal`` and b̂ = C(y, v) v + G(y) + τ_d
    into ``bias``."""
    chain = a.work.chain
    chain_geometry(y, a.l, a.lc, chain)
    chain_mass(chain, a.m, a.inertia, nominal)
    chain_bias(chain, v, a.m, a.gravity, bias)
    for i in range(y.shape[0]):
        bias[i] += a.tau_d[i]


@no_refcount_jit(cache=True, inline="always")
def moved_model(a, y, v, mass, minv, base):
    """At a predicted state (y, v): M̂⁻¹ into ``minv`` and M̂⁻¹b̂ into ``base`` (so that
    q̈ = M̂⁻¹τ − base), with M̂ moved from row k's by the nominal chain's change."""
    matrices, moved_bias = a.work.matrices, a.work.vectors[MOVED_BIAS]
    nominal, shifted = matrices[NOMINAL], matrices[SHIFTED]
    nominal_model(a, y, v, nominal, moved_bias)
    n = y.shape[0]
    for i in range(n):
        for j in range(n):
            shifted[i, j] = mass[i, j] + nominal[i, j] - matrices[NOMINAL_NOW, i, j]
    invert(shifted, minv, matrices[LU])
    product(minv, moved_bias, base)


@no_refcount_jit(cache=True)
def payload_structure(low, high, minv, base, planar, pairs, squares, s_grid):
    """The payload's structure (see the package docstring) at one state, J and γ given (in
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
        jb[r] = dot(jac[r], base)
    for r in range(2):
        for c in range(2):
            kmat[r, c] = dot(jm[r], jac[c])
    symmetric_eigen(kmat, lam, vec)
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


@no_refcount_jit(cache=True, inline="always")
def robust_model(a, y, v, eps, minv, base):
    """What the hard rows at (y, v) need beyond M̂⁻¹ and M̂⁻¹b̂: the bound on |M̂⁻¹(Δb + d)|
    (ROWS_ERROR of the work vectors) and the payload's structure, or, when M̂ is the plant's,
    M̂⁻¹Jᵀγ (PLANT_SHIFT). Returns the number of payload corners a row is taken at."""
    n = y.shape[0]
    w = a.work
    vectors, forms = w.vectors, w.forms
    robust = a.payload_high != 0.0 or a.payload_low != 0.0
    velocity_forms_into(y, a.m, a.l, a.lc, w.chain, forms[0])
    if robust:  # else the payload's forms stay zero, as its range is
        velocity_forms_into(y, vectors[UNIT], a.l, a.lc, w.chain, forms[1])
    acceleration_error_bound_into(v, eps, minv, a.payload_low, a.payload_high, a.disturbance,
                                  forms[0], forms[1], w.linear, vectors[QUADRATIC],
                                  vectors[ROWS_ERROR])
    # the payload's structure (see the package docstring)
    corners = 1
    jac, gamma = w.planar[JAC], w.pairs[GAMMA]
    plant_shift = vectors[PLANT_SHIFT]
    plant_shift[:] = 0.0
    if robust:
        com_kinematics(y, v, a.l, a.lc, a.gravity, jac, gamma)
    if robust and not a.inertia_is_plant:
        payload_structure(a.payload_low, a.payload_high, minv, base, w.planar, w.pairs,
                          w.squares, w.s_grid)
        corners = w.corner_index.shape[0]
    elif robust:  # q̈ = u − Δm·M̂⁻¹Jᵀγ
        for i in range(n):
            for col in range(n):
                plant_shift[i] += minv[i, col] * (jac[0, col] * gamma[0]
                                                  + jac[1, col] * gamma[1])
    return corners
