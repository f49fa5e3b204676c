"""The blocks' nominal rigid-body model M̂(q), b̂(q, q̇) and the payload's point, whatever the
arm: one record (:class:`RigidBodyModel`) the kernels take, and four calls on it that the
observer, the PD controller's gravity compensation and the safety filter make:

- :func:`model_geometry` (q): the position's kinematics, once, into the model's scratch;
- :func:`model_mass` (bodies, Δm): M of the bodies (times ``bodies``, 1 or 0) plus a point
  mass Δm at the payload's point, at that position;
- :func:`model_bias` (v, bodies, Δm, gravity): b = C(q, v) v + G(q) likewise (gravity times
  ``gravity``: 0 leaves b's velocity part, a quadratic form in v);
- :func:`model_payload` (v, gravity): the payload point's Jacobian J (dim × n) and
  γ = J̇ v − g, so that Δm there adds Δm JᵀJ to M and Δm Jᵀγ to b.

Two instances: the planar chain (:mod:`.planar`, the paper's arm and the built-in plant's
model; its payload point the last link's centre of mass, dim = 2) and the spatial chain of a
URDF (:mod:`.spatial`, its payload point the tip frame's origin, dim = 3). A kernel takes one
record and branches on ``spatial`` at run time (both compiled once), so one compiled
observer or filter serves every arm. SI units, radians.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..numba_compat import no_refcount_jit
from .planar import (
    CHAIN_ROWS,
    CX,
    LX,
    chain_bias,
    chain_geometry,
    chain_mass,
    com_kinematics,
)
from .spatial import (
    SpatialChain,
    spatial_bias,
    spatial_chain,
    spatial_geometry,
    spatial_mass,
    spatial_payload,
)


class RigidBodyModel(NamedTuple):
    """A nominal arm for the kernels: the planar chain's parameters or the spatial chain,
    and the scratch its calls fill (each block holds its own, :func:`own_scratch`)."""

    spatial: bool
    dim: int  # the payload point's coordinates: 2 (the plane) or 3
    m: np.ndarray  # planar: per link mass (kg), length (m), centre of mass (m), inertia
    l: np.ndarray  # noqa: E741
    lc: np.ndarray
    inertia: np.ndarray
    gravity: float  # |g|, m/s²
    chain: np.ndarray  # planar scratch (CHAIN_ROWS, n)
    masses: np.ndarray  # planar scratch (n,): the masses of one call
    q: np.ndarray  # (n,) the position model_geometry was last given
    body: SpatialChain  # spatial: the chain (planar: an unused one of n bodies)


def planar_model(m, l, lc, inertia, gravity: float) -> RigidBodyModel:  # noqa: E741
    """The planar chain as a model (its payload at the last link's centre of mass)."""
    n = len(m)
    return RigidBodyModel(
        spatial=False, dim=2, m=np.asarray(m, float).copy(), l=np.asarray(l, float).copy(),
        lc=np.asarray(lc, float).copy(), inertia=np.asarray(inertia, float).copy(),
        gravity=float(gravity), chain=np.zeros((CHAIN_ROWS, n)), masses=np.zeros(n),
        q=np.zeros(n), body=_unused_chain(n))


def chain_model(chain) -> RigidBodyModel:
    """The spatial chain of a URDF's table (plant_fmu.urdf.Chain, or anything with its
    fields) as a model, its payload point the tip frame's origin."""
    n = len(chain.mass)
    zeros = np.zeros(n)
    return RigidBodyModel(
        spatial=True, dim=3, m=zeros, l=zeros, lc=zeros, inertia=zeros,
        gravity=float(np.linalg.norm(chain.gravity)), chain=np.zeros((CHAIN_ROWS, n)),
        masses=np.zeros(n), q=np.zeros(n),
        body=spatial_chain(chain.parent, chain.kind, chain.placement, chain.axis, chain.mass,
                           chain.com, chain.inertia, chain.tip, chain.gravity))


def _unused_chain(n: int) -> SpatialChain:
    eye = np.broadcast_to(np.eye(4), (n, 4, 4))
    return spatial_chain(-np.ones(n), np.zeros(n), eye, np.tile([0.0, 0.0, 1.0], (n, 1)),
                         np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3, 3)), np.eye(4),
                         np.zeros(3))


def own_scratch(model: RigidBodyModel) -> RigidBodyModel:
    """The same model with scratch of its own (a block's, so that two blocks never share)."""
    body = model.body
    return model._replace(
        chain=np.zeros_like(model.chain), masses=np.zeros_like(model.masses),
        q=np.zeros_like(model.q),
        body=body._replace(frames=np.zeros_like(body.frames), kin=np.zeros_like(body.kin),
                           world_inertia=np.zeros_like(body.world_inertia),
                           composite=np.zeros_like(body.composite),
                           first=np.zeros_like(body.first), total=np.zeros_like(body.total),
                           point=np.zeros_like(body.point)))


