"""The small linear algebra of the filter's step, written out."""

from __future__ import annotations

import numpy as np

from ...numba_compat import no_refcount_jit

# The small linear algebra of a step, on n joints and 2-vectors, written out: numba's
# np.linalg and @ allocate their results and call LAPACK/BLAS, which costs more than the
# arithmetic at these sizes. (The observer's solve, cosim.paper.observer._solve, is another
# elimination, forward only, on one right-hand side: the two round differently, and each
# block's numbers are kept as they are.)


@no_refcount_jit(cache=True, inline="always")
def dot(x, y):
    total = 0.0
    for i in range(x.shape[0]):
        total += x[i] * y[i]
    return total


@no_refcount_jit(cache=True, inline="always")
def product(matrix, vector, out):
    """out = matrix @ vector."""
    for i in range(matrix.shape[0]):
        out[i] = dot(matrix[i], vector)


@no_refcount_jit(cache=True, inline="always")
def invert(matrix, out, lu):
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


@no_refcount_jit(cache=True, inline="always")
def symmetric_eigen(kmat, lam, vec):
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

