"""What the CBF-QP safety filter costs, on the paper's proposed_cbf run
(pipelines/paper_safety.toml):

1. the fused closed loop with and without the filter against the floor, the FMU alone in
   one compiled call (bench_cosim.fmu_only_compiled): the target is the filtered loop
   within 2.5× of the floor;
2. the filter's parts per step, each in one compiled loop over every row of the finished
   run (no Python between steps): building the rows, the rows and the recording of the
   outputs — the recording is the difference — (the step's own parts, called as the step
   calls them) and the whole step as the fused loop calls it (``cbf_step``) — the QP
   solve is what it adds to those two (with that one call);
3. the QP alone at the steps where the filter acts, solved by the compiled semismooth Newton
   (called from Python) and by qpsolvers' backends: µs per QP and the largest difference of
   each from the compiled solution (relative to ‖τ_nom‖).

    .venv/bin/python benchmarks/bench_cbf.py [--repeat 5]

Every figure is the best of ``--repeat`` repetitions, interleaved so that a slow spell of the
machine hits every variant. The last line is

    filtered_us_per_step=X floor_us_per_step=Y ratio=X/Y
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
from bench_cosim import fmu_only_compiled
from numba import njit

from cosim.assemble import assemble
from cosim.config import load_pipeline
from cosim.engine import simulate
from cosim.numba_compat import no_refcount_jit
from cosim.paper.cbf_filter import cbf_rows, cbf_step, solve_soft_qp
from cosim.paper.cbf_filter.rows import step_rows
from cosim.paper.cbf_filter.step import step_record

PIPELINE = Path(__file__).resolve().parent.parent / "pipelines" / "paper_safety.toml"


# Compiled as the step is (without reference counting), its parts called as cbf_step calls
# them.


@no_refcount_jit()
def rows_only(a, steps: int) -> float:
    """The rows at every row; returns a sum of the counts so that none is optimised away."""
    total = 0.0
    for k in range(steps + 1):
        total += step_rows(k, a, False)
    return total


@no_refcount_jit()
def rows_and_record(a, steps: int) -> float:
    """The rows, then the record of the torque the run chose (the QP's own answer: the
    outputs are rewritten as they were)."""
    total = 0.0
    for k in range(steps + 1):
        count = step_rows(k, a, False)
        total += step_record(k, a, count, a.tau[k])
    return total


@njit
def whole_step(a, steps: int) -> float:
    total = 0.0
    for k in range(steps + 1):
        total += cbf_step(k, a)
    return total


def parts(a, steps: int, repeat: int) -> dict[str, float]:
    """µs per step of rows, record and solve (best of ``repeat``, interleaved)."""
    loops = {"rows": rows_only, "rows+record": rows_and_record, "step": whole_step}
    for loop in loops.values():  # compile outside the timing
        loop(a, 1)
    best = dict.fromkeys(loops, float("inf"))
    for _ in range(repeat):
        for name, loop in loops.items():
            began = time.perf_counter()
            loop(a, steps)
            best[name] = min(best[name], (time.perf_counter() - began) / (steps + 1))
    us = {name: 1e6 * value for name, value in best.items()}
    return {"rows": us["rows"], "record": us["rows+record"] - us["rows"],
            "solve": us["step"] - us["rows+record"], "step": us["step"]}


def problems(plan, trace) -> list[tuple]:
    a = plan.block("cbf_filter").args
    acting = np.flatnonzero(trace["cbf_active"] > 0)
    out = []
    for k in sorted({*range(0, len(trace.time), 100), *acting[:: max(1, len(acting) // 400)]}):
        count = cbf_rows(k, a)
        limits = a.limits[:count].copy()
        hard = a.is_hard[:count] > 0
        limits[hard] -= a.hard_tolerance
        out.append((a.tau_nominal[k].copy(), a.rows[:count].copy(), limits,
                    a.weights[:count].copy(), hard))
    return out


def solvers_compared(cases: list[tuple], repeat: int) -> None:
    import qpsolvers

    solvers = ["newton", *[s for s in ("daqp", "clarabel", "osqp", "proxqp", "quadprog")
                           if s in qpsolvers.available_solvers]]

    def solve(solver, tau_nominal, G, h, weights, hard):
        """Hard rows as constraints, soft rows with an explicit slack."""
        if solver == "newton":
            return solve_soft_qp(tau_nominal, G, h, weights, 50, 1e-12)[0]
        n, m, k = G.shape[1], int((~hard).sum()), int(hard.sum())
        P = np.diag(np.concatenate([np.ones(n), weights[~hard]]))
        q = np.concatenate([-tau_nominal, np.zeros(m)])
        G_full = np.block([[G[hard], np.zeros((k, m))], [G[~hard], -np.eye(m)],
                           [np.zeros((m, n)), -np.eye(m)]])
        kwargs = {"eps_abs": 1e-9, "eps_rel": 1e-9} if solver == "osqp" else {}
        x = qpsolvers.solve_qp(P, q, G_full, np.concatenate([h[hard], h[~hard], np.zeros(m)]),
                               solver=solver, **kwargs)
        return np.full(n, np.nan) if x is None else x[:n]

    warnings.simplefilter("ignore")
    reference = [solve("newton", *case) for case in cases]
    cost = dict.fromkeys(solvers, float("inf"))
    error = {}
    for _ in range(repeat):
        for solver in solvers:
            began = time.perf_counter()
            results = [solve(solver, *case) for case in cases]
            cost[solver] = min(cost[solver], (time.perf_counter() - began) / len(cases))
            error[solver] = max(np.abs(r - ref).max() / (1 + np.abs(c[0]).max())
                                for r, ref, c in zip(results, reference, cases, strict=True))
    binding = sum(bool((c[1] @ r > c[2]).any()) for c, r in zip(cases, reference, strict=True))
    print(f"{len(cases)} QPs of the run ({binding} with a binding row), "
          f"{cases[0][1].shape[0]} rows, 2 torques, called from Python:")
    for solver in solvers:
        print(f"  {solver:<9} {1e6 * cost[solver]:9.1f} us per QP   max |Δτ|/(1+|τ_nom|) "
              f"vs newton {error[solver]:.1e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="repetitions (best is kept)")
    args = parser.parse_args()
    pipeline = load_pipeline(PIPELINE)
    pipeline.runs = {n: pipeline.runs[n] for n in ("proposed", "proposed_cbf")}
    scenario = assemble(pipeline)
    steps = scenario.steps
    duration = steps * pipeline.simulation.step
    try:
        fmu_only_compiled(scenario.plant, 0.01)  # JIT compile and load outside the timing
        for plan in scenario.runs.values():
            simulate(scenario.plant, plan, plan.new_trace(10))
        loops = dict.fromkeys([*scenario.runs, "floor"], float("inf"))
        for _ in range(args.repeat):
            for name, plan in scenario.runs.items():
                trace = plan.new_trace(steps)
                loops[name] = min(loops[name], simulate(scenario.plant, plan, trace) / steps)
            loops["floor"] = min(loops["floor"], fmu_only_compiled(scenario.plant, duration))
        plan = scenario.runs["proposed_cbf"]
        trace = plan.new_trace(steps)
        simulate(scenario.plant, plan, trace)
    finally:
        scenario.close()
    a = plan.block("cbf_filter").args
    us = {name: 1e6 * value for name, value in loops.items()}
    acting = float(np.mean(trace["cbf_active"] > 0))
    print(f"paper_safety, {steps} steps at 1 kHz, best of {args.repeat}, interleaved:")
    print(f"  FMU alone, one compiled call   {us['floor']:7.2f} us/step  (the floor)")
    print(f"  proposed, fused                {us['proposed']:7.2f} us/step  "
          f"({us['proposed'] / us['floor']:.2f}x the floor)")
    print(f"  proposed_cbf, fused            {us['proposed_cbf']:7.2f} us/step  "
          f"({us['proposed_cbf'] / us['floor']:.2f}x the floor; the filter "
          f"{us['proposed_cbf'] - us['proposed']:.2f} us/step)")
    cost = parts(a, steps, args.repeat)
    print(f"the filter's parts on proposed_cbf ({a.rows.shape[0]} rows allocated, a constraint "
          f"binds at {100 * acting:.1f} % of the steps), compiled loops, us/step:")
    print(f"  rows {cost['rows']:.2f}, solve {cost['solve']:.2f}, record {cost['record']:.2f}; "
          f"the whole step {cost['step']:.2f}")
    solvers_compared(problems(plan, trace), args.repeat)
    print(f"filtered_us_per_step={us['proposed_cbf']:.2f} floor_us_per_step={us['floor']:.2f} "
          f"ratio={us['proposed_cbf'] / us['floor']:.2f}")


if __name__ == "__main__":
    main()
