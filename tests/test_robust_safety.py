"""Safety under declared uncertainty: the robust filter's rows against an independent model
of the plant, its margins against brute force, the observer's error bound and drift, the
classification of runs, the safe set's centre, infeasibility, and the Monte Carlo's figures
on a small sample. Real FMU; the independent model is the paper's closed-form two-link arm
(Lewis), written in tests/test_references.py apart from the code under test."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from cli_helpers import cosim_cli
from test_references import two_link_closed_form

from cosim.assemble import assemble
from cosim.config import load_pipeline
from cosim.engine import simulate
from cosim.paper.cbf_filter import acceleration_error_bound, velocity_forms
from cosim.paper.observer import error_envelope
from cosim.runner import run

MC = "pipelines/monte_carlo.toml"
A1 = A2 = 1.0
M1, M2, GRAVITY = 0.8, 2.3, 9.8


def closed_form(q, qdot, m2):
    """The paper's arm (Lewis): M(q) and Vm(q, q̇)q̇ + G(q), point masses at the tips."""
    return two_link_closed_form(q, qdot, A1, A2, M1, m2, GRAVITY)


def worst_condition(qddot, x, qdot, v, p, k_v, alpha_q, alpha_v) -> float:
    """The least of both hard sets' continuous-time conditions, both sides, per joint:
    position ḧ + 2p ḣ + p² h and velocity ḣ + k·max(h, 0) (past the bound, within the hold's
    margin, "do not move further out": docs/safety/filter.md, "How the margins follow");
    x = q − q_s, v = q̇ − q̇_s."""
    worst = np.inf
    for side in (1.0, -1.0):
        velocity = -side * qddot + k_v * np.maximum(alpha_v - side * v, 0.0)
        position = -side * qddot - 2 * p * side * qdot + p * p * (alpha_q - side * x)
        worst = min(worst, velocity.min(), position.min())
    return worst


def simulated(sets: list[str], name: str, duration: float = 3.0):
    """One run of the Monte Carlo pipeline, with its assembled plan (the blocks' arguments)."""
    pipeline = load_pipeline(MC, [f"simulation.duration={duration}", *sets])
    pipeline.runs = {name: pipeline.runs[name]}
    scenario = assemble(pipeline)
    try:
        plan = scenario.runs[name]
        trace = plan.new_trace(scenario.steps)
        simulate(scenario.plant, plan, trace)
    finally:
        scenario.close()
    return pipeline, plan, trace


def test_the_hard_rows_hold_for_every_payload_in_the_declared_range():
    """baseline_cbf (true state, no estimate) under a 0.6 kg payload, 0-1 kg declared: at
    every step where a hard constraint acts, the torque the filter chose keeps the
    continuous-time conditions of both hard sets for every payload on a fine grid of the
    range, with the true acceleration from the closed-form arm (not the filter's model).
    (The filter's true state is exact here: baseline_cbf reads the plant's q̇, ε = 0.)"""
    # No sensor noise: M̂ is evaluated at the measured position, a first-order effect of the
    # noise the filter does not cover (docs/safety/filter.md); measured −0.003 rad/s² here at
    # 1e-4 rad.
    pipeline, plan, trace = simulated(['plant.parameters."m[2]"=2.9', "sensor.noise_std=0",
                                       'plant.parameters."qdot0[1]"=13.3'], "baseline_cbf")
    f = pipeline.runs["baseline_cbf"].cbf_filter
    p, k_v = f.position_rate, f.velocity_rate
    alpha_q = pipeline.safety.position_bound * (1 - f.bound_margin)
    alpha_v = pipeline.safety.velocity_bound * (1 - f.bound_margin)
    acting = np.flatnonzero((trace["cbf_position_active"] + trace["cbf_velocity_active"])
                            .sum(axis=1) > 0)
    assert len(acting) > 100  # the check covers the steps where the hard rows bind
    worst = np.inf
    for k in acting:
        q, qdot, tau = trace["q"][k], trace["qdot"][k], trace["tau"][k]
        x, v = q - trace["q_s"][k], qdot - trace["qdot_s"][k]
        for payload in np.linspace(0.0, 1.0, 41):
            mass, bias = closed_form(q, qdot, M2 + payload)
            qddot = np.linalg.solve(mass, tau - bias - 0.01)
            worst = min(worst, worst_condition(qddot, x, qdot, v, p, k_v, alpha_q, alpha_v))
    assert worst > -1e-6, worst


