"""A spatial rigid-body chain read from a URDF (:func:`plant_fmu.urdf.read_urdf`): the
model-agnostic algorithms in ``spatial_chain.h`` (ABA, CRBA, RNEA), integrated in
``model.c``, and per robot the generated ``chain.h`` and variable table.

Why the chain's geometry and inertias are compiled-in constants (``chain.h``) and not FMU
parameters: the URDF is the one source of truth for them, and the FMU is built (and cached)
per URDF, so a different robot, or a nominal robot beside the true one, is another URDF; a
7-joint arm would otherwise carry some 90 parameters that must stay mutually consistent (a
mass with its inertia, a placement with its rotation). What a pipeline varies between runs
is a parameter: the payload at the tip frame (kg), the joints' viscous and Coulomb friction,
a disturbance, the initial state; the URDF's velocity and effort limits are parameters for
it to read (the plant does not clip tau), and its position limits are the min/max of the
start positions q0.

Equations: M(q) qdd + h(q, qd) + b qd + fc tanh(qd / fc_vel) + tau_d = tau, with h the
Coriolis, centrifugal and gravity forces (gravity along the base's -z). SI units; angles in
rad, a prismatic joint's positions in m and its forces in N.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ... import c_literals as c
from ...urdf import Chain
from ...variables import Variable, VariableFamily, constant, expand

HERE = Path(__file__).parent
MODEL_IDENTIFIER = "SpatialChain"
MAX_LINKS = 32  # the C keeps per-joint arrays on the stack
SOURCES = (HERE / "model.c",)
# Unrolled and vectorised 3x3 and 6x6 loops: 42 % fewer instructions per RK4 sub-step than
# -O2 alone (callgrind, Panda), as few as -O3 at half its compile time. No fast-math: the
# same IEEE arithmetic.
CFLAGS = ("-funroll-loops", "-ftree-vectorize")
HEADERS = (HERE / "spatial_chain.h", HERE.parent / "common" / "rk4.h",
           HERE.parent / "common" / "joint_state.h", HERE.parent / "common" / "value_references.h")

# A joint's units: revolute, prismatic.
POSITION = ("rad", "m")
VELOCITY = ("rad/s", "m/s")
ACCELERATION = ("rad/s2", "m/s2")
FORCE = ("N.m", "N")
VISCOUS = ("N.m.s/rad", "N.s/m")
# M[i, j] by the kinds of joints i and j: a moment per angular acceleration, a moment per
# linear (or force per angular) acceleration, a force per linear acceleration.
INERTIA = {(0, 0): "kg.m2", (0, 1): "kg.m", (1, 0): "kg.m", (1, 1): "kg"}


def start_position(lower: float, upper: float) -> float:
    """The default start position: 0 if the limits allow it, else the middle of the range
    (or its one finite end)."""
    if lower <= 0.0 <= upper:
        return 0.0
    if np.isfinite(lower) and np.isfinite(upper):
        return 0.5 * (lower + upper)
    return lower if np.isfinite(lower) else upper


class SpatialChainModel:
    """The model of one chain, with the interface of a built-in model package
    (:mod:`plant_fmu.models`): ``variables``, ``describe``, ``MODEL_IDENTIFIER``,
    ``MAX_LINKS``, ``SOURCES``, ``HEADERS``; plus ``GENERATED``, the generated sources, and
    ``CFLAGS``, its own compiler options after the common ones."""

    MODEL_IDENTIFIER = MODEL_IDENTIFIER
    MAX_LINKS = MAX_LINKS
    SOURCES = SOURCES
    HEADERS = HEADERS
    CFLAGS = CFLAGS
    __file__ = __file__

    def __init__(self, chain: Chain, source: str = ""):
        if not 1 <= chain.n <= MAX_LINKS:
            raise ValueError(f"a spatial chain has 1 to {MAX_LINKS} moving joints, "
                             f"{chain.name} has {chain.n}")
        self.chain = chain
        self.source = source  # the URDF's path, for the description
        self.GENERATED = {"chain.h": chain_header(chain)}

    def _per_joint(self, units: tuple[str, str]):
        kind = self.chain.kind
        return lambda index: units[int(kind[index[0]])]

    def _naming(self, words: tuple[str, str]):
        """A description per joint with its URDF name: "Angle of joint 'panda_joint3'"
        (``words`` before the name: for a revolute joint, for a prismatic one)."""
        joints, kind = self.chain.joints, self.chain.kind
        return lambda index: f"{words[int(kind[index[0]])]} joint '{joints[index[0]]}'"

    def families(self) -> tuple[VariableFamily, ...]:
        c = self.chain
        per_joint, named = self._per_joint, self._naming
        tip = f"the tip frame (link '{c.tip_link}')"
        return (
            VariableFamily("time", "", "independent", "continuous", "s", "Simulation time"),
            VariableFamily("payload", "", "parameter", "fixed", "kg",
                           f"Point mass at the origin of {tip}", constant(0.0), "nonnegative"),
            VariableFamily("b", "n", "parameter", "fixed", None,
                           "Viscous friction of joint i (URDF <dynamics damping>)",
                           lambda i: float(c.damping[i]), "nonnegative",
                           unit_of=per_joint(VISCOUS)),
            VariableFamily("fc", "n", "parameter", "fixed", None,
                           "Coulomb friction of joint i (URDF <dynamics friction>), smoothed as "
                           "fc*tanh(qdot/fc_vel)", lambda i: float(c.friction[i]), "nonnegative",
                           unit_of=per_joint(FORCE)),
            VariableFamily("fc_vel", "n", "parameter", "fixed", None,
                           "Smoothing velocity of joint i's Coulomb friction", constant(0.01),
                           "positive", unit_of=per_joint(VELOCITY)),
            VariableFamily("tau_d", "n", "parameter", "fixed", None,
                           "Constant disturbance on joint i (enters as M qdd + h + ... + tau_d "
                           "= tau)", constant(0.0), "finite", unit_of=per_joint(FORCE)),
            VariableFamily("qdot_max", "n", "parameter", "fixed", None,
                           "Velocity limit of joint i (URDF <limit velocity>; INF: none given); "
                           "for the pipeline to read, the plant does not enforce it",
                           lambda i: float(c.velocity[i]), "limit", unit_of=per_joint(VELOCITY)),
            VariableFamily("tau_max", "n", "parameter", "fixed", None,
                           "Effort limit of joint i (URDF <limit effort>; INF: none given); "
                           "for the pipeline to read, the plant does not clip tau",
                           lambda i: float(c.effort[i]), "limit", unit_of=per_joint(FORCE)),
            VariableFamily("q0", "n", "parameter", "fixed", None,
                           "Initial position of joint i, within its URDF limits (min/max)",
                           lambda i: start_position(c.lower[i], c.upper[i]), "finite",
                           unit_of=per_joint(POSITION),
                           bounds=lambda i: (float(c.lower[i]), float(c.upper[i]))),
            VariableFamily("qdot0", "n", "parameter", "fixed", None,
                           "Initial velocity of joint i", constant(0.0), "finite",
                           unit_of=per_joint(VELOCITY)),
            VariableFamily("rk4_step", "", "parameter", "fixed", "s",
                           "Largest internal RK4 step of Co-Simulation", constant(1e-4),
                           "positive"),
            VariableFamily("rk4_motion", "", "parameter", "fixed", "rad",
                           "Largest motion of a joint in one RK4 step of Co-Simulation "
                           "(m for a prismatic joint): a faster arm takes shorter steps, "
                           "down to rk4_step/8", constant(4e-3), "positive"),
            VariableFamily("tau", "n", "input", "continuous", None,
                           "Applied force at joint i (torque for a revolute joint)",
                           constant(0.0), "finite", unit_of=per_joint(FORCE),
                           description_of=named(("Torque applied to", "Force applied to"))),
            VariableFamily("q", "n", "output", "continuous", None, "Position of joint i",
                           unit_of=per_joint(POSITION), depends=("q[i]",),
                           description_of=named(("Angle of", "Position of"))),
            VariableFamily("qdot", "n", "output", "continuous", None, "Velocity of joint i",
                           derivative_of="q", unit_of=per_joint(VELOCITY), depends=("qdot[i]",),
                           description_of=named(("Angular velocity of", "Velocity of"))),
            VariableFamily("M", "nn", "output", "continuous", None,
                           "Joint-space inertia matrix M(q) (CRBA)", depends=("q",),
                           unit_of=lambda ij: INERTIA[(int(c.kind[ij[0]]), int(c.kind[ij[1]]))]),
            VariableFamily("h", "n", "output", "continuous", None,
                           "Bias force h(q, qdot) of joint i: Coriolis, centrifugal and gravity "
                           "(RNEA)", unit_of=per_joint(FORCE), depends=("q", "qdot")),
            VariableFamily("energy", "", "output", "continuous", "J",
                           "Kinetic plus potential energy (zero potential at the base's origin)",
                           depends=("q", "qdot")),
            VariableFamily("der(qdot)", "n", "local", "continuous", None,
                           "Acceleration of joint i (ABA)", derivative_of="qdot",
                           unit_of=per_joint(ACCELERATION)),
        )

    def variables(self, links: int) -> list[Variable]:
        """All scalar variables, ordered by value reference (``links`` is the chain's n)."""
        if links != self.chain.n:
            raise ValueError(f"{self.chain.name} has {self.chain.n} moving joints, not {links}")
        return expand(self.families(), links)

    def describe(self, links: int) -> str:
        c = self.chain
        joints = ", ".join(f"{i + 1}: {name}" for i, name in enumerate(c.joints))
        return (f"{c.name}: spatial {links}-joint chain from link '{c.base_link}' to link "
                f"'{c.tip_link}' (URDF {Path(self.source).name}; joints {joints}; SI units, "
                "radians)")


def chain_header(chain: Chain) -> str:
    """chain.h: the chain's constants for spatial_chain.h, from the Chain table."""
    n = chain.n
    rotation = chain.placement[:, :3, :3]
    k = np.array([[[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]] for a in chain.axis])
    rk = rotation @ k
    joints = ", ".join(c.string_literal(name) for name in chain.joints)
    lines = [
        # No name from the URDF in a comment: names reach C only as escaped literals.
        "/* Generated by plant_fmu/models/spatial_chain from a URDF: the chain's constants. */",
        "#ifndef CHAIN_H", "#define CHAIN_H", "", "#include <math.h>", "",
        "/* Joint kinds (0 revolute, 1 prismatic) and each joint's parent body (-1 the base). */",
        f"static const int CHAIN_KIND[{n}] = {{{', '.join(c.integer(k) for k in chain.kind)}}};",
        f"static const int CHAIN_PARENT[{n}] = "
        f"{{{', '.join(c.integer(p) for p in chain.parent)}}};",
        f"static const char *const CHAIN_JOINTS[{n}] = {{{joints}}};",
        "/* Placement of each joint in its parent body at q = 0: rotation (parent <- joint,",
        " * row-major) and origin (m); the joint's unit axis in its own frame. */",
        f"static const double CHAIN_ROTATION[{n}][9] = "
        f"{c.array(chain.placement[:, :3, :3].reshape(n, 9))};",
        f"static const double CHAIN_TRANSLATION[{n}][3] = {c.array(chain.placement[:, :3, 3])};",
        f"static const double CHAIN_AXIS[{n}][3] = {c.array(chain.axis)};",
        "/* Derived, for the joint transform: R K and R K^2 (K = [axis]x), and R axis. */",
        f"static const double CHAIN_ROTATION_K[{n}][9] = {c.array(rk.reshape(n, 9))};",
        f"static const double CHAIN_ROTATION_KK[{n}][9] = {c.array((rk @ k).reshape(n, 9))};",
        f"static const double CHAIN_ROTATED_AXIS[{n}][3] = "
        f"{c.array(np.einsum('nij,nj->ni', rotation, chain.axis))};",
        "/* Each body (folded links lumped in): mass (kg), centre of mass (m) and inertia about",
        " * it (kg m^2, row-major), in the body's frame. */",
        f"static const double CHAIN_MASS[{n}] = {c.array(chain.mass)};",
        f"static const double CHAIN_COM[{n}][3] = {c.array(chain.com)};",
        f"static const double CHAIN_INERTIA[{n}][9] = {c.array(chain.inertia.reshape(n, 9))};",
        "/* Position limits (rad or m), for the start positions. */",
        f"static const double CHAIN_LOWER[{n}] = {c.array(chain.lower)};",
        f"static const double CHAIN_UPPER[{n}] = {c.array(chain.upper)};",
        "/* The tip frame's origin in the last body's frame (m): where the payload sits. */",
        f"static const double CHAIN_TIP_TRANSLATION[3] = {c.array(chain.tip[:3, 3])};",
        "/* Gravity in the base's frame (m/s^2). */",
        f"static const double CHAIN_GRAVITY[3] = {c.array(chain.gravity)};",
        "", "#endif", "",
    ]
    return "\n".join(lines)
