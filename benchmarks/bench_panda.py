"""The Panda's closed loop against its own FMU floor, and the blocks' nominal model against
Pinocchio (issue 32), in one process:

1. pipelines/panda.toml's runs ``proposed`` (observer + NN controller) and ``proposed_cbf``
   (+ the safety filter) in the fused compiled engine, µs per step, against the floor: the
   same spatial-chain FMU alone in one compiled call (benchmarks/bench_cosim.py's
   ``fmu_only_compiled``), and their ratio;
2. M̂ + b̂ of the Panda's nominal model (cosim.dynamics: CRBA + RNEA in numba), called from
   compiled code as the blocks call it, against Pinocchio's crba + rnea through its Python
   bindings (what the blocks could call instead, from Python only), µs per call.

With ``--parts``, also the filter's step on proposed_cbf in parts, each in one compiled
loop over the run's rows (benchmarks/bench_cbf.py's ``parts``): the rows it builds (the
model at the state and at the hold's end, the hard rows' groups, the soft rows), the
record (the backup's check of the torque, the next velocity interval, the outputs) and
the QP's solve (compiling those loops for the 7-joint chain takes a minute or two).

With ``--blocks``, also each block of proposed_cbf alone: its kernel driven over the run's
rows after its reset, reading what the blocks before it wrote (bench_cosim.py --profile's
way for the paper's run), µs per step.

Each figure is the best of ``--repeat`` repetitions.

Run: .venv/bin/python benchmarks/bench_panda.py [--duration 3] [--repeat 3] [--parts]
[--blocks]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from bench_cosim import block_ports, fmu_only_compiled, kernel_seconds
from numba import njit

from cosim.assemble import assemble_run
from cosim.config import load_pipeline
from cosim.dynamics.model import chain_model, model_bias, model_geometry, model_mass
from cosim.engine import simulate
from cosim.plant_source import open_plant

PIPELINE = Path(__file__).resolve().parent.parent / "pipelines" / "panda.toml"


@njit
def _model_loop(model, q, v, mass, bias, reps):
    for r in range(reps):
        q[0] = 1e-3 * r  # a new position each call
        model_geometry(model, q)
        model_mass(model, 1.0, 0.0, mass)
        model_bias(model, v, 1.0, 0.0, 1.0, bias)


def nominal_model_cost(repeat: int) -> tuple[float, float]:
    """(µs per M̂ + b̂ in our compiled kernels, µs per crba + rnea through Pinocchio)."""
    import pinocchio as pin

    from plant_fmu.urdf import read_urdf, resolve_uri

    path = resolve_uri("package://example-robot-data/robots/panda_description/urdf/panda.urdf",
                       Path.cwd())
    chain = read_urdf(path, tip="panda_hand")
    model = chain_model(chain)
    reference = pin.buildModelFromUrdf(str(path))
    locked = [reference.getJointId(name) for name in reference.names[1:]
              if name not in chain.joints]
    reference = pin.buildReducedModel(reference, locked, pin.neutral(reference))
    data = reference.createData()
    n = chain.n
    rng = np.random.default_rng(0)
    q, v = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    mass, bias = np.zeros((n, n)), np.zeros(n)
    reps = 20000
    _model_loop(model, q, v, mass, bias, 10)
    ours = theirs = np.inf
    zeros = np.zeros(n)
    for _ in range(repeat):
        start = time.perf_counter()
        _model_loop(model, q, v, mass, bias, reps)
        ours = min(ours, (time.perf_counter() - start) / reps)
        start = time.perf_counter()
        for _ in range(reps):
            pin.crba(reference, data, q)
            pin.rnea(reference, data, q, v, zeros)
        theirs = min(theirs, (time.perf_counter() - start) / reps)
    return 1e6 * ours, 1e6 * theirs


def block_costs(plan, trace, steps: int, repeat: int) -> dict[str, float]:
    """µs per step of each block's kernel alone over the run in ``trace`` (in chain order:
    each reset reads what the blocks before it wrote; 0 for a block with no kernel)."""
    us = {}
    for block, ins, outs, constants in zip(plan.blocks, plan.inputs, plan.outputs,
                                           plan.constants, strict=True):
        best = np.inf
        for _ in range(repeat):
            block.reset(block_ports(trace, ins, outs, constants))
            if block.kernel is None:
                best = 0.0
                break
            best = min(best, kernel_seconds(block, steps))
        us[block.kind] = 1e6 * best / steps
    return us


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=3.0, help="simulated seconds")
    parser.add_argument("--repeat", type=int, default=3, help="repetitions (best is kept)")
    parser.add_argument("--parts", action="store_true",
                        help="also time the filter's step in parts (rows, record, solve)")
    parser.add_argument("--blocks", action="store_true",
                        help="also time each block of proposed_cbf alone over its run")
    args = parser.parse_args()
    pipeline = load_pipeline(PIPELINE, [f"simulation.duration={args.duration}"])
    steps = int(round(args.duration / pipeline.simulation.step))
    plant = open_plant(pipeline)
    try:
        us, torques = {}, {}
        for run in ("proposed", "proposed_cbf"):
            plan = assemble_run(pipeline, run, plant)
            best = np.inf
            for _ in range(args.repeat):
                trace = plan.new_trace(steps)
                best = min(best, simulate(plant, plan, trace, engine="fused"))
            us[run] = 1e6 * best / steps
            torques[run] = trace["tau"].copy()
            filtered, filtered_trace = plan, trace  # proposed_cbf's, last
        # The FMU alone along the filtered run's own trajectory (its torques replayed): the
        # same RK4 sub-steps as in the closed loop (a constant torque would let the arm fall
        # through its limits, where the FMU's sub-steps shorten: rk4_motion).
        floor = min(1e6 * fmu_only_compiled(plant, args.duration, tau=torques["proposed_cbf"])
                    for _ in range(args.repeat))
        blocks = block_costs(filtered, filtered_trace, steps, args.repeat) if args.blocks \
            else {}
    finally:
        plant.close()
    if args.parts:
        from bench_cbf import parts

        cost = parts(filtered.block("cbf_filter").args, steps, args.repeat)
    ours, theirs = nominal_model_cost(args.repeat)
    print(f"Panda, {args.duration:g} s at 1 kHz, fused engine (best of {args.repeat}):")
    for run, value in us.items():
        print(f"  {run:<14} {value:8.2f} us/step   {value / floor:6.2f} x the floor")
    print(f"  {'floor':<14} {floor:8.2f} us/step   (the FMU alone, one compiled call, "
          "proposed_cbf's torques)")
    if args.parts:
        print(f"  the filter's step in compiled loops: rows {cost['rows']:.2f}, record "
              f"{cost['record']:.2f} (the backup's check, the next interval, the outputs), "
              f"solve {cost['solve']:.2f}; the whole step {cost['step']:.2f} us")
    if blocks:
        print("  proposed_cbf's blocks alone, us/step: " + ", ".join(
            f"{name} {value:.2f}" for name, value in blocks.items()))
    print(f"nominal model M + b (7 joints): {ours:.2f} us compiled (cosim.dynamics), "
          f"{theirs:.2f} us Pinocchio crba + rnea through Python")
    print(f"panda_closed_loop_us_per_step={us['proposed_cbf']:.2f} floor_us_per_step="
          f"{floor:.2f} ratio={us['proposed_cbf'] / floor:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