def test_the_hard_rows_hold_for_every_state_the_estimate_allows():
    """proposed_cbf (output feedback) under noise, a 5 rad/s initial velocity error and a
    0.6 kg payload, all declared: at every feasible step where a hard row acts, the torque
    keeps both hard sets' continuous-time conditions for every true state the filter cannot
    rule out — position y ± n̄, velocity x̂2 ± ε(t) per joint (the corners), payload on a
    grid of the range — with the closed-form arm's acceleration. M and b are taken at y, the
    one approximation docs/safety/filter.md declares (first order in n̄); h and ḣ at the corner."""
    pipeline, plan, trace = simulated(['plant.parameters."m[2]"=2.9',
                                       'plant.parameters."qdot0[1]"=13.0',
                                       'plant.parameters."qdot0[2]"=6.0'], "proposed_cbf", 4.0)
    f = pipeline.runs["proposed_cbf"].cbf_filter
    noise = pipeline.uncertainty.noise_bound
    p, k_v = f.position_rate, f.velocity_rate
    alpha_q = pipeline.safety.position_bound * (1 - f.bound_margin)
    alpha_v = pipeline.safety.velocity_bound * (1 - f.bound_margin)
    # The steps whose applied torque met the hard rows as given (before the filter checked
    # its torques against a braking backup, cbf_infeasible == 0 said so; now cbf_rows_met).
    acting = np.flatnonzero(((trace["cbf_position_active"] + trace["cbf_velocity_active"])
                             .sum(axis=1) > 0) & (trace["cbf_rows_met"] == 1))
    assert len(acting) > 100 and np.any(trace["cbf_position_active"][acting, 0] > 0)
    signs = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], float)
    worst = np.inf
    for k in acting:
        y, v, eps, tau = (trace["q_meas"][k], trace["qdot_hat"][k], trace["qdot_hat_bound"][k],
                          trace["tau"][k])
        for payload in np.linspace(0.0, 1.0, 11):
            for dq in signs * noise:
                for dv in signs * eps:
                    qdot = v + dv
                    mass, bias = closed_form(y, qdot, M2 + payload)
                    qddot = np.linalg.solve(mass, tau - bias - 0.01)
                    worst = min(worst, worst_condition(
                        qddot, y + dq - trace["q_s"][k], qdot, qdot - trace["qdot_s"][k], p,
                        k_v, alpha_q, alpha_v))
    assert worst > -1e-6, worst


def test_the_hard_rows_the_solve_leaves_out_are_met_with_the_tolerance_to_spare():
    """The step solves over the soft rows and the torque limits and adds the hard rows it
    needs (cutting planes: cosim.paper.cbf_filter.rows.add_cuts), so its answer is the whole
    QP's only if every hard row left out is met with hard_tolerance to spare. At three steps
    of a run, for torques that put a random payload corner's row (the whole QP's, from
    cbf_rows, scaled to unit norm as the QP has it) past its limit, within the tolerance of
    it, or just beyond that, plus a random part along the row's null space: every row
    add_cuts leaves out has g·τ − h ≤ −hard_tolerance, and a row within the tolerance or
    past its limit is added."""
    from cosim.paper.cbf_filter.groups import add_cuts
    from cosim.paper.cbf_filter.rows import cbf_rows
    from cosim.paper.cbf_filter.scratch import Flag, GroupLabel

    _, plan, _ = simulated([], "proposed_cbf", duration=0.05)
    a = plan.block("cbf_filter").args
    work, tol = a.work, a.hard_tolerance
    rng = np.random.default_rng(5)
    counts = {"past": 0, "within": 0, "beyond": 0}
    for k in (0, 25, 49):
        full = cbf_rows(k, a)  # the groups' rows first, in their order
        groups = int(work.flags[Flag.GROUPS])
        corners = work.group_labels[:groups, GroupLabel.CORNERS]
        rows = int(corners.sum())
        assert rows > 100 and np.all(a.is_hard[:rows] == 1) and np.all(a.kinds[:rows] >= 0)
        G, h = a.rows[:rows].copy(), a.limits[:rows].copy()
        assert full > rows  # the soft rows and the torque limits after them
        for _ in range(60):
            j = int(rng.integers(rows))
            kind = str(rng.choice(list(counts)))
            depth = {"past": -rng.uniform(0.0, 3.0), "within": rng.uniform(0.05, 0.95),
                     "beyond": rng.uniform(1.05, 3.0)}[kind] * tol
            spread = rng.normal(size=G.shape[1]) * 10.0
            tau = (h[j] - depth) * G[j] + spread - (spread @ G[j]) * G[j]
            work.group_added[:] = False  # none among the QP's rows yet: add_cuts writes
            add_cuts(a, 0, tau)  # its rows over G's (copied above), reads only the groups
            added = np.concatenate([work.group_added[g, :corners[g]] for g in range(groups)])
            excess = G @ tau - h
            assert np.all(excess[~added] <= -tol + 1e-9), (k, kind, excess[~added].max())
            if kind != "beyond":
                assert added[j], (k, kind, depth)
            counts[kind] += 1
    assert min(counts.values()) > 30, counts


