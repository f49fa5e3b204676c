"""The fixed-step co-simulation master.

Each step k: copy the plant's outputs at t_k into the trace, step every block in chain order,
then hold the torque over [t_k, t_k + h] and step the plant. The master knows blocks only
through ``reset``/``step`` (and, for the fused loop, their numba ``kernel``).

Two engines give the same rows bit for bit: the fused loop (:mod:`.fused`: blocks and FMU
calls in one compiled function per second of simulated time), used whenever every block has
a kernel and the plant exposes its FMI functions, and the plain Python loop otherwise.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from numba import typeof, types

from .. import interrupts
from ..blocks import Block
from ..blocks.plugins import describe_exception
from ..numba_compat import compiled_entry_point
from ..plant.mapping import FmuError
from ..plant.ports import OUTPUT_PORTS
from ..schema import PipelineError
from ..signals import Trace
from .fused import fused_loop

ENGINES = ("auto", "fused", "python")


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


class Stopped(Diverged):
    """A Python block's step returned False (or nothing): the block stopped the run."""

    @staticmethod
    def describe(where: str, t: float, detail: str) -> str:
        return f"{where} stopped the run at t = {t:.6g} s: {detail}"


class PlantFailed(Diverged):
    """The plant FMU returned an error status from a step; ``detail`` names the FMI call."""

    def __init__(self, t: float, detail: str):
        super().__init__("the plant FMU", t, detail)

    @staticmethod
    def describe(where: str, t: float, detail: str) -> str:
        return f"{where} stopped the run at t = {t:.6g} s: {detail}"


class BlockFailed(Diverged):
    """A block's own code raised (a user's block with a bug): the exception and the line of
    the block's code it came from, as a run that cannot go on, so the rows done are kept."""

    def __init__(self, where: str, t: float, exc: BaseException):
        super().__init__(where, t, describe_exception(exc))

    @staticmethod
    def describe(where: str, t: float, detail: str) -> str:
        return f"{where} raised at t = {t:.6g} s: {detail}"


def _fusable(block) -> bool:
    # A block with a kernel, or one whose step does nothing (the reference, a plant-M model).
    return block.kernel is not None or type(block).step is Block.step


def simulate(plant, plan, trace: Trace, progress: Callable[[int], None] | None = None,
             progress_every: int = 1000, engine: str = "auto") -> float:
    """Run the closed loop of ``plan`` (an assembled run) over all rows of ``trace``.
    ``progress(k)`` is called every ``progress_every`` steps with the rows done so far.
    Returns the wall time in seconds of steps 1..N (step 0 is left out: it is where the
    blocks' JIT kernels get loaded, and its progress call may wait for a recording writer to
    start).

    On divergence raises :class:`Diverged`; ``trace.rows_done`` then counts the rows that
    were completed, which stay valid for logging.
    """
    if engine not in ENGINES:
        raise ValueError(f"engine {engine!r}: one of {ENGINES}")
    plant.start(0.0)
    if hasattr(plant, "bind_trace"):  # a plant that records its own signals (a system's)
        plant.bind_trace(trace)
    try:
        plan.reset(trace)
    except (PipelineError, FmuError):
        raise  # a block's own refusal (e.g. the filter's moving centre): already one message
    except (Exception, SystemExit) as exc:  # a user's block: anything, sys.exit() too
        trace.rows_done = 0
        raise BlockFailed("a block's reset", 0.0, exc) from exc
    fused = engine == "fused" or (engine == "auto" and all(_fusable(b) for b in plan.blocks)
                                  and hasattr(plant, "fused_io"))
    run = _fused if fused else _python
    return run(plant, plan, trace, progress, progress_every)


def _stepper(block) -> Callable[[int], bool]:
    """A kernel block's compiled overload, called directly (numba's type dispatch on a
    NamedTuple of arrays costs more than the kernel itself); else ``block.step``. A block's
    kernel, when it has one, is its step."""
    if block.kernel is None:
        return block.step
    entry = compiled_entry_point(block.kernel, (types.int64, typeof(block.args)))
    args = block.args
    return lambda k: entry(k, args)


def _python(plant, plan, trace: Trace, progress, progress_every: int) -> float:
    blocks = [(block, _stepper(block)) for block in plan.blocks]
    rows = [(trace[port.name], plant.values[port.name]) for port in OUTPUT_PORTS
            if port.name in trace]
    tau = trace[plan.plant_input]
    h, steps = trace.dt, trace.steps
    start = time.perf_counter()
    for k in range(steps + 1):
        t = k * h
        for row, value in rows:
            row[k] = value
        for block, step in blocks:
            try:
                finite = step(k)
            except (Exception, SystemExit) as exc:  # a user's block: anything, sys.exit()
                trace.rows_done = k
                raise BlockFailed(f"the {block.name} block", t, exc) from exc
            if not finite:
                trace.rows_done = k
                if block.kernel is not None:
                    raise Diverged(f"the {block.name} block", t, "a non-finite value")
                raise Stopped(f"the {block.name} block", t,
                              f"its step returned {finite!r} (a block's step returns True "
                              "to go on; False, or nothing, stops the run)")
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


def _fused(plant, plan, trace: Trace, progress, progress_every: int) -> float:
    stepping = [b for b in plan.blocks if b.kernel is not None]
    io = plant.fused_io()
    loop = fused_loop(tuple(b.kernel for b in stepping), io.fmi_version)
    args = tuple(b.args for b in stepping)
    # A port the trace does not hold is one the plant does not map: the loop never writes
    # it, but its typed slot needs an array of the port's shape.
    arrays = (trace[plan.plant_input],
              tuple(trace[port.name] if port.name in trace
                    else np.empty((0,) + plant.values[port.name].shape)
                    for port in OUTPUT_PORTS))
    h, steps = trace.dt, trace.steps
    # Row 0 alone first: its progress call may wait for the recording writer, and the
    # kernels load on first use; neither belongs in the timing.
    k, start, failed, status = 0, time.perf_counter(), -1, 0
    while k <= steps:
        stop = 1 if k == 0 else min(steps + 1, k + progress_every)
        signals = interrupts.heard()
        try:
            k, failed, status = loop(k, stop, steps, h, io.functions, io.handles, *arrays, args)
        except Exception as exc:  # a kernel raised (numba's linalg on non-finite input)
            # ... unless a stop signal's exception was replaced by this one on its way out
            if (why := interrupts.heard_since(signals)) is not None:
                raise KeyboardInterrupt(why) from None
            raise BlockFailed(f"a block of the compiled loop (rows {k} to {stop - 1})", k * h,
                              exc) from exc
        trace.rows_done = k
        if failed != -1:
            break
        if progress is not None and k <= steps and (k - 1) % progress_every == 0:
            progress(k - 1)
        if k == 1:
            start = time.perf_counter()
    wall = time.perf_counter() - start
    if failed >= 0:
        raise Diverged(f"the {stepping[failed].name} block", k * h, "a non-finite value")
    if failed < -1:  # the plant step after row k - 1: that row is complete
        t = (k - 1) * h
        raise PlantFailed(t, plant.describe_failure(-failed - 2, status, t))
    return wall
