"""The spatial chain's quadratic velocity forms, in closed form at the geometry a
:class:`~cosim.dynamics.spatial.SpatialChain` holds: the tip point's J̇v as vᵀP_r v
(:func:`spatial_point_forms`) and the bias's velocity part b_l(v) = vᵀΓ_l v
(:func:`spatial_velocity_forms`), what the safety filter's bounds on b over a velocity box
read. SI units, radians.
"""

from __future__ import annotations

from ..numba_compat import no_refcount_jit
from .spatial import PRISMATIC, Kin, _composites, _cross, _tip_jacobian


@no_refcount_jit(cache=True)
def spatial_point_forms(s, jac, out):
    """The tip point's J into ``jac`` and J̇v's quadratic forms into ``out`` (3, n, n),
    (J̇v)_r = vᵀP_r v, in closed form at the geometry ``s`` holds. For joints a before b on
    the tip's path, a revolute a turns b's column, ∂J_b/∂q_a = z_a × J_b, and b moves the
    point a's column reaches, ∂J_a/∂q_b = z_a × J_b too; a prismatic a turns nothing (0). So
    P_r,ab = P_r,ba = (z_a × J_b)_r, a = b included, and 0 off the path (n² cross products
    where polarising γ took n(n + 1)/2 forward passes)."""
    n = jac.shape[1]
    kin = s.kin
    _tip_jacobian(s, jac)
    for r in range(3):
        for a in range(n):
            for b in range(n):
                out[r, a, b] = 0.0
    b = n - 1
    while b >= 0:
        a = b
        while a >= 0:
            if s.kind[a] != PRISMATIC:
                z = kin[Kin.AXIS, a]
                x, y, w = jac[0, b], jac[1, b], jac[2, b]
                out[0, a, b] = out[0, b, a] = z[1] * w - z[2] * y
                out[1, a, b] = out[1, b, a] = z[2] * x - z[0] * w
                out[2, a, b] = out[2, b, a] = z[0] * y - z[1] * x
            a = s.parent[a]
        b = s.parent[b]


@no_refcount_jit(cache=True)
def _point_mass_forms(s, payload, out):
    """Γ of a point mass ``payload`` at the tip alone, payload Σ_r J_rl P_r
    (:func:`spatial_point_forms`)."""
    n = out.shape[0]
    jac, forms = s.tip_jacobian, s.tip_forms
    spatial_point_forms(s, jac, forms)
    for l in range(n):  # noqa: E741
        for j in range(n):
            for k in range(j, n):
                total = 0.0
                for r in range(3):
                    total += jac[r, l] * forms[r, j, k]
                out[l, j, k] = out[l, k, j] = payload * total


@no_refcount_jit(cache=True)
def spatial_velocity_forms(s, bodies, payload, out):
    """Γ (n, n, n) at the geometry ``s`` holds, b's velocity part b_l(v) = vᵀΓ_l v, of the
    bodies' masses times ``bodies`` plus a point mass ``payload`` at the tip, in closed form
    from the composite inertias I_m (:func:`_composites`). In the base frame a body's
    velocity is Σ_j S_j v_j over its path, its acceleration at q̈ = 0 Σ_{j<k} v_j v_k S_j ×
    S_k, its force I a + V ×* I V, and b_l = S_l · Σ (the forces of the bodies after l).
    A term v_j v_k in b_l sums the bodies after the deepest m of l, j, k (on one path, else
    0), so that, with S_l · (V ×* F) = −(V × S_l) · F and X_ab = S_a × S_b,

        Γ_l,jk = ½ [(I_m S_l) · X_jk − X_jl · (I_m S_k) − X_kl · (I_m S_j)]

    (Featherstone 2008, ch. 2 and 5): ~n³/2 six-vector products where polarising b took
    n(n + 1)/2 recursive Newton–Euler passes. A point mass alone (``bodies`` 0) is cheaper
    still: its b is payload·Jᵀ(J̇v − g), so Γ_l = payload Σ_r J_rl P_r
    (:func:`spatial_point_forms`)."""
    n = out.shape[0]
    if bodies == 0.0:
        _point_mass_forms(s, payload, out)
        return
    kin, comp, first, total = s.kin, s.composite, s.first, s.total
    motion, crosses, momenta = s.motion, s.crosses, s.momenta
    _composites(s, bodies, payload)
    for j in range(n):  # S_j = (z, o × z) revolute, (0, z) prismatic
        z, o = kin[Kin.AXIS, j], kin[Kin.ORIGIN, j]
        revolute = s.kind[j] != PRISMATIC
        for r in range(3):
            motion[j, r] = z[r] if revolute else 0.0
            motion[j, 3 + r] = _cross(o, z, r) if revolute else z[r]
    for b in range(n):
        a = b
        while a >= 0:  # X_ab = S_a × S_b = (ω_a × ω_b, ω_a × v_b + v_a × ω_b), and X_ba
            sa, sb, x = motion[a], motion[b], crosses[a, b]
            x[0] = sa[1] * sb[2] - sa[2] * sb[1]
            x[1] = sa[2] * sb[0] - sa[0] * sb[2]
            x[2] = sa[0] * sb[1] - sa[1] * sb[0]
            x[3] = sa[1] * sb[5] - sa[2] * sb[4] + sa[4] * sb[2] - sa[5] * sb[1]
            x[4] = sa[2] * sb[3] - sa[0] * sb[5] + sa[5] * sb[0] - sa[3] * sb[2]
            x[5] = sa[0] * sb[4] - sa[1] * sb[3] + sa[3] * sb[1] - sa[4] * sb[0]
            for r in range(6):
                crosses[b, a, r] = -x[r]
            a = s.parent[a]
    for m in range(n):
        ic, h = comp[m], first[m]
        a = m
        while a >= 0:  # I_m S_a = (Ī ω + h × v, M v + ω × h)
            sa, y = motion[a], momenta[m, a]
            for r in range(3):
                y[r] = ic[r, 0] * sa[0] + ic[r, 1] * sa[1] + ic[r, 2] * sa[2]
            y[0] += h[1] * sa[5] - h[2] * sa[4]
            y[1] += h[2] * sa[3] - h[0] * sa[5]
            y[2] += h[0] * sa[4] - h[1] * sa[3]
            y[3] = total[m] * sa[3] + sa[1] * h[2] - sa[2] * h[1]
            y[4] = total[m] * sa[4] + sa[2] * h[0] - sa[0] * h[2]
            y[5] = total[m] * sa[5] + sa[0] * h[1] - sa[1] * h[0]
            a = s.parent[a]
    for l in range(n):  # noqa: E741
        for j in range(n):
            for k in range(n):
                out[l, j, k] = 0.0
    for m in range(n):
        k = m
        while k >= 0:  # k on m's path, j on k's: the deepest of l, j, k is m when k or l is
            j = k
            while j >= 0:
                l = m  # noqa: E741 — then, where k is m, every l on m's path
                while l >= 0:
                    y_l, y_k, y_j = momenta[m, l], momenta[m, k], momenta[m, j]
                    x_jk, x_jl, x_kl = crosses[j, k], crosses[j, l], crosses[k, l]
                    value = 0.0
                    for r in range(6):
                        value += y_l[r] * x_jk[r] - x_jl[r] * y_k[r] - x_kl[r] * y_j[r]
                    out[l, j, k] = out[l, k, j] = 0.5 * value
                    l = s.parent[l] if k == m else -1  # noqa: E741
                j = s.parent[j]
            k = s.parent[k]