def test_each_hard_constraint_is_sound_at_arbitrary_states_with_wide_margins():
    """Away from any trajectory, where every margin is large and so each one matters: at
    random states inside the sets (non-zero centres), a velocity uncertainty ε up to 2 rad/s
    per joint and a noise bound n̄ widened to 0.02 rad, the torque that pushes each hard
    constraint (set, joint, side: its payload corners together) as far out as they allow —
    a linear programme — keeps that set's continuous-time condition, on that side, for every
    true state the filter cannot rule out (position y ± n̄, velocity x̂2 ± ε, corners; payload
    on a grid of the declared range), with the closed-form arm's acceleration. Dropping any
    one margin (n̄, ε in either set, the bias error) lets some such torque through."""
    from scipy.optimize import linprog

    from cosim.paper.cbf_filter import cbf_rows

    pipeline, plan, _ = simulated([], "proposed_cbf", duration=0.01)
    f = pipeline.runs["proposed_cbf"].cbf_filter
    p, k_v = f.position_rate, f.velocity_rate
    alpha_q = pipeline.safety.position_bound * (1 - f.bound_margin)
    alpha_v = pipeline.safety.velocity_bound * (1 - f.bound_margin)
    noise = 0.02
    a = plan.block("cbf_filter").args._replace(noise_bound=noise)
    low, high = pipeline.uncertainty.payload
    corners = 3 * a.payload_grid + 1  # rows per (set, joint, side): the payload's boxes
    signs = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], float)
    rng = np.random.default_rng(11)
    centre_q, centre_v = np.array([0.4, -0.3]), np.array([1.5, -2.0])
    worst, tightest = np.inf, np.inf
    for _ in range(60):
        eps = rng.uniform(0.2, 2.0, 2)
        y = centre_q + rng.uniform(-0.9, 0.9, 2) * (alpha_q - noise)
        v = centre_v + rng.uniform(-0.9, 0.9, 2) * (alpha_v - eps)
        a.position[0], a.velocity[0], a.velocity_bound[0] = y, v, eps
        a.centres[0], a.centres[1] = centre_q, centre_v
        a.M_model[0] = closed_form(y, v, M2)[0]  # M̂: the nominal arm at y
        cbf_rows(0, a)
        minv = np.linalg.inv(a.M_model[0])
        for group in range(8):  # (set, joint, side) in the filter's order
            s, i, side = group // 4, group // 2 % 2, 1.0 - 2.0 * (group % 2)
            rows = slice(group * corners, (group + 1) * corners)
            assert np.all(a.is_hard[rows] == 1) and np.all(a.kinds[rows] == s)
            assert np.all(a.joints[rows] == i)
            # the most outward torque the constraint allows: max side·(M̂⁻¹τ)_i
            lp = linprog(-side * minv[i], A_ub=a.rows[rows], b_ub=a.limits[rows],
                         bounds=[(-1e5, 1e5)] * 2, method="highs")
            assert lp.status == 0, lp.message
            tau = lp.x
            for payload in np.linspace(low, high, 11):
                for dv in signs * eps:
                    qdot = v + dv
                    mass, bias = closed_form(y, qdot, M2 + payload)
                    qddot = np.linalg.solve(mass, tau - bias - 0.01)[i]  # the paper's τ_d, N·m
                    if s == 0:
                        for dq in (noise, -noise):
                            x = y[i] + dq - centre_q[i]
                            condition = (-side * qddot - 2 * p * side * qdot[i]
                                         + p * p * (alpha_q - side * x))
                            worst = min(worst, condition)
                            tightest = min(tightest, abs(condition))
                    else:
                        condition = -side * qddot + k_v * max(
                            alpha_v - side * (qdot[i] - centre_v[i]), 0.0)
                        worst = min(worst, condition)
                        tightest = min(tightest, abs(condition))
    assert worst > -1e-6, worst
    assert tightest < 1.0  # not vacuous: some true state sits on the condition's edge


def polygon_vertices(rows: np.ndarray, limits: np.ndarray, box: float) -> np.ndarray:
    """The vertices of {τ ∈ R²: rows·τ ≤ limits, |τ_j| ≤ box}: every pair of edges
    intersected, the points that satisfy every constraint kept."""
    edges = np.vstack([rows, np.eye(2), -np.eye(2)])
    bounds = np.concatenate([limits, np.full(4, box)])
    out = []
    for i in range(len(edges)):
        for j in range(i + 1, len(edges)):
            pair = edges[[i, j]]
            if abs(np.linalg.det(pair)) < 1e-12:
                continue
            tau = np.linalg.solve(pair, bounds[[i, j]])
            if np.all(edges @ tau <= bounds + 1e-9 * (1 + np.abs(bounds))):
                out.append(tau)
    return np.array(out)


def test_the_payload_rows_hold_between_their_corners():
    """The payload's worst case as the filter builds it (the corners of boxes over the curve
    s(Δm)), without noise or velocity error so that nothing else gives margin: at random
    states, every vertex of the torque polygon a hard constraint allows (set, joint, side)
    keeps its condition for every payload on a fine grid of the declared range (101 values,
    most between the filter's grid points), with the closed-form arm's acceleration. The
    polygon's vertices are where the constraint is tightest, so this checks all of it."""
    from cosim.paper.cbf_filter import cbf_rows

    pipeline, plan, _ = simulated(["sensor.noise_std=0"], "proposed_cbf", duration=0.01)
    f = pipeline.runs["proposed_cbf"].cbf_filter
    p, k_v = f.position_rate, f.velocity_rate
    alpha_q = pipeline.safety.position_bound * (1 - f.bound_margin)
    alpha_v = pipeline.safety.velocity_bound * (1 - f.bound_margin)
    a = plan.block("cbf_filter").args._replace(noise_bound=0.0)
    low, high = pipeline.uncertainty.payload
    corners = 3 * a.payload_grid + 1
    rng = np.random.default_rng(5)
    centre_q, centre_v = np.array([-0.2, 0.5]), np.array([0.5, 1.0])
    worst, vertices = np.inf, 0
    for _ in range(25):
        y = centre_q + rng.uniform(-0.9, 0.9, 2) * alpha_q
        y[1] = rng.choice([rng.uniform(-0.3, 0.3), rng.uniform(-3, 3)])  # stretched, or not
        v = centre_v + rng.uniform(-0.9, 0.9, 2) * alpha_v
        a.position[0], a.velocity[0], a.velocity_bound[0] = y, v, 0.0
        a.centres[0], a.centres[1] = centre_q, centre_v
        a.M_model[0] = closed_form(y, v, M2)[0]
        cbf_rows(0, a)
        models = [closed_form(y, v, M2 + payload) for payload in np.linspace(low, high, 101)]
        for group in range(8):
            s, i, side = group // 4, group // 2 % 2, 1.0 - 2.0 * (group % 2)
            rows = slice(group * corners, (group + 1) * corners)
            for tau in polygon_vertices(a.rows[rows], a.limits[rows], 2e4):
                vertices += 1
                for mass, bias in models:
                    qddot = np.linalg.solve(mass, tau - bias - 0.01)[i]
                    if s == 0:
                        condition = (-side * qddot - 2 * p * side * v[i]
                                     + p * p * (alpha_q - side * (y[i] - centre_q[i])))
                    else:
                        condition = -side * qddot + k_v * max(
                            alpha_v - side * (v[i] - centre_v[i]), 0.0)
                    worst = min(worst, condition / (1.0 + abs(qddot)))
    assert vertices > 8 * 25 * 3
    assert worst > -1e-9, worst


