"""The blocks' nominal rigid-body models M̂(q), b̂(q, q̇) and the payload's point, whatever the
arm: two model types the kernels take (:data:`RigidBodyModel`, either of them), and the calls
on them that the observer, the PD controller's gravity compensation and the safety filter
make:

- :func:`model_geometry` (q): the position's kinematics, once, into the model's scratch;
- :func:`model_mass` (bodies, Δm): M of the bodies (times ``bodies``, 1 or 0) plus a point
  mass Δm at the payload's point, at that position;
- :func:`model_bias` (v, bodies, Δm, gravity): b = C(q, v) v + G(q) likewise (gravity times
  ``gravity``: 0 leaves b's velocity part, a quadratic form in v);
- :func:`model_payload` (v, gravity): the payload point's Jacobian J (dim × n) and
  γ = J̇ v − g, so that Δm there adds Δm JᵀJ to M and Δm Jᵀγ to b;
- :func:`model_velocity_forms` (bodies, Δm): b's velocity part as quadratic forms Γ;
- :func:`model_point_forms`: J̇v's quadratic form and −g at the payload point;
- :func:`payload_dim`: dim, the payload point's coordinates.

The two types: the planar chain (:class:`PlanarModel`, :mod:`.planar`, the paper's arm and
the built-in plant's model; its payload point the last link's centre of mass, dim = 2) and
the spatial chain of a URDF (:class:`.spatial.SpatialChain`, its payload point the tip
frame's origin, dim = 3). They are distinct numba types, and each call picks its kind's code
by the model's type when a kernel compiles (an ``@overload``): a kernel is compiled once per
kind, so the planar one holds no spatial code, branches on no kind at run time and knows
dim as a constant (its loops over the payload's coordinates unroll). From Python a call
picks by ``isinstance``. SI units, radians.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from enum import auto
from typing import NamedTuple

import numpy as np
from numba.extending import overload

from ..numba_compat import no_refcount_jit
from ..records import Rows, kernel_record
from .planar import CHAIN_ROWS, Link, chain_bias, chain_geometry, chain_mass, com_kinematics
from .spatial import (
    SpatialChain,
    spatial_bias,
    spatial_chain,
    spatial_geometry,
    spatial_mass,
    spatial_payload,
)
from .spatial_forms import spatial_point_forms, spatial_velocity_forms


@kernel_record
class PlanarModel(NamedTuple):
    """The planar chain for the kernels: its parameters and the scratch its calls fill (each
    block holds its own, :func:`own_scratch`)."""

    m: np.ndarray  # per link mass (kg), length (m), centre of mass (m), inertia (kg·m²)
    l: np.ndarray  # noqa: E741
    lc: np.ndarray
    inertia: np.ndarray
    gravity: float  # |g|, m/s²
    friction: np.ndarray  # (FRICTION_ROWS, n) the joints' friction (module docstring)
    chain: np.ndarray  # scratch (CHAIN_ROWS, n)
    masses: np.ndarray  # scratch (n,): the masses of one call
    q: np.ndarray  # (n,) the position model_geometry was last given


# A nominal arm for the kernels: the planar chain or a URDF's spatial chain.
RigidBodyModel = PlanarModel | SpatialChain
RIGID_BODY_MODELS = (PlanarModel, SpatialChain)  # the same, for isinstance and PUBLISHES

PLANAR_DIM, SPATIAL_DIM = 2, 3  # the payload point's coordinates: the plane's, space's


class Friction(Rows):
    """Rows of a model's ``friction`` (n each): the nominal friction, and the declared bounds
    on the true friction's departure from it."""

    DAMPING = auto()  # the nominal viscous friction b̂, N·m·s/rad
    COULOMB = auto()  # the nominal Coulomb friction f̂c, N·m
    COULOMB_VELOCITY = auto()  # its smoothing velocity, rad/s
    DAMPING_ERROR = auto()  # |b − b̂| at most, N·m·s/rad
    COULOMB_ERROR = auto()  # |fc − f̂c| at most, N·m


FRICTION_ROWS = len(Friction)
NO_FRICTION_VELOCITY = 0.01  # rad/s: the plant FMUs' default fc_vel


