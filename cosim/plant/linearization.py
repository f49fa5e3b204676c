"""Linearise an FMU about its start state into a python-control state-space model, from the
FMU's own directional derivatives (Model Exchange): ``cosim inspect FMU --linearize``.

    from cosim import linearize
    sys = linearize("arm.fmu", inputs=["tau[1]", "tau[2]"], outputs=["q[1]", "q[2]"])
    sys.poles()

With x the continuous states, u the inputs and y the outputs, about (x0, u0) at t = 0 after
initialisation: A = ∂ẋ/∂x, B = ∂ẋ/∂u, C = ∂y/∂x, D = ∂y/∂u, each column one directional
derivative with a unit seed. The start state need not be an equilibrium (the arm's default
start moves at q̇0 = 10 rad/s); ``x0`` and ``xdot0`` are returned alongside so a caller can
tell.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import control
import numpy as np

from .inspection import provides_directional_derivatives
from .lifecycle import open_instance
from .mapping import (
    FmuError,
    check_binary,
    check_parameters,
    map_variables,
    read_description,
    real_names,
)


@dataclass
class Linearization:
    """The model, and the point it was taken at (SI units of the FMU's variables)."""

    system: control.StateSpace
    x0: np.ndarray  # start state
    xdot0: np.ndarray  # its derivative: zero at an equilibrium
    u0: np.ndarray  # start inputs


def linearize(path: str | Path, inputs: list[str] | None = None,
              outputs: list[str] | None = None, parameters: dict[str, float] | None = None
              ) -> control.StateSpace:
    """``path``'s linearisation about its start state as a ``control.StateSpace`` with named
    states, inputs and outputs. Default inputs/outputs: our plant interface's ``tau`` and
    ``q`` (+ ``qdot``) when the FMU fits it, else all its Real inputs/outputs.
    ``parameters`` are set before initialisation, like ``plant.parameters``."""
    return linearize_at_start(path, inputs, outputs, parameters).system


def linearize_at_start(path: str | Path, inputs: list[str] | None = None,
                       outputs: list[str] | None = None,
                       parameters: dict[str, float] | None = None) -> Linearization:
    """:func:`linearize`, with the operating point."""
    path = Path(path)
    md = read_description(path)
    if md.modelExchange is None:
        raise FmuError(f"{path}: no Model Exchange interface (it offers Co-Simulation only); "
                       "linearising needs the model's derivatives")
    if not provides_directional_derivatives(path, md):
        raise FmuError(f"{path}: its Model Exchange interface does not provide directional "
                       "derivatives (providesDirectionalDerivative is not true)")
    check_binary(path, md, md.modelExchange.modelIdentifier, "Model Exchange")
    check_parameters(path, md, parameters or {})
    mapping, _ = map_variables(md)
    if inputs is None:
        inputs = mapping.tau if mapping else real_names(md, "input")
    if outputs is None:
        outputs = mapping.q + (mapping.qdot or []) if mapping else real_names(md, "output")
    by_name = {v.name: v for v in md.modelVariables}
    for kind, names in (("input", inputs), ("output", outputs)):
        for name in names:
            if name not in by_name or by_name[name].causality != kind:
                raise FmuError(f"{path}: {name!r} is not a Real {kind} of the FMU (its "
                               f"{kind}s: {', '.join(real_names(md, kind)) or 'none'})")
    derivatives = [d.variable for d in md.derivatives]
    states = [d.derivative for d in derivatives]
    if not states:
        raise FmuError(f"{path}: the FMU declares no continuous states (ModelStructure/"
                       "Derivatives is empty): nothing to linearise")

    def refs(variables) -> list[int]:
        return [v.valueReference for v in variables]

    x_vr, dx_vr = refs(states), refs(derivatives)
    u_vr, y_vr = refs(by_name[n] for n in inputs), refs(by_name[n] for n in outputs)
    parameters = {by_name[n].valueReference: float(v) for n, v in (parameters or {}).items()}
    instance = open_instance(path, md, "ModelExchange", "linearize")
    try:
        instance.initialize(0.0, parameters)
        get = instance.get_reals
        x0, xdot0 = np.array(get(x_vr)), np.array(get(dx_vr))
        u0 = np.array(get(u_vr)) if u_vr else np.zeros(0)

        def jacobian(unknowns: list[int], knowns: list[int]) -> np.ndarray:
            out = np.zeros((len(unknowns), len(knowns)))
            if not unknowns:
                return out
            for j, known in enumerate(knowns):  # same call in FMPy's FMI 2 and 3 wrappers
                out[:, j] = instance.fmu.getDirectionalDerivative(unknowns, [known], [1.0])
            return out

        system = control.ss(jacobian(dx_vr, x_vr), jacobian(dx_vr, u_vr),
                            jacobian(y_vr, x_vr), jacobian(y_vr, u_vr),
                            states=[v.name for v in states], inputs=list(inputs),
                            outputs=list(outputs), name=md.modelName)
        return Linearization(system, x0, xdot0, u0)
    finally:
        instance.close()