def test_the_bias_error_bound_holds_against_brute_force():
    """|M̂⁻¹(b(q, v + δ) − b(q, v))| ≤ the filter's bound for every |δ_j| ≤ ε_j and payload in
    the declared range, b from the closed form: at random states, corners and random δ."""
    _, plan, _ = simulated([], "proposed_cbf", duration=0.01)
    a = plan.block("cbf_filter").args
    rng = np.random.default_rng(4)
    tightest = np.inf
    for _ in range(300):
        q = rng.uniform(-3, 3, 2)
        v = rng.uniform(-15, 15, 2)
        eps = rng.uniform(0, 3, 2)
        mass, _ = closed_form(q, v, M2)
        minv = np.linalg.inv(mass)
        bound = acceleration_error_bound(q, v, eps, minv, a,
                                         velocity_forms(a.model, q))
        signs = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]])
        deltas = np.vstack([signs * eps, rng.uniform(-1, 1, (20, 2)) * eps])
        for payload in (0.0, 1.0):
            _, base = closed_form(q, v, M2 + payload)
            for delta in deltas:
                _, moved = closed_form(q, v + delta, M2 + payload)
                error = np.abs(minv @ (moved - base))
                assert np.all(error <= bound * (1 + 1e-9) + 1e-9), (q, v, eps, delta)
                tightest = min(tightest, float(np.min(bound - error)))
    assert tightest < 0.05 * 1e3  # not vacuous: some δ comes close to the bound


def test_the_error_envelope_matches_a_numerical_impulse_response():
    """The L1 norm of 1/(s² + (kp + kD)s + k0)'s impulse response, coth(σπ/2ω)/k0 in closed
    form, against scipy's impulse response integrated numerically (and the overdamped
    case against 1/k0); the free response's peak factor against a simulation."""
    from scipy import integrate, signal

    for k0 in (5e3, 2e4, 9e4, 4e5):
        decay, peak, l1 = error_envelope(100.0, 100.0, k0)
        t = np.linspace(0, 0.5, 400_001)
        _, h = signal.impulse(([1.0], [1.0, 200.0, k0]), T=t)
        assert l1 == pytest.approx(integrate.trapezoid(np.abs(h), t), rel=1e-3), k0
        # w' = −k0 x − 200 w, x' = w from w(0) = 1: |w(t)| ≤ peak·e^{−decay t}
        system = signal.StateSpace([[0, 1], [-k0, -200.0]], [[0], [0]], [[0, 1]], [[0]])
        _, w, _ = signal.lsim(system, np.zeros_like(t[:20001]), t[:20001], X0=[0.0, 1.0])
        assert np.all(np.abs(w) <= peak * np.exp(-decay * t[:20001]) + 1e-9), k0



def test_the_modelled_derivative_of_the_velocity_estimate_matches_its_finite_difference():
    """What the filter's rows on x̂2 take for dx̂2/dt, the published drift + M̂⁻¹τ plus the
    kp(ẏ − x̂2) term the filter bounds by kp·ε, against x̂2's finite difference in the trace,
    from q̇1(0) = 14 with x̂2(0) = 10 (measured: x̂2 moves at ~3000 rad/s² there, the
    plant at ~−800). At a 10 µs step the observer's stiff output injection (k0 ~ 1e5 1/s²)
    is resolved, so the continuous law must agree to within discretisation; the plant's own
    q̈ (a model that ignores the injection) must not."""
    _, plan, trace = simulated(["simulation.step=1e-5", "sensor.noise_std=0",
                                    'plant.parameters."qdot0[1]"=14'], "proposed", 0.05)
    kp = plan.block("observer").params.kp
    dt = trace.time[1] - trace.time[0]
    estimate = trace["qdot_hat"]
    finite_difference = np.diff(estimate, axis=0) / dt
    measured_rate = np.diff(trace["q_meas"], axis=0) / dt
    modelled = (trace["qdot_hat_drift"] + np.linalg.solve(
        trace["M_model"], trace["tau"][..., None])[..., 0])[:-1] + kp * (
        measured_rate - estimate[:-1])
    scale = np.abs(finite_difference).max()
    assert scale > 2000.0  # the output injection acts: the estimate races to the plant
    assert np.abs(finite_difference - modelled).max() < 0.01 * scale
    plant = np.diff(trace["qdot"], axis=0) / dt
    assert np.abs(finite_difference - plant).max() > 0.5 * scale

def test_the_safe_set_centre_is_the_pipelines_not_the_horizons():
    """q_s is the midpoint of the reference over the declared 20 s, whatever the duration:
    a 5 s run is judged against the same sets as the 20 s run, and says so."""
    results = {}
    for duration in (5.0, 20.0):
        pipeline = load_pipeline("pipelines/paper_two_link.toml",
                                 [f"simulation.duration={duration}"])
        pipeline.runs = {"proposed": pipeline.runs["proposed"]}
        results[duration] = run(pipeline, None, progress=False)["proposed"]
    short, full = results[5.0], results[20.0]
    np.testing.assert_array_equal(short.trace["q_s"][0], full.trace["q_s"][0])
    assert np.abs(full.trace["q_s"][0]).max() < 1e-6  # the paper's sinusoids: centre 0
    described = short.summary()["blocks"]["reference"]
    assert described["q_s_source"] == "midpoint of the reference over 0–20 s"
    assert short.safety["position_joint1"]["reference_worst"] < 20.0  # not yet at the peak
    assert full.safety["position_joint1"]["reference_worst"] == pytest.approx(20.0, abs=1e-6)


