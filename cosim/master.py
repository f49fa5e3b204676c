"""The fixed-step co-simulation master.

Each step k: copy the plant's outputs at t_k into the trace, step every block in order
(reference, sensor, observer, controller), then hold the controller's torque over
[t_k, t_k + h] and step the plant. The master knows blocks only through reset/step.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from .blocks import Block
from .fmu import Fmu, FmuError
from .trace import Trace


class Diverged(RuntimeError):
    """The run cannot go on: a block produced a non-finite value (or the plant failed, below).
    ``where`` and ``t`` (s) say where and when."""

    def __init__(self, where: str, t: float, detail: str = ""):
        self.where, self.t = where, t
        super().__init__(self.describe(where, t, detail))

    @staticmethod
    def describe(where: str, t: float, detail: str) -> str:
        extra = f": {detail}" if detail else ""
        return f"the run diverged in {where} at t = {t:.6g} s{extra}"


class PlantFailed(Diverged):
    """The plant FMU returned an error status from a step; ``detail`` names the FMI call."""

    def __init__(self, t: float, detail: str):
        super().__init__("the plant FMU", t, detail)

    @staticmethod
    def describe(where: str, t: float, detail: str) -> str:
        return f"{where} stopped the run at t = {t:.6g} s: {detail}"


def simulate(plant: Fmu, blocks: Sequence[Block], trace: Trace,
             progress: Callable[[int], None] | None = None, progress_every: int = 1000) -> float:
    """Run the closed loop over all rows of ``trace``. Returns the wall time in seconds of
    steps 1..N (step 0 is left out: it is where the blocks' JIT kernels get compiled, and its
    progress call may wait for a recording writer to start).

    On divergence raises :class:`Diverged`; ``trace.rows_done`` then counts the rows that
    were completed, which stay valid for logging.
    """
    plant.start(0.0)
    for block in blocks:
        block.reset(trace)
    q, qdot, mass, tau = trace["q"], trace["qdot"], trace["M"], trace["tau"]
    h, steps = trace.dt, trace.steps
    start = time.perf_counter()
    for k in range(steps + 1):
        t = k * h
        q[k] = plant.q
        qdot[k] = plant.qdot
        mass[k] = plant.M
        for block in blocks:
            if not block.step(k):
                trace.rows_done = k
                raise Diverged(f"the {block.name} block", t, "a non-finite value")
        trace.rows_done = k + 1
        if k == steps:
            break
        plant.tau[:] = tau[k]
        try:
            plant.step(t, h)
        except FmuError as exc:
            raise PlantFailed(t, str(exc)) from None
        if progress is not None and k % progress_every == 0:
            progress(k)
        if k == 0:
            start = time.perf_counter()
    return time.perf_counter() - start
