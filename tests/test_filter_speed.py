"""The filter made fast stays the filter: its allocation-free chain model (the inertia
model's kernels) is the closed form's, and at every step of the safety pipeline's filtered
runs the torque it chose (warm-started, compiled, in the fused loop) is the answer of that
step's QP, checked against an independent least-squares solution of the penalty form and
against DAQP."""

from __future__ import annotations

import sys
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from cosim.assemble import assemble
from cosim.config import load_pipeline
from cosim.dynamics.model import planar_model
from cosim.dynamics.planar import CHAIN_ROWS
from cosim.engine import simulate
from cosim.paper import cbf_filter as cf
from cosim.paper.cbf_filter.check import verified
from cosim.paper.cbf_filter.interval import checked, predict_interval
from cosim.paper.cbf_filter.scratch import Flag, Rollout
from cosim.paper.inertia import (
    chain_bias,
    chain_geometry,
    chain_mass,
    planar_bias,
    planar_mass_matrix,
)

SAFETY = "pipelines/paper_safety.toml"
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
from deceleration import filter_args as filter_args_of  # noqa: E402


def closed_form_chain(q, v, m, lengths, lc, inertia, gravity):
    """M(q) and b(q, v) = C v + G of the planar chain in NumPy, from their closed forms:
    M_ij = Σ_{k ≥ max(i, j)} [m_k (p_k − o_i)·(p_k − o_j) + I_k], and with q̈ = 0 (no
    angular acceleration) b_i = Σ_{k ≥ i} ẑ·((p_k − o_i) × m_k (p̈_k + g ŷ)), p̈_k the centre
    of mass's acceleration, −Σ_{j<k} θ̇_j² l_j u_j − θ̇_k² lc_k u_k (u_j along link j)."""
    theta, omega = np.cumsum(q), np.cumsum(v)
    u = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    origins = np.vstack([np.zeros(2), np.cumsum(lengths[:, None] * u, axis=0)[:-1]])
    centres = origins + lc[:, None] * u
    n = len(q)
    mass = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            k = np.arange(max(i, j), n)
            mass[i, j] = np.sum(m[k] * np.einsum("kd,kd->k", centres[k] - origins[i],
                                                 centres[k] - origins[j]) + inertia[k])
    swept = omega[:, None] ** 2 * lengths[:, None] * u
    accelerations = np.array([-swept[:k].sum(axis=0) - omega[k] ** 2 * lc[k] * u[k]
                              for k in range(n)]) + np.array([0.0, gravity])
    forces = m[:, None] * accelerations
    arms = [centres[i:] - origins[i] for i in range(n)]
    bias = np.array([np.sum(arm[:, 0] * forces[i:, 1] - arm[:, 1] * forces[i:, 0])
                     for i, arm in enumerate(arms)])
    return mass, bias


@pytest.mark.parametrize("links", [2, 3])
def test_the_chain_model_is_one_kernel_and_its_closed_form(links):
    """M, b = C v + G of the nominal chain as the filter and the nominal inertia model
    compute them (the chain kernels writing into a scratch) are the allocating wrappers'
    (inertia.planar_mass_matrix, planar_bias) bit for bit, and the closed forms evaluated in
    NumPy to 1e-12; Γ (b's velocity part, by polarisation) gives b's velocity part."""
    rng = np.random.default_rng(links)
    m, lengths = rng.uniform(0.5, 3, links), rng.uniform(0.5, 1.5, links)
    lc, inertia = rng.uniform(0.2, 1, links), rng.uniform(0, 0.1, links)
    chain = np.zeros((CHAIN_ROWS, links))
    for _ in range(50):
        q, v = rng.uniform(-3, 3, links), rng.uniform(-15, 15, links)
        mass, bias = np.zeros((links, links)), np.zeros(links)
        chain_geometry(q, lengths, lc, chain)
        chain_mass(chain, m, inertia, mass)
        chain_bias(chain, v, m, 9.8, bias)
        wrapped_mass, wrapped_bias = np.zeros((links, links)), np.zeros(links)
        planar_mass_matrix(q, m, lengths, lc, inertia, wrapped_mass)
        planar_bias(q, v, m, lengths, lc, inertia, 9.8, wrapped_bias)
        assert np.array_equal(mass, wrapped_mass) and np.array_equal(bias, wrapped_bias)
        expected_mass, expected_bias = closed_form_chain(q, v, m, lengths, lc, inertia, 9.8)
        np.testing.assert_allclose(mass, expected_mass, rtol=1e-12,
                                   atol=1e-12 * np.abs(expected_mass).max())
        np.testing.assert_allclose(bias, expected_bias, rtol=1e-12,
                                   atol=1e-12 * np.abs(expected_bias).max())
        forms = cf.velocity_forms(planar_model(m, lengths, lc, inertia, 9.8), q)
        no_gravity = np.zeros(links)
        planar_bias(q, v, m, lengths, lc, inertia, 0.0, no_gravity)
        np.testing.assert_allclose(np.einsum("ijk,j,k->i", forms, v, v), no_gravity,
                                   rtol=1e-12, atol=1e-9)


