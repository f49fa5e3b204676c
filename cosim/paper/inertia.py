"""The controller's inertia model M̂(q), which the observer's (7) needs (Assumption 3: M(q) is
known). Two sources, written to the trace's ``M_model`` for row k:

- ``fmu``: the plant's own ``M`` outputs at the true q (the FMU maps ``M``);
- ``nominal``: a planar serial chain with the pipeline's link parameters, evaluated at the
  measured position ``q_meas`` — all an output-feedback controller can know. A plant whose
  masses differ from these is how a model mismatch is studied.

The planar chain is the built-in plant's (its kernels in cosim.dynamics.planar).
SI units, radians.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np
from numba import njit

from plant_fmu.models.planar_arm import PAPER_MASSES

from ..blocks.base import Block, BlockContext, Ports, kernel_args, register_block
from ..blocks.binding import reads, writes
from ..dynamics.model import (
    NO_FRICTION_VELOCITY,
    RIGID_BODY_MODELS,
    RigidBodyModel,
    chain_model,
    friction_table,
    model_geometry,
    model_mass,
    own_scratch,
    planar_model,
)
from ..dynamics.planar import (  # noqa: F401  (re-exported: the planar chain's kernels)
    CHAIN_ROWS,
    Link,
    chain_bias,
    chain_geometry,
    chain_mass,
    planar_bias,
    planar_mass_matrix,
)
from ..records import kernel_record
from ..schema import (
    FileName,
    FiniteFloat,
    JointList,
    NonNegativeFloat,
    PerJoint,
    PipelineError,
    PositiveFloat,
    Section,
)
from ..signals import Signal


class InertiaModelParams(Section):
    """Where the observer's M(q) (Assumption 3) comes from: ``fmu`` (its mapped M outputs),
    ``nominal`` (this planar chain, evaluated at the measured position) or ``auto`` (the FMU's
    when mapped, else nominal). Per link; unset: the paper's arm (m = 0.8, 2.3 kg, l = lc =
    1 m, I = 0), further links 1 kg, 1 m, like the built-in plant's defaults."""

    # where the inertia model M̂(q) comes from (a name): "fmu", the FMU's M outputs;
    # "nominal", the nominal chain (m, l, lc, I); "auto", the FMU's when mapped, else nominal
    source: Literal["auto", "fmu", "nominal"] = "auto"
    m: JointList[PositiveFloat] | None = None  # the nominal chain's mass of each link, kg
    # the nominal chain's length of each link, joint i to joint i+1, m
    l: JointList[PositiveFloat] | None = None  # noqa: E741
    # the nominal chain's distance from joint i to link i's centre of mass, m
    lc: JointList[FiniteFloat] | None = None
    # the nominal chain's rotational inertia of each link about its centre of mass, kg·m²
    I: JointList[NonNegativeFloat] | None = None  # noqa: E741
    # gravitational acceleration of the nominal chain's bias b̂ = C q̇ + G, m/s²
    gravity: FiniteFloat = 9.8
    # a nominal URDF instead of the planar chain (a path relative to the pipeline file, to
    # where cosim runs when given by --set, or package://…, e.g. package://example-robot-data/robots/ur_description/urdf/
    # ur5_robot.urdf): its spatial chain from ``base`` to ``tip`` (link names; defaults as
    # cosim build-fmu --urdf), ``fixed`` joints held at a value (rad or m); the payload's
    # point is the tip link's origin
    urdf: FileName | None = None
    base: str | None = None  # the nominal URDF's base link (a name)
    tip: str | None = None  # the nominal URDF's tip link, where the payload is (a name)
    # joints of the nominal URDF held at a value, by name, rad or m
    fixed: dict[str, FiniteFloat] | None = None
    # the nominal model's viscous friction b̂ per joint (or one for all), N·m·s/rad; unset:
    # the nominal URDF's <dynamics damping>, 0 for the planar chain (the plant's b[i])
    b: PerJoint[NonNegativeFloat] | None = None
    # its Coulomb friction f̂c per joint (or one for all), smoothed as f̂c tanh(q̇/fc_vel),
    # N·m; unset: the nominal URDF's <dynamics friction>, 0 for the planar chain (fc[i])
    fc: PerJoint[NonNegativeFloat] | None = None
    # the Coulomb friction's smoothing velocity, as the plant FMUs' fc_vel[i], rad/s
    fc_vel: PositiveFloat = NO_FRICTION_VELOCITY


