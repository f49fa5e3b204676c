"""The filter's model of the plant at one state: the nominal model's M̂ and b̂ (the
inertia model's ``nominal_model``, cosim.dynamics: the planar chain or a URDF's spatial
chain), b's velocity part and the bound on its error, the payload point's Jacobian and the
payload's structure (see the package docstring)."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...dynamics.model import (
    model_bias,
    model_friction,
    model_friction_spread,
    model_geometry,
    model_mass,
    model_payload,
    model_velocity_forms,
    own_scratch,
)
from ...numba_compat import no_refcount_jit
from ..linalg import dot, invert, linear_part, product, small_symmetric_eigen
from .scratch import POLAR_ROWS, Matrix, PointRow, PointVector, Polar, Square, Vector


@no_refcount_jit(cache=True)
def velocity_forms_into(model, q, bodies, payload, polar, out):
    """Γ of the model at q (its bodies times ``bodies``, a point mass ``payload`` at its
    payload point) into ``out`` (n, n, n), ``polar`` (POLAR_ROWS, n) its scratch."""
    model_geometry(model, q)
    model_velocity_forms(model, bodies, payload, polar[Polar.E], polar[Polar.PLUS], out)


def velocity_forms(model, q) -> np.ndarray:
    """Γ (n, n, n): b's velocity part b_i(v) = vᵀ Γ_i v of the model (gravity 0), by
    polarisation of the recursive Newton–Euler bias."""
    n = q.shape[0]
    out = np.zeros((n, n, n))
    velocity_forms_into(own_scratch(model), q, 1.0, 0.0, np.zeros((POLAR_ROWS, n)), out)
    return out


@no_refcount_jit(cache=True)
def acceleration_error_bound_into(model, v, eps, minv, low, high, disturbance, nominal,
                                  payload, linear, quadratic, friction, out):
    """acceleration_error_bound into ``out``, with Γ of a unit payload given (``payload``)
    and ``linear`` (2, n, n), ``quadratic`` and ``friction`` (n,) as scratch."""
    quadratic_error_into(eps, low, high, disturbance, nominal, payload, quadratic)
    friction_error_into(model, v, eps, friction)
    linear_error_bound_into(v, eps, minv, low, high, nominal, payload, linear, quadratic,
                            friction, out)


@no_refcount_jit(cache=True, inline="always")
def friction_error_into(model, v, eps, out):
    """Per joint, the most the true friction at a velocity within ``eps`` of v differs from
    the nominal model's at v (cosim.dynamics.model.model_friction_spread), into ``out``."""
    out[:] = 0.0
    model_friction_spread(model, v, eps, out)


@no_refcount_jit(cache=True)
def quadratic_error_into(eps, low, high, disturbance, nominal, payload, quadratic):
    """Per row l of b, d̄ + Σ_jk (|Γ_l,jk| + |Δm|max |Γ^p_l,jk|) ε_j ε_k into ``quadratic``:
    the bias error's quadratic part and the disturbance, which depend on neither v nor M̂
    (a rollout, its ε and Γ fixed, takes them once)."""
    n = eps.shape[0]
    size = max(abs(low), abs(high))
    quadratic[:] = disturbance
    for l in range(n):  # noqa: E741
        for j in range(n):
            for k in range(n):
                quadratic[l] += (abs(nominal[l, j, k]) + size * abs(payload[l, j, k])) \
                    * eps[j] * eps[k]


