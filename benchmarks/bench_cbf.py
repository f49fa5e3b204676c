"""What the CBF-QP safety filter costs: the filter's QP at the steps of the paper's
proposed_cbf run where it acts, solved by the compiled semismooth Newton (the default) and
by qpsolvers' backends; and the closed loop with and without the filter.

    .venv/bin/python benchmarks/bench_cbf.py

Prints µs per QP for each solver (best of 3 passes over the same problems, interleaved), the
largest difference of each from the compiled solution (relative to ‖τ_nom‖), and the fused
closed loop's µs per step with and without the filter.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from cosim.assemble import assemble
from cosim.blocks.cbf_filter import cbf_rows, solve_soft_qp
from cosim.config import load_pipeline
from cosim.engine import simulate

PIPELINE = Path(__file__).resolve().parent.parent / "pipelines" / "paper_safety.toml"


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


def main() -> None:
    import qpsolvers

    pipeline = load_pipeline(PIPELINE)
    pipeline.runs = {n: pipeline.runs[n] for n in ("proposed", "proposed_cbf")}
    scenario = assemble(pipeline)
    loops = {}
    try:
        for name, plan in scenario.runs.items():
            best = float("inf")
            for _ in range(3):
                trace = plan.new_trace(scenario.steps)
                best = min(best, simulate(scenario.plant, plan, trace) / scenario.steps)
            loops[name] = best
        plan = scenario.runs["proposed_cbf"]
        trace = plan.new_trace(scenario.steps)
        simulate(scenario.plant, plan, trace)
    finally:
        scenario.close()
    cases = problems(plan, trace)
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

    import warnings

    warnings.simplefilter("ignore")
    reference = [solve("newton", *case) for case in cases]
    cost = {s: float("inf") for s in solvers}
    error = {}
    for _ in range(3):
        for solver in solvers:
            began = time.perf_counter()
            results = [solve(solver, *case) for case in cases]
            cost[solver] = min(cost[solver], (time.perf_counter() - began) / len(cases))
            error[solver] = max(np.abs(r - ref).max() / (1 + np.abs(c[0]).max())
                                for r, ref, c in zip(results, reference, cases, strict=True))
    binding = sum(bool((c[1] @ r > c[2]).any()) for c, r in zip(cases, reference, strict=True))
    print(f"{len(cases)} QPs of the paper's proposed_cbf run ({binding} with a binding row), "
          f"{cases[0][1].shape[0]} rows, 2 torques; best of 3:")
    for solver in solvers:
        print(f"  {solver:<9} {1e6 * cost[solver]:9.1f} us per QP   max |Δτ|/(1+|τ_nom|) "
              f"vs newton {error[solver]:.1e}")
    print(f"closed loop (fused): proposed {1e6 * loops['proposed']:.1f} us/step, "
          f"proposed_cbf {1e6 * loops['proposed_cbf']:.1f} us/step "
          f"(the filter: {1e6 * (loops['proposed_cbf'] - loops['proposed']):.1f} us/step)")


if __name__ == "__main__":
    main()