class Chain(NamedTuple):
    """The nominal planar chain, as the inertia model publishes it (constant
    ``nominal_chain``): per link mass (kg), length (m), centre of mass (m), inertia (kg·m²),
    and gravity (m/s²)."""

    m: np.ndarray
    l: np.ndarray  # noqa: E741
    lc: np.ndarray
    inertia: np.ndarray
    gravity: float


def default_links(links: int) -> dict[str, list[float]]:
    """Nominal link parameters when the pipeline gives none: the paper's arm (Lewis et al.),
    further links as the built-in plant's defaults (1 kg, 1 m, centre of mass at the tip,
    no rotational inertia)."""
    return {"m": [PAPER_MASSES[i] if i < len(PAPER_MASSES) else 1.0 for i in range(links)],
            "l": [1.0] * links, "lc": [1.0] * links, "I": [0.0] * links}


@kernel_record
class NominalArgs(NamedTuple):
    q_meas: reads()
    model: RigidBodyModel
    M_model: writes()


@njit(cache=True)
def nominal_step(k, a):
    model_geometry(a.model, a.q_meas[k])
    model_mass(a.model, 1.0, 0.0, a.M_model[k])
    return True  # a non-finite M̂ makes the observer's output non-finite: caught there


# M̂ is not recorded: it is n² series per run of little use on their own (the plant's M is
# in the trace files).
M_MODEL = Signal("nn", "kg·m²", "the controller's inertia model M̂(q)")


def read_nominal_urdf(params: InertiaModelParams, context: BlockContext):
    """The chain of the nominal URDF (``urdf``, ``base``, ``tip``, ``fixed``), its joint
    count checked against the plant's; a URDF the reader refuses is a PipelineError naming
    the key."""
    from plant_fmu.urdf import UrdfError, read_urdf, resolve_uri

    path = resolve_uri(params.urdf, Path.cwd())
    try:
        chain = read_urdf(path, base=params.base, tip=params.tip, fixed=params.fixed,
                          held_by="inertia_model.fixed")
    except UrdfError as exc:
        raise PipelineError(f"inertia_model.urdf (run '{context.run}'): {exc}") from None
    if chain.n != context.links:
        raise PipelineError(
            f"inertia_model.urdf = {params.urdf!r} (run '{context.run}'): its chain has "
            f"{chain.n} moving joints ({', '.join(chain.joints)}), the plant {context.links}; "
            "give the plant's URDF, or hold joints with inertia_model.fixed")
    return chain


