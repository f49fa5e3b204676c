"""The arm's drives: per joint a DC motor under current control behind a gear (``model.c``),
and the one table of its FMU's variables. A component of a system (cosim's ``[plant]
system``, docs/systems.md), between the controller's torque and the arm.

Per joint i, with the commanded joint torque u (the input ``tau_cmd[i]``), gear ratio N,
torque constant kt, current limit i_max and current-loop time constant T:

    i_cmd = sat(u / (N kt), i_max),   T di/dt = i_cmd − i  (T = 0: i = i_cmd),
    τ = N kt i                          (the joint-side torque, the output ``tau[i]``),

and the rotor's inertia J reflected through the gear, J N², as the output ``J_reflected[i]``
for the arm's ``Jm[i]`` input (it turns with the joint: the arm carries it on M's
diagonal; a drive cannot add it itself without the joint's acceleration of the same instant,
an algebraic loop). Ideal drives (T = 0, i_max = INF, J = 0) deliver the command exactly.
The current starts settled on the command the drive is given while it initialises (0 unless
an importer sets it). SI units, radians.
"""

from __future__ import annotations

from pathlib import Path

from ...variables import Variable, VariableFamily, constant, expand

MODEL_IDENTIFIER = "Drives"
MAX_LINKS = 7
COMMON = Path(__file__).parent.parent / "common"

FAMILIES: tuple[VariableFamily, ...] = (
    VariableFamily("time", "", "independent", "continuous", "s", "Simulation time"),
    VariableFamily("N", "n", "parameter", "fixed", None,
                   "Gear ratio of drive i: motor turns per joint turn", constant(1.0),
                   "positive"),
    VariableFamily("kt", "n", "parameter", "fixed", "N.m/A",
                   "Torque constant of motor i (motor side)", constant(1.0), "positive"),
    VariableFamily("i_max", "n", "parameter", "fixed", "A",
                   "Current limit of drive i (INF: none); the joint torque's limit is "
                   "N kt i_max", constant(float("inf")), "limit"),
    VariableFamily("T", "n", "parameter", "fixed", "s",
                   "Time constant of drive i's current loop (first-order lag; 0: ideal)",
                   constant(0.0), "nonnegative"),
    VariableFamily("J", "n", "parameter", "fixed", "kg.m2",
                   "Rotor inertia of motor i (motor side)", constant(0.0), "nonnegative"),
    VariableFamily("tau_cmd", "n", "input", "continuous", "N.m",
                   "Joint torque commanded of drive i", constant(0.0), "finite"),
    # The current loop's state: what the lag has reached (with T = 0, the command itself).
    VariableFamily("i_lag", "n", "local", "continuous", "A",
                   "Current of motor i as the current loop's lag has reached it"),
    # Both depend on the command within an instant when T = 0 (declared so whatever T).
    VariableFamily("current", "n", "output", "continuous", "A", "Current of motor i",
                   depends=("tau_cmd[i]", "i_lag[i]")),
    VariableFamily("tau", "n", "output", "continuous", "N.m",
                   "Joint torque drive i delivers (joint side)",
                   depends=("tau_cmd[i]", "i_lag[i]")),
    VariableFamily("J_reflected", "n", "output", "continuous", "kg.m2",
                   "Rotor inertia of motor i reflected to its joint, J N^2", depends=()),
    VariableFamily("der(i_lag)", "n", "local", "continuous", "A/s",
                   "Rate of the current loop's lag", derivative_of="i_lag"),
)


def variables(links: int) -> list[Variable]:
    """All scalar variables of the drives of ``links`` joints, by value reference."""
    if not 1 <= links <= MAX_LINKS:
        raise ValueError(f"joints must be between 1 and {MAX_LINKS}, got {links}")
    return expand(FAMILIES, links)


def describe(links: int) -> str:
    """The modelDescription's one-line description."""
    return (f"Drives of {links} joints: DC motors under current control (limit, first-order "
            "lag) behind gears; joint torque in, joint torque out; SI units")


SOURCES = (Path(__file__).parent / "model.c",)
HEADERS = (COMMON / "value_references.h",)
