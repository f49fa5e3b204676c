"""The spatial rigid-body chain's model, for the blocks (the plant's is the FMU's C): from
the chain table of a URDF (plant_fmu.urdf.Chain: per moving joint its parent body, placement,
axis, revolute or prismatic, and its body's mass, centre of mass and inertia tensor), M(q) by
the composite-rigid-body algorithm and b(q, q̇) = C(q, q̇) q̇ + G(q) by recursive
Newton–Euler (Featherstone, "Rigid Body Dynamics Algorithms", 2008, ch. 5-6), plus a
payload: a point mass at the tip (flange) frame's origin, and that point's Jacobian J and
γ = J̇ q̇ − g, so that the payload Δm adds Δm JᵀJ to M and Δm Jᵀγ to b.

Everything is in the base (world) frame: each body's axis z_i, origin o_i, centre of mass
c_i and inertia tensor rotated there once per position (:func:`spatial_geometry`), so that
M and b at one position and many velocities (the filter's rollouts) share that work. The
recursions are written on 3-vectors, with a joint's motion subspace S_i = (z_i, o_i × z_i)
(revolute) or (0, z_i) (prismatic) in the (angular, linear-at-the-origin) order. A body's
parent comes before it (the table's order); branches are allowed (bodies off the tip's path
only load their ancestors).

Why our own kernels and not Pinocchio's (a test extra, checked against here): the blocks'
kernels are compiled loops that cannot call Python, and Pinocchio is C++ behind Python
bindings; measured (benchmarks/bench_panda.py's method, this machine, load 1.5), a Panda's
M + b costs 0.79 µs in these kernels called from compiled code against 1.57 µs for
Pinocchio's crba + rnea called from Python. SI units, radians.
"""

from __future__ import annotations

from enum import auto
from typing import NamedTuple

import numpy as np

from ..numba_compat import no_refcount_jit
from ..records import Rows, kernel_record

REVOLUTE, PRISMATIC = 0, 1


class Kin(Rows):
    """Rows of SpatialChain.kin (n × 3 each), per body, in the world frame."""

    AXIS = auto()  # its joint's axis z
    ORIGIN = auto()  # its origin o
    CENTRE = auto()  # its centre of mass c
    OMEGA = auto()  # its angular velocity ω
    ALPHA = auto()  # its angular acceleration α
    ACCELERATION = auto()  # its origin's acceleration a
    # the force and the moment about the world origin it needs (with the bodies after it,
    # after the backward pass)
    FORCE = auto()
    MOMENT = auto()


KIN_ROWS = len(Kin)


@kernel_record
class SpatialChain(NamedTuple):
    """The chain's constants (from plant_fmu.urdf.Chain) and the scratch its kernels fill."""

    parent: np.ndarray  # (n,) int: the parent body, −1 the base
    kind: np.ndarray  # (n,) int: REVOLUTE or PRISMATIC
    placement: np.ndarray  # (n, 4, 4): parent body frame → joint frame at q = 0
    axis: np.ndarray  # (n, 3) unit axis in the joint frame
    mass: np.ndarray  # (n,) kg
    com: np.ndarray  # (n, 3) m, in the body frame
    inertia: np.ndarray  # (n, 3, 3) kg·m² about the centre of mass, body axes
    tip: np.ndarray  # (4, 4) the payload's frame in the last body's frame
    gravity: np.ndarray  # (3,) m/s² in the base frame
    friction: np.ndarray  # (FRICTION_ROWS, n) the joints' friction (cosim.dynamics.model)
    # scratch
    frames: np.ndarray  # (n, 4, 4) each body's frame in the base frame
    kin: np.ndarray  # (KIN_ROWS, n, 3): Kin
    world_inertia: np.ndarray  # (n, 3, 3) each body's inertia about its centre, base axes
    composite: np.ndarray  # (n, 3, 3) the composite body's rotational inertia about o = 0
    first: np.ndarray  # (n, 3) its first moment Σ m c, kg·m
    total: np.ndarray  # (n,) its mass, kg
    point: np.ndarray  # (2, 3) the tip's point in the base frame; its acceleration
    motion: np.ndarray  # (n, 6) each joint's S (:func:`spatial_velocity_forms`)
    tip_jacobian: np.ndarray  # (3, n) the tip point's J (a point mass's Γ)
    tip_forms: np.ndarray  # (3, n, n) its J̇v's forms P_r (:func:`spatial_point_forms`)
    crosses: np.ndarray  # (n, n, 6) S_a × S_b along a path
    momenta: np.ndarray  # (n, n, 6) the composite m's momentum under S_a, I_m S_a


