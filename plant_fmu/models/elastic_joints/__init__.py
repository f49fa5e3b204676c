"""The arm with elastic joints (Spong 1987): the rigid planar chain's links, each driven
through a joint spring and damper by a motor with its own inertia (``model.c``), and the one
table of its FMU's variables.

The links' parameters, the torque input and the outputs ``q``, ``qdot`` (link angles and
velocities) and ``M`` (the links' inertia matrix) are the rigid arm's, so a pipeline written
for the rigid arm runs on it unchanged. Added: per joint the stiffness ``k``, damping ``d``
and motor inertia ``J``, the initial spring deflection ``deflection0``, and the motor angle
``theta`` as an extra output (its velocity ``thetadot`` is a local state). SI units, radians.
"""

from __future__ import annotations

from pathlib import Path

from ...variables import Variable, VariableFamily, constant, expand
from ..planar_arm import ANGLE, COMMON, INERTIA, LINK_PARAMETERS, TIME, VELOCITY

MODEL_IDENTIFIER = "ElasticJointArm"
MAX_LINKS = 7

FAMILIES: tuple[VariableFamily, ...] = (
    TIME, *LINK_PARAMETERS,
    VariableFamily("k", "n", "parameter", "fixed", "N.m/rad",
                   "Stiffness of joint i's spring (motor angle minus link angle)",
                   constant(1e4), "positive"),
    VariableFamily("d", "n", "parameter", "fixed", "N.m.s/rad",
                   "Damping of joint i's spring", constant(10.0), "nonnegative"),
    VariableFamily("J", "n", "parameter", "fixed", "kg.m2",
                   "Inertia of motor i, referred to the link side", constant(0.05), "positive"),
    VariableFamily("deflection0", "n", "parameter", "fixed", "rad",
                   "Initial spring deflection of joint i (motor angle minus link angle)",
                   constant(0.0), "finite"),
    VariableFamily("tau", "n", "input", "continuous", "N.m", "Motor torque at joint i",
                   constant(0.0), "finite"),
    ANGLE, VELOCITY,
    VariableFamily("theta", "n", "output", "continuous", "rad",
                   "Angle of motor i, referred to the link side", depends=("theta[i]",)),
    VariableFamily("thetadot", "n", "local", "continuous", "rad/s", "Velocity of motor i",
                   derivative_of="theta"),
    INERTIA,
    VariableFamily("energy", "", "output", "continuous", "J",
                   "Kinetic plus potential energy of links, motors and springs",
                   depends=("q", "qdot", "theta", "thetadot")),
    VariableFamily("der(qdot)", "n", "local", "continuous", "rad/s2",
                   "Acceleration of link i", derivative_of="qdot"),
    VariableFamily("der(thetadot)", "n", "local", "continuous", "rad/s2",
                   "Acceleration of motor i", derivative_of="thetadot"),
)


def variables(links: int) -> list[Variable]:
    """All scalar variables of an ``links``-link elastic-joint arm, by value reference."""
    if not 1 <= links <= MAX_LINKS:
        raise ValueError(f"links must be between 1 and {MAX_LINKS}, got {links}")
    return expand(FAMILIES, links)


def describe(links: int) -> str:
    """The modelDescription's one-line description."""
    return (f"Planar {links}-link arm with elastic joints (Spong): links driven through joint "
            "springs by motors; SI units, radians")


SOURCES = (Path(__file__).parent / "model.c",)
HEADERS = (COMMON / "planar_chain.h", COMMON / "rk4.h", COMMON / "joint_state.h",
           COMMON / "value_references.h")