def exact_piece_minimiser(tau_nominal: np.ndarray, G: np.ndarray, h: np.ndarray,
                          weights: np.ndarray) -> np.ndarray:
    """argmin ½‖τ − τ_nom‖² + ½Σ_j ρ_j (g_j τ − h_j)² over the rows given, in exact
    rational arithmetic on the float data: (I + Σ ρ_j g_jᵀ g_j) τ = τ_nom + Σ ρ_j g_j h_j
    by Gaussian elimination (no rounding, so no conditioning to lose digits to)."""
    n = len(tau_nominal)
    exact = [[Fraction(float(x)) for x in row] for row in G]
    rho, limit = [Fraction(float(x)) for x in weights], [Fraction(float(x)) for x in h]
    matrix = [[Fraction(int(i == j)) for j in range(n)] for i in range(n)]
    rhs = [Fraction(float(x)) for x in tau_nominal]
    for g, r, b in zip(exact, rho, limit, strict=True):
        for i in range(n):
            rhs[i] += r * g[i] * b
            for j in range(n):
                matrix[i][j] += r * g[i] * g[j]
    for c in range(n):  # positive definite: no pivoting needed
        for r in range(c + 1, n):
            factor = matrix[r][c] / matrix[c][c]
            for j in range(c, n):
                matrix[r][j] -= factor * matrix[c][j]
            rhs[r] -= factor * rhs[c]
    out = [Fraction(0)] * n
    for c in range(n - 1, -1, -1):
        out[c] = (rhs[c] - sum(matrix[c][j] * out[j] for j in range(c + 1, n))) / matrix[c][c]
    return np.array([float(x) for x in out])


def filtered_run(name: str):
    """One filtered run of the safety pipeline, 25 s (q_s is the reference's midpoint over
    its 20 s safe horizon; 5 s more than the paper's run, as the observer's certified ε(t)
    lets the filter act at fewer steps: 871 of 20 s on proposed_cbf), in the fused loop:
    its trace and the filter's arguments."""
    pipeline = load_pipeline(SAFETY, ["simulation.duration=25"])
    pipeline.runs = {name: pipeline.runs[name]}
    scenario = assemble(pipeline)
    try:
        plan = scenario.runs[name]
        trace = plan.new_trace(scenario.steps)
        simulate(scenario.plant, plan, trace, engine="fused")
    finally:
        scenario.close()
    return trace, plan.block("cbf_filter").args


