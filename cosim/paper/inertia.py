"""The controller's inertia model M̂(q), which the observer's (7) needs (Assumption 3: M(q) is
known). Two sources, written to the trace's ``M_model`` for row k:

- ``fmu``: the plant's own ``M`` outputs at the true q (the FMU maps ``M``);
- ``nominal``: a planar serial chain with the pipeline's link parameters, evaluated at the
  measured position ``q_meas`` — all an output-feedback controller can know. A plant whose
  masses differ from these is how a model mismatch is studied.

The chain is the built-in plant's: link i of mass m_i, length l_i, centre of mass lc_i
along it and rotational inertia I_i; joint angles relative, link 1 from the horizontal.
With absolute angles θ_k = q_1 + … + q_k, joint origins o_i and centres of mass p_k,

    M_ij = Σ_{k ≥ max(i, j)} [ m_k (p_k − o_i)·(p_k − o_j) + I_k ],

since a rotation about joint i moves p_k by ẑ × (p_k − o_i) and (ẑ × a)·(ẑ × b) = a·b.
SI units, radians.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import numpy as np
from numba import njit

from plant_fmu.models.planar_arm import PAPER_MASSES

from ..blocks.base import Block, BlockContext, Ports, kernel_args, register_block
from ..schema import FiniteFloat, NonNegativeFloat, PipelineError, PositiveFloat, Section
from ..signals import Signal


class InertiaModelParams(Section):
    """Where the observer's M(q) (Assumption 3) comes from: ``fmu`` (its mapped M outputs),
    ``nominal`` (this planar chain, evaluated at the measured position) or ``auto`` (the FMU's
    when mapped, else nominal). Per link; unset: the paper's arm (m = 0.8, 2.3 kg, l = lc =
    1 m, I = 0), further links 1 kg, 1 m, like the built-in plant's defaults."""

    # where the inertia model M̂(q) comes from (a name): "fmu", the FMU's M outputs;
    # "nominal", the nominal chain (m, l, lc, I); "auto", the FMU's when mapped, else nominal
    source: Literal["auto", "fmu", "nominal"] = "auto"
    m: list[PositiveFloat] | None = None  # the nominal chain's mass of each link, kg
    # the nominal chain's length of each link, joint i to joint i+1, m
    l: list[PositiveFloat] | None = None  # noqa: E741
    # the nominal chain's distance from joint i to link i's centre of mass, m
    lc: list[FiniteFloat] | None = None
    # the nominal chain's rotational inertia of each link about its centre of mass, kg·m²
    I: list[NonNegativeFloat] | None = None  # noqa: E741
    # gravitational acceleration of the nominal chain's bias b̂ = C q̇ + G, m/s²
    gravity: FiniteFloat = 9.8


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


# The chain's geometry at one position and the forces of its bias, per link: the rows of a
# (CHAIN_ROWS, n) scratch array, so that a kernel evaluating the chain every step allocates
# nothing. Joint i's centre-of-mass offset (CX, CY) and link vector (LX, LY), its origin
# (OX, OY), and m_i a_ci, the force link i's own motion needs (FX, FY).
CX, CY, LX, LY, OX, OY, FX, FY = range(8)
CHAIN_ROWS = 8


@njit(cache=True, inline="always")
def chain_geometry(q, l, lc, chain):  # noqa: E741
    """The chain's geometry at q into rows CX … OY of ``chain``."""
    theta, x, y = 0.0, 0.0, 0.0
    for k in range(q.shape[0]):
        theta += q[k]
        c, s = np.cos(theta), np.sin(theta)
        chain[CX, k], chain[CY, k] = lc[k] * c, lc[k] * s
        chain[LX, k], chain[LY, k] = l[k] * c, l[k] * s
        chain[OX, k], chain[OY, k] = x, y
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
                px, py = chain[OX, k] + chain[CX, k], chain[OY, k] + chain[CY, k]
                total += (m[k] * ((px - chain[OX, i]) * (px - chain[OX, j])
                                  + (py - chain[OY, i]) * (py - chain[OY, j])) + inertia[k])
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
        chain[FX, i] = m[i] * (ax - w2 * chain[CX, i])
        chain[FY, i] = m[i] * (ay - w2 * chain[CY, i])
        ax -= w2 * chain[LX, i]
        ay -= w2 * chain[LY, i]
    force_x, force_y, moment = 0.0, 0.0, 0.0  # what link i+1 exerts, about joint i+1
    for i in range(n - 1, -1, -1):
        # moment about joint i: the next link's moment, its force at the link's end, and
        # this link's own inertial force at its centre of mass (I α = 0)
        moment += (chain[LX, i] * force_y - chain[LY, i] * force_x
                   + chain[CX, i] * chain[FY, i] - chain[CY, i] * chain[FX, i])
        force_x += chain[FX, i]
        force_y += chain[FY, i]
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


class NominalArgs(NamedTuple):
    q_meas: np.ndarray
    m: np.ndarray  # kg
    l: np.ndarray  # m  # noqa: E741
    lc: np.ndarray  # m
    inertia: np.ndarray  # kg·m²
    M_model: np.ndarray
    chain: np.ndarray  # (CHAIN_ROWS, n) scratch


@njit(cache=True)
def nominal_step(k, a):
    chain_geometry(a.q_meas[k], a.l, a.lc, a.chain)
    chain_mass(a.chain, a.m, a.inertia, a.M_model[k])
    return True  # a non-finite M̂ makes the observer's output non-finite: caught there


# M̂ is not recorded: it is n² series per run of little use on their own (the plant's M is
# in the trace files).
M_MODEL = Signal("nn", "kg·m²", "the controller's inertia model M̂(q)")


@register_block
class InertiaModel(Block):
    """``source`` "auto" resolves here: "fmu" when the plant outputs M, else "nominal"."""

    kind = "inertia_model"
    Params = InertiaModelParams
    per_joint = ("m", "l", "lc", "I")
    # nominal_chain: Chain; inertia_is_plant: True when M̂ is the plant's own M (so it
    # includes any payload), False when it is the nominal chain's.
    PUBLISHES = {"nominal_chain": Chain, "inertia_is_plant": bool}

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
        links = self.nominal_links()
        self.publishes = {
            "nominal_chain": kernel_args(Chain, **self.chain_arrays(links),
                                         gravity=params.gravity),
            "inertia_is_plant": source == "fmu"}

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
        links = self.nominal_links()
        self.args = kernel_args(
            NominalArgs, q_meas=ports.inputs["q_meas"], **self.chain_arrays(links),
            M_model=ports.outputs["M_model"], chain=np.empty((CHAIN_ROWS, self.context.links)))

    def describe(self) -> dict:
        return ({"source": "nominal", **self.nominal_links()} if self.source == "nominal"
                else {"source": "fmu"})

    def headline(self) -> str:
        file = self.context.plant_file
        if self.source == "fmu":
            return f"inertia model from {file}'s M outputs"
        links = self.nominal_links()
        return (f"inertia model nominal (m = {links['m']} kg, l = {links['l']} m, "
                f"lc = {links['lc']} m, I = {links['I']} kg·m²) at the measured position"
                + ("" if "M" in self.context.plant_outputs else f"; {file} maps no M outputs"))
