"""The plant's ports: the one table of what cosim exchanges with a plant FMU.

Everything plant-facing is derived from :data:`PORTS`: the pipeline's ``plant.variables``
keys, the mapping's checks and messages (:mod:`.mapping`), the adapter's buffers
(:mod:`.fmu`), the rows the master and the fused loop copy the outputs into, and the
plant's signals in every trace. A new plant output is one line here (and the variables in
the FMU); blocks then read it by its name. SI units, radians.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..signals import Signal


@dataclass(frozen=True)
class PlantPort:
    """One port. ``name``: the trace signal and the ``plant.variables`` key; ``shape``: "n"
    (one variable per joint) or "nn" (n×n, row-major); ``required``: the plant must map it
    (an optional output the FMU does not have stays NaN in the trace, and no block may read
    it); ``role``: what it is, in messages."""

    name: str
    direction: str  # "input" | "output"
    shape: str
    required: bool
    role: str
    signal: Signal
    unmapped: str = ""  # what a plant without this optional output cannot do (cosim inspect)
    # The paper's interface (q, q̇, M) is in every trace, NaN where the plant does not map
    # it, so that every run folder holds the same arrays; another port only where mapped.
    always_traced: bool = True

    def default_names(self, links: int) -> list[str]:
        """The built-in plants' names: ``q[1]``, …, ``M[1,2]``, …"""
        idx = range(1, links + 1)
        if self.shape == "nn":
            return [f"{self.name}[{i},{j}]" for i in idx for j in idx]
        return [f"{self.name}[{i}]" for i in idx]

    def width(self, links: int) -> int:
        return links * links if self.shape == "nn" else links


PORTS: tuple[PlantPort, ...] = (
    PlantPort("tau", "input", "n", True, "joint torques",
              Signal("n", "N·m", "joint torques τ applied to the plant", "plant/tau")),
    PlantPort("q", "output", "n", True, "joint angles",
              Signal("n", "rad", "joint angles q (plant)", "plant/q")),
    PlantPort("qdot", "output", "n", False, "joint velocities",
              Signal("n", "rad/s", "joint velocities q̇ (plant)", "plant/qdot"),
              "the full-state baseline cannot run on it, and the true-velocity sets are "
              "not judged"),
    # n² series per run add little to the review; the trace files keep M.
    PlantPort("M", "output", "nn", False, "inertia matrix",
              Signal("nn", "kg·m²", "inertia matrix M(q) (plant)"),
              "the controller uses the pipeline's nominal inertia model"),
    # The bias forces of a URDF's spatial chain (C q̇ + G, its RNEA): with M, what tells the
    # guarantee whether the plant is the nominal model's arm (its gravity, its base); in
    # the trace files.
    PlantPort("h", "output", "n", False, "bias forces",
              Signal("n", "N·m", "bias forces h(q, q̇) = C(q, q̇) q̇ + G(q) (plant)"),
              always_traced=False),
    # The elastic-joint arm's motor angles (θ, link side); in the trace files.
    PlantPort("theta", "output", "n", False, "motor angles",
              Signal("n", "rad", "motor angles θ (plant with elastic joints)"),
              always_traced=False),
)
PORT = {port.name: port for port in PORTS}
OUTPUT_PORTS = tuple(port for port in PORTS if port.direction == "output")
(INPUT_PORT,) = (port for port in PORTS if port.direction == "input")

# Ground truth from the plant, a signal per output port (NaN where not mapped).
PLANT_OUTPUTS = {port.name: port.signal for port in OUTPUT_PORTS}


def traced_outputs(mapped: frozenset[str]) -> dict[str, Signal]:
    """The plant outputs a run's trace holds: the paper's interface always (NaN where not
    ``mapped``), every other port where mapped."""
    return {port.name: port.signal for port in OUTPUT_PORTS
            if port.always_traced or port.name in mapped}
# The plant's input: the torque the last block in the chain produces under this name.
PLANT_INPUT = INPUT_PORT.name
PLANT_INPUT_ENTITY = INPUT_PORT.signal.entity


class Plant(Protocol):
    """What the master, the assembly and the tests' stand-in plants share: the joint count,
    the output ports the plant maps, their latest values (``values[name]``, NaN where not
    mapped) and the input ``tau``, held over each :meth:`step`. A plant may also record
    signals of its own (a system's components'): ``signals`` (trace key -> declaration),
    which the assembly adds to every run's trace, and ``bind_trace(trace)``, which the
    master calls after :meth:`start`."""

    links: int
    mapped: frozenset[str]
    values: dict[str, np.ndarray]
    tau: np.ndarray

    def start(self, start_time: float) -> None: ...

    def step(self, t: float, h: float) -> None: ...


def output_buffers(links: int) -> dict[str, np.ndarray]:
    """A plant's output values, one array per output port (n or n×n), NaN until read."""
    return {port.name: np.full((links, links) if port.shape == "nn" else (links,), np.nan)
            for port in OUTPUT_PORTS}