def test_the_fused_and_the_python_engine_filter_bit_for_bit():
    """The filter's step carries state from one step to the next (the rows that bound, where
    the solver starts), reset with the run: both engines give the same rows, bit for bit,
    on both filtered runs, the second time as the first. (3.5 s: the proposed run's filter
    first acts at 2.9 s, with the observer's certified ε(t).)"""
    pipeline = load_pipeline(SAFETY, ["simulation.duration=3.5"])
    pipeline.runs = {name: pipeline.runs[name] for name in ("proposed_cbf", "baseline_cbf")}
    scenario = assemble(pipeline)
    try:
        for plan in scenario.runs.values():
            traces = []
            for engine in ("fused", "python", "fused"):
                traces.append(plan.new_trace(scenario.steps))
                simulate(scenario.plant, plan, traces[-1], engine=engine)
            assert (traces[0]["cbf_active"] > 0).any()
            for trace in traces[1:]:
                for name in traces[0].arrays:
                    np.testing.assert_array_equal(trace[name], traces[0][name], err_msg=name)
    finally:
        scenario.close()


@pytest.mark.parametrize("name", ["proposed_cbf", "baseline_cbf"])
def test_every_filtered_torque_is_its_steps_qp_answer(name):
    """At every step (the rows rebuilt from the run's own state): the torque in the trace is
    the minimiser of the penalty form ½‖τ − τ_nom‖² + ½Σρ_j(g_jτ − h_j)₊², solved here
    apart in exact arithmetic on the rows it violates, to 1e-12 of 1 + ‖τ_nom‖∞ (measured
    3e-13; a normal-equation solve would be off by up to 3e-5), and
    DAQP's answer of the QP (hard rows as constraints, soft ones with slack) to 1e-6
    (measured 1e-9 on proposed_cbf, 8e-8 on baseline_cbf: the penalty form lets a hard row
    slip by its multiplier over ρ_hard)."""
    qpsolvers = pytest.importorskip("qpsolvers")
    if "daqp" not in qpsolvers.available_solvers:
        pytest.skip("daqp is not installed")
    trace, a = filtered_run(name)
    assert not trace["cbf_infeasible"].any()  # so the trace's torque is the QP's own
    worst_penalty = worst_daqp = 0.0
    binding_steps = 0
    for k in range(len(trace.time) - 1):
        count = cf.cbf_rows(k, a)  # the run's state: a.tau[k - 1] is the torque it held
        G, given = a.rows[:count], a.limits[:count]
        hard = a.is_hard[:count] > 0
        h = np.where(hard, given - a.hard_tolerance, given)
        tau, tau_nominal = trace["tau"][k], a.tau_nominal[k]
        scale = 1.0 + np.abs(tau_nominal).max()
        rows = G @ tau > h
        if rows.any():
            binding_steps += 1
            reference = exact_piece_minimiser(tau_nominal, G[rows], h[rows],
                                              a.weights[:count][rows])
            assert np.array_equal(G @ reference > h, rows), k  # the same piece
        else:
            reference = tau_nominal
        worst_penalty = max(worst_penalty, np.abs(tau - reference).max() / scale)
        if rows.any() or k % 50 == 0:
            n, m = G.shape[1], int((~hard).sum())
            P = np.diag(np.concatenate([np.ones(n), a.weights[:count][~hard]]))
            q = np.concatenate([-tau_nominal, np.zeros(m)])
            G_full = np.block([[G[hard], np.zeros((int(hard.sum()), m))],
                               [G[~hard], -np.eye(m)], [np.zeros((m, n)), -np.eye(m)]])
            x = qpsolvers.solve_qp(P, q, G_full,
                                   np.concatenate([h[hard], h[~hard], np.zeros(m)]),
                                   solver="daqp")
            worst_daqp = max(worst_daqp, np.abs(tau - x[:n]).max() / scale)
    assert binding_steps > 1000  # the filter acts at many steps
    assert worst_penalty < 1e-12, worst_penalty
    assert worst_daqp < 1e-6, worst_daqp