def test_the_filter_refuses_a_moving_centre():
    from cosim.config import PipelineError

    pipeline = load_pipeline(MC, ["simulation.duration=0.1", 'reference.safe_case="tracking"'])
    pipeline.runs = {"proposed_cbf": pipeline.runs["proposed_cbf"]}
    with pytest.raises(PipelineError, match="constant safe-set centres, but q_s moves"):
        run(pipeline, None, progress=False)


def test_a_run_starting_outside_a_set_is_classified_as_such():
    pipeline = load_pipeline(MC, ["simulation.duration=0.5", 'plant.parameters."qdot0[1]"=14'])
    pipeline.runs = {"proposed_cbf": pipeline.runs["proposed_cbf"]}
    guarantee = run(pipeline, None, progress=False)["proposed_cbf"].metrics["guarantee"]
    assert guarantee["starts_inside"] is False
    assert guarantee["broken"] is False  # whatever happens next: not the filter's failure


def test_an_infeasible_hard_part_raises_the_flag_and_the_backup_brakes():
    """A 3 kg payload (1 kg declared) and a 60 N·m torque limit: the hard sets cannot be
    kept; the steps are flagged, the backup (braking within the limit) acts there, and the
    run is classified outside the declared uncertainty, never as a broken guarantee. The
    backup is recomputed apart: the q̈ nearest k_b (0 − (v − q̇_s)) that the limits allow
    (a QP solved by DAQP), τ = M̂ q̈ + b̂ (M̂, b̂ of the nominal arm carrying the middle of
    the declared payload range), at the velocity the filter held (its interval's centre).
    (Before the filter verified its torques against the backup, this test set backup =
    "brake", q̈ = −20 (v − q̇_s) clipped per joint, since removed.)"""
    qpsolvers = pytest.importorskip("qpsolvers")
    if "daqp" not in qpsolvers.available_solvers:
        pytest.skip("daqp is not installed")
    from cosim.paper.inertia import planar_bias, planar_mass_matrix

    sets = ['plant.parameters."m[2]"=5.3', "runs.proposed_cbf.cbf_filter.torque_limit=60.0"]
    _, plan, trace = simulated(sets, "proposed_cbf", duration=1.0)
    flagged = np.flatnonzero(trace["cbf_infeasible"] > 0)
    assert len(flagged) > 0
    a = plan.block("cbf_filter").args
    # the model the backup acts on carries the middle of the declared payload range, 0.5 kg
    # at the tip: link 2 with it by the parallel-axis theorem
    payload = 0.5 * (a.payload_low + a.payload_high)
    m, length, lc, inertia = (np.array(x, float) for x in (a.model.m, a.model.l, a.model.lc,
                                                             a.model.inertia))
    carried = m[-1] + payload
    com = (m[-1] * lc[-1] + payload * length[-1]) / carried
    inertia[-1] += m[-1] * (lc[-1] - com) ** 2 + payload * (length[-1] - com) ** 2
    m[-1], lc[-1] = carried, com
    for k in flagged[:50]:  # the braking torque, recomputed from the signals
        y, centre = trace["q_meas"][k], trace["cbf_velocity_centre"][k]
        mass, bias = np.zeros((2, 2)), np.zeros(2)
        planar_mass_matrix(y, m, length, lc, inertia, mass)
        planar_bias(y, centre, m, length, lc, inertia, 9.8, bias)
        bias += 0.01
        desired = -a.backup_rate * (centre - trace["qdot_s"][k])
        u = qpsolvers.solve_qp(np.eye(2), -desired, np.vstack([mass, -mass]),
                               np.concatenate([60.0 - bias, 60.0 + bias]), solver="daqp")
        brake = np.clip(mass @ u + bias, -60, 60)
        np.testing.assert_allclose(trace["tau"][k], brake, rtol=1e-6, atol=1e-6)
    assert np.abs(trace["tau"]).max() <= 60.0 + 1e-9
    pipeline = load_pipeline(MC, ["simulation.duration=1.0", *sets])
    pipeline.runs = {"proposed_cbf": pipeline.runs["proposed_cbf"]}
    guarantee = run(pipeline, None, progress=False)["proposed_cbf"].metrics["guarantee"]
    assert guarantee["feasible"] is False and guarantee["infeasible_steps"] == len(flagged)
    assert any("payload 3 kg outside [0, 1]" in text for text in guarantee["outside"])
    assert guarantee["broken"] is False