@no_refcount_jit(cache=True)
def linear_error_bound_into(v, eps, minv, low, high, nominal, payload, linear, quadratic,
                            friction, out):
    """acceleration_error_bound into ``out`` with the quadratic part and the friction's
    error given per row (:func:`quadratic_error_into`, :func:`friction_error_into`),
    ``linear`` (2, n, n) as scratch."""
    n = v.shape[0]
    # B_lj = 2 Σ_k (Γ_l,jk + Δm Γ^p_l,jk) v_k at each end of the payload range, stored
    # transposed (linear[end, j, l]) so that (M̂⁻¹B)_ij runs along contiguous memory
    for l in range(n):  # noqa: E741
        for j in range(n):
            linear[0, j, l], linear[1, j, l] = linear_part(nominal, payload, v, low, high, l, j)
    for i in range(n):
        total = 0.0
        for j in range(n):
            at_low = at_high = 0.0
            for l in range(n):  # noqa: E741
                at_low += minv[i, l] * linear[0, j, l]
                at_high += minv[i, l] * linear[1, j, l]
            total += max(abs(at_low), abs(at_high)) * eps[j]
        for l in range(n):  # noqa: E741
            total += abs(minv[i, l]) * (quadratic[l] + friction[l])
        out[i] = total


@njit(cache=True)
def acceleration_error_bound(q, v, eps, minv, a, nominal):
    """Per joint i, a bound on |(M̂⁻¹(b(q, q̇) − b(q, v)))_i + (M̂⁻¹d)_i| for |q̇_j − v_j| ≤ ε_j
    and a disturbance |d_l| ≤ d̄. b's velocity part is b_l(v) = vᵀΓ_l v (``nominal``, plus
    Δm times a unit payload's), so b(v + δ) − b(v) = B δ + (δᵀΓ_l δ)_l with
    B_lj = 2 Σ_k Γ_l,jk v_k: the linear part through M̂⁻¹B keeps its cancellations (in a
    stretched arm most of the Coriolis force is radial: no torque), the quadratic part, the
    friction's error and d̄ are bounded row by row. Affine in Δm, so the worst case is at an
    end of its range."""
    n = q.shape[0]
    payload = np.zeros((n, n, n))
    velocity_forms_into(a.model, q, 0.0, 1.0, np.zeros((POLAR_ROWS, n)), payload)
    out = np.zeros(n)
    acceleration_error_bound_into(a.model, v, eps, minv, a.payload_low, a.payload_high,
                                  a.disturbance, nominal, payload, np.zeros((2, n, n)),
                                  np.zeros(n), np.zeros(n), out)
    return out


@no_refcount_jit(cache=True)
def nominal_model(a, y, v, nominal, bias):
    """The nominal model at (y, v): its M(y) into ``nominal`` and b̂ = C(y, v) v + G(y) +
    F̂(v) + τ_d (F̂ the nominal friction) into ``bias``."""
    model_geometry(a.model, y)
    model_mass(a.model, 1.0, 0.0, nominal)
    model_bias(a.model, v, 1.0, 0.0, 1.0, bias)
    model_friction(a.model, v, bias)
    for i in range(y.shape[0]):
        bias[i] += a.tau_d[i]


@no_refcount_jit(cache=True)
def moved_model(a, y, v, mass, minv, base):
    """At a predicted state (y, v): M̂⁻¹ into ``minv`` and M̂⁻¹b̂ into ``base`` (so that
    q̈ = M̂⁻¹τ − base), with M̂ moved from row k's by the nominal model's change."""
    matrices, moved_bias = a.work.matrices, a.work.vectors[Vector.MOVED_BIAS]
    nominal, shifted = matrices[Matrix.NOMINAL], matrices[Matrix.SHIFTED]
    nominal_model(a, y, v, nominal, moved_bias)
    n = y.shape[0]
    for i in range(n):
        for j in range(n):
            shifted[i, j] = mass[i, j] + nominal[i, j] - matrices[Matrix.NOMINAL_NOW, i, j]
    invert(shifted, minv, matrices[Matrix.LU])
    product(minv, moved_bias, base)


