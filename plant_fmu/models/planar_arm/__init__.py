"""The built-in planar arm: an n-link serial chain (CRBA + RNEA in model.c), and the one table
of its FMU's variables.

Everything else is generated from :func:`variables`: the FMI 2.0 and 3.0
``modelDescription.xml`` and the C header ``variables.h`` that the model code
indexes by value reference. Adding a variable here adds it everywhere.

Names are the same in FMI 2.0 and 3.0 (scalar variables, 1-based indices):
``tau[i]``, ``q[i]``, ``qdot[i]``, ``M[i,j]``, ``energy`` and the parameters below.
All units are SI with angles in radians.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

MODEL_IDENTIFIER = "PlanarArm"
MAX_LINKS = 7

# Paper's arm (Lewis et al., SPEC §2) for links 1 and 2; extra links get 1 kg.
PAPER_MASSES = (0.8, 2.3)


@dataclass(frozen=True)
class Variable:
    """One scalar FMU variable. ``vr`` is its value reference."""

    name: str
    vr: int
    causality: str  # parameter | input | output | local | independent
    variability: str  # fixed | continuous
    unit: str | None
    description: str
    start: float | None = None
    check: str | None = None  # positive | nonnegative | finite (parameters, inputs)
    derivative_of: str | None = None  # name of the variable this is the derivative of
    group: str = ""  # base name: "m" for "m[1]"


@dataclass(frozen=True)
class _Block:
    """A family of variables sharing a base name: scalar, per link or n×n."""

    base: str
    shape: str  # "" | "n" | "nn"
    causality: str
    variability: str
    unit: str | None
    description: str
    start: Callable[[int], float] | None = None  # link index (0-based) -> start value
    check: str | None = None
    derivative_of: str | None = None


def _per_link(first_links: tuple[float, ...], rest: float) -> Callable[[int], float]:
    return lambda i: first_links[i] if i < len(first_links) else rest


def _const(value: float) -> Callable[[int], float]:
    return lambda i: value


_BLOCKS: tuple[_Block, ...] = (
    _Block("time", "", "independent", "continuous", "s", "Simulation time"),
    # Link parameters.
    _Block("m", "n", "parameter", "fixed", "kg", "Mass of link i",
           _per_link(PAPER_MASSES, 1.0), "positive"),
    _Block("l", "n", "parameter", "fixed", "m", "Length of link i (joint i to joint i+1)",
           _const(1.0), "positive"),
    _Block("lc", "n", "parameter", "fixed", "m",
           "Distance from joint i to the centre of mass of link i, along the link",
           _const(1.0), "finite"),
    _Block("I", "n", "parameter", "fixed", "kg.m2",
           "Rotational inertia of link i about its centre of mass", _const(0.0), "nonnegative"),
    _Block("b", "n", "parameter", "fixed", "N.m.s/rad", "Viscous friction of joint i",
           _const(0.0), "nonnegative"),
    _Block("fc", "n", "parameter", "fixed", "N.m",
           "Coulomb friction of joint i, smoothed as fc*tanh(qdot/fc_vel)", _const(0.0),
           "nonnegative"),
    _Block("fc_vel", "", "parameter", "fixed", "rad/s",
           "Smoothing velocity of the Coulomb friction", _const(0.01), "positive"),
    _Block("tau_d", "n", "parameter", "fixed", "N.m",
           "Constant disturbance torque on joint i (enters as M qdd + ... + tau_d = tau)",
           _const(0.01), "finite"),
    _Block("tau_d_amp", "n", "parameter", "fixed", "N.m",
           "Amplitude of the sinusoidal disturbance on joint i", _const(0.0), "finite"),
    _Block("tau_d_freq", "n", "parameter", "fixed", "Hz",
           "Frequency of the sinusoidal disturbance on joint i", _const(0.0), "nonnegative"),
    _Block("g", "", "parameter", "fixed", "m/s2",
           "Gravity, acting along -y in the plane of motion", _const(9.8), "finite"),
    _Block("q0", "n", "parameter", "fixed", "rad", "Initial angle of joint i",
           _const(0.1), "finite"),
    _Block("qdot0", "n", "parameter", "fixed", "rad/s", "Initial velocity of joint i",
           _const(10.0), "finite"),
    _Block("rk4_step", "", "parameter", "fixed", "s",
           "Largest internal RK4 step of Co-Simulation", _const(1e-4), "positive"),
    # Interface.
    _Block("tau", "n", "input", "continuous", "N.m", "Applied torque at joint i",
           _const(0.0), "finite"),
    _Block("q", "n", "output", "continuous", "rad",
           "Angle of joint i (link 1 from the horizontal, others relative)"),
    _Block("qdot", "n", "output", "continuous", "rad/s", "Velocity of joint i",
           derivative_of="q"),
    _Block("M", "nn", "output", "continuous", "kg.m2", "Joint-space inertia matrix M(q)"),
    _Block("energy", "", "output", "continuous", "J",
           "Kinetic plus potential energy (zero potential at y = 0)"),
    _Block("der(qdot)", "n", "local", "continuous", "rad/s2", "Acceleration of joint i",
           derivative_of="qdot"),
)


def _element_name(base: str, index: tuple[int, ...]) -> str:
    if not index:
        return base
    inner = ",".join(str(k + 1) for k in index)
    if base.startswith("der("):  # der(qdot)[1] reads badly: der(qdot[1])
        return f"der({base[4:-1]}[{inner}])"
    return f"{base}[{inner}]"


def variables(links: int) -> list[Variable]:
    """All scalar variables of an ``links``-link arm, ordered by value reference."""
    if not 1 <= links <= MAX_LINKS:
        raise ValueError(f"links must be between 1 and {MAX_LINKS}, got {links}")
    out: list[Variable] = []
    for block in _BLOCKS:
        if block.shape == "":
            indices: list[tuple[int, ...]] = [()]
        elif block.shape == "n":
            indices = [(i,) for i in range(links)]
        else:
            indices = [(i, j) for i in range(links) for j in range(links)]
        for index in indices:
            start = block.start(index[0] if index else 0) if block.start else None
            derivative_of = (
                _element_name(block.derivative_of, index) if block.derivative_of else None
            )
            out.append(Variable(
                name=_element_name(block.base, index), vr=len(out),
                causality=block.causality, variability=block.variability, unit=block.unit,
                description=block.description, start=start, check=block.check,
                derivative_of=derivative_of, group=block.base,
            ))
    return out


def first_vr(table: list[Variable], group: str) -> int:
    """Value reference of the first element of a variable group."""
    return next(v.vr for v in table if v.group == group)


# The model's C sources (beside this file): the arm's equations. The FMI glue they plug into
# is shared by every model (plant_fmu/fmi).
SOURCE_DIR = Path(__file__).parent
SOURCES = ("model.c",)
HEADERS = ("model.h", "arm_dynamics.h")