def spatial_chain(parent, kind, placement, axis, mass, com, inertia, tip,
                  gravity, friction) -> SpatialChain:
    """The kernels' chain from the table's arrays (copied, as float64 / int64), its scratch
    allocated; ``friction`` (FRICTION_ROWS, n) as cosim.dynamics.model lays it out."""
    n = len(mass)
    return SpatialChain(friction=np.asarray(friction, float).copy(),
        parent=np.asarray(parent, np.int64).copy(), kind=np.asarray(kind, np.int64).copy(),
        placement=np.asarray(placement, float).copy(), axis=np.asarray(axis, float).copy(),
        mass=np.asarray(mass, float).copy(), com=np.asarray(com, float).copy(),
        inertia=np.asarray(inertia, float).copy(), tip=np.asarray(tip, float).copy(),
        gravity=np.asarray(gravity, float).copy(), frames=np.zeros((n, 4, 4)),
        kin=np.zeros((KIN_ROWS, n, 3)), world_inertia=np.zeros((n, 3, 3)),
        composite=np.zeros((n, 3, 3)), first=np.zeros((n, 3)), total=np.zeros(n),
        point=np.zeros((2, 3)), motion=np.zeros((n, 6)), tip_jacobian=np.zeros((3, n)),
        tip_forms=np.zeros((3, n, n)), crosses=np.zeros((n, n, 6)), momenta=np.zeros((n, n, 6)))


@no_refcount_jit(cache=True, inline="always")
def _cross(a, b, i):
    """Component i of a × b."""
    if i == 0:
        return a[1] * b[2] - a[2] * b[1]
    if i == 1:
        return a[2] * b[0] - a[0] * b[2]
    return a[0] * b[1] - a[1] * b[0]


@no_refcount_jit(cache=True)
def spatial_geometry(s, q):
    """Each body's frame, axis, origin, centre of mass and inertia tensor in the base frame
    at q, and the tip's point, into the scratch of ``s``."""
    n = q.shape[0]
    kin = s.kin
    for i in range(n):
        frame, place, axis = s.frames[i], s.placement[i], s.axis[i]
        p = s.parent[i]
        # base = parent's frame · placement (the joint's frame before its motion)
        for r in range(3):
            for c in range(4):
                if p < 0:
                    frame[r, c] = place[r, c]
                else:
                    total = s.frames[p, r, 3] if c == 3 else 0.0
                    for m in range(3):
                        total += s.frames[p, r, m] * place[m, c]
                    frame[r, c] = total
        frame[3, 0] = frame[3, 1] = frame[3, 2] = 0.0
        frame[3, 3] = 1.0
        for r in range(3):  # the world axis (a joint's motion leaves its axis alone)
            kin[Kin.AXIS, i, r] = frame[r, 0] * axis[0] + frame[r, 1] * axis[1] \
                + frame[r, 2] * axis[2]
        if s.kind[i] == PRISMATIC:
            for r in range(3):
                frame[r, 3] += kin[Kin.AXIS, i, r] * q[i]
        else:  # frame's rotation · Rodrigues' rotation about the axis by q_i
            cq, sq = np.cos(q[i]), np.sin(q[i])
            x, y, z = axis[0], axis[1], axis[2]
            u = 1.0 - cq
            r00, r01, r02 = cq + x * x * u, x * y * u - z * sq, x * z * u + y * sq
            r10, r11, r12 = y * x * u + z * sq, cq + y * y * u, y * z * u - x * sq
            r20, r21, r22 = z * x * u - y * sq, z * y * u + x * sq, cq + z * z * u
            for r in range(3):
                f0, f1, f2 = frame[r, 0], frame[r, 1], frame[r, 2]
                frame[r, 0] = f0 * r00 + f1 * r10 + f2 * r20
                frame[r, 1] = f0 * r01 + f1 * r11 + f2 * r21
                frame[r, 2] = f0 * r02 + f1 * r12 + f2 * r22
        com, local, world = s.com[i], s.inertia[i], s.world_inertia[i]
        for r in range(3):
            kin[Kin.ORIGIN, i, r] = frame[r, 3]
            kin[Kin.CENTRE, i, r] = frame[r, 3] + frame[r, 0] * com[0] + frame[r, 1] * com[1] \
                + frame[r, 2] * com[2]
        for r in range(3):  # R I Rᵀ
            for c in range(3):
                total = 0.0
                for a in range(3):
                    for b in range(3):
                        total += frame[r, a] * local[a, b] * frame[c, b]
                world[r, c] = total
    last, tip = s.frames[n - 1], s.tip
    for r in range(3):
        s.point[0, r] = last[r, 3] + last[r, 0] * tip[0, 3] + last[r, 1] * tip[1, 3] \
            + last[r, 2] * tip[2, 3]


