"""The built-in planar arm: an n-link serial chain (CRBA + RNEA in
``plant_fmu/models/common/planar_chain.h``, integrated in ``model.c``), and the one table of
its FMU's variables.

Everything else is generated from :func:`variables`: the FMI 2.0 and 3.0
``modelDescription.xml`` and the C header ``variables.h`` that the model and the FMI glue
index by value reference. Adding a variable here adds it everywhere.

Names: ``tau[i]``, ``Jm[i]`` (inputs), ``q[i]``, ``qdot[i]``, ``M[i,j]``, ``energy``
and the parameters below.
All units are SI with angles in radians.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ...variables import Variable, VariableFamily, constant, expand, per_link

MODEL_IDENTIFIER = "PlanarArm"
MAX_LINKS = 7
COMMON = Path(__file__).parent.parent / "common"

# The paper's arm (Lewis et al.) for links 1 and 2; extra links get 1 kg.
PAPER_MASSES = (0.8, 2.3)

TIME = VariableFamily("time", "", "independent", "continuous", "s", "Simulation time")

# The chain's parameters, in the order planar_chain.h's chain_params reads them (shared
# with the elastic-joint arm's links).
LINK_PARAMETERS: tuple[VariableFamily, ...] = (
    VariableFamily("m", "n", "parameter", "fixed", "kg", "Mass of link i",
                   per_link(PAPER_MASSES, 1.0), "positive"),
    VariableFamily("l", "n", "parameter", "fixed", "m",
                   "Length of link i (joint i to joint i+1)", constant(1.0), "positive"),
    VariableFamily("lc", "n", "parameter", "fixed", "m",
                   "Distance from joint i to the centre of mass of link i, along the link",
                   constant(1.0), "finite"),
    VariableFamily("I", "n", "parameter", "fixed", "kg.m2",
                   "Rotational inertia of link i about its centre of mass", constant(0.0),
                   "nonnegative"),
    VariableFamily("b", "n", "parameter", "fixed", "N.m.s/rad", "Viscous friction of joint i",
                   constant(0.0), "nonnegative"),
    VariableFamily("fc", "n", "parameter", "fixed", "N.m",
                   "Coulomb friction of joint i, smoothed as fc*tanh(qdot/fc_vel)",
                   constant(0.0), "nonnegative"),
    VariableFamily("fc_vel", "", "parameter", "fixed", "rad/s",
                   "Smoothing velocity of the Coulomb friction", constant(0.01), "positive"),
    VariableFamily("tau_d", "n", "parameter", "fixed", "N.m",
                   "Constant disturbance torque on joint i (enters as M qdd + ... + tau_d = "
                   "tau)", constant(0.01), "finite"),
    VariableFamily("tau_d_amp", "n", "parameter", "fixed", "N.m",
                   "Amplitude of the sinusoidal disturbance on joint i", constant(0.0),
                   "finite"),
    VariableFamily("tau_d_freq", "n", "parameter", "fixed", "Hz",
                   "Frequency of the sinusoidal disturbance on joint i", constant(0.0),
                   "nonnegative"),
    VariableFamily("g", "", "parameter", "fixed", "m/s2",
                   "Gravity, acting along -y in the plane of motion", constant(9.8), "finite"),
    VariableFamily("q0", "n", "parameter", "fixed", "rad", "Initial angle of joint i",
                   constant(0.1), "finite"),
    VariableFamily("qdot0", "n", "parameter", "fixed", "rad/s", "Initial velocity of joint i",
                   constant(10.0), "finite"),
    VariableFamily("rk4_step", "", "parameter", "fixed", "s",
                   "Largest internal RK4 step of Co-Simulation", constant(1e-4), "positive"),
)

TORQUE = VariableFamily("tau", "n", "input", "continuous", "N.m", "Applied torque at joint i",
                        constant(0.0), "finite")
# What a drive adds to its joint's inertia: its rotor's, reflected through its gear (J N²).
# An input, so that a drive component of a system supplies it (plant_fmu/models/drives)
# rather than a second copy of its parameters; 0 when nothing is connected.
DRIVE_INERTIA = VariableFamily("Jm", "n", "input", "continuous", "kg.m2",
                               "Inertia a drive adds at joint i (its rotor's reflected through "
                               "its gear, J N^2), on M's diagonal", constant(0.0), "nonnegative")
# The outputs' direct dependencies: q and qdot are states (no input reaches them within an
# instant), M depends on q (and on Jm where the model has it).
ANGLE = VariableFamily("q", "n", "output", "continuous", "rad",
                       "Angle of joint i (link 1 from the horizontal, others relative)",
                       depends=("q[i]",))
VELOCITY = VariableFamily("qdot", "n", "output", "continuous", "rad/s", "Velocity of joint i",
                          derivative_of="q", depends=("qdot[i]",))
INERTIA = VariableFamily("M", "nn", "output", "continuous", "kg.m2",
                         "Joint-space inertia matrix M(q)", depends=("q",))

FAMILIES: tuple[VariableFamily, ...] = (
    TIME, *LINK_PARAMETERS, TORQUE, DRIVE_INERTIA, ANGLE, VELOCITY,
    replace(INERTIA, depends=("q", "Jm")),
    VariableFamily("energy", "", "output", "continuous", "J",
                   "Kinetic plus potential energy (zero potential at y = 0)",
                   depends=("q", "qdot", "Jm")),
    VariableFamily("der(qdot)", "n", "local", "continuous", "rad/s2",
                   "Acceleration of joint i", derivative_of="qdot"),
)


def variables(links: int) -> list[Variable]:
    """All scalar variables of an ``links``-link arm, ordered by value reference."""
    if not 1 <= links <= MAX_LINKS:
        raise ValueError(f"links must be between 1 and {MAX_LINKS}, got {links}")
    return expand(FAMILIES, links)


def describe(links: int) -> str:
    """The modelDescription's one-line description."""
    return f"Planar {links}-link serial arm (Euler-Lagrange, SI units, radians)"


# The model's C sources: its equations (model.c) against the FMI glue's contract
# (plant_fmu/fmi/model.h), and what it shares with the other built-in models.
SOURCES = (Path(__file__).parent / "model.c",)
HEADERS = (COMMON / "planar_chain.h", COMMON / "rk4.h", COMMON / "joint_state.h",
           COMMON / "value_references.h")
