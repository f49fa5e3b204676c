"""The QP's solver: the penalty form by semismooth Newton, each step a least-squares solve
in square-root form (Givens rotations), warm-started from the rows that bound before; and
:func:`add_row`, which writes a row of the QP it solves (scaled to unit norm)."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...numba_compat import no_refcount_jit
from ..linalg import dot
from .scratch import Solver

SOLVER_ROWS = len(Solver)  # a constant: compiled code takes no len() of a class


@no_refcount_jit(cache=True, inline="always")
def add_row(qp, count, row, limit, weight, hard, kind, joint):
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
    inverse = 1.0 / norm  # one division, not n + 1 (a step builds ~1000 rows)
    for j in range(n):
        G[count, j] = row[j] * inverse
    limits[count] = limit * inverse
    weights[count] = weight
    is_hard[count] = 1.0 if hard else 0.0
    kinds[count] = kind
    joints[count] = joint
    return count + 1


@no_refcount_jit(cache=True, inline="always")
def penalty(tau, tau_nominal, G, h, weights, count):
    """½‖τ − τ_nom‖² + ½Σ ρ_j (g_j τ − h_j)₊² over the first ``count`` rows."""
    own = 0.0
    for i in range(tau.shape[0]):
        own += (tau[i] - tau_nominal[i]) ** 2
    rows = 0.0
    for j in range(count):
        rows += weights[j] * np.maximum(dot(G[j], tau) - h[j], 0.0) ** 2
    return 0.5 * own + 0.5 * rows


@no_refcount_jit(cache=True, inline="always")
def piece_minimiser(tau_nominal, G, h, weights, count, binding, factor, rotated, out):
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


@no_refcount_jit(cache=True)
def newton(tau_nominal, G, h, weights, count, iterations, tolerance, solver, factor,
           binding, warm):
    """solve_soft_qp on the first ``count`` rows of G, h and the weights, its vectors in
    ``solver`` (Solver, n), R in ``factor`` and the rows violated in ``binding``: τ into
    ``solver[Solver.TAU]``; returns the iterations used. ``warm``: start from the minimiser of the
    piece the rows flagged in ``binding`` make (the step before's, where the rows keep their
    order; other rows' flags only make a worse start), not from τ_nom; where the rows
    violated there are those, it is the answer (the convex function's gradient is that
    piece's, zero), at no iteration."""
    n = tau_nominal.shape[0]
    tau, trial = solver[Solver.TAU], solver[Solver.TRIAL]
    gradient, direction = solver[Solver.GRADIENT], solver[Solver.DIRECTION]
    if warm:
        piece_minimiser(tau_nominal, G, h, weights, count, binding, factor, solver[Solver.ROTATED],
                        tau)
    else:
        for i in range(n):
            tau[i] = tau_nominal[i]
        binding[:count] = False
    scale = 1.0 + np.sqrt(dot(tau_nominal, tau_nominal))
    full_step = warm  # at τ, a minimiser of the piece ``binding`` flags
    for it in range(iterations):
        gradient[:] = 0.0
        same = True
        for j in range(count):
            excess = np.maximum(dot(G[j], tau) - h[j], 0.0)
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
        if np.sqrt(dot(gradient, gradient)) <= tolerance * scale:
            return it
        # The piece is quadratic: the Newton step goes to its minimiser.
        piece_minimiser(tau_nominal, G, h, weights, count, binding, factor, solver[Solver.ROTATED],
                        direction)
        for i in range(n):
            direction[i] -= tau[i]
        if not (np.isfinite(np.sum(direction)) and np.isfinite(np.sum(gradient))):
            for i in range(n):  # a diverging loop: the filter's step reports it
                tau[i] = np.nan
            return it
        value = penalty(tau, tau_nominal, G, h, weights, count)
        slope = dot(gradient, direction)
        step = 1.0
        while step > 1e-12:
            for i in range(n):
                trial[i] = tau[i] + step * direction[i]
            if penalty(trial, tau_nominal, G, h, weights, count) \
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
    in square-root form: piece_minimiser) is exact; repeated until the set of violated rows
    no longer changes, with a backtracking line search. Its Hessian stays positive definite
    for opposing or conflicting rows, where a dual method stalls. Returns (τ, iterations
    used). From τ_nom (the filter's step starts from the step before's binding rows)."""
    n, m = tau_nominal.shape[0], G.shape[0]
    solver = np.zeros((SOLVER_ROWS, n))
    used = newton(tau_nominal, G, h, weights, m, iterations, tolerance, solver,
                  np.zeros((n, n)), np.zeros(m, np.bool_), False)
    return solver[Solver.TAU], used