def friction_table(n: int, damping=0.0, coulomb=0.0, coulomb_velocity=NO_FRICTION_VELOCITY,
                   damping_error=0.0, coulomb_error=0.0) -> np.ndarray:
    """A model's ``friction`` rows, each given per joint or one value for all."""
    rows = (damping, coulomb, coulomb_velocity, damping_error, coulomb_error)
    return np.array([np.broadcast_to(np.asarray(row, float), (n,)) for row in rows])


def planar_model(m, l, lc, inertia, gravity: float,  # noqa: E741
                 friction: np.ndarray | None = None) -> PlanarModel:
    """The planar chain as a model (its payload at the last link's centre of mass), without
    friction unless ``friction`` (:func:`friction_table`) is given."""
    n = len(m)
    return PlanarModel(
        m=np.asarray(m, float).copy(), l=np.asarray(l, float).copy(),
        lc=np.asarray(lc, float).copy(), inertia=np.asarray(inertia, float).copy(),
        gravity=float(gravity),
        friction=friction_table(n) if friction is None else np.asarray(friction, float).copy(),
        chain=np.zeros((CHAIN_ROWS, n)), masses=np.zeros(n), q=np.zeros(n))


def chain_model(chain, friction: np.ndarray | None = None) -> SpatialChain:
    """The spatial chain of a URDF's table (plant_fmu.urdf.Chain, or anything with its
    fields) as a model, its payload point the tip frame's origin; its friction ``friction``
    (:func:`friction_table`), none if not given."""
    return spatial_chain(chain.parent, chain.kind, chain.placement, chain.axis, chain.mass,
                         chain.com, chain.inertia, chain.tip, chain.gravity,
                         friction_table(len(chain.mass)) if friction is None else friction)


@no_refcount_jit(cache=True)
def model_friction(model, v, out):
    """Add the nominal joint friction at the velocity v to ``out`` (n): b̂ v + f̂c tanh(v/w),
    per joint (a model of either kind)."""
    f = model.friction
    for i in range(v.shape[0]):  # a term without its coefficient is 0, even at v = ±inf
        if f[Friction.DAMPING, i] != 0.0:
            out[i] += f[Friction.DAMPING, i] * v[i]
        if f[Friction.COULOMB, i] != 0.0:
            out[i] += f[Friction.COULOMB, i] * np.tanh(v[i] / f[Friction.COULOMB_VELOCITY, i])


@no_refcount_jit(cache=True)
def model_friction_spread(model, centre, radius, out):
    """Add to ``out`` (n), per joint, the most the true friction at a velocity within
    ``radius`` of ``centre`` can differ from the nominal friction at ``centre``: at the end
    e = c ± r where it is largest (every part grows towards an end), the nominal law's change
    there, b̂ r + f̂c |tanh(e/w) − tanh(c/w)|, plus the declared bounds on the true law's
    departure from it, |b − b̂| |e| + |fc − f̂c| (|tanh| ≤ 1)."""
    f = model.friction
    for i in range(centre.shape[0]):  # a term without its coefficient is 0, even at r = inf
        c, r, w = centre[i], radius[i], f[Friction.COULOMB_VELOCITY, i]
        worst = 0.0
        for side in (-1.0, 1.0):
            end = c + side * r
            total = 0.0
            if f[Friction.DAMPING, i] != 0.0:
                total += f[Friction.DAMPING, i] * r
            if f[Friction.COULOMB, i] != 0.0:
                total += f[Friction.COULOMB, i] * abs(np.tanh(end / w) - np.tanh(c / w))
            if f[Friction.DAMPING_ERROR, i] != 0.0:
                total += f[Friction.DAMPING_ERROR, i] * abs(end)
            worst = max(worst, total)
        out[i] += worst + f[Friction.COULOMB_ERROR, i]


def own_scratch(model: RigidBodyModel) -> RigidBodyModel:
    """The same model with scratch of its own (a block's, so that two blocks never share)."""
    if isinstance(model, PlanarModel):
        return model._replace(chain=np.zeros_like(model.chain),
                              masses=np.zeros_like(model.masses), q=np.zeros_like(model.q))
    return model._replace(
        frames=np.zeros_like(model.frames), kin=np.zeros_like(model.kin),
        world_inertia=np.zeros_like(model.world_inertia),
        composite=np.zeros_like(model.composite), first=np.zeros_like(model.first),
        total=np.zeros_like(model.total), point=np.zeros_like(model.point),
        motion=np.zeros_like(model.motion), tip_jacobian=np.zeros_like(model.tip_jacobian),
        tip_forms=np.zeros_like(model.tip_forms), crosses=np.zeros_like(model.crosses),
        momenta=np.zeros_like(model.momenta))