def joint_count(model: RigidBodyModel) -> int:
    return len(model.q)


@no_refcount_jit(cache=True, inline="always")
def model_geometry(model, q):
    """The kinematics of position q into the model's scratch, for the calls that follow."""
    for i in range(q.shape[0]):
        model.q[i] = q[i]
    if model.spatial:
        spatial_geometry(model.body, q)
    else:
        chain_geometry(q, model.l, model.lc, model.chain)


@no_refcount_jit(cache=True, inline="always")
def _planar_masses(model, bodies, payload):
    masses = model.masses
    n = masses.shape[0]
    for i in range(n):
        masses[i] = bodies * model.m[i]
    masses[n - 1] += payload
    return masses


@no_refcount_jit(cache=True, inline="always")
def model_mass(model, bodies, payload, out):
    """M (n×n) at the last geometry, of the bodies times ``bodies`` plus a point mass
    ``payload`` (kg) at the payload's point, into ``out``."""
    if model.spatial:
        spatial_mass(model.body, bodies, payload, out)
    else:
        chain_mass(model.chain, _planar_masses(model, bodies, payload), model.inertia, out)


@no_refcount_jit(cache=True, inline="always")
def model_bias(model, v, bodies, payload, gravity, out):
    """b = C(q, v) v + G(q) (n,) at the last geometry, of the bodies times ``bodies`` plus
    a point mass ``payload`` at the payload's point, gravity times ``gravity``, into
    ``out``."""
    if model.spatial:
        spatial_bias(model.body, v, bodies, payload, gravity, out)
    else:
        chain_bias(model.chain, v, _planar_masses(model, bodies, payload),
                   gravity * model.gravity, out)


@no_refcount_jit(cache=True, inline="always")
def model_payload(model, v, gravity, jac, gamma):
    """The payload point's Jacobian J (dim × n) into ``jac`` and γ = J̇ v − g (gravity
    times ``gravity``, dim) into ``gamma`` at the last geometry."""
    if model.spatial:
        spatial_payload(model.body, v, gravity, jac, gamma)
    else:
        com_kinematics(model.q, v, model.l, model.lc, gravity * model.gravity, jac, gamma)


@no_refcount_jit(cache=True, inline="always")
def model_point_forms(model, e, jac, gamma, out, lift):
    """The payload point's J̇v = (vᵀP_r v)_r into ``out`` (dim, n, n) and −g there into
    ``lift`` (dim,), at the last geometry (``e``, ``jac``, ``gamma``: scratch of n, dim × n
    and dim). The planar chain's from its link vectors a_k (the last link's to its centre of
    mass), which the geometry holds: J̇v = −Σ_k ω_k² a_k with ω_k = v_1 + … + v_k, so
    P_r,ij = −Σ_{k ≥ max(i, j)} a_k,r; a spatial chain's by polarisation of
    :func:`model_payload` (n(n + 1)/2 + 1 calls)."""
    n = out.shape[1]
    if not model.spatial:
        chain = model.chain
        lift[0], lift[1] = 0.0, model.gravity
        for r in range(2):
            tail = 0.0  # Σ_{k ≥ j} a_k,r, from the last link down
            for j in range(n - 1, -1, -1):
                tail += chain[CX + r, j] if j == n - 1 else chain[LX + r, j]
                for i in range(j + 1):
                    out[r, i, j] = out[r, j, i] = -tail
        return
    d = out.shape[0]
    e[:] = 0.0
    model_payload(model, e, 1.0, jac, gamma)
    for r in range(d):
        lift[r] = gamma[r]
    for i in range(n):
        e[:] = 0.0
        e[i] = 1.0
        model_payload(model, e, 0.0, jac, gamma)
        for r in range(d):
            out[r, i, i] = gamma[r]
    for i in range(n):
        for j in range(i + 1, n):
            e[:] = 0.0
            e[i] = e[j] = 1.0
            model_payload(model, e, 0.0, jac, gamma)
            for r in range(d):
                out[r, i, j] = out[r, j, i] = 0.5 * (gamma[r] - out[r, i, i] - out[r, j, j])


@no_refcount_jit(cache=True)
def mass_matrix(model, q, out):
    """M̂(q) into ``out``: geometry and mass in one call (tests, benchmarks)."""
    model_geometry(model, q)
    model_mass(model, 1.0, 0.0, out)


@no_refcount_jit(cache=True)
def bias(model, q, v, out):
    """b̂(q, v) = C v + G into ``out``: geometry and bias in one call (tests, benchmarks)."""
    model_geometry(model, q)
    model_bias(model, v, 1.0, 0.0, 1.0, out)
