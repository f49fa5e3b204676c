"""The planar serial chain's rigid-body model: link i of mass m_i, length l_i, centre of
mass lc_i along it and rotational inertia I_i; joint angles relative, link 1 from the
horizontal, gravity along −y. The paper's arm is its two-link instance (the built-in plant's
model, plant_fmu/models/planar_arm). With absolute angles θ_k = q_1 + … + q_k, joint origins
o_i and centres of mass p_k,

    M_ij = Σ_{k ≥ max(i, j)} [ m_k (p_k − o_i)·(p_k − o_j) + I_k ],

since a rotation about joint i moves p_k by ẑ × (p_k − o_i) and (ẑ × a)·(ẑ × b) = a·b; the
bias b = C q̇ + G by recursive Newton–Euler. SI units, radians.
"""

from __future__ import annotations

from enum import auto

import numpy as np
from numba import njit

from ..numba_compat import no_refcount_jit
from ..records import Rows


class Link(Rows):
    """The chain's geometry at one position and the forces of its bias, per link: the rows of
    a (CHAIN_ROWS, n) scratch array, so that a kernel evaluating the chain every step
    allocates nothing."""

    CX = auto()  # joint i's centre-of-mass offset
    CY = auto()
    LX = auto()  # its link vector
    LY = auto()
    OX = auto()  # its origin
    OY = auto()
    FX = auto()  # m_i a_ci, the force link i's own motion needs
    FY = auto()


CHAIN_ROWS = len(Link)


@njit(cache=True, inline="always")
def chain_geometry(q, l, lc, chain):  # noqa: E741
    """The chain's geometry at q into rows Link.CX … Link.OY of ``chain``."""
    theta, x, y = 0.0, 0.0, 0.0
    for k in range(q.shape[0]):
        theta += q[k]
        c, s = np.cos(theta), np.sin(theta)
        chain[Link.CX, k], chain[Link.CY, k] = lc[k] * c, lc[k] * s
        chain[Link.LX, k], chain[Link.LY, k] = l[k] * c, l[k] * s
        chain[Link.OX, k], chain[Link.OY, k] = x, y
        x += l[k] * c
        y += l[k] * s


@njit(cache=True, inline="always")
def chain_mass(chain, m, inertia, out):
    """M of the chain whose geometry ``chain`` holds, into ``out`` (n×n):
    M_ij = Σ_{k ≥ max(i, j)} [m_k (p_k − o_i)·(p_k − o_j) + I_k]."""
    n = m.shape[0]
    for i in range(n):
        for j in range(i, n):
            total = 0.0
            for k in range(j, n):
                px = chain[Link.OX, k] + chain[Link.CX, k]
                py = chain[Link.OY, k] + chain[Link.CY, k]
                total += (m[k] * ((px - chain[Link.OX, i]) * (px - chain[Link.OX, j])
                                  + (py - chain[Link.OY, i]) * (py - chain[Link.OY, j]))
                          + inertia[k])
            out[i, j] = total
            out[j, i] = total


@njit(cache=True, inline="always")
def chain_bias(chain, qdot, m, gravity, out):
    """b(q, q̇) = C(q, q̇) q̇ + G(q) of the chain whose geometry ``chain`` holds, into
    ``out`` (n,): recursive Newton–Euler with q̈ = 0 and the base accelerating upwards at
    ``gravity`` (m/s²), link 1 from the horizontal, gravity along −y."""
    n = qdot.shape[0]
    omega = 0.0
    ax, ay = 0.0, gravity  # acceleration of joint i's origin
    for i in range(n):
        omega += qdot[i]
        w2 = omega * omega  # no angular acceleration: q̈ = 0
        chain[Link.FX, i] = m[i] * (ax - w2 * chain[Link.CX, i])
        chain[Link.FY, i] = m[i] * (ay - w2 * chain[Link.CY, i])
        ax -= w2 * chain[Link.LX, i]
        ay -= w2 * chain[Link.LY, i]
    force_x, force_y, moment = 0.0, 0.0, 0.0  # what link i+1 exerts, about joint i+1
    for i in range(n - 1, -1, -1):
        # moment about joint i: the next link's moment, its force at the link's end, and
        # this link's own inertial force at its centre of mass (I α = 0)
        moment += (chain[Link.LX, i] * force_y - chain[Link.LY, i] * force_x
                   + chain[Link.CX, i] * chain[Link.FY, i] - chain[Link.CY, i] * chain[Link.FX, i])
        force_x += chain[Link.FX, i]
        force_y += chain[Link.FY, i]
        out[i] = moment


@njit(cache=True)
def planar_mass_matrix(q, m, l, lc, inertia, out):  # noqa: E741
    """M(q) of a planar serial chain into ``out`` (n×n), its scratch allocated here."""
    chain = np.empty((CHAIN_ROWS, q.shape[0]))
    chain_geometry(q, l, lc, chain)
    chain_mass(chain, m, inertia, out)


@njit(cache=True)
def planar_bias(q, qdot, m, l, lc, inertia, gravity, out):  # noqa: E741
    """b(q, q̇) = C(q, q̇) q̇ + G(q) of the same chain into ``out`` (n,), its scratch
    allocated here. (A link's rotational ``inertia`` adds nothing to b in the plane: the
    argument keeps the chain's signature.)"""
    chain = np.empty((CHAIN_ROWS, q.shape[0]))
    chain_geometry(q, l, lc, chain)
    chain_bias(chain, qdot, m, gravity, out)


@no_refcount_jit(cache=True)
def com_kinematics(q, v, l, lc, gravity, jac, gamma):  # noqa: E741
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
