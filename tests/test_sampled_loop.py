"""The step check (cosim/paper/sampled_loop.py): its sampled closed loop against SciPy's
zero-order-hold discretisation of the continuous plant (what we did not write), its
largest stable step against the eigenvalues just below and just past it, the inertia-scaled
gains giving every joint the same loop whatever its inertia, and the check refusing, at
--dry-run, a pipeline whose gains are too stiff for its step, naming the joint, its inertia
and the largest stable step (the reviewer's xArm7 with a Panda's gains)."""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import cosim_cli, error_line
from scipy.signal import cont2discrete

from cosim.dynamics.model import planar_model
from cosim.paper.sampled_loop import (
    LinearGains,
    cases,
    closed_loop,
    largest_stable_step,
    spectral_radius,
    worst_case,
)

MASS = np.array([[10.0, 4.6], [4.6, 2.3]])  # the paper's arm at q2 = 0 (its stiffest)


def scipy_loop(mass, gain_matrix, gains: LinearGains, h: float) -> np.ndarray:
    """Φ + Γ K from SciPy's ZOH of ë = −M⁻¹ G u (B = −M⁻¹G) on the state (e, ė),
    u = K_p e + K_v ė (the velocity the true one); with the backward difference the
    previous error joins the state, u = (K_p + K_v/h) e_k − (K_v/h) e_k−1."""
    n = len(mass)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [np.zeros((n, n)), np.zeros((n, n))]])
    b = np.vstack([np.zeros((n, n)), -np.linalg.solve(mass, gain_matrix)])
    phi, gamma, *_ = cont2discrete((a, b, np.eye(2 * n), np.zeros((2 * n, n))), h, "zoh")
    if not gains.difference:
        return phi + gamma @ np.hstack([np.diag(gains.position), np.diag(gains.velocity)])
    kp, kv = np.diag(gains.position), np.diag(gains.velocity)
    top = np.hstack([phi + gamma @ np.hstack([kp + kv / h, np.zeros((n, n))]),
                     -gamma @ kv / h])
    return np.vstack([top, np.hstack([np.eye(n), np.zeros((n, 2 * n))])])


@pytest.mark.parametrize("difference", [False, True])
@pytest.mark.parametrize("scaled", [False, True])
def test_the_sampled_loop_is_scipys_zero_order_hold(difference, scaled):
    rng = np.random.default_rng(3)
    for _ in range(5):
        root = rng.normal(size=(3, 3))
        mass = root @ root.T + 0.1 * np.eye(3)
        gains = LinearGains(rng.uniform(1, 500, 3), rng.uniform(1, 80, 3), scaled, difference)
        gain_matrix = mass * rng.uniform(0.5, 1.5) if scaled else np.eye(3)
        h = rng.uniform(1e-4, 5e-3)
        np.testing.assert_allclose(closed_loop(mass, gain_matrix, gains, h),
                                   scipy_loop(mass, gain_matrix, gains, h), atol=1e-12)


def test_the_largest_stable_step_is_where_the_eigenvalues_leave_the_unit_circle():
    gains = LinearGains(np.array([1200.0, 1200.0]), np.array([240.0, 240.0]))
    loop = cases(planar_model([0.8, 2.3], [1.0, 1.0], [1.0, 1.0], [0.0, 0.0], 9.8),
                 [np.array([0.3, 0.0]), np.array([0.0, 1.0])], [0.0], False)
    largest = largest_stable_step(loop, gains, 1e-2)
    assert 1e-4 < largest < 1e-2
    below = max(spectral_radius(scipy_loop(m, np.eye(2), gains, 0.99 * largest))
                for m in loop.masses)
    past = max(spectral_radius(scipy_loop(m, np.eye(2), gains, 1.02 * largest))
               for m in loop.masses)
    assert below < 1.0 < past
    worst = worst_case(loop, gains, 1.02 * largest)
    # at q2 = 0 the arm is stretched: M's smallest eigenvalue (0.15 kg·m²) is its lightest
    # direction, which joint 2 dominates
    assert worst.q.tolist() == [0.3, 0.0] and worst.joint == 1
    assert worst.inertia == pytest.approx(MASS[1, 1])


def test_inertia_scaled_gains_give_a_light_and_a_heavy_joint_the_same_loop():
    """With G = M̂(q) and M = M̂ the loop is the same double integrator on every joint: one
    set of gains is stable on an arm a thousand times lighter, where torque gains are not."""
    gains = LinearGains(np.array([500.0, 500.0]), np.array([50.0, 50.0]), inertia_scaled=True)
    for scale in (1.0, 1e-3):
        mass = MASS * scale
        radius = spectral_radius(closed_loop(mass, mass, gains, 1e-3))
        assert radius == pytest.approx(spectral_radius(closed_loop(MASS, MASS, gains, 1e-3)))
        assert radius < 1.0
    torque = LinearGains(np.array([500.0, 500.0]), np.array([50.0, 50.0]))
    assert spectral_radius(closed_loop(MASS * 1e-3, np.eye(2), torque, 1e-3)) > 1.0


def test_a_step_too_long_for_the_gains_is_refused_before_the_run():
    """The paper's proposed controller with its robust term's Kz ten times larger: refused
    at --dry-run, naming the run, the joint, its inertia and the largest stable step; a
    step just below it is accepted."""
    result = cosim_cli("run", "pipelines/paper_two_link.toml", "--dry-run", "--set",
                       "runs.proposed.controller.kz=50")
    message = error_line(result)
    assert message.startswith(
        "cosim: error: run 'proposed': the controller's gains make its sampled loop unstable "
        "at simulation.step = 1 ms (spectral radius "), message
    assert "joint 2, inertia 2.3 kg·m² at the reference's q = [" in message
    assert "is stable up to a step of " in message and message.endswith(
        " ms; lower controller.kv or kz or the step, or give controller.scale = \"inertia\" "
        "(gains in accelerations, scaled by each joint's inertia)"), message
    largest = float(message.split("is stable up to a step of ")[1].split(" ms")[0])
    assert 0.1 < largest < 1.0
    step = 0.95 * largest / 1000
    stable = cosim_cli("run", "pipelines/paper_two_link.toml", "--dry-run", "--set",
                       "runs.proposed.controller.kz=50", "--set", f"simulation.step={step:.6g}",
                       "--set", f"simulation.duration={1000 * float(f'{step:.6g}'):.6g}")
    assert stable.returncode == 0, stable.stderr


def test_bounded_robust_terms_too_stiff_for_the_step_are_said_not_refused():
    """The smooth-sign and ψ_B terms of (27) are bounded: at r̂ = 0 they may make the
    sampled loop chatter, not diverge. The run goes on, saying so as it starts."""
    from cosim.assemble import assemble
    from cosim.config import load_pipeline

    pipeline = load_pipeline("pipelines/paper_two_link.toml",
                             ["runs.proposed.controller.psi_b=80"], warn=None)
    scenario = assemble(pipeline)
    try:
        controller = scenario.runs["proposed"].block("controller")
        headline = controller.headline()
    finally:
        scenario.close()
    assert headline.startswith(
        "the controller: its bounded robust terms (controller.c0, psi_b, or raise delta) at "
        "r̂ = 0 make its sampled loop chatter about the reference at this step, "
        "simulation.step = 1 ms (spectral radius "), headline
    assert "they cannot make it diverge, but the chatter drives the NN's weights" in headline
    assert scenario.runs["baseline"].block("controller").headline() is None