def test_the_filter_holds_the_velocity_in_the_observers_certified_interval():
    """proposed_cbf under the declared payload and noise, x̂2(0) off by 4 rad/s: the filter
    holds q̇ in the interval the observer's ε(t) is taken from, c ± (ε − |x̂2 − c|) (each
    step intersected with its own prediction), not in x̂2 ± ε, which contains it: the true
    q̇ inside at every step, the half-width never past ε and, where x̂2 is off the
    envelope's centre, narrower (the backup's check then verifies more torques)."""
    sets = ['plant.parameters."m[2]"=3.1', 'plant.parameters."qdot0[1]"=14.0',
            'plant.parameters."qdot0[2]"=6.0', "sensor.seed=7",
            "runs.proposed_cbf.cbf_filter.torque_limit=2000.0"]
    _, _, trace = simulated(sets, "proposed_cbf", duration=1.0)
    centre, spread = trace["cbf_velocity_centre"], trace["cbf_velocity_spread"]
    truth, bound = trace["qdot"], trace["qdot_hat_bound"]
    outside = np.abs(truth - centre) > spread + 1e-9
    assert not outside.any(), np.argwhere(outside)[:5]
    assert np.all(spread <= bound + 1e-12)
    assert np.median(spread / bound) < 0.9
    np.testing.assert_allclose(spread[0], 5.0)  # t = 0: the declared error, nothing more


def test_the_tracking_rows_ask_no_more_torque_than_the_controller_has():
    """tracking_torque = "controller", baseline_cbf at 2000 N·m (its tracking rows pushed it
    to ~1600 N·m against the controller's ~290): wherever no hard row binds and the backup
    takes no share, every |τ_i| is within the largest |τ_nom,i| the controller has asked so
    far; the hard sets still hold (the hard rows' torque is not capped). With "limit" (the
    default; monte_carlo.toml asks for "controller") the same run goes past it. Both solvers
    (Newton, DAQP) agree on the rule."""
    sets = ["cbf_filter.torque_limit=2000", 'plant.parameters."qdot0[1]"=9',
            'plant.parameters."qdot0[2]"=9', "sensor.noise_std=0"]

    def excess(trace) -> tuple[float, int]:
        peak = np.maximum.accumulate(np.abs(trace["tau_controller"]), axis=0)
        free = ((trace["cbf_position_active"] + trace["cbf_velocity_active"]).sum(axis=1)
                == 0) & (trace["cbf_backup"] == 0)
        return float(np.max((np.abs(trace["tau"]) - peak)[free])), int(free.sum())

    _, _, trace = simulated([*sets, 'cbf_filter.tracking_torque="limit"'], "baseline_cbf",
                            duration=1.0)
    assert excess(trace)[0] > 500.0  # N·m beyond the controller's peak, for tracking
    for solver in ("newton", "daqp"):
        _, _, trace = simulated([*sets, 'cbf_filter.tracking_torque="controller"',
                                 f'cbf_filter.solver="{solver}"'], "baseline_cbf",
                                duration=1.0)
        beyond, free = excess(trace)
        assert free > 500 and beyond <= 1e-6, solver
        assert np.all(np.abs(trace["qdot"]) <= 13.5) and np.all(np.abs(trace["q"]) <= 20.0)


def test_the_backup_brakes_within_braking_torque_where_that_is_verified():
    """proposed_cbf at a 2000 N·m limit from a start of the project's distribution
    (x̂2(0) = 10 ± 5 rad/s reaches past the 13.5 rad/s bound: nothing is verified at first,
    and the backup brakes with the whole limit either way, startup_torque at the limit
    where monte_carlo.toml declares 1000 N·m). After start-up, with
    braking_torque at the limits (nothing in reserve) the filter spends the whole limit
    again at the edge of its verified set; with 1000 N·m the limits beyond it are spent in a
    few steps only, where the check proves them needed. The hard sets hold (true state)
    either way, viable alike after start-up. Likewise baseline_cbf from the same start.

    The start: the first draw of the distribution (numpy's default_rng(23), the benchmark's
    project_point, joint speeds within 13 rad/s) where this holds with the check taking the
    candidate step's drift (holds.held_drift). It holds at 12 of the first 140 such draws.
    At the start the test used before, (−0.221, 0.240) rad, (9.673, 8.705) rad/s, the
    check keeps the state farther from its edge now, and after start-up the filter spends
    1639 N·m at most with nothing in reserve (1511 N·m within 1000 N·m)."""
    sets = ["cbf_filter.torque_limit=2000", 'plant.parameters."q0[1]"=-0.198',
            'plant.parameters."q0[2]"=-0.182', 'plant.parameters."qdot0[1]"=12.166',
            'plant.parameters."qdot0[2]"=9.707', 'plant.parameters."m[2]"=2.715',
            "sensor.seed=853457", "cbf_filter.startup_torque=2000"]
    traces = {braking: simulated([*sets, f"cbf_filter.braking_torque={braking}"],
                                 "proposed_cbf", duration=0.3)[2]
              for braking in (1e9, 1000.0)}
    after = {}
    for braking, trace in traces.items():
        first = int(np.argmax(trace["cbf_viable"] > 0))
        assert 0 < first <= 10 and np.max(np.abs(trace["tau"][:first])) == 2000.0
        after[braking] = np.abs(trace["tau"][first:])
        assert np.all(np.abs(trace["qdot"]) <= 13.5) and np.all(np.abs(trace["q"]) <= 20.0)
        assert np.all(trace["cbf_viable"][first:] == 1.0)
    assert np.max(after[1e9][:, 0]) > 1800.0
    beyond = np.any(after[1000.0] > 1000.0 + 1e-6, axis=1)
    assert beyond.sum() <= 0.03 * len(beyond), int(beyond.sum())
    assert np.max(after[1000.0][:, 0]) < 0.85 * np.max(after[1e9][:, 0])
    # baseline_cbf from the same start (the true state: viable from t = 0) holds joint 1
    # near its velocity bound: with nothing in reserve its torque goes past 1000 N·m (at
    # 0.18–1.14 s); braked within 1000 N·m first, it never does (the state is kept where that
    # braking keeps it, rather than at the edge of where 2000 N·m does)
    base = {braking: simulated([*sets, f"cbf_filter.braking_torque={braking}"],
                               "baseline_cbf", duration=1.2)[2] for braking in (1e9, 1000.0)}
    assert np.sum(np.any(np.abs(base[1e9]["tau"]) > 1000.0 + 1e-6, axis=1)) > 10
    assert np.max(np.abs(base[1000.0]["tau"])) <= 1000.0 + 1e-6
    for trace in base.values():
        assert np.all(np.abs(trace["qdot"]) <= 13.5) and np.all(trace["cbf_viable"] == 1.0)