@register_block
class InertiaModel(Block):
    """``source`` "auto" resolves here: "fmu" when the plant outputs M, else "nominal"."""

    kind = "inertia_model"
    Params = InertiaModelParams
    # nominal_model: the rigid-body model (planar chain or a URDF's spatial chain) the
    # observer, the PD controller and the filter compute M̂, b̂ and the payload's point with;
    # nominal_chain: the planar chain's parameters (planar only), for the guarantee's
    # comparison with the plant's; inertia_is_plant: True when M̂ is the plant's own M (so it
    # includes any payload), False when it is the nominal model's; nominal_urdf: the
    # nominal URDF's chain (spatial only: its joint limits are the safe sets' defaults).
    PUBLISHES = {"nominal_model": RIGID_BODY_MODELS, "nominal_chain": Chain,
                 "inertia_is_plant": bool, "nominal_urdf": object}

    def __init__(self, params: InertiaModelParams, context: BlockContext):
        super().__init__(params, context)
        source = params.source
        if source == "auto":
            source = "fmu" if "M" in context.plant_outputs else "nominal"
        if source == "fmu" and "M" not in context.plant_outputs:
            n = context.links
            raise PipelineError(
                f"inertia_model.source = \"fmu\" (run '{context.run}'), but "
                f"{context.plant_file} has no M mapping (no outputs M[1,1]..M[{n},{n}]); map "
                "them with plant.variables.M = [...] (n×n, row-major) or use source = "
                "\"nominal\"")
        self.source = source
        self.inputs = ("M",) if source == "fmu" else ("q_meas",)
        self.outputs = {"M_model": M_MODEL}
        if source == "nominal":
            self.kernel = nominal_step
        self.publishes = {"inertia_is_plant": source == "fmu"}
        if params.urdf is not None:
            self.urdf_chain = read_nominal_urdf(params, context)
            self.model = chain_model(self.urdf_chain, self.friction())
            self.publishes["nominal_urdf"] = self.urdf_chain
        else:
            self.urdf_chain = None
            links = self.nominal_links()
            self.model = planar_model(**self.chain_arrays(links), gravity=params.gravity,
                                      friction=self.friction())
            self.publishes["nominal_chain"] = kernel_args(
                Chain, **self.chain_arrays(links), gravity=params.gravity)
        self.publishes["nominal_model"] = self.model
        self._check_payload_range()

    def _check_payload_range(self) -> None:
        """A declared payload range must leave every plant it allows a positive mass at the
        payload point: the planar chain's payload is added to its last link's mass, so it
        may be negative down to −m[n] (excluded); a URDF chain's is a point mass of its own
        at the tip frame's origin, at least 0 kg. Below that the robust margins would take
        the worst case over mass matrices that are not positive definite (the payload's
        corners are exact only where 1 + Δm λ_j(J M̂⁻¹ Jᵀ) > 0)."""
        low, high = map(float, self.context.uncertainty.payload)
        if self.urdf_chain is not None:
            lightest, strict = 0.0, False
            where = (f"a point mass of its own at the tip frame's origin (link "
                     f"'{self.urdf_chain.tip_link}'), which cannot be negative")
        else:
            lightest, strict = -float(self.model.m[-1]), True
            where = (f"added to the last link's mass, m[{len(self.model.m)}] = "
                     f"{-lightest:g} kg in the nominal model, which must stay positive")
        if low < lightest or (strict and low == lightest):
            raise PipelineError(
                f"uncertainty.payload = [{low:g}, {high:g}] (run '{self.context.run}'): the "
                f"low end allows a plant with a negative mass: the payload is {where}; give "
                f"low {'>' if strict else '≥'} {lightest:g} kg")

    def friction(self) -> np.ndarray:
        """The nominal model's friction rows (cosim.dynamics.model.friction_table): b̂ and
        f̂c as given, else the nominal URDF's, else none; the declared bounds on the true
        friction's departure from them (``uncertainty.viscous_friction``,
        ``coulomb_friction``)."""
        p, n, chain = self.params, self.context.links, self.urdf_chain
        declared = self.context.uncertainty
        return friction_table(
            n, p.b if p.b is not None else (chain.damping if chain is not None else 0.0),
            p.fc if p.fc is not None else (chain.friction if chain is not None else 0.0),
            p.fc_vel, declared.viscous_friction, declared.coulomb_friction)

    def nominal_links(self) -> dict[str, list[float]]:
        """The nominal chain as used: given values, else the defaults."""
        return {key: getattr(self.params, key) or value
                for key, value in default_links(self.context.links).items()}

    @staticmethod
    def chain_arrays(links: dict[str, list[float]]) -> dict[str, np.ndarray]:
        """The chain's per-link parameters as the kernels' arrays, by field name."""
        return {"m": np.asarray(links["m"], float), "l": np.asarray(links["l"], float),
                "lc": np.asarray(links["lc"], float), "inertia": np.asarray(links["I"], float)}

    def reset(self, ports: Ports) -> None:
        if self.source == "fmu":
            # M̂ is the plant's own M: the trace's M_model is that same array, so a step
            # has nothing to copy.
            ports.trace.arrays["M_model"] = ports.inputs["M"]
            return
        self.args = self.bind(NominalArgs, ports, model=own_scratch(self.model))

    def describe(self) -> dict:
        if self.source == "fmu":
            return {"source": "fmu"}
        if self.urdf_chain is not None:
            return {"source": "nominal", "urdf": self.params.urdf,
                    "joints": list(self.urdf_chain.joints),
                    "tip": self.urdf_chain.tip_link}
        return {"source": "nominal", **self.nominal_links()}

    def headline(self) -> str:
        file = self.context.plant_file
        if self.source == "fmu":
            return f"inertia model from {file}'s M outputs"
        if self.urdf_chain is not None:
            return (f"inertia model nominal from {self.params.urdf} ({self.urdf_chain.n} "
                    f"joints, payload point at {self.urdf_chain.tip_link}) at the measured "
                    "position")
        links = self.nominal_links()
        return (f"inertia model nominal (m = {links['m']} kg, l = {links['l']} m, "
                f"lc = {links['lc']} m, I = {links['I']} kg·m²) at the measured position"
                + ("" if "M" in self.context.plant_outputs else f"; {file} maps no M outputs"))