@no_refcount_jit(cache=True, inline="always")
def _motion_dot(s, i, angular, linear):
    """S_iᵀ (angular; linear): joint i's share of a force (moment about the origin, force)
    or the power of a twist's dual."""
    kin = s.kin
    z = kin[Kin.AXIS, i]
    if s.kind[i] == PRISMATIC:
        return z[0] * linear[0] + z[1] * linear[1] + z[2] * linear[2]
    o = kin[Kin.ORIGIN, i]
    total = 0.0
    for r in range(3):  # z·n + (o × z)·f
        total += z[r] * angular[r] + _cross(o, z, r) * linear[r]
    return total


@no_refcount_jit(cache=True, inline="always")
def _composites(s, bodies, payload):
    """Each body's composite (it and the bodies after it) about the base's origin, of the
    bodies' masses times ``bodies`` plus a point mass ``payload`` (kg) at the tip: its
    rotational inertia, first moment and mass into s.composite, s.first, s.total."""
    n = s.mass.shape[0]
    kin, comp, first, total = s.kin, s.composite, s.first, s.total
    for i in range(n):
        c, m = kin[Kin.CENTRE, i], bodies * s.mass[i]
        cc = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
        for r in range(3):
            first[i, r] = m * c[r]
            for col in range(3):
                comp[i, r, col] = bodies * s.world_inertia[i, r, col] \
                    + m * ((cc if r == col else 0.0) - c[r] * c[col])
        total[i] = m
    if payload != 0.0:
        p = s.point[0]
        pp = p[0] * p[0] + p[1] * p[1] + p[2] * p[2]
        for r in range(3):
            first[n - 1, r] += payload * p[r]
            for col in range(3):
                comp[n - 1, r, col] += payload * ((pp if r == col else 0.0) - p[r] * p[col])
        total[n - 1] += payload
    for i in range(n - 1, 0, -1):
        p = s.parent[i]
        if p >= 0:
            total[p] += total[i]
            for r in range(3):
                first[p, r] += first[i, r]
                for col in range(3):
                    comp[p, r, col] += comp[i, r, col]