def start_up_guarantee(q1: float, q2: float, v1: float, v2: float, m2: float,
                       seed: int) -> dict:
    """baseline_cbf's first 0.1 s from a start of the project's distribution at 2000 N·m
    (rad, rad/s, kg): its guarantee, asserted covered, not broken and inside the check's
    tube (and the plan's) on every row."""
    pipeline = load_pipeline(MC, [
        f'plant.parameters."q0[1]"={q1}', f'plant.parameters."q0[2]"={q2}',
        f'plant.parameters."qdot0[1]"={v1}', f'plant.parameters."qdot0[2]"={v2}',
        f'plant.parameters."m[2]"={m2}', f"sensor.seed={seed}",
        "cbf_filter.torque_limit=2000", "simulation.duration=0.1"])
    pipeline.runs = {"baseline_cbf": pipeline.runs["baseline_cbf"]}
    g = run(pipeline, None, progress=False)["baseline_cbf"].metrics["guarantee"]
    assert g["covered"] is True and g["broken"] is False, g["violations"]
    assert g["plan_tube_exceeded_steps"] == 0 and g["tube_exceeded_steps"] == 0
    return g


def test_braking_at_start_up_the_true_state_keeps_the_plans_tube_where_the_filter_follows_it():
    """The plan's tube is held where the filter follows its plan (cosim/paper/premises.py).
    baseline_cbf (the true velocity, ε = 0) from the project distribution's sample 108, the
    one full-state run of its 200 at 2000 N·m that still left the plan's tube with the
    candidate step's drift taken (by 0.0016 rad/s, broken, at 44193ca), braking at
    start-up: joint 1 at 12.7 rad/s, 3.2 kg on the 2.3 kg link. A torque held over a 1 ms
    step drifts in q̈ by more than the tube's D there: the candidate's step (mutant
    cbf-candidate-drift-dropped) and a backup's step where a limit binds, which took the
    first hold's q̈ for 2 ms before. With both taken: covered, the plan followed and its
    tube kept with room to spare. (The start this test ran from before now verifies a
    torque afresh at every step, and no plan is followed there: the next test.)"""
    g = start_up_guarantee(-0.2376148038108299, -0.25466337557561725, 12.747330486829124,
                           8.824556995306782, 3.226966707284615, 463058)
    assert g["plan_tube_slack"]["velocity"] > 0.0 and g["plan_tube_slack"]["position"] > 0.0


def test_braking_at_start_up_from_both_joints_near_the_velocity_bound_keeps_the_checks_tube():
    """baseline_cbf from the project distribution's start where the plan's tube was left
    furthest before the check took the candidate step's drift (0.031 rad/s past the room
    it leaves, at 0426454; mutant cbf-candidate-drift-dropped): both joints at 13.3 rad/s,
    braking with the whole 2000 N·m at start-up. The candidate's torque, held over the 1 ms
    step, drifts in q̈ by more than the tube's D. With the drift taken the filter verifies
    a torque afresh at every step here, and the true state keeps the check's tube on every
    row with room."""
    g = start_up_guarantee(0.476071, -0.074912, 13.26808, 13.276226, 3.18488, 871421)
    assert g["tube_slack"]["velocity"] > 0.0 and g["tube_slack"]["position"] > 0.0


def test_start_up_brakes_within_startup_torque_until_the_first_viable_step():
    """The start-up policy: from the same start (nothing verified at first), with
    startup_torque at the 2000 N·m limit (its default) the backup brakes with the whole
    limit; with monte_carlo.toml's own cbf_filter.startup_torque = 1000 every joint's torque
    is within 1000 N·m until the first viable step; from then on the limits are the
    filter's again. The start becomes viable all the same, and the hard sets hold (true
    state)."""
    sets = ["cbf_filter.torque_limit=2000", 'plant.parameters."q0[1]"=-0.221',
            'plant.parameters."q0[2]"=0.240', 'plant.parameters."qdot0[1]"=9.673',
            'plant.parameters."qdot0[2]"=8.705', 'plant.parameters."m[2]"=2.655',
            "sensor.seed=831061", "cbf_filter.braking_torque=1000"]
    default = simulated([*sets, "cbf_filter.startup_torque=2000"], "proposed_cbf",
                        duration=0.3)[2]
    policy = simulated(sets, "proposed_cbf", duration=0.3)[2]
    for trace in (default, policy):
        assert np.all(np.abs(trace["qdot"]) <= 13.5) and np.all(np.abs(trace["q"]) <= 20.0)
    first = {name: int(np.argmax(trace["cbf_viable"] > 0))
             for name, trace in (("default", default), ("policy", policy))}
    assert 0 < first["default"] <= 10 and 0 < first["policy"] <= 30, first
    assert np.max(np.abs(default["tau"][:first["default"]])) == 2000.0
    assert np.max(np.abs(policy["tau"][:first["policy"]])) == 1000.0
    assert np.all(policy["cbf_viable"][first["policy"]:] == 1.0)