def test_the_interval_takes_the_checks_hull_only_where_it_checked_that_torque():
    """The velocity's interval for the next step takes the hull of q̈ the check's candidate
    step took where that step was the torque applied, from row k's state; it is then, bit
    for bit, the interval taken afresh. Where the last check was of another torque (a
    blend's candidate that failed), from another velocity interval or of another row, it is
    taken afresh (mutant cbf-checked-torque-ignored). The filter of near_boundary.toml (a
    payload of 0-1 kg, so D has every part), rows 0 and 1, the velocity 1 and −0.5 rad/s
    ± 0.1."""
    a = filter_args_of("pipelines/near_boundary.toml", 1000.0)
    r = a.work.rollout
    rows = [Rollout.NEXT_LOW, Rollout.NEXT_HIGH, Rollout.ACC_LOW, Rollout.ACC_HIGH]

    def interval(tau, half=0.1, centre=(1.0, -0.5), after=None, k=0):
        """The interval predicted at row k for τ from the velocity centre ± half, after a
        check at row 0 of ``after`` from 1, −0.5 ± 0.1 rad/s if given."""
        a.work.flags[Flag.CHECKED_ROW] = 0.0
        r[Rollout.CENTRE], r[Rollout.HALF] = [1.0, -0.5], 0.1
        if after is not None:
            verified(0, a, a.position[0], r[Rollout.CENTRE], r[Rollout.HALF], after, True, 0,
                     a.torque_limit)
        r[Rollout.CENTRE], r[Rollout.HALF] = centre, half
        predict_interval(k, a, tau)
        return r[rows].copy()

    applied, other = np.array([20.0, -5.0]), np.array([-10.0, 8.0])
    afresh = interval(applied)
    assert np.all(np.isfinite(afresh)) and np.all(afresh[1] > afresh[0])
    assert np.array_equal(interval(applied, after=applied), afresh)
    assert checked(0, a, applied)  # the check's hull was taken
    assert np.array_equal(interval(other, after=applied), interval(other))
    assert np.array_equal(interval(applied, 0.2, after=applied), interval(applied, 0.2))
    assert not np.array_equal(interval(applied, 0.2), afresh)
    assert np.array_equal(interval(applied, centre=(1.2, -0.5), after=applied),
                          interval(applied, centre=(1.2, -0.5)))
    assert not np.array_equal(a.position[1], a.position[0])
    assert np.array_equal(interval(applied, after=applied, k=1), interval(applied, k=1))


def test_the_small_eigen_decomposition_is_numpys():
    """The payload structure's K = VΛVᵀ (cosim.paper.linalg.small_symmetric_eigen: 2×2 in
    closed form, 3×3 by Jacobi rotations): eigenvalues equal numpy's eigvalsh, V orthonormal
    and VΛVᵀ = K, each to 1e-14 of K's scale, on random symmetric matrices and the hard
    cases (diagonal, a multiple of I, nearly repeated, rank-deficient, indefinite, 0)."""
    from cosim.paper.linalg import small_symmetric_eigen

    rng = np.random.default_rng(11)
    for d in (2, 3):
        q = np.linalg.qr(rng.normal(size=(d, d)))[0]
        cases = [(lambda a: a + a.T)(rng.normal(size=(d, d)) * 10.0 ** rng.uniform(-6, 6))
                 for _ in range(300)]
        cases += [np.diag(np.arange(1.0, d + 1)), np.eye(d), np.zeros((d, d))]
        cases += [q @ np.diag(values[:d]) @ q.T for values in
                  ([1.0, 1.0 + 1e-12, 1.0], [0.0, 1e-8, 5.0], [2.0, -1.0, 2.0])]
        lam, vec, work = np.zeros(d), np.zeros((d, d)), np.zeros((d, d))
        for matrix in cases:
            small_symmetric_eigen(matrix, lam, vec, work)
            scale = max(np.abs(matrix).max(), 1e-300)
            np.testing.assert_allclose(lam, np.linalg.eigvalsh(matrix), rtol=0,
                                       atol=1e-14 * scale)
            np.testing.assert_allclose(vec.T @ vec, np.eye(d), rtol=0, atol=1e-14)
            np.testing.assert_allclose(vec @ np.diag(lam) @ vec.T, matrix, rtol=0,
                                       atol=1e-14 * scale)
