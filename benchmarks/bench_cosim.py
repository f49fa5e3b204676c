"""Closed-loop cost against the FMU alone, and what writing the recording costs, in one
process.

1. The paper's two runs (baseline + proposed, 20 s at 1 kHz) through ``cosim.run`` into a
   run folder, without and with ``recording.rrd``: the loops' wall time (what the master
   measures, chunks evaluated and handed to the recording writer included) and the whole
   call (start-up, evaluation, summary and the writer's final flush included), and the
   file's size.
2. The full closed loop of the paper's proposed run (observer + NN controller + FMU), in
   the fused compiled engine and in the Python engine, against an FMU-only loop through the
   Python adapter (the same FMU, constant torque, same step count) — the ratio the issue
   asks for — and against the physical floor: the same FMU-only loop in one compiled call
   (FMI functions through their C pointers, no Python per step).

3. With ``--profile``: where the fused closed loop's time goes, in µs per step: each block
   of the proposed chain alone (its kernel in a compiled loop over the rows of the run just
   simulated, fed the same inputs, so it does the run's own work), the floor, and the rest
   (the fused loop's calls, cache misses between kernels). The inertia model's nominal chain
   is timed too, though the paper's run takes M̂ from the FMU.

Each figure is the best of ``--repeat`` repetitions, interleaved so that a slow spell of the
machine hits every variant. The last line is

    closed_loop_us_per_step=X fmu_only_us_per_step=Y ratio=X/Y

Run: .venv/bin/python benchmarks/bench_cosim.py [--duration 20] [--repeat 5] [--no-recording]
     [--profile]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from numba import njit

from cosim.assemble import assemble_run
from cosim.blocks import Ports
from cosim.config import load_pipeline
from cosim.engine import simulate
from cosim.engine.fused import fused_loop
from cosim.paper.inertia import InertiaModel, InertiaModelParams
from cosim.plant.ports import OUTPUT_PORTS
from cosim.plant_source import open_plant
from cosim.runner import run

PIPELINE = Path(__file__).resolve().parent.parent / "pipelines" / "paper_two_link.toml"


def closed_loop(plant, duration: float, engine: str) -> float:
    pipeline = load_pipeline(PIPELINE, [f"simulation.duration={duration}"])
    steps = int(round(duration / pipeline.simulation.step))
    plan = assemble_run(pipeline, "proposed", plant)
    wall = simulate(plant, plan, plan.new_trace(steps), engine=engine)
    return wall / steps


def fmu_only(plant, duration: float, h: float = 1e-3) -> float:
    steps = int(round(duration / h))
    plant.start(0.0)
    plant.tau[:] = 1.0
    start = time.perf_counter()
    for k in range(steps):
        plant.step(k * h, h)
    return (time.perf_counter() - start) / steps


def fmu_only_compiled(plant, duration: float, h: float = 1e-3,
                      tau: np.ndarray | None = None) -> float:
    """The floor: the fused loop with no blocks, the FMU's set/doStep/get per step, driven
    by ``tau`` (steps + 1, n; N·m), or 1 N·m at every joint."""
    steps = int(round(duration / h))
    n = plant.links
    tau = np.ones((steps + 1, n)) if tau is None else np.ascontiguousarray(tau[:steps + 1])
    rows = tuple(np.zeros((steps + 1,) + plant.values[port.name].shape) for port in OUTPUT_PORTS)
    plant.start(0.0)
    io = plant.fused_io()
    loop = fused_loop((), io.fmi_version)
    start = time.perf_counter()
    loop(0, steps + 1, steps, h, io.functions, io.handles, tau, rows, ())
    return (time.perf_counter() - start) / steps


@njit
def _drive(kernel, start: int, stop: int, args) -> int:
    """One kernel over rows [start, stop), compiled: what it costs inside the fused loop
    (numba specialises this per kernel; a kernel as an argument cannot be cached)."""
    for k in range(start, stop):
        if not kernel(k, args):
            return k
    return stop


def block_ports(trace, ins: dict, outs: dict, constants: dict) -> Ports:
    """A block's ports on ``trace``, as the plan's reset builds them."""
    return Ports({port: trace[key] for port, key in ins.items()},
                 {port: trace[key] for port, key in outs.items()}, trace, constants)


def kernel_seconds(block, steps: int) -> float:
    """Seconds for the block's kernel alone over rows [0, steps), compiled outside the
    timing; the block reset just before."""
    _drive(block.kernel, 0, 0, block.args)
    start = time.perf_counter()
    done = _drive(block.kernel, 0, steps, block.args)
    assert done == steps, f"{block.kind} failed at row {done}"
    return time.perf_counter() - start


def profile(plant, duration: float, repeat: int) -> dict[str, tuple[float, float]]:
    """µs per step of each block of the proposed run: its reset (once per run, spread over
    the steps) and its kernel alone (see the module docstring); and of the fused loop and
    the floor over the same steps (as (0, µs))."""
    pipeline = load_pipeline(PIPELINE, [f"simulation.duration={duration}"])
    steps = int(round(duration / pipeline.simulation.step))
    plan = assemble_run(pipeline, "proposed", plant)
    trace = plan.new_trace(steps)
    # The nominal inertia model on the same measured positions, into an array of its own.
    nominal = InertiaModel(InertiaModelParams(source="nominal"), plan.blocks[0].context)
    trace.arrays["M_model (nominal)"] = np.empty_like(trace["M"])
    blocks = {b.kind: b for b in plan.blocks} | {"inertia_model (nominal)": nominal}
    wiring = [*zip(plan.inputs, plan.outputs, plan.constants, strict=True),
              ({"q_meas": "q_meas"}, {"M_model": "M_model (nominal)"}, {})]

    def reset(block, ins: dict, outs: dict, constants: dict) -> float:
        # the ports as the plan's reset builds them, after the blocks before this one (the
        # inertia model's reset puts the plant's M in the trace as M_model)
        ports = block_ports(trace, ins, outs, constants)
        start = time.perf_counter()
        block.reset(ports)
        return 1e6 * (time.perf_counter() - start) / steps

    # resets of fresh blocks (the reference keeps its safe-set centres once computed)
    us = {name: [reset(block, *ports), float("inf")]
          for (name, block), ports in zip(blocks.items(), wiring, strict=True)}
    us["fused"], us["floor"] = [0.0, float("inf")], [0.0, float("inf")]
    for _ in range(repeat):
        us["fused"][1] = min(us["fused"][1],
                             1e6 * simulate(plant, plan, trace, engine="fused") / steps)
        us["floor"][1] = min(us["floor"][1], 1e6 * fmu_only_compiled(plant, duration))
        # in chain order: each block reads what the one before it rewrote, as in the run
        for (name, block), ports in zip(blocks.items(), wiring, strict=True):
            reset(block, *ports)
            if block.kernel is None:
                us[name][1] = 0.0
                continue
            us[name][1] = min(us[name][1], 1e6 * kernel_seconds(block, steps + 1) / (steps + 1))
    return {name: (value[0], value[1]) for name, value in us.items()}


def print_profile(us: dict[str, tuple[float, float]], duration: float, repeat: int) -> None:
    blocks = [name for name in us if name not in ("fused", "floor", "inertia_model (nominal)")]
    total = sum(us[name][1] for name in blocks)
    print(f"profile of the proposed run, {int(duration * 1000)} steps, best of {repeat}, "
          "us/step (reset: once per run, over the steps; kernel: in the loop):")
    for name in [*blocks, "inertia_model (nominal)"]:
        reset, kernel = us[name]
        print(f"  {name:<24} kernel {kernel:6.2f}   reset {reset:6.2f}")
    print("  (inertia_model nominal: not in the paper's chain, whose M̂ is the FMU's M)")
    print(f"  {'blocks':<24} kernel {total:6.2f}")
    print(f"  {'floor':<24}        {us['floor'][1]:6.2f}   (FMU set/doStep/get, the plant's "
          "output rows)")
    print(f"  {'rest':<24}        {us['fused'][1] - us['floor'][1] - total:6.2f}   "
          "(fused - floor - blocks: the loop, cache misses between kernels)")
    print(f"  {'fused closed loop':<24}        {us['fused'][1]:6.2f}")


def paper_run(record: bool, out: Path) -> tuple[float, float, float]:
    """(sum of the runs' loop wall times, wall time of the whole call, time the loops spent
    handing rows to the recording writer), in seconds."""
    start = time.perf_counter()
    results = run(load_pipeline(PIPELINE), out, progress=False, record=record, figures=False,
                  force=True)
    total = time.perf_counter() - start
    return (sum(r.metrics["wall_time_s"] for r in results.values()), total,
            sum(r.metrics.get("recording_handoff_s", 0.0) for r in results.values()))


def recording_cost(repeat: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        paper_run(False, out)  # JIT compile and FMU build outside the timing
        plain, recorded = [], []
        for _ in range(repeat):  # interleaved, so a slow spell of the machine hits both
            plain.append(paper_run(False, out))
            recorded.append(paper_run(True, out))
        size = (out / "recording.rrd").stat().st_size
    loop_off, loop_on = min(p[0] for p in plain), min(r[0] for r in recorded)
    call_off, call_on = min(p[1] for p in plain), min(r[1] for r in recorded)
    print(f"paper pipeline, 2 runs x 20 s at 1 kHz, best of {repeat}:")
    print(f"  loops without recording {loop_off:.3f} s, with {loop_on:.3f} s: "
          f"recording_overhead_loop={100 * (loop_on / loop_off - 1):.1f} %")
    print(f"  whole call without recording {call_off:.3f} s, with {call_on:.3f} s: "
          f"recording_overhead_call={100 * (call_on / call_off - 1):.1f} %")
    handoff = min(r[2] for r in recorded)
    print(f"  the loops' own share (handing rows over): {1e3 * handoff:.1f} ms = "
          f"{100 * handoff / loop_off:.1f} % of the loops")
    print(f"  recording.rrd {size / 1e6:.1f} MB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds")
    parser.add_argument("--repeat", type=int, default=5, help="repetitions (best is kept)")
    parser.add_argument("--no-recording", action="store_true",
                        help="skip the recording on/off comparison")
    parser.add_argument("--profile", action="store_true",
                        help="also print µs per step of each block of the fused loop")
    args = parser.parse_args()
    if not args.no_recording:
        recording_cost(args.repeat)
    plant = open_plant(load_pipeline(PIPELINE))
    variants = {"fused": lambda d: closed_loop(plant, d, "fused"),
                "python": lambda d: closed_loop(plant, d, "python"),
                "fmu_only": lambda d: fmu_only(plant, d),
                "fmu_only_compiled": lambda d: fmu_only_compiled(plant, d)}
    try:
        for measure in variants.values():  # JIT compile and load outside the timing
            measure(0.01)
        best = {name: float("inf") for name in variants}
        for _ in range(args.repeat):
            for name, measure in variants.items():
                best[name] = min(best[name], measure(args.duration))
        if args.profile:
            print_profile(profile(plant, args.duration, args.repeat), args.duration,
                          args.repeat)
    finally:
        plant.close()
    us = {name: 1e6 * value for name, value in best.items()}
    print(f"steps: {int(args.duration * 1000)} at 1 kHz, best of {args.repeat}, interleaved")
    print(f"  closed loop, python engine   {us['python']:7.2f} us/step")
    print(f"  closed loop, fused engine    {us['fused']:7.2f} us/step")
    print(f"  FMU alone, Python adapter    {us['fmu_only']:7.2f} us/step")
    print(f"  FMU alone, one compiled call {us['fmu_only_compiled']:7.2f} us/step  (the floor: "
          "the FMU's own set/doStep/get)")
    print(f"  fused closed loop / floor = {us['fused'] / us['fmu_only_compiled']:.2f}; "
          f"python engine / python FMU-only = {us['python'] / us['fmu_only']:.2f}")
    print(f"closed_loop_us_per_step={us['fused']:.2f} fmu_only_us_per_step={us['fmu_only']:.2f} "
          f"ratio={us['fused'] / us['fmu_only']:.2f}")


if __name__ == "__main__":
    main()