@no_refcount_jit(cache=True)
def spatial_mass(s, bodies, payload, out):
    """M at the geometry ``s`` holds into ``out`` (n×n), of the bodies' masses times
    ``bodies`` (1: the chain, 0: none) plus a point mass ``payload`` (kg) at the tip: the
    composite-rigid-body algorithm, composite inertias about the base's origin."""
    n = out.shape[0]
    kin, comp, first, total = s.kin, s.composite, s.first, s.total
    _composites(s, bodies, payload)
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.0
    angular, linear = s.point[1], kin[Kin.FORCE, 0]  # scratch: the composite's force under S_i
    for i in range(n):
        z = kin[Kin.AXIS, i]
        h = first[i]
        if s.kind[i] == PRISMATIC:  # S = (0, z): f = (h × z, m z)
            for r in range(3):
                angular[r] = _cross(h, z, r)
                linear[r] = total[i] * z[r]
        else:  # S = (z, v = o × z): f = (Ī z + h × v, m v + z × h)
            o = kin[Kin.ORIGIN, i]
            for r in range(3):
                linear[r] = _cross(o, z, r)
            for r in range(3):
                angular[r] = comp[i, r, 0] * z[0] + comp[i, r, 1] * z[1] \
                    + comp[i, r, 2] * z[2] + _cross(h, linear, r)
            for r in range(3):
                linear[r] = total[i] * linear[r]
            for r in range(3):
                linear[r] += _cross(z, h, r)
        j = i
        while j >= 0:
            value = _motion_dot(s, j, angular, linear)
            out[i, j] = out[j, i] = value
            j = s.parent[j]


@no_refcount_jit(cache=True)
def spatial_forward(s, v, gravity):
    """The forward pass of recursive Newton–Euler at q̈ = 0: each body's angular velocity,
    angular acceleration and its origin's acceleration, the base accelerating at −g times
    ``gravity`` (so that the forces include their weight)."""
    n = v.shape[0]
    kin = s.kin
    for i in range(n):
        p = s.parent[i]
        z, o = kin[Kin.AXIS, i], kin[Kin.ORIGIN, i]
        w, al, a = kin[Kin.OMEGA, i], kin[Kin.ALPHA, i], kin[Kin.ACCELERATION, i]
        if p < 0:
            for r in range(3):
                w[r], al[r], a[r] = 0.0, 0.0, -gravity * s.gravity[r]
        else:
            wp, ap = kin[Kin.OMEGA, p], kin[Kin.ALPHA, p]
            _point_acceleration(s, p, o, a)  # o_i's, as a point of body p
            for r in range(3):
                w[r], al[r] = wp[r], ap[r]
        if s.kind[i] == PRISMATIC:  # the Coriolis term 2 ω_p × z q̇
            for r in range(3):
                a[r] += 2.0 * v[i] * _cross(w, z, r)
        else:  # α_i = α_p + ω_p × z q̇, ω_i = ω_p + z q̇
            for r in range(3):
                al[r] += v[i] * _cross(w, z, r)
            for r in range(3):
                w[r] += v[i] * z[r]


@no_refcount_jit(cache=True, inline="always")
def _point_acceleration(s, i, point, out):
    """The acceleration of ``point`` (base frame) fixed to body i, from the forward pass:
    a_i + α_i × r + ω_i × (ω_i × r), r = point − o_i."""
    kin = s.kin
    w, al, a, o = kin[Kin.OMEGA, i], kin[Kin.ALPHA, i], kin[Kin.ACCELERATION, i], kin[Kin.ORIGIN, i]
    rx, ry, rz = point[0] - o[0], point[1] - o[1], point[2] - o[2]
    cx = w[1] * rz - w[2] * ry
    cy = w[2] * rx - w[0] * rz
    cz = w[0] * ry - w[1] * rx
    out[0] = a[0] + al[1] * rz - al[2] * ry + w[1] * cz - w[2] * cy
    out[1] = a[1] + al[2] * rx - al[0] * rz + w[2] * cx - w[0] * cz
    out[2] = a[2] + al[0] * ry - al[1] * rx + w[0] * cy - w[1] * cx


