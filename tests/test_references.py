"""Every law and bound against an independent reference.

Each test computes the expected value here, in plain NumPy from the paper's equations (its
arm and laws, and the choices of docs/choices.md) or with SciPy, and compares the project's
implementation with it at many random states; nothing under test produces an expected value.
The kernels are called with the arguments their blocks' ``reset`` builds (the blocks are
constructed and reset on small arrays, their state then set to random values).

Tolerances, and why (each stated again where it is used):

- closed forms and linear algebra (inertia model, controllers, checks, barriers, Theorem 1's
  formulas): ``RTOL`` = 1e-9 relative to the quantity's scale (max(1, max|expected|)). Both
  sides are a few dozen floating-point operations on O(1–1e4) numbers; measured: inertia
  model ≤ 3.7e-14, controllers ≤ 7e-15, checks and barriers ≤ 3e-16. 1e-9 leaves over four
  orders of magnitude for round-off and still catches any wrong coefficient, sign or dropped
  term: where that could hide (the terms of (25)–(27)), each term is asserted to move the
  result by ≥ 1e3·RTOL of its scale.
- the observer step against its documented scheme: also ``RTOL``. Up to ten sub-steps, each
  with a 1/h = 1e4 amplified difference quotient (the lagged q̂̈) and k0 up to 1e6; measured
  ≤ 1.1e-12 of the scale (the drift and q̂̈), so 1e-9 leaves ~1000×.
- the observer step against the continuous ODE (solve_ivp, Radau, rtol 1e-12): backward
  Euler is first order, so the error must fall ~10× from 100 to 1000 sub-steps (measured
  0.09–0.11; asserted ≤ 0.15) and at 1000 sub-steps stay ≤ 2e-4 of the scale (measured
  ≤ 5e-5).
- Theorem 1's R in a simulation (RK45, rtol 1e-10): the sets must hold to 1e-6 relative
  (the integration error is ~1e-9); tightness: 1.01·R must leave a set by ≥ 0.9 %.
- Wilson: 1e-12 absolute against SciPy (numbers ≤ 1; measured ≤ 3.4e-16).
- event times (first violation, time outside): a count of rows times dt, to 1e-12.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, linalg, special, stats

from cosim.blocks import BlockContext, Ports
from cosim.declared import Uncertainty, safety_section
from cosim.evaluate import Evaluator, SafeSet
from cosim.paper.controller import ControllerParams, NnController, NnGains, controller_step
from cosim.paper.guarantee import classify
from cosim.paper.inertia import planar_bias, planar_mass_matrix
from cosim.paper.observer import _gain, observer_step
from cosim.paper.observer_block import FlnnObserver, ObserverParams
from cosim.paper.theorem import theorem1
from cosim.signals import Signal, Trace
from cosim.sweep import wilson

RTOL = 1e-9  # closed forms: see the module docstring
DT = 1e-3  # the master step, s


def close(actual: np.ndarray, expected: np.ndarray, rtol: float = RTOL) -> bool:
    """|actual − expected| ≤ rtol · max(1, max|expected|), element-wise."""
    actual, expected = np.asarray(actual, float), np.asarray(expected, float)
    scale = max(1.0, float(np.max(np.abs(expected), initial=0.0)))
    return bool(np.all(np.abs(actual - expected) <= rtol * scale))


# --------------------------------------------------------------------------------------------
# 1. The inertia model


def two_link_closed_form(q: np.ndarray, qdot: np.ndarray, a1: float, a2: float, m1: float,
                         m2: float, g: float) -> tuple[np.ndarray, np.ndarray]:
    """The paper's arm (Lewis): M(q) and Vm(q, q̇)q̇ + G(q), point masses at the
    link tips, angles from the horizontal."""
    c2, s2 = math.cos(q[1]), math.sin(q[1])
    m11 = (m1 + m2) * a1**2 + m2 * a2**2 + 2 * m2 * a1 * a2 * c2
    m12 = m2 * a2**2 + m2 * a1 * a2 * c2
    mass = np.array([[m11, m12], [m12, m2 * a2**2]])
    vm = np.array([-m2 * a1 * a2 * (2 * qdot[0] * qdot[1] + qdot[1] ** 2) * s2,
                   m2 * a1 * a2 * qdot[0] ** 2 * s2])
    gravity = np.array([(m1 + m2) * g * a1 * math.cos(q[0]) + m2 * g * a2 * math.cos(q[0] + q[1]),
                        m2 * g * a2 * math.cos(q[0] + q[1])])
    return mass, vm + gravity


def chain_mass(q: np.ndarray, m: np.ndarray, l: np.ndarray, lc: np.ndarray,  # noqa: E741
               inertia: np.ndarray) -> np.ndarray:
    """The Lagrangian's M(q) of a planar chain (relative angles, link 1 from the horizontal):
    T = ½ Σ_k (m_k |ṗ_k|² + I_k ω_k²), ṗ_k = J_k q̇, ω_k = q̇_1 + … + q̇_k, with the centre-of-mass
    Jacobian differentiated by hand from p_k = Σ_{i<k} l_i u(θ_i) + lc_k u(θ_k):
    ∂p_k/∂q_j = Σ_{j≤i<k} l_i u'(θ_i) + lc_k u'(θ_k) for j ≤ k, u' = (−sin, cos).
    Analytic in q, so it takes complex q for the complex-step derivatives below."""
    n = len(q)
    theta = np.cumsum(q)
    du = np.stack([-np.sin(theta), np.cos(theta)])  # (2, n): u'(θ_i)
    mass = np.zeros((n, n), dtype=np.result_type(q, float))
    for k in range(n):
        jac = np.zeros((2, n), dtype=mass.dtype)
        for j in range(k + 1):
            jac[:, j] = du[:, j:k] @ l[j:k] + lc[k] * du[:, k]
        spin = np.zeros(n)
        spin[:k + 1] = 1.0
        mass = mass + m[k] * jac.T @ jac + inertia[k] * np.outer(spin, spin)
    return mass


def chain_potential(q: np.ndarray, m: np.ndarray, l: np.ndarray, lc: np.ndarray,  # noqa: E741
                    g: float) -> complex:
    """V(q) = g Σ_k m_k y_k (gravity along −y)."""
    theta = np.cumsum(q)
    heights = np.concatenate(([0.0], np.cumsum(l * np.sin(theta))))[:-1] + lc * np.sin(theta)
    return g * np.sum(m * heights)


def chain_bias(q: np.ndarray, qdot: np.ndarray, m: np.ndarray, l: np.ndarray,  # noqa: E741
               lc: np.ndarray, inertia: np.ndarray, g: float) -> np.ndarray:
    """C(q, q̇)q̇ + G(q) from Lagrange's equations at q̈ = 0:
    b = Ṁ q̇ − ½ ∂(q̇ᵀM q̇)/∂q + ∂V/∂q, every derivative by the complex step
    (f'(x) = Im f(x + ih)/h, exact to round-off: no subtraction)."""
    h = 1e-30
    n = len(q)
    m_dot = chain_mass(q + 1j * h * qdot, m, l, lc, inertia).imag / h  # Σ_k ∂M/∂q_k q̇_k
    bias = m_dot @ qdot
    for i in range(n):
        step = np.zeros(n)
        step[i] = h
        dm = chain_mass(q + 1j * step, m, l, lc, inertia).imag / h
        bias[i] += -0.5 * qdot @ dm @ qdot + chain_potential(q + 1j * step, m, l, lc, g).imag / h
    return bias


def test_inertia_model_two_link_equals_the_papers_closed_form():
    """planar_mass_matrix / planar_bias with lc = l and I = 0 (point masses at the tips)
    against the paper's M(q) and Vm q̇ + G at 200 random states and arms (lengths, masses and
    gravity drawn too, so no coefficient is right by accident). Tolerance RTOL of the largest
    entry (closed form against a recursion: round-off ~1e-15 relative)."""
    rng = np.random.default_rng(1)
    mass, bias = np.empty((2, 2)), np.empty(2)
    for _ in range(200):
        a = rng.uniform(0.3, 2.0, 2)
        m = rng.uniform(0.2, 5.0, 2)
        g = rng.uniform(0.0, 20.0)
        q, qdot = rng.uniform(-np.pi, np.pi, 2), rng.uniform(-20, 20, 2)
        planar_mass_matrix(q, m, a, a, np.zeros(2), mass)
        planar_bias(q, qdot, m, a, a, np.zeros(2), g, bias)
        mass_ref, bias_ref = two_link_closed_form(q, qdot, *a, *m, g)
        assert close(mass, mass_ref) and close(bias, bias_ref), (q, qdot, a, m, g)


@pytest.mark.parametrize("links", [1, 2, 3, 4])
def test_inertia_model_chain_equals_the_lagrangian(links):
    """Any n, with centres of mass off the tips (lc in [−0.5, 2] m, behind the joint too) and
    rotational inertia I > 0: M(q) and C q̇ + G against the Lagrangian written above (hand
    Jacobians, complex-step derivatives), 200 random states and chains each. Tolerance RTOL
    of the largest entry (round-off ~1e-14 relative on both sides)."""
    rng = np.random.default_rng(10 + links)
    mass, bias = np.empty((links, links)), np.empty(links)
    for _ in range(200):
        m = rng.uniform(0.2, 5.0, links)
        l = rng.uniform(0.3, 2.0, links)  # noqa: E741
        lc = rng.uniform(-0.5, 2.0, links)
        inertia = rng.uniform(0.0, 1.0, links)
        g = rng.uniform(0.0, 20.0)
        q, qdot = rng.uniform(-np.pi, np.pi, links), rng.uniform(-20, 20, links)
        planar_mass_matrix(q, m, l, lc, inertia, mass)
        planar_bias(q, qdot, m, l, lc, inertia, g, bias)
        assert close(mass, chain_mass(q, m, l, lc, inertia)), (q, m, l, lc, inertia)
        assert close(bias, chain_bias(q, qdot, m, l, lc, inertia, g)), (q, qdot, m, l, lc)


# --------------------------------------------------------------------------------------------
# 2. The observer


def k0_of_eq8(kp: float, kd: float, nu: float, n_o: int, z_wo: float, eps_om: float,
              zeta_om: float, x1_err: np.ndarray, w_hat: np.ndarray, e: np.ndarray) -> float:
    """Eq. (8): k0 = ((kp kD‖x̃1‖ + √No (Z_Wo + ‖Ŵo‖) + (ε_oM + ζ_oM) + ‖e‖)
    / (2√(kp kD) (‖x̃1‖² + ν)))², ‖Ŵo‖ the Frobenius norm (the paper's matrix norm is not
    stated; Frobenius ≥ spectral, the conservative reading)."""
    x1n = np.linalg.norm(x1_err)
    num = kp * kd * x1n + math.sqrt(n_o) * (z_wo + np.linalg.norm(w_hat, "fro")) + (
        eps_om + zeta_om) + np.linalg.norm(e)
    return (num / (2.0 * math.sqrt(kp * kd) * (x1n**2 + nu))) ** 2


def sigma_o(x1: np.ndarray, x2: np.ndarray, qdd: np.ndarray, lagged: bool) -> np.ndarray:
    """The FLNN basis of Sec. IV, [q̂; q̂̇; q̂̈; |q̂|; |q̂̇|] ("lagged": q̂̈ as given), or
    without q̂̈ ("no_acceleration")."""
    parts = [x1, x2, qdd] if lagged else [x1, x2]
    return np.concatenate([*parts, np.abs(x1), np.abs(x2)])


def observer_reference(p: ObserverParams, n: int, state: dict, y0: np.ndarray, y1: np.ndarray,
                       tau: np.ndarray, mass0: np.ndarray, mass1: np.ndarray, qd0: np.ndarray,
                       qd1: np.ndarray) -> dict:
    """One master step [t_{k−1}, t_k] of the observer in its z form (7)/(9), as the module
    documents it: x̂1' = x̂2 + kD x̃1, ẑ2' = Ŵoᵀσo + M⁻¹(τ − τ_d) + k0 x̃1, x̂2 = ẑ2 + kp x̃1,
    x̃1 = y − x̂1, over ``substeps`` sub-steps with y interpolated linearly; per sub-step the
    linear part in (x̂1, ẑ2) by backward Euler — here the 2n×2n linear system solved as
    such —, the NN and torque terms, k0 and the weight law frozen at the sub-step's start
    x̂1 (with the sub-step's y, the one the implicit part uses), M and τ held over the step
    and ‖e‖ = ‖q_d − y‖ at its start. Weight laws: (24) solved exactly over the sub-step,
    Ŵo(h) = κo + (Ŵo − κo)e^{−Fo h}; or the error-driven law with its decay implicit."""
    kp, kd, h = p.kp, p.kd, DT / p.substeps
    lagged = p.basis == "lagged"
    n_o = (5 if lagged else 4) * n
    x1, z2, qdd, w = (state[key].copy() for key in ("x1", "z2", "qdd", "W"))
    tau_d = np.full(n, p.tau_d)
    torque = np.linalg.solve(mass0, tau - tau_d)
    eye = np.eye(n)
    matrix_base = np.block([[(1 + h * (kp + kd)) * eye, -h * eye], [0 * eye, eye]])
    for j in range(p.substeps):
        y = y0 + (y1 - y0) * (j + 1) / p.substeps
        x1_err = y - x1
        x2 = z2 + kp * x1_err  # (9)
        k0 = k0_of_eq8(kp, kd, p.nu, n_o, p.z_wo, p.eps_om, p.zeta_om, x1_err, w, qd0 - y0)
        sig = sigma_o(x1, x2, qdd, lagged)
        g = w.T @ sig + torque
        matrix = matrix_base.copy()
        matrix[n:, :n] = h * k0 * eye
        rhs = np.concatenate([x1 + h * (kp + kd) * y, z2 + h * g + h * k0 * y])
        x1_new, z2_new = np.split(np.linalg.solve(matrix, rhs), 2)
        qdd = (z2_new + kp * (y - x1_new) - x2) / h  # the lagged q̂̈: x̂2's difference quotient
        if p.law == "paper":
            w = p.kappa_o + (w - p.kappa_o) * math.exp(-p.fo * h)
        else:  # W_new = W + h Fo (σo x̃1ᵀ − κo ‖x̃1‖ W_new)
            w = (w + h * p.fo * np.outer(sig, x1_err)) / (
                1 + h * p.fo * p.kappa_o * np.linalg.norm(x1_err))
        x1, z2 = x1_new, z2_new
    x1_err = y1 - x1
    x2 = z2 + kp * x1_err
    k0 = k0_of_eq8(kp, kd, p.nu, n_o, p.z_wo, p.eps_om, p.zeta_om, x1_err, w, qd1 - y1)
    # dx̂2/dt of (10) without M⁻¹τ and the unknown kp x̃2: kp x̃1' = kp x̃2 − kp kD x̃1
    drift = w.T @ sigma_o(x1, x2, qdd, lagged) - np.linalg.solve(mass1, tau_d) + (
        k0 - kp * kd) * x1_err
    return {"x1": x1, "z2": z2, "qdd": qdd, "W": w, "q_hat": x1,
            "qdot_hat": x2, "k0": k0, "W_o_norm": np.linalg.norm(w, "fro"),
            "drift": drift}


def random_mass(rng: np.random.Generator, n: int) -> np.ndarray:
    """A symmetric positive definite M (an arm's at a random pose, plus a random SPD part)."""
    a = rng.normal(size=(n, n))
    return a @ a.T + n * np.eye(n)


def random_weights(rng: np.random.Generator, n_o: int, n: int, lagged: bool) -> np.ndarray:
    """Ŵo (No × n) of a few units; the rows on q̂̈ ("lagged") small: q̂̈ is x̂2's difference
    quotient, so those rows feed it back with gain ~‖Ŵo,q̂̈‖ per sub-step, and a gain above 1
    diverges within a step (docs/choices.md: the reason the default drops q̂̈), which would compare
    1e30-sized numbers."""
    w = rng.normal(size=(n_o, n)) * rng.uniform(0, 3)
    if lagged:
        w[2 * n:3 * n] *= 0.05
    return w


def observer_block(p: ObserverParams, n: int, uncertainty: Uncertainty, rows: dict
                   ) -> FlnnObserver:
    """The observer block built and reset on the given two-row inputs, as assembly does."""
    block = FlnnObserver(p, BlockContext(n, DT, "reference", frozenset({"q", "qdot"}),
                                         uncertainty=uncertainty))
    outputs = {name: np.full(signal.rows_shape(2, n), np.nan)
               for name, signal in block.outputs.items()}
    block.reset(Ports(rows, outputs, None))
    return block


def test_k0_is_eq8():
    """The observer's k0 (its ``_gain``) against eq. (8) at 500 random gains, errors and
    weights (‖x̃1‖ from 0 to 1, ν from 1e-5 to 1, k0 from ~1 to ~1e12). Tolerance RTOL."""
    rng = np.random.default_rng(2)
    n = 2
    rows = {"q_meas": np.zeros((2, n)), "M_model": np.tile(np.eye(n), (2, 1, 1)),
            "q_d": np.zeros((2, n)), "qdot_d": np.zeros((2, n)), "tau": np.zeros((2, n))}
    for _ in range(500):
        p = ObserverParams(kp=rng.uniform(1, 300), kd=rng.uniform(1, 300),
                           nu=10 ** rng.uniform(-5, 0), z_wo=rng.uniform(0, 20),
                           eps_om=rng.uniform(0, 3), zeta_om=rng.uniform(0, 3),
                           basis=str(rng.choice(["lagged", "no_acceleration"])))
        args = observer_block(p, n, Uncertainty(), rows).args
        x1_err = rng.normal(size=n) * 10 ** rng.uniform(-6, 0) * (rng.uniform() > 0.1)
        w_hat = rng.normal(size=(args.n_basis, n)) * rng.uniform(0, 10)
        e = rng.normal(size=n) * rng.uniform(0, 3)
        expected = k0_of_eq8(p.kp, p.kd, p.nu, args.n_basis, p.z_wo, p.eps_om, p.zeta_om,
                             x1_err, w_hat, e)
        actual = _gain(args, np.linalg.norm(x1_err), np.linalg.norm(w_hat), np.linalg.norm(e))
        assert actual == pytest.approx(expected, rel=RTOL), (p, x1_err, e)


@pytest.mark.parametrize("law", ["paper", "error_driven"])
@pytest.mark.parametrize("basis", ["lagged", "no_acceleration"])
def test_one_observer_step_equals_the_documented_integration(law, basis):
    """observer_step at k = 1 from 50 random observer states, gains and inputs (3 links, 1–10
    sub-steps, k0 from ~1e2 to ~1e6) against ``observer_reference``: the new state (x̂1, ẑ2,
    q̂̈, Ŵo) and every output of the FLNN (x̂1, x̂2, k0 of (8), ‖Ŵo‖, the drift of (10)).
    Row 0 too: x̂1(0) = y(0), x̂2(0) as configured, k0 of (8) with x̃1 = 0 and Ŵo = 0, and
    ε(0) = the declared initial error. (ε(t) after row 0 is the certified envelope's,
    checked in tests/test_observer_bound.py.)
    Tolerance RTOL of each quantity's scale (measured ≤ 1.1e-12: module docstring)."""
    rng = np.random.default_rng(3 + 2 * (law == "paper") + (basis == "lagged"))
    n = 3
    for case in range(50):
        p = ObserverParams(kp=rng.uniform(20, 200), kd=rng.uniform(20, 200),
                           nu=10 ** rng.uniform(-3, -1), z_wo=rng.uniform(0, 20),
                           eps_om=rng.uniform(0, 2), zeta_om=rng.uniform(0, 2),
                           fo=rng.uniform(0.5, 5), kappa_o=rng.uniform(0, 10), law=law,
                           basis=basis, substeps=int(rng.choice([1, 3, 10])),
                           tau_d=rng.uniform(-1, 1), initial_velocity=list(rng.uniform(-5, 5, n)))
        uncertainty = Uncertainty(noise_bound=rng.uniform(0, 1e-3),
                                  initial_velocity_error=rng.uniform(0, 5))
        y = rng.uniform(-2, 2, (2, n))
        y[1] = y[0] + DT * rng.uniform(-15, 15, n)
        rows = {"q_meas": y, "M_model": np.stack([random_mass(rng, n), random_mass(rng, n)]),
                "q_d": y + rng.uniform(-1, 1, (2, n)), "qdot_d": rng.uniform(-10, 10, (2, n)),
                "tau": rng.uniform(-300, 300, (2, n))}
        block = observer_block(p, n, uncertainty, rows)
        a = block.args
        # row 0
        observer_step(0, a)
        n_o = a.n_basis
        k0_start = k0_of_eq8(p.kp, p.kd, p.nu, n_o, p.z_wo, p.eps_om, p.zeta_om, np.zeros(n),
                             np.zeros((n_o, n)), rows["q_d"][0] - y[0])
        assert np.array_equal(a.q_hat[0], y[0])
        assert close(a.qdot_hat[0], p.initial_velocity, RTOL)
        assert a.k0[0] == pytest.approx(k0_start, rel=RTOL)
        assert close(a.error_bound[0], np.full(n, uncertainty.initial_velocity_error), RTOL)
        # row 1, from a random state
        state = {"x1": y[0] + rng.normal(size=n) * 10 ** rng.uniform(-5, -2),
                 "z2": rng.uniform(-15, 15, n), "qdd": rng.uniform(-100, 100, n),
                 "W": random_weights(rng, n_o, n, basis == "lagged")}
        a.state[:] = np.concatenate([state["x1"], state["z2"], state["qdd"],
                                     state["W"].ravel()])
        assert observer_step(1, a)
        ref = observer_reference(p, n, state, y[0], y[1], rows["tau"][0], rows["M_model"][0],
                                 rows["M_model"][1], rows["q_d"][0], rows["q_d"][1])
        got = {"x1": a.state[:n], "z2": a.state[n:2 * n], "qdd": a.state[2 * n:3 * n],
               "W": a.state[3 * n:].reshape(n_o, n),
               "q_hat": a.q_hat[1], "qdot_hat": a.qdot_hat[1], "k0": a.k0[1],
               "W_o_norm": a.W_o_norm[1], "drift": a.drift[1]}
        for key, expected in ref.items():
            assert close(got[key], expected, RTOL), (case, key, got[key], expected)


@pytest.mark.parametrize("law", ["paper", "error_driven"])
def test_the_observer_step_converges_to_the_continuous_observer_ode(law):
    """The same step against the observer ODE itself, (7)/(9) with (8) and the weight law in
    continuous time (no scheme choices: y(t) linear over the step, M, τ and ‖e‖ held),
    integrated by SciPy's Radau at rtol 1e-12: x̂1, x̂2 and Ŵo at 100 and 1000 sub-steps.
    Backward Euler is first order, so the error falls ~10× (asserted ≤ 0.15×) and is
    ≤ 2e-4 of the scale at 1000 sub-steps (measured ≤ 5e-5). No q̂̈ in the basis: the lagged
    one is a discretisation artefact with no ODE. 4 random states, 2 links."""
    rng = np.random.default_rng(5 + (law == "paper"))
    n, n_o = 2, 8
    for _ in range(4):
        gains = {"kp": rng.uniform(50, 150), "kd": rng.uniform(50, 150),
                 "nu": 10 ** rng.uniform(-3, -1), "z_wo": rng.uniform(0, 20),
                 "eps_om": rng.uniform(0, 2), "zeta_om": rng.uniform(0, 2),
                 "fo": rng.uniform(0.5, 5), "kappa_o": rng.uniform(0, 10), "law": law,
                 "basis": "no_acceleration", "tau_d": rng.uniform(-1, 1)}
        p = ObserverParams(**gains)
        y = rng.uniform(-2, 2, (2, n))
        y[1] = y[0] + DT * rng.uniform(-15, 15, n)
        rows = {"q_meas": y, "M_model": np.stack([random_mass(rng, n), random_mass(rng, n)]),
                "q_d": y + rng.uniform(-1, 1, (2, n)), "qdot_d": rng.uniform(-10, 10, (2, n)),
                "tau": rng.uniform(-300, 300, (2, n))}
        x1_0 = y[0] + rng.normal(size=n) * 10 ** rng.uniform(-4, -2)
        z2_0, w_0 = rng.uniform(-15, 15, n), random_weights(rng, n_o, n, False)
        torque = np.linalg.solve(rows["M_model"][0], rows["tau"][0] - p.tau_d)
        e = rows["q_d"][0] - y[0]

        def rhs(t: float, s: np.ndarray, p: ObserverParams = p, torque: np.ndarray = torque,
                e: np.ndarray = e, y: np.ndarray = y) -> np.ndarray:
            x1, z2, w = s[:n], s[n:2 * n], s[2 * n:].reshape(n_o, n)
            x1_err = y[0] + (y[1] - y[0]) * t / DT - x1
            x2 = z2 + p.kp * x1_err
            k0 = k0_of_eq8(p.kp, p.kd, p.nu, n_o, p.z_wo, p.eps_om, p.zeta_om, x1_err, w, e)
            sig = sigma_o(x1, x2, x2, False)
            w_dot = (p.fo * (p.kappa_o - w) if p.law == "paper" else
                     p.fo * np.outer(sig, x1_err) - p.kappa_o * p.fo * np.linalg.norm(x1_err) * w)
            return np.concatenate([x2 + p.kd * x1_err, w.T @ sig + torque + k0 * x1_err,
                                   w_dot.ravel()])

        solution = integrate.solve_ivp(rhs, (0, DT), np.concatenate([x1_0, z2_0, w_0.ravel()]),
                                       method="Radau", rtol=1e-12, atol=1e-14).y[:, -1]
        x1_ref = solution[:n]
        expected = {"x1": x1_ref, "x2": solution[n:2 * n] + p.kp * (y[1] - x1_ref),
                    "W": solution[2 * n:]}
        errors = []
        for substeps in (100, 1000):
            a = observer_block(p.model_copy(update={"substeps": substeps}), n, Uncertainty(),
                               rows).args
            a.state[:] = np.concatenate([x1_0, z2_0, np.zeros(n), w_0.ravel()])
            assert observer_step(1, a)
            got = {"x1": a.q_hat[1], "x2": a.qdot_hat[1], "W": a.state[3 * n:]}
            errors.append({key: float(np.max(np.abs(got[key] - value))
                                      / max(1.0, np.max(np.abs(value))))
                           for key, value in expected.items()})
        coarse, fine = errors
        for key in ("x1", "x2") if law == "paper" else ("x1", "x2", "W"):
            assert fine[key] <= 0.15 * coarse[key], (key, coarse, fine)
        assert max(fine.values()) <= 2e-4, fine


# --------------------------------------------------------------------------------------------
# 3. The controllers


def robust_terms(e: np.ndarray, r: np.ndarray, z_norm: float, p: ControllerParams,
                 proposed: bool) -> dict[str, np.ndarray]:
    """The robust term's parts: the baseline's v = −Kz(‖Ẑ‖_F + Z_B) r (Lewis 1999); the
    proposed controller's v_c of (27) with its scalar middle term multiplying r̂ (a smooth sign):
    −Kz(‖Ẑ‖_F + Z_Wc) r̂ − [κ(Z_Wc + C1/κ)²/4 + C0] r̂/√(δ + ‖r̂‖²) − e − ψ_B² r̂/(δ + ‖r̂‖²)."""
    if not proposed:
        return {"Kz": -p.kz * (z_norm + p.z_b) * r}
    r_sq = float(r @ r)
    return {"Kz": -p.kz * (z_norm + p.z_wc) * r,
            "C0, C1": -(p.kappa * (p.z_wc + p.c1 / p.kappa) ** 2 / 4 + p.c0) / math.sqrt(
                p.delta + r_sq) * r,
            "e": -e,
            "psi_B": -p.psi_b**2 / (p.delta + r_sq) * r}


def controller_reference(w: np.ndarray, v: np.ndarray, e: np.ndarray, edot: np.ndarray,
                         q_d: np.ndarray, qdot_d: np.ndarray, qddot_d: np.ndarray,
                         p: ControllerParams, proposed: bool) -> dict:
    """(21)–(22) with v from ``robust_terms``, and one step of (25)–(26) (σ̂' in (26), as
    Lewis; the printed σ̂ does not make the dimensions agree), Euler at the master step with
    the κ‖r̂‖ decay implicit, as the module documents:
    Ŵ⁺ = Ŵ + dt[F(σ̂ − σ̂'V̂ᵀξ) r̂ᵀ − κF‖r̂‖Ŵ⁺],  V̂⁺ = V̂ + dt[G ξ (σ̂'ᵀŴ r̂)ᵀ − κG‖r̂‖V̂⁺].
    Built with explicit matrices: σ̂' = [0; diag(σ(1 − σ))], Ẑ = diag(V̂, Ŵ)."""
    n = len(e)
    lam, kv = np.broadcast_to(p.lam, (n,)), np.broadcast_to(p.kv, (n,))
    xi = np.concatenate([[1.0], e, edot, q_d, qdot_d, qddot_d])
    s = special.expit(v.T @ xi)
    sig_hat = np.concatenate([[1.0], s])
    sig_prime = np.vstack([np.zeros(len(s)), np.diag(s * (1 - s))])
    r = edot + lam * e
    z_norm = np.linalg.norm(linalg.block_diag(v, w), "fro")
    terms = robust_terms(e, r, z_norm, p, proposed)
    robust = sum(terms.values())
    f_hat = w.T @ sig_hat
    r_norm = np.linalg.norm(r)
    w_next = (w + DT * p.f * np.outer(sig_hat - sig_prime @ v.T @ xi, r)) / (
        1 + DT * p.kappa * p.f * r_norm)
    v_next = (v + DT * p.g * np.outer(xi, sig_prime.T @ w @ r)) / (
        1 + DT * p.kappa * p.g * r_norm)
    feedback = kv * r - robust
    # each term of (25) and (26) times dt, to show that none is negligible
    weight_terms = {"W": [DT * p.f * np.outer(sig_hat, r),
                          DT * p.f * np.outer(sig_prime @ v.T @ xi, r),
                          DT * p.kappa * p.f * r_norm * w_next],
                    "V": [DT * p.g * np.outer(xi, sig_prime.T @ w @ r),
                          DT * p.kappa * p.g * r_norm * v_next]}
    return {"tau": f_hat + feedback, "e": e, "edot": edot, "r_hat": r, "nn_output": f_hat,
            "v_c": robust, "W_norm": np.linalg.norm(w, "fro"), "V_norm": np.linalg.norm(v, "fro"),
            "feedback_gain": np.linalg.norm(feedback) / r_norm, "W": w_next, "V": v_next,
            "terms": terms, "weight_terms": weight_terms}


def random_controller_case(rng: np.random.Generator, variant: str, velocity: str = "auto"
                           ) -> tuple[ControllerParams, NnController, dict, np.ndarray, np.ndarray]:
    """A controller block with random gains, reset on two random rows (k = 0, 1), its
    weights set to random values: (params, block, rows, Ŵ, V̂)."""
    n, hidden = 2, int(rng.integers(3, 12))
    p = ControllerParams(variant=variant, velocity=velocity, kv=list(rng.uniform(5, 50, n)),
                         lam=list(rng.uniform(1, 10, n)), f=rng.uniform(1, 20),
                         g=rng.uniform(1, 20), kappa=rng.uniform(0.01, 1), kz=rng.uniform(0.1, 10),
                         z_b=rng.uniform(0, 20), z_wc=rng.uniform(1, 20), c0=rng.uniform(10, 300),
                         c1=rng.uniform(0.5, 5), delta=rng.uniform(0.5, 10),
                         psi_b=rng.uniform(5, 30), hidden=hidden)
    block = NnController(p, BlockContext(n, DT, "reference", frozenset({"q", "qdot"})))
    rows = {name: rng.uniform(-1, 1, (2, n)) * scale for name, scale in
            [("q", 3), ("q_meas", 3), ("qdot", 12), ("qdot_hat", 12), ("q_d", 3),
             ("qdot_d", 12), ("qddot_d", 10)]}
    # y's backward difference (velocity = "finite_difference") a plausible velocity too
    rows["q_meas"][1] = rows["q_meas"][0] + DT * rng.uniform(-12, 12, n)
    inputs = {name: rows[name] for name in block.inputs}
    outputs = {name: np.full(signal.rows_shape(2, n), np.nan)
               for name, signal in block.outputs.items()}
    block.reset(Ports(inputs, outputs, None))
    w = rng.normal(size=(hidden + 1, n)) * rng.uniform(0, 20)
    v = rng.normal(size=(1 + 5 * n, hidden)) * rng.uniform(0, 0.3)
    block.args.state[:] = np.concatenate([w.ravel(), v.ravel()])
    return p, block, rows, w, v


@pytest.mark.parametrize("variant,velocity", [("baseline", "auto"), ("proposed", "auto"),
                                              ("proposed", "finite_difference")])
def test_controller_torque_and_weight_laws_equal_the_papers(variant, velocity):
    """controller_step at 200 random states, gains and weights against
    ``controller_reference``: τ (22), e, ė (the baseline's from the true q̇, the proposed
    one's ė̂ from x̂2, or the backward difference of y), r̂, f̂ (21), v of (27) or Lewis's,
    ‖Ŵ‖, ‖V̂‖, the effective gain, and the weights after (25)–(26). Tolerance RTOL
    (measured ≤ 7e-15 of the scale)."""
    rng = np.random.default_rng(7 + len(variant) + len(velocity))
    proposed = variant == "proposed"
    for case in range(200):
        p, block, rows, w, v = random_controller_case(rng, variant, velocity)
        assert controller_step(1, block.args)
        if not proposed:
            position, measured_velocity = rows["q"][1], rows["qdot"][1]
        elif velocity == "finite_difference":
            position = rows["q_meas"][1]
            measured_velocity = (rows["q_meas"][1] - rows["q_meas"][0]) / DT
        else:
            position, measured_velocity = rows["q_meas"][1], rows["qdot_hat"][1]
        e = rows["q_d"][1] - position
        ref = controller_reference(w, v, e, rows["qdot_d"][1] - measured_velocity,
                                   rows["q_d"][1], rows["qdot_d"][1], rows["qddot_d"][1], p,
                                   proposed)
        a = block.args
        hidden = p.hidden
        got = {name: getattr(a, name)[1] for name in ("tau", "e", "edot", "r_hat", "nn_output",
                                                      "v_c", "W_norm", "V_norm", "feedback_gain")}
        got["W"] = a.state[:(hidden + 1) * 2].reshape(hidden + 1, 2)
        got["V"] = a.state[(hidden + 1) * 2:].reshape(11, hidden)
        for key, value in got.items():
            assert close(value, ref[key]), (case, key, value, ref[key])
        # not vacuous: every term of (25)–(26) moves the weights by ≥ 1e3·RTOL of their
        # scale (measured ≥ 3e-6 of it), so a dropped or wrong term fails above
        for key, terms in ref["weight_terms"].items():
            scale = max(1.0, float(np.max(np.abs(ref[key]))))
            for i, term in enumerate(terms):
                assert np.max(np.abs(term)) >= 1e3 * RTOL * scale, (case, key, i)


def test_every_term_of_the_robust_term_27_counts():
    """Dropping any one term of (27) — Kz(‖Ẑ‖_F + Z_Wc)r̂, the smooth sign with C0 and C1,
    −e, the ψ_B² term — or the C1/κ inside the square, or C0, would fail the comparison
    above: at each of 200 random states the code's v_c equals the full reference (RTOL of its
    scale, as ``close``) and differs from every reduced one by more than 1e3·RTOL of that
    scale (measured: ≥ 2e-5 of it, the −e term, i.e. ≥ 2e4× the tolerance)."""
    rng = np.random.default_rng(9)
    for _ in range(200):
        p, block, rows, w, v = random_controller_case(rng, "proposed")
        assert controller_step(1, block.args)
        e = rows["q_d"][1] - rows["q_meas"][1]
        ref = controller_reference(w, v, e, rows["qdot_d"][1] - rows["qdot_hat"][1],
                                   rows["q_d"][1], rows["qdot_d"][1], rows["qddot_d"][1], p, True)
        got = block.args.v_c[1]
        scale = max(1.0, float(np.max(np.abs(ref["v_c"]))))
        assert close(got, ref["v_c"])
        r = ref["r_hat"]
        reduced = {name: ref["v_c"] - term for name, term in ref["terms"].items()}
        sign = -1 / math.sqrt(p.delta + r @ r) * r
        reduced["C1/κ in the square"] = ref["v_c"] - p.kappa * (
            (p.z_wc + p.c1 / p.kappa) ** 2 - p.z_wc**2) / 4 * sign
        reduced["C0 in the smooth sign"] = ref["v_c"] - p.c0 * sign
        for name, without in reduced.items():
            assert np.max(np.abs(got - without)) >= 1e3 * RTOL * scale, (name, got, without)


# --------------------------------------------------------------------------------------------
# 4.–5. The safety checks, the barriers and Theorem 1

SIGNALS = {name: Signal(shape, "SI", name) for name, shape in [
    ("q", "n"), ("qdot", "n"), ("M", "nn"), ("q_d", "n"), ("qdot_d", "n"), ("q_s", "n"),
    ("qdot_s", "n"), ("q_hat", "n"), ("qdot_hat", "n"), ("k0", "1"), ("W_o_norm", "1"),
    ("M_model", "nn"), ("tau", "n"), ("e", "n"), ("edot", "n"), ("r_hat", "n"),
    ("W_norm", "1"), ("V_norm", "1")]}
SAFE = safety_section()(
    position_bound=2.0, velocity_bound=3.0, error_bound=0.5, error_rate_bound=1.5,
    observer_error_bound=0.4, z_wo_tilde=20.0, z_wc_tilde=50.0, z_vc_tilde=40.0,
    barrier_alpha=0.7)
LAMBDA = np.array([4.0, 7.0])
CENTRE, VELOCITY_CENTRE = np.array([0.7, -1.3]), np.array([0.4, -0.9])  # q_s, q̇_s: not 0


def r_of_theorem1(lam: np.ndarray, e1: float, e2: float) -> float:
    """R, the bound on ‖r̂‖ of (15) under docs/choices.md's reading of Theorem 1: r̂ = ė + Λe with
    ‖r̂‖ ≤ R keeps ‖e‖ ≤ R/λmin (d/dt ½‖e‖² ≤ −λmin‖e‖² + R‖e‖), and then
    ‖ė‖ = ‖r̂ − Λe‖ ≤ R(1 + λmax/λmin); both within E1, E2 iff R ≤ this."""
    lmin, lmax = float(np.min(lam)), float(np.max(lam))
    return min(lmin * e1, e2 * lmin / (lmin + lmax))


def waves(t: np.ndarray, amplitude: tuple[float, float], rng: np.random.Generator
          ) -> np.ndarray:
    """Two joints of sinusoids with random frequencies and phases, joint 1 of the given
    amplitude (beyond a bound, so that it leaves the set on both sides)."""
    freq, phase = rng.uniform(0.3, 2.0, 2), rng.uniform(0, 2 * np.pi, 2)
    return np.asarray(amplitude) * np.sin(2 * np.pi * freq * t[:, None] + phase)


def evaluation_case(rng: np.random.Generator, output_feedback: bool, plant_mass: bool
                    ) -> tuple[Trace, dict]:
    """A consistent random trace (3001 rows, 1 ms) whose joint-1 position, velocities, error
    and error rates cross both bounds of their sets around NON-ZERO centres, with the
    weight matrices its norms come from: (trace, raw arrays)."""
    rows, n = 3001, 2
    t = np.arange(rows) * DT
    q = CENTRE + waves(t, (1.3 * SAFE.position_bound, 1.0), rng)
    qdot = VELOCITY_CENTRE + waves(t, (1.3 * SAFE.velocity_bound, 2.0), rng)
    qdot_hat = qdot + waves(t, (0.6, 0.3), rng)  # the observer's error
    e = waves(t, (1.3 * SAFE.error_bound, 0.2), rng)
    used = qdot_hat if output_feedback else qdot
    edot = waves(t, (1.3 * SAFE.error_rate_bound, 0.5), rng)
    raw = {"q": q, "qdot": qdot, "qdot_hat": qdot_hat, "q_d": q + e, "qdot_d": used + edot,
           "q_hat": q + waves(t, (0.05, 0.02), rng), "k0": 10 ** rng.uniform(3, 5, rows),
           "W_o": rng.normal(size=(rows, 8, n)) * 2, "W_c": rng.normal(size=(rows, 11, n)) * 4,
           "V_c": rng.normal(size=(rows, 11, 10)) * 0.5, "tau": rng.normal(size=(rows, n)) * 50}
    raw["e"], raw["edot"] = raw["q_d"] - q, raw["qdot_d"] - used
    raw["r_hat"] = raw["edot"] + LAMBDA * raw["e"]
    raw["M_plant"] = np.stack([two_link_closed_form(x, x, 1.0, 1.0, 0.8, 2.3, 9.8)[0] for x in q])
    raw["M_model"] = np.stack([two_link_closed_form(x, x, 1.1, 0.9, 0.8, 2.0, 9.8)[0] for x in q])
    trace = Trace(SIGNALS, n, rows - 1, DT)
    values = {"q_s": np.tile(CENTRE, (rows, 1)), "qdot_s": np.tile(VELOCITY_CENTRE, (rows, 1)),
              "M": raw["M_plant"] if plant_mass else np.full((rows, n, n), np.nan),
              "W_o_norm": np.linalg.norm(raw["W_o"], axis=(1, 2)),
              "W_norm": np.linalg.norm(raw["W_c"], axis=(1, 2)),
              "V_norm": np.linalg.norm(raw["V_c"], axis=(1, 2))}
    for name in trace.arrays:
        trace.arrays[name][:] = values[name] if name in values else raw[name]
    trace.rows_done = rows
    return trace, raw


def expected_checks(raw: dict, output_feedback: bool, r_bound: float) -> dict:
    """Each set of docs/safety/index.md's list ("The checks") computed from the primary
    arrays: name -> (signed value per row, lower, upper, the reference trajectory's own
    value or None). Joint checks are signed (x − centre), every joint's, norms by hypot."""
    def joint_and_norm(stem: str, x: np.ndarray, bound: float, ref: np.ndarray | None) -> dict:
        return {**{f"{stem}_joint{j + 1}": (x[:, j], -bound, bound,
                                            None if ref is None else ref[:, j])
                   for j in range(x.shape[1])},
                f"{stem}_norm": (np.hypot(x[:, 0], x[:, 1]), 0.0, bound,
                                 None if ref is None else np.hypot(ref[:, 0], ref[:, 1]))}

    used = raw["qdot_hat"] if output_feedback else raw["qdot"]
    ref_position, ref_velocity = raw["q_d"] - CENTRE, raw["qdot_d"] - VELOCITY_CENTRE
    out = {**joint_and_norm("position", raw["q"] - CENTRE, SAFE.position_bound, ref_position),
           **joint_and_norm("velocity_estimated", used - VELOCITY_CENTRE, SAFE.velocity_bound,
                            ref_velocity),
           **joint_and_norm("velocity_true", raw["qdot"] - VELOCITY_CENTRE, SAFE.velocity_bound,
                            ref_velocity),
           **joint_and_norm("error", raw["q_d"] - raw["q"], SAFE.error_bound, None),
           **joint_and_norm("error_rate", raw["qdot_d"] - used, SAFE.error_rate_bound, None)}
    if output_feedback:
        out.update(joint_and_norm("error_rate_true", raw["qdot_d"] - raw["qdot"],
                                  SAFE.error_rate_bound, None))
    r = (raw["qdot_d"] - used) + LAMBDA * (raw["q_d"] - raw["q"])
    out["filtered_error_norm"] = (np.hypot(r[:, 0], r[:, 1]), 0.0, r_bound, None)
    if output_feedback:
        x2_err = raw["qdot"] - raw["qdot_hat"]
        out["observer_error_norm"] = (np.hypot(x2_err[:, 0], x2_err[:, 1]), 0.0,
                                      SAFE.observer_error_bound, None)
    return out


def evaluated(trace: Trace, output_feedback: bool):
    """The project's evaluation of the trace, chunk by chunk as a run streams it."""
    published = {"nn_gains": NnGains(LAMBDA, 8.0, 13.0), "observer_gain": 2.5,
                 "velocity_source": "observer" if output_feedback else "plant"}
    evaluator = Evaluator(trace, SAFE, published)
    evaluator.update(700)
    evaluator.update(1901)
    return evaluator.result()


@pytest.mark.parametrize("output_feedback", [True, False])
def test_every_safety_check_against_the_trace_arrays(output_feedback):
    """Every check of summary.json (per joint 1 and as a norm) with non-zero centres q_s, q̇_s
    and a joint 1 that leaves each set above the upper bound and below the lower: its values
    and bounds, and "bound", "worst", "satisfied", "first_violation_s", "time_outside_s",
    "reference_worst" and "attainable" against ``expected_checks`` (values RTOL; times exact
    to a count of rows times dt)."""
    rng = np.random.default_rng(11 + output_feedback)
    trace, raw = evaluation_case(rng, output_feedback, plant_mass=True)
    r_bound = r_of_theorem1(LAMBDA, SAFE.error_bound, SAFE.error_rate_bound)
    expected = expected_checks(raw, output_feedback, r_bound)
    result = evaluated(trace, output_feedback)
    assert set(result.checks) == set(expected) and set(result.safety) == set(expected)
    for name, (value, lower, upper, reference) in expected.items():
        check, entry = result.checks[name], result.safety[name]
        if name.endswith("_joint1"):  # the data leave the set on both sides
            assert (value > upper).any() and (value < lower).any(), name
        if not name.endswith("_joint2"):  # joint 2's data stay inside its sets
            assert (value > upper).any() and (value <= upper).any(), name
        assert close(check.value, value), name
        assert (check.lower, check.upper) == pytest.approx((lower, upper), rel=RTOL), name
        outside = (value > upper) | (value < lower)
        worst = float(np.max(np.abs(value)))
        assert entry["bound"] == pytest.approx(upper, rel=RTOL), name
        assert entry["worst"] == pytest.approx(worst, rel=RTOL), name
        assert entry["satisfied"] is (worst <= upper), name
        assert entry["time_outside_s"] == pytest.approx(np.count_nonzero(outside) * DT,
                                                        rel=1e-12), name
        if outside.any():
            assert entry["first_violation_s"] == pytest.approx(np.argmax(outside) * DT,
                                                               rel=1e-12), name
        else:
            assert entry["first_violation_s"] is None, name
        if reference is None:
            assert "reference_worst" not in entry, name
        else:
            reference_worst = float(np.max(np.abs(reference)))
            assert entry["reference_worst"] == pytest.approx(reference_worst, rel=RTOL), name
            assert entry["attainable"] is (reference_worst <= upper), name


def test_the_guarantees_hard_sets_against_the_trace_arrays():
    """cosim/paper/guarantee.py's classify on 12 random traces (non-zero centres, joint 1
    crossing both bounds): "starts_inside" (every joint's |q − q_s| ≤ α_q and true
    |q̇ − q̇_s| ≤ α_v at t = 0), "starts_inside_observer_set" (‖q̇(0) − x̂2(0)‖ ≤ ε_max),
    "hard_kept" and "first_exit" (the earliest row, position before velocity at a tie, the
    lowest joint in that row: its set, time, |value| and bound) from the arrays directly."""
    starts = set()
    for seed in range(12):
        trace, raw = evaluation_case(np.random.default_rng(100 + seed), True, True)
        got = classify(trace, SAFE, Uncertainty(initial_velocity_error=100.0), 0.0, [])
        distance = {"position": (np.abs(raw["q"] - CENTRE), SAFE.position_bound),
                    "velocity_true": (np.abs(raw["qdot"] - VELOCITY_CENTRE), SAFE.velocity_bound)}
        inside = all(bool(np.all(d[0] <= bound)) for d, bound in distance.values())
        starts.add(inside)
        assert got["starts_inside"] is inside
        x2_err = raw["qdot"][0] - raw["qdot_hat"][0]
        assert got["starts_inside_observer_set"] is (
            math.hypot(*x2_err) <= SAFE.observer_error_bound)
        exits = []
        for order, (name, (d, bound)) in enumerate(distance.items()):
            for row in range(len(d)):
                joints = [j for j in range(2) if d[row, j] > bound]
                if joints:
                    exits.append((row, order, {"set": f"{name}_joint{joints[0] + 1}",
                                               "t": row * DT, "value": d[row, joints[0]],
                                               "bound": bound}))
                    break
        assert exits, "the data leave a hard set"
        first = min(exits, key=lambda x: x[:2])[2]
        assert got["hard_kept"] is False and got["broken"] is False
        assert got["first_exit"]["set"] == first["set"]
        for key in ("t", "value", "bound"):
            assert got["first_exit"][key] == pytest.approx(first[key], rel=RTOL), key
        assert got["first_exit"]["unit"] == ("rad" if first["set"].startswith("position")
                                             else "rad/s")
    assert starts == {True, False}  # both classes met


@pytest.mark.parametrize("plant_mass", [True, False])
def test_barriers_and_the_barrier_condition_are_28_and_29(plant_mass):
    """H1 (28), H2 (29), H = H1 + H2 and Ḣ + αH per row against the proof sketch of
    Theorem 2, with the module's documented choices: ideal weights 0 (W̃ = −Ŵ), scalar gains
    (Fo, F, G times I), 𝓔1 the declared E1, R of Theorem 1 (``r_of_theorem1``), M the
    plant's own when the trace has it, else the controller's model; Ḣ the backward difference
    (row 0 has none). Written with the weight matrices: σmax(Fo⁻¹)Z² − tr(W̃ᵀFo⁻¹W̃), and
    σmax(M) by SVD. Evaluated in three chunks, so the condition's first row of a chunk uses
    the previous chunk's H. Tolerance RTOL of H's scale."""
    rng = np.random.default_rng(13 + plant_mass)
    trace, raw = evaluation_case(rng, True, plant_mass)
    result = evaluated(trace, True)
    gains = {"Fo": 2.5, "F": 8.0, "G": 13.0}
    eps = SAFE.observer_error_bound

    def weight_term(bound: float, gain: float, w_hat: np.ndarray) -> np.ndarray:
        inverse = np.linalg.inv(gain * np.eye(w_hat.shape[1]))
        w_tilde = 0.0 - w_hat
        trace_term = np.einsum("kji,jl,kli->k", w_tilde, inverse, w_tilde)
        return np.linalg.norm(inverse, 2) * bound**2 - trace_term

    x1_err, x2_err = raw["q"] - raw["q_hat"], raw["qdot"] - raw["qdot_hat"]
    k0 = raw["k0"]
    h1 = 0.5 * ((k0 * eps**2 - k0 * np.einsum("ki,ki->k", x1_err, x1_err))
                + (eps**2 - np.einsum("ki,ki->k", x2_err, x2_err))
                + weight_term(SAFE.z_wo_tilde, gains["Fo"], raw["W_o"]))
    mass = raw["M_plant"] if plant_mass else raw["M_model"]
    r = raw["r_hat"]
    r_bound = r_of_theorem1(LAMBDA, SAFE.error_bound, SAFE.error_rate_bound)
    h2 = 0.5 * ((SAFE.error_bound**2 - np.einsum("ki,ki->k", raw["e"], raw["e"]))
                + (np.linalg.svd(mass, compute_uv=False)[:, 0] * r_bound**2
                   - np.einsum("ki,kij,kj->k", r, mass, r))
                + weight_term(SAFE.z_wc_tilde, gains["F"], raw["W_c"])
                + weight_term(SAFE.z_vc_tilde, gains["G"], raw["V_c"]))
    h = h1 + h2
    condition = np.concatenate(([np.nan], np.diff(h) / DT + SAFE.barrier_alpha * h[1:]))
    for name, value in {"H1": h1, "H2": h2, "H": h, "condition": condition}.items():
        got = result.barriers[name]
        assert np.isnan(got[0]) if name == "condition" else close(got[:1], value[:1]), name
        assert close(got[1:], value[1:]), name
    assert result.metrics["min_barrier_H"] == pytest.approx(h.min(), rel=RTOL)
    assert result.metrics["barrier_condition"]["fraction_failing"] == pytest.approx(
        np.mean(condition[1:] < 0), rel=RTOL)


def test_theorem1_quantities_are_their_formulas():
    """theorem1 at 100 random references, centres, bounds and per-joint Λ: E1, E2 of (14)
    read as |α − max_t‖q_s − q_d‖| (the L∞ over t inside: the reading under which
    ‖e‖ ≤ E1 ⇒ ‖q − q_s‖ ≤ α by the triangle inequality; the printed |α − ‖·‖|_{L∞} taken
    over t outside would give α − min_t‖·‖, too large), the declared E1, E2, R of
    ``r_of_theorem1``, and M_R − M_r = R as (15) defines R. Tolerance RTOL."""
    rng = np.random.default_rng(17)
    for _ in range(100):
        rows, n = 200, int(rng.integers(1, 4))
        q_d, qdot_d = rng.normal(size=(rows, n)) * 5, rng.normal(size=(rows, n)) * 5
        q_s, qdot_s = rng.normal(size=n), rng.normal(size=n)
        trace = {"q_d": q_d, "qdot_d": qdot_d, "q_s": np.tile(q_s, (rows, 1)),
                 "qdot_s": np.tile(qdot_s, (rows, 1))}
        safe = SafeSet(position_bound=rng.uniform(1, 30), velocity_bound=rng.uniform(1, 30),
                       error_bound=rng.uniform(0.1, 3), error_rate_bound=rng.uniform(0.5, 10))
        lam = rng.uniform(0.5, 20, n)
        got = theorem1(trace, safe, lam)
        distance = max(math.sqrt(sum(x * x for x in row)) for row in q_s - q_d)
        speed = max(math.sqrt(sum(x * x for x in row)) for row in qdot_s - qdot_d)
        r_bound = r_of_theorem1(lam, safe.error_bound, safe.error_rate_bound)
        assert got["E1_formula"] == pytest.approx(abs(safe.position_bound - distance), rel=RTOL)
        assert got["E2_formula"] == pytest.approx(abs(safe.velocity_bound - speed), rel=RTOL)
        assert (got["E1"], got["E2"]) == (safe.error_bound, safe.error_rate_bound)
        assert got["R"] == pytest.approx(r_bound, rel=RTOL)
        assert got["M_R"] - got["M_r"] == pytest.approx(r_bound, rel=RTOL)


def test_theorem1_m_r_is_15s():
    """(15): M_R = min{σmax(Λ)E1, E2}, at scalar Λ = αI (the paper's Λ = αI, so
    σmax = λmin and the two readings of Λ agree), both when σmax(Λ)E1 binds and when E2
    does. At the paper's numbers (Λ = 5 I, E1 = 1, E2 = 5) both give 5: the bug shows only
    when αE1 > E2."""
    trace = {"q_d": np.zeros((3, 2)), "qdot_d": np.zeros((3, 2)), "q_s": np.zeros((3, 2)),
             "qdot_s": np.zeros((3, 2))}
    for alpha, e1, e2 in [(5.0, 1.0, 5.0), (2.0, 1.0, 5.0), (10.0, 1.0, 5.0)]:
        got = theorem1(trace, SafeSet(error_bound=e1, error_rate_bound=e2), np.full(2, alpha))
        assert got["M_R"] == pytest.approx(min(alpha * e1, e2), rel=RTOL), (alpha, got)


def test_theorem1s_bound_on_r_keeps_the_error_sets_in_a_simulation():
    """What R promises, checked by integrating ė = −Λe + r̂ (SciPy RK45, rtol 1e-10) under the
    worst r̂ of norm R: first pushing e outwards (r̂ = R e/‖e‖, until ‖e‖ has settled at
    R/λmin), then turned to maximise ‖ė‖ (r̂ = −R Λe/‖Λe‖): ‖e‖ ≤ E1 and ‖ė‖ ≤ E2 throughout
    (within 1e-6 relative, the integration's error being ~1e-9), at 20 random per-joint Λ,
    E1, E2. And for scalar Λ the bound is tight: 1.01·R leaves the binding set by ~1 %."""
    rng = np.random.default_rng(19)

    def worst_case(lam: np.ndarray, r_norm: float) -> tuple[float, float]:
        n = len(lam)
        settle = 20.0 / float(np.min(lam))
        e0 = np.zeros(n)
        e0[np.argmin(lam)] = 1e-3 * r_norm  # along the slowest direction

        def outwards(_: float, e: np.ndarray) -> np.ndarray:
            return -lam * e + r_norm * e / np.linalg.norm(e)

        first = integrate.solve_ivp(outwards, (0, settle), e0, rtol=1e-10, atol=1e-13,
                                    t_eval=np.linspace(0, settle, 2001))
        e_settled = first.y[:, -1]
        e_max = float(np.max(np.linalg.norm(first.y, axis=0)))
        # ė at the turn: r̂ opposing Λe, the largest ‖ė‖ for that e
        r_turn = -r_norm * lam * e_settled / np.linalg.norm(lam * e_settled)
        edot_max = float(np.linalg.norm(-lam * e_settled + r_turn))
        edot_first = -lam[:, None] * first.y + r_norm * first.y / np.linalg.norm(first.y, axis=0)
        return e_max, max(edot_max, float(np.max(np.linalg.norm(edot_first, axis=0))))

    for _ in range(20):
        n = int(rng.integers(1, 4))
        lam, e1, e2 = rng.uniform(0.5, 20, n), rng.uniform(0.1, 3), rng.uniform(0.5, 10)
        e_max, edot_max = worst_case(lam, r_of_theorem1(lam, e1, e2))
        assert e_max <= e1 * (1 + 1e-6) and edot_max <= e2 * (1 + 1e-6), (lam, e1, e2)
    for alpha, e1, e2 in [(5.0, 1.0, 20.0), (5.0, 1.0, 5.0), (10.0, 1.0, 5.0)]:
        lam = np.full(2, alpha)
        e_max, edot_max = worst_case(lam, 1.01 * r_of_theorem1(lam, e1, e2))
        assert max(e_max / e1, edot_max / e2) >= 1.009, (alpha, e1, e2, e_max, edot_max)


# --------------------------------------------------------------------------------------------
# 6. The Wilson score interval


def test_wilson_interval_equals_scipys():
    """cosim.sweep.wilson(k, n) against scipy.stats.binomtest(k, n).proportion_ci(method=
    "wilson") for every k of small n and 40 k of each large n, k = 0 and k = n included: at
    the default z = 1.96 (SciPy at the confidence level 2Φ(1.96) − 1 it implies) and at
    z = Φ⁻¹(0.975) against SciPy's 95 %. Tolerance 1e-12 absolute (round-off of a few
    operations on numbers ≤ 1; measured ≤ 2e-16). n = 0 gives NaNs (SciPy refuses it)."""
    level_196 = 2 * stats.norm.cdf(1.96) - 1
    z_95 = float(stats.norm.ppf(0.975))
    cases = [(k, n) for n in (1, 2, 3, 5, 10, 11, 29, 40) for k in range(n + 1)]
    rng = np.random.default_rng(23)
    for n in (100, 122, 729, 1000, 3000, 10**6):
        cases += [(0, n), (1, n), (n - 1, n), (n, n)]
        cases += [(int(k), n) for k in rng.integers(0, n + 1, 36)]
    assert len(cases) > 300
    for k, n in cases:
        test = stats.binomtest(k, n)
        for (low, high), ci in [(wilson(k, n), test.proportion_ci(level_196, "wilson")),
                                (wilson(k, n, z=z_95), test.proportion_ci(0.95, "wilson"))]:
            assert low == pytest.approx(ci.low, abs=1e-12), (k, n)
            assert high == pytest.approx(ci.high, abs=1e-12), (k, n)
            assert 0.0 <= low <= high <= 1.0, (k, n)
    assert all(math.isnan(x) for x in wilson(0, 0))


def test_wilson_interval_contains_the_observed_proportion():
    """For k = 0 the Wilson interval starts at exactly 0 and for k = n it ends at exactly 1
    (centre = half analytically; SciPy sets them so), and every interval contains k/n:
    every (k, n) with n < 300 at the default z."""
    for n in range(1, 300):
        assert wilson(0, n)[0] == 0.0 and wilson(n, n)[1] == 1.0, n
        for k in range(n + 1):
            low, high = wilson(k, n)
            assert low <= k / n <= high, (k, n)