def _by_kind(planar: Callable, spatial: Callable) -> Callable[[Callable], Callable]:
    """Make the decorated function (its name, signature and docstring; its body is never
    run) a model call that runs ``planar`` or ``spatial`` (numba functions of the model and
    the call's arguments) by the model's type: in a kernel chosen when it compiles, from
    Python by ``isinstance``. Each kind's functions are compiled functions of their own,
    not inlined where they are called: the model is a kernel record (one pointer to pass),
    and inlining the planar chain's at every call site made the filter's compile 18 % longer
    for no speed (docs/performance.md)."""

    def register(declared: Callable) -> Callable:
        def call(model, *args):
            return (spatial if isinstance(model, SpatialChain) else planar)(model, *args)

        # One overload per kind, each declining the other kind's model, each compiled as a
        # function of its own (numba's IR inlining of overloads is not used: it passed wrong
        # arguments in numba 0.68.1), its implementation the kind's function itself.
        for kind, model_type in ((planar, PlanarModel), (spatial, SpatialChain)):
            overload(call, jit_options={"_nrt": False})(_overload_typing(kind, model_type))
        return functools.update_wrapper(call, declared)

    return register


def _overload_typing(kind: Callable, model_type: type) -> Callable:
    """The typing function of an overload that implements a call by ``kind`` (a numba
    function) for a model of ``model_type``: it takes ``kind``'s signature, which numba
    requires of an overload's typing function and its implementation alike."""

    def typing(model, *args):
        return kind.py_func if getattr(model, "instance_class", None) is model_type else None

    typing.__signature__ = inspect.signature(kind.py_func)
    return typing


@no_refcount_jit(cache=True)
def _planar_geometry(model, q):
    for i in range(q.shape[0]):
        model.q[i] = q[i]
    chain_geometry(q, model.l, model.lc, model.chain)


@no_refcount_jit(cache=True, inline="always")
def _planar_masses(model, bodies, payload):
    masses = model.masses
    n = masses.shape[0]
    for i in range(n):
        masses[i] = bodies * model.m[i]
    masses[n - 1] += payload
    return masses


@no_refcount_jit(cache=True)
def _planar_mass(model, bodies, payload, out):
    chain_mass(model.chain, _planar_masses(model, bodies, payload), model.inertia, out)


@no_refcount_jit(cache=True)
def _planar_bias(model, v, bodies, payload, gravity, out):
    chain_bias(model.chain, v, _planar_masses(model, bodies, payload), gravity * model.gravity,
               out)


@no_refcount_jit(cache=True)
def _planar_velocity_forms(model, bodies, payload, e, plus, out):
    """By polarisation of the planar chain's b without gravity."""
    n = out.shape[0]
    for i in range(n):
        e[:] = 0.0
        e[i] = 1.0
        _planar_bias(model, e, bodies, payload, 0.0, plus)
        for l in range(n):  # noqa: E741
            out[l, i, i] = plus[l]
    for i in range(n):
        for j in range(i + 1, n):
            e[:] = 0.0
            e[i] = e[j] = 1.0
            _planar_bias(model, e, bodies, payload, 0.0, plus)
            for l in range(n):  # noqa: E741
                out[l, i, j] = out[l, j, i] = 0.5 * (plus[l] - out[l, i, i] - out[l, j, j])


@no_refcount_jit(cache=True)
def _spatial_velocity_forms(model, bodies, payload, e, plus, out):
    """In closed form (:func:`.spatial_forms.spatial_velocity_forms`; ``e``, ``plus`` unused: the
    planar chain's polarisation's scratch)."""
    spatial_velocity_forms(model, bodies, payload, out)


@no_refcount_jit(cache=True)
def _planar_payload(model, v, gravity, jac, gamma):
    com_kinematics(model.q, v, model.l, model.lc, gravity * model.gravity, jac, gamma)