def test_the_rows_left_out_could_not_bind_within_the_torque_limits():
    """A hard row is left out of the QP only where no torque within the limits could
    violate it: at every step of a run near the velocity bound at 1000 N·m, each row of the
    full set (the limits made huge, so nothing is left out) that some torque in the box
    |τ_i| ≤ 1000 N·m would violate is in the QP as built, and rows were left out."""
    from cosim.paper.cbf_filter.rows import cbf_rows

    limit = 1000.0
    _, plan, trace = simulated([f"cbf_filter.torque_limit={limit}",
                                'plant.parameters."qdot0[1]"=12.5'], "proposed_cbf",
                               duration=0.3)
    a = next(b for b in plan.blocks if b.kind == "cbf_filter").args
    unlimited = a._replace(torque_limit=np.full_like(a.torque_limit, 1e30))
    left_out = binding = 0
    for k in range(0, trace.rows_done, 10):
        count = cbf_rows(k, a)
        sets = (a.kinds[:count] >= 0) & (a.kinds[:count] < 2)  # position, velocity rows
        kept = np.column_stack([a.rows[:count], a.limits[:count]])[sets]
        full = cbf_rows(k, unlimited)
        hard = (a.kinds[:full] >= 0) & (a.kinds[:full] < 2) & (a.is_hard[:full] > 0)
        rows, limits = a.rows[:full][hard], a.limits[:full][hard]
        could_bind = np.abs(rows).sum(axis=1) * limit > limits
        left_out += len(rows) - len(kept)
        binding += int(np.sum(could_bind))
        for row, bound in zip(rows[could_bind], limits[could_bind], strict=True):
            assert np.any(np.all(np.isclose(kept, [*row, bound], rtol=1e-12, atol=1e-9),
                                 axis=1)), k
    assert left_out > 0 and binding > 0, (left_out, binding)


@pytest.fixture(scope="module")
def monte_carlo(tmp_path_factory):
    """The Monte Carlo of the robust-safety issue on 40 samples, 10 s each (the reference's
    first position peak at π s and velocity peaks at 0 and 2π s), on a LocalCluster."""
    out = tmp_path_factory.mktemp("mc") / "mc"
    done = cosim_cli(
        "sweep", MC, "--out", str(out), "--quiet", "--set", "simulation.duration=10",
        "--sample", 'plant.parameters."q0[1]"=uniform(-0.4,0.6)',
        "--sample", 'plant.parameters."q0[2]"=uniform(-0.4,0.6)',
        "--sample", 'plant.parameters."qdot0[1]"=uniform(5,15)',
        "--sample", 'plant.parameters."qdot0[2]"=uniform(5,15)',
        "--sample", 'plant.parameters."m[2]"=uniform(2.3,3.3)',
        "--sample", "sensor.seed=integers(0,1000000)", "--samples", "40", "--seed", "7",
        "--runs", "proposed", "proposed_cbf", "baseline_cbf", "--workers", "2")
    assert done.returncode == 0, done.stderr[-3000:]
    rows = pq.read_table(out / "results.parquet").to_pylist()
    return rows, json.loads((out / "sweep.json").read_text()), done.stdout


def test_monte_carlo_no_broken_guarantee_and_the_hard_sets_kept(monte_carlo):
    rows, summary, printed = monte_carlo
    assert len(rows) == 120 and all(r["status"] == "ok" for r in rows)
    assert "covered = starts inside" in printed
    by_run = {e["run"]: e for e in summary["guarantee"]}
    for name in ("proposed_cbf", "baseline_cbf"):
        assert by_run[name]["broken"] == 0
        inside = [r for r in rows if r["run"] == name and r["guarantee.starts_inside"]]
        assert len(inside) >= 20  # ~72 %: both joints' q̇(0) ≤ 13.5 of 5..15 rad/s
        assert all(r["hard_sets_kept"] for r in inside), name
    # the unfiltered controller, for contrast, leaves the position set at the peaks
    assert not any(r["hard_sets_kept"] for r in rows if r["run"] == "proposed")
    # starting outside is its own class, never pooled with the filter's results
    outside = [r for r in rows if r["guarantee.starts_inside"] is False]
    assert outside and all(not r["guarantee.broken"] for r in outside)


def test_monte_carlo_tracking_against_the_unfiltered_controller(monte_carlo):
    """What holds on the tracking sets: the filtered run keeps joint 1's error set and the
    error norm at least as often as the unfiltered proposed controller, at no more RMS error
    (+10 %). (The error-rate sets are left for a few ms at start-up: on N = 1000 the true
    ė ≤ 5 is kept more often with the filter, 87.6 % against 81.2 %, but on these 40 samples
    of 10 s less, 77.5 % against 87.5 %; ‖ė̂‖ 20.9 % against 35.3 % on N = 1000, docs/sweeps.md,
    "Monte Carlo". That part is not reached on 40 samples, so it is not asserted.)"""
    rows, _, _ = monte_carlo

    def kept(name: str, check: str) -> float:
        return float(np.mean([r[f"{check}.satisfied"] for r in rows if r["run"] == name]))

    def rms(name: str) -> float:
        return float(np.mean([r["rms_error.1"] for r in rows if r["run"] == name]))

    for check in ("error_joint1", "error_norm"):
        assert kept("proposed_cbf", check) >= kept("proposed", check), check
    assert rms("proposed_cbf") <= 1.1 * rms("proposed")