@no_refcount_jit(cache=True)
def spatial_bias(s, v, bodies, payload, gravity, out):
    """b(q, v) = C(q, v) v + G(q) at the geometry ``s`` holds into ``out`` (n,), of the
    bodies' masses times ``bodies`` plus a point mass ``payload`` (kg) at the tip, gravity
    times ``gravity`` (1: on, 0: b's velocity part alone): recursive Newton–Euler at q̈ = 0."""
    n = v.shape[0]
    kin = s.kin
    spatial_forward(s, v, gravity)
    acc = s.point[1]
    for i in range(n):
        f, moment = kin[Kin.FORCE, i], kin[Kin.MOMENT, i]
        c, w, al = kin[Kin.CENTRE, i], kin[Kin.OMEGA, i], kin[Kin.ALPHA, i]
        _point_acceleration(s, i, c, acc)
        m = bodies * s.mass[i]
        for r in range(3):
            f[r] = m * acc[r]
        # N = I α + ω × I ω about the centre, then moved to the origin: + c × f
        inertia = s.world_inertia[i]
        iw0 = inertia[0, 0] * w[0] + inertia[0, 1] * w[1] + inertia[0, 2] * w[2]
        iw1 = inertia[1, 0] * w[0] + inertia[1, 1] * w[1] + inertia[1, 2] * w[2]
        iw2 = inertia[2, 0] * w[0] + inertia[2, 1] * w[1] + inertia[2, 2] * w[2]
        moment[0] = bodies * (inertia[0, 0] * al[0] + inertia[0, 1] * al[1]
                              + inertia[0, 2] * al[2] + w[1] * iw2 - w[2] * iw1)
        moment[1] = bodies * (inertia[1, 0] * al[0] + inertia[1, 1] * al[1]
                              + inertia[1, 2] * al[2] + w[2] * iw0 - w[0] * iw2)
        moment[2] = bodies * (inertia[2, 0] * al[0] + inertia[2, 1] * al[1]
                              + inertia[2, 2] * al[2] + w[0] * iw1 - w[1] * iw0)
        for r in range(3):
            moment[r] += _cross(c, f, r)
        if i == n - 1 and payload != 0.0:
            point = s.point[0]
            _point_acceleration(s, i, point, acc)
            for r in range(3):
                f[r] += payload * acc[r]
            for r in range(3):
                moment[r] += payload * _cross(point, acc, r)
    for i in range(n - 1, -1, -1):
        out[i] = _motion_dot(s, i, kin[Kin.MOMENT, i], kin[Kin.FORCE, i])
        p = s.parent[i]
        if p >= 0:
            for r in range(3):
                kin[Kin.FORCE, p, r] += kin[Kin.FORCE, i, r]
                kin[Kin.MOMENT, p, r] += kin[Kin.MOMENT, i, r]


@no_refcount_jit(cache=True, inline="always")
def _tip_jacobian(s, jac):
    """The tip point's Jacobian J (3×n) into ``jac`` at the geometry ``s`` holds: z_j × (p −
    o_j) for a revolute joint on the tip's path, z_j for a prismatic one, 0 off the path."""
    n = jac.shape[1]
    kin = s.kin
    point = s.point[0]
    for r in range(3):
        for j in range(n):
            jac[r, j] = 0.0
    j = n - 1
    while j >= 0:
        z = kin[Kin.AXIS, j]
        if s.kind[j] == PRISMATIC:
            for r in range(3):
                jac[r, j] = z[r]
        else:  # z × (p − o_j)
            o = kin[Kin.ORIGIN, j]
            rx, ry, rz = point[0] - o[0], point[1] - o[1], point[2] - o[2]
            jac[0, j] = z[1] * rz - z[2] * ry
            jac[1, j] = z[2] * rx - z[0] * rz
            jac[2, j] = z[0] * ry - z[1] * rx
        j = s.parent[j]


@no_refcount_jit(cache=True)
def spatial_payload(s, v, gravity, jac, gamma):
    """The tip point's Jacobian J (3×n, into ``jac``) and γ = J̇ v − g (times ``gravity``)
    into ``gamma``: the acceleration a point mass there needs beyond J q̈, at the geometry
    ``s`` holds."""
    _tip_jacobian(s, jac)
    spatial_forward(s, v, gravity)
    _point_acceleration(s, v.shape[0] - 1, s.point[0], gamma)