@no_refcount_jit(cache=True)
def _planar_point_forms(model, e, jac, gamma, out, lift):
    """From the link vectors a_k (the last link's to its centre of mass), which the geometry
    holds: J̇v = −Σ_k ω_k² a_k with ω_k = v_1 + … + v_k, so P_r,ij = −Σ_{k ≥ max(i, j)} a_k,r
    (``e``, ``jac``, ``gamma`` unused: the spatial chain's scratch)."""
    n = out.shape[1]
    chain = model.chain
    lift[0], lift[1] = 0.0, model.gravity
    for r in range(PLANAR_DIM):
        tail = 0.0  # Σ_{k ≥ j} a_k,r, from the last link down
        for j in range(n - 1, -1, -1):
            tail += chain[Link.CX + r, j] if j == n - 1 else chain[Link.LX + r, j]
            for i in range(j + 1):
                out[r, i, j] = out[r, j, i] = -tail


@no_refcount_jit(cache=True)
def _spatial_point_forms(model, e, jac, gamma, out, lift):
    """In closed form (:func:`.spatial_forms.spatial_point_forms`; ``e``, ``gamma`` unused: the
    planar chain's signature), −g the same at every point."""
    for r in range(SPATIAL_DIM):
        lift[r] = -model.gravity[r]
    spatial_point_forms(model, jac, out)


@no_refcount_jit(cache=True, inline="always")
def _planar_dim(model):
    return PLANAR_DIM


@no_refcount_jit(cache=True)
def _spatial_dim(model):
    return SPATIAL_DIM


@_by_kind(_planar_geometry, spatial_geometry)
def model_geometry(model: RigidBodyModel, q: np.ndarray) -> None:
    """The kinematics of position q into the model's scratch, for the calls that follow."""


@_by_kind(_planar_mass, spatial_mass)
def model_mass(model: RigidBodyModel, bodies: float, payload: float, out: np.ndarray) -> None:
    """M (n×n) at the last geometry, of the bodies times ``bodies`` plus a point mass
    ``payload`` (kg) at the payload's point, into ``out``."""


@_by_kind(_planar_bias, spatial_bias)
def model_bias(model: RigidBodyModel, v: np.ndarray, bodies: float, payload: float,
               gravity: float, out: np.ndarray) -> None:
    """b = C(q, v) v + G(q) (n,) at the last geometry, of the bodies times ``bodies`` plus
    a point mass ``payload`` at the payload's point, gravity times ``gravity``, into
    ``out``."""


@_by_kind(_planar_velocity_forms, _spatial_velocity_forms)
def model_velocity_forms(model: RigidBodyModel, bodies: float, payload: float, e: np.ndarray,
                         plus: np.ndarray, out: np.ndarray) -> None:
    """Γ (n, n, n) at the last geometry, of the bodies times ``bodies`` plus a point mass
    ``payload`` at the payload's point, into ``out``: b's velocity part b_l(v) = vᵀΓ_l v.
    The planar chain's by polarisation, from the bias without gravity at e_i (Γ_l,ii) and
    at e_i + e_j (Γ_l,ii + Γ_l,jj + 2Γ_l,ij), n(n + 1)/2 evaluations (``e``, ``plus``:
    scratch of n); the spatial chain's in closed form
    (:func:`.spatial_forms.spatial_velocity_forms`)."""


@_by_kind(_planar_payload, spatial_payload)
def model_payload(model: RigidBodyModel, v: np.ndarray, gravity: float, jac: np.ndarray,
                  gamma: np.ndarray) -> None:
    """The payload point's Jacobian J (dim × n) into ``jac`` and γ = J̇ v − g (gravity
    times ``gravity``, dim) into ``gamma`` at the last geometry."""


@_by_kind(_planar_point_forms, _spatial_point_forms)
def model_point_forms(model: RigidBodyModel, e: np.ndarray, jac: np.ndarray,
                      gamma: np.ndarray, out: np.ndarray, lift: np.ndarray) -> None:
    """The payload point's J̇v = (vᵀP_r v)_r into ``out`` (dim, n, n) and −g there into
    ``lift`` (dim,), at the last geometry (``e``, ``jac``, ``gamma``: scratch of n, dim × n
    and dim)."""


@_by_kind(_planar_dim, _spatial_dim)
def payload_dim(model: RigidBodyModel) -> int:
    """dim, the payload point's coordinates (2 in the plane, 3 in space): in a kernel a
    compile-time constant of the model's type."""