@no_refcount_jit(cache=True)
def payload_structure(low, high, minv, base, point_rows, point_vectors, squares, s_grid):
    """The payload's structure (see the package docstring) at one state, J and γ given (in
    ``point_rows`` and ``point_vectors``): K's eigenvalues and eigenvectors, s_j(Δm) on the
    grid, and the α_j = v_jᵀJM̂⁻¹ and β_j = v_jᵀ(γ − JM̂⁻¹b̂) a row is linear in."""
    n = minv.shape[0]
    jac, jm, alpha = point_rows[PointRow.JAC], point_rows[PointRow.JM], point_rows[PointRow.ALPHA]
    gamma, jb = point_vectors[PointVector.GAMMA], point_vectors[PointVector.JB]
    lam, beta = point_vectors[PointVector.LAM], point_vectors[PointVector.BETA]
    kmat, vec = squares[Square.KMAT], squares[Square.VEC]
    d = kmat.shape[0]
    for r in range(d):  # J M̂⁻¹ along M̂⁻¹'s rows (contiguous), each sum in the same order
        for col in range(n):
            jm[r, col] = 0.0
        for l in range(n):  # noqa: E741
            entry = jac[r, l]
            for col in range(n):
                jm[r, col] += entry * minv[l, col]
        jb[r] = dot(jac[r], base)
    for r in range(d):
        for c in range(d):
            kmat[r, c] = dot(jm[r], jac[c])
    small_symmetric_eigen(kmat, lam, vec, squares[Square.EIGEN])
    grid = s_grid.shape[0] - 1
    for g in range(grid + 1):
        payload = low + (high - low) * g / grid
        for j in range(d):
            s_grid[g, j] = payload / (1.0 + payload * lam[j])
    for j in range(d):
        for col in range(n):
            total = 0.0
            for r in range(d):
                total += vec[r, j] * jm[r, col]
            alpha[j, col] = total
        projected = 0.0
        for r in range(d):
            projected += vec[r, j] * jb[r]
        beta[j] = -projected
        for r in range(d):
            beta[j] += vec[r, j] * gamma[r]


@no_refcount_jit(cache=True)
def robust_model(a, y, v, eps, minv, base):
    """What the hard rows at (y, v) need beyond M̂⁻¹ and M̂⁻¹b̂: the bound on |M̂⁻¹(Δb + d)|
    (Vector.ROWS_ERROR) and the payload's structure, or, when M̂ is the plant's, M̂⁻¹Jᵀγ
    (Vector.PLANT_SHIFT). Returns the number of payload corners a row is taken at."""
    n = y.shape[0]
    w = a.work
    vectors, forms = w.vectors, w.forms
    robust = a.payload_high != 0.0 or a.payload_low != 0.0
    velocity_forms_into(a.model, y, 1.0, 0.0, w.polar, forms[0])
    if robust:  # else the payload's forms stay zero, as its range is
        velocity_forms_into(a.model, y, 0.0, 1.0, w.polar, forms[1])
    acceleration_error_bound_into(a.model, v, eps, minv, a.payload_low, a.payload_high,
                                  a.disturbance, forms[0], forms[1], w.linear,
                                  vectors[Vector.QUADRATIC], vectors[Vector.FRICTION],
                                  vectors[Vector.ROWS_ERROR])
    # the payload's structure (see the package docstring)
    corners = 1
    jac, gamma = w.point_rows[PointRow.JAC], w.point_vectors[PointVector.GAMMA]
    plant_shift = vectors[Vector.PLANT_SHIFT]
    plant_shift[:] = 0.0
    if robust:
        model_payload(a.model, v, 1.0, jac, gamma)
    if robust and not a.inertia_is_plant:
        payload_structure(a.payload_low, a.payload_high, minv, base, w.point_rows,
                          w.point_vectors, w.squares, w.s_grid)
        corners = w.corner_index.shape[0]
    elif robust:  # q̈ = u − Δm·M̂⁻¹Jᵀγ
        for i in range(n):
            for col in range(n):
                projected = 0.0
                for r in range(gamma.shape[0]):
                    projected += jac[r, col] * gamma[r]
                plant_shift[i] += minv[i, col] * projected
    return corners
