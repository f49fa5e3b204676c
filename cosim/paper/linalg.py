"""The small dense linear algebra of the paper's kernels (the observer's and the filter's
step), on n joints and 2-vectors, written out: numba's np.linalg and @ allocate their
results and call LAPACK/BLAS, which costs more than the arithmetic at these sizes. Every
function writes into arrays passed in and allocates nothing; each is inlined into its
caller."""

from __future__ import annotations

import numpy as np

from ..numba_compat import no_refcount_jit


@no_refcount_jit(cache=True, inline="always")
def dot(x, y):
    total = 0.0
    for i in range(x.shape[0]):
        total += x[i] * y[i]
    return total


@no_refcount_jit(cache=True, inline="always")
def linear_part(nominal, payload, v, low, high, l, j):  # noqa: E741
    """B_lj at Δm = ``low`` and at ``high``, the linear part of b(v + δ) − b(v) for b's
    velocity forms Γ_l = ``nominal``[l] + Δm ``payload``[l]: 2 Σ_k Γ_l,jk v_k (the
    observer's envelope and the filter's bias error bound)."""
    bodies = point = 0.0
    for k in range(v.shape[0]):
        bodies += nominal[l, j, k] * v[k]
        point += payload[l, j, k] * v[k]
    return 2.0 * (bodies + low * point), 2.0 * (bodies + high * point)


@no_refcount_jit(cache=True, inline="always")
def product(matrix, vector, out):
    """out = matrix @ vector."""
    for i in range(matrix.shape[0]):
        out[i] = dot(matrix[i], vector)


@no_refcount_jit(cache=True, inline="always")
def solve(matrix, out, lu):
    """out ← matrix⁻¹ out: the n×n ``matrix`` (left as it is) solved for the n×m right-hand
    sides in ``out``, all columns at once, by Gaussian elimination with partial pivoting in
    ``lu`` (n×n scratch; it ends holding the upper triangle) and back substitution. A nearly
    singular matrix gives huge or non-finite entries; an exactly zero pivot raises
    ZeroDivisionError (numba's Python error model)."""
    n, m = out.shape
    for i in range(n):
        for j in range(n):
            lu[i, j] = matrix[i, j]
    for col in range(n):
        pivot = col
        for i in range(col + 1, n):
            if abs(lu[i, col]) > abs(lu[pivot, col]):
                pivot = i
        if pivot != col:
            for j in range(col, n):
                lu[col, j], lu[pivot, j] = lu[pivot, j], lu[col, j]
            for j in range(m):
                out[col, j], out[pivot, j] = out[pivot, j], out[col, j]
        for i in range(col + 1, n):
            factor = lu[i, col] / lu[col, col]
            for j in range(col + 1, n):
                lu[i, j] -= factor * lu[col, j]
            for j in range(m):
                out[i, j] -= factor * out[col, j]
    for i in range(n - 1, -1, -1):
        for c in range(i + 1, n):
            factor = lu[i, c]
            for j in range(m):
                out[i, j] -= factor * out[c, j]
        inverse = 1.0 / lu[i, i]
        for j in range(m):
            out[i, j] *= inverse


@no_refcount_jit(cache=True, inline="always")
def invert(matrix, out, lu):
    """out = matrix⁻¹: :func:`solve` on the identity's columns (``lu``: n×n scratch)."""
    n = matrix.shape[0]
    for i in range(n):
        for j in range(n):
            out[i, j] = 1.0 if i == j else 0.0
    solve(matrix, out, lu)


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



@no_refcount_jit(cache=True, inline="always")
def small_symmetric_eigen(kmat, lam, vec, work):
    """The eigenvalues (ascending, into ``lam``) and unit eigenvectors (columns of ``vec``)
    of a small symmetric d×d matrix (its lower triangle; ``work``: d×d scratch): d = 2 in
    closed form (:func:`symmetric_eigen`), else by cyclic Jacobi rotations, each setting its
    off-diagonal pair to exactly 0 (Golub and Van Loan, "Matrix Computations", 8.5), until
    the off-diagonal part is 0. After three sweeps a pair too small to change either
    diagonal entry it meets, even 100 times over, is set to 0 (Numerical Recipes' rule):
    the matrix is then diagonal to rounding. 3×3 K = J M⁻¹ Jᵀ of 7 joints: 4-5 sweeps
    (rotating whole rows and columns, with no exact zero, took 5-17)."""
    d = kmat.shape[0]
    if d == 2:
        symmetric_eigen(kmat, lam, vec)
        return
    for i in range(d):
        for j in range(d):
            work[i, j] = kmat[i, j] if i >= j else kmat[j, i]
            vec[i, j] = 1.0 if i == j else 0.0
    for sweep in range(50):
        off = 0.0
        for i in range(d):
            for j in range(i + 1, d):
                off += abs(work[i, j])
        if off == 0.0:
            break
        for p in range(d):
            for q in range(p + 1, d):
                pair = work[p, q]
                small = 100.0 * abs(pair)
                if sweep > 2 and abs(work[p, p]) + small == abs(work[p, p]) \
                        and abs(work[q, q]) + small == abs(work[q, q]):
                    work[p, q] = work[q, p] = 0.0
                    continue
                if pair == 0.0:
                    continue
                theta = 0.5 * (work[q, q] - work[p, p]) / pair
                t = np.sign(theta) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                if theta == 0.0:
                    t = 1.0
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                # A ← Jᵀ A J: the pair to 0, the diagonal by ∓t·pair, the rest rotated
                work[p, p] -= t * pair
                work[q, q] += t * pair
                work[p, q] = work[q, p] = 0.0
                for r in range(d):
                    if r != p and r != q:
                        first, second = work[r, p], work[r, q]
                        work[r, p] = work[p, r] = c * first - s * second
                        work[r, q] = work[q, r] = s * first + c * second
                for r in range(d):
                    first, second = vec[r, p], vec[r, q]
                    vec[r, p], vec[r, q] = c * first - s * second, s * first + c * second
    for i in range(d):
        lam[i] = work[i, i]
    for i in range(1, d):  # ascending, the vectors with them (insertion sort)
        j = i
        while j > 0 and lam[j - 1] > lam[j]:
            lam[j - 1], lam[j] = lam[j], lam[j - 1]
            for r in range(d):
                vec[r, j - 1], vec[r, j] = vec[r, j], vec[r, j - 1]
            j -= 1
