"""FLNN velocity observer, eqs. (5)–(10), gain k0 from (8), weight law (24) or error-driven.

The observer is integrated in its z form (7)/(9), which needs only the measured position y:

    x̂1' = x̂2 + kD x̃1,   ẑ2' = Ŵoᵀ σo(x̂) + M⁻¹(τ − τ_d) + k0 x̃1,   x̂2 = ẑ2 + kp x̃1,

with x̃1 = y − x̂1. When ν is small k0 exceeds 10⁴ and the output injection is stiff, so each
sub-step treats the linear part (x̂1, ẑ2) by backward Euler, which is L-stable for every k0
(it cannot blow up, it only damps), and the NN and torque terms explicitly. y is interpolated
linearly between the two samples that bound the master step; a sub-step's σo, k0 and the
error-driven weight law are evaluated with the old x̂1 and the sub-step's *end* measurement
y_{j+1} (consistent first order; tests/test_references.py checks the scheme as written and
its convergence to the continuous law).

Basis choices for the printed σo = [q̂; q̂̇; q̂̈; |q̂|; |q̂̇|], whose q̂̈ closes an algebraic
loop: "lagged" uses q̂̈ from the previous sub-step; "no_acceleration" drops it.
Weight laws: "paper" is (24) as printed, Ŵo' = Fo(κo·1 − Ŵo), which has no error signal;
"error_driven" is Kim & Lewis's Ŵo' = Fo σo x̃1ᵀ − κo Fo ‖x̃1‖ Ŵo.

**The bound ε(t) on |q̇ − x̂2|** (``qdot_hat_bound``) is certified beside the FLNN, from a
velocity interval the loop proves (:mod:`cosim.paper.envelope`), whatever x̂2 does.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ..blocks.binding import master_step, parameter, reads, scratch, uncertainty, writes
from ..records import kernel_record
from .envelope import Envelope, envelope_position, envelope_step
from .linalg import solve


def basis_size(links: int, basis: str) -> int:
    return (5 if basis == "lagged" else 4) * links


@kernel_record
class ObserverArgs(NamedTuple):
    dt: master_step()  # s
    substeps: parameter()
    law: int  # LAWS (cosim.paper.observer_block)
    basis: int  # BASES
    kp: parameter()
    kd: parameter()
    nu: parameter()
    z_wo: parameter()
    eps_sum: float  # ε_oM + ζ_oM
    kp_kd: float  # kp kD, √No and 2√(kp kD): (8)'s constant factors, once
    sqrt_basis: float
    den_scale: float
    fo: parameter()
    kappa_o: parameter()
    n_basis: int
    tau_d: parameter()  # (n,) N·m
    initial_velocity: np.ndarray  # (n,) x̂2(0)
    noise_bound: uncertainty()  # declared |q_meas − q|, rad
    initial_error: uncertainty("initial_velocity_error")  # declared |q̇(0) − x̂2(0)|, rad/s
    state: scratch("3 * n + n_basis * n")  # x̂1, ẑ2, q̂̈, Ŵo (n_basis × n), flat; Ŵo from 0
    q_meas: reads()
    tau: reads()
    M_model: reads()
    q_d: reads()
    q_hat: writes()
    qdot_hat: writes()
    k0: writes()
    W_o_norm: writes()
    error_bound: writes("qdot_hat_bound")  # ε(t) per joint
    envelope_centre: writes("qdot_envelope_centre")  # the certified interval's centre c
    drift: writes("qdot_hat_drift")  # dx̂2/dt − M̂⁻¹τ
    # scratch, so that a step allocates nothing
    sigma: scratch("n_basis")  # σo
    y: scratch("n")
    x1_err: scratch("n")  # x̃1
    x2: scratch("n")  # x̂2
    g: scratch("n")  # Ŵoᵀσo (+ M̂⁻¹τ)
    torque_term: scratch("n, 1")  # M̂⁻¹(τ − τ_d), the solve's right-hand side
    lu: scratch("n, n")  # M̂'s elimination
    env: Envelope  # the certified velocity envelope behind ε(t)


@njit(cache=True)
def error_envelope(kp, kd, k0):
    """The frozen-time error dynamics of (12), x̃1' = w, w' = −k0 x̃1 − (kp + kD) w + f̃, with
    w = x̃1' = x̃2 − kD x̃1: (decay rate of the slowest mode (1/s), peak factor of w's free
    response to w(0) (≥ 1), L1 norm of the impulse response from f̃' to w (s²)).
    Not what ε(t) rests on any more (cosim.paper.envelope): a frozen-time envelope is no proof
    while k0 moves, and its forcing's rate is the closed loop's; kept as the analysis
    docs/safety/filter.md describes."""
    sigma = 0.5 * (kp + kd)
    if k0 > sigma * sigma:  # complex poles −σ ± jω: |w| ≤ w0·√k0/ω·e^{−σt}
        omega = np.sqrt(k0 - sigma * sigma)
        ratio = sigma * np.pi / (2.0 * omega)  # ∫|e^{−σt} sin ωt/ω| dt = coth(σπ/2ω)/k0
        return sigma, np.sqrt(k0) / omega, 1.0 / (np.tanh(ratio) * k0)
    root = np.sqrt(sigma * sigma - k0)  # real poles −σ ± root: a positive impulse response
    slow, fast = sigma - root, sigma + root
    peak = (slow + fast) / max(fast - slow, 1e-12)
    return slow, max(peak, 1.0), 1.0 / max(k0, 1e-300)


@njit(cache=True)
def _basis(x1, x2, qdd, basis, out):
    """σo = [x̂1; x̂2; q̂̈ (basis "lagged" only); |x̂1|; |x̂2|] into ``out``."""
    n = x1.shape[0]
    k = 3 * n if basis == 0 else 2 * n  # where |x̂1| starts
    for i in range(n):
        out[i] = x1[i]
        out[n + i] = x2[i]
        if basis == 0:
            out[2 * n + i] = qdd[i]
        out[k + i] = abs(x1[i])
        out[k + n + i] = abs(x2[i])


@njit(cache=True)
def _gain(a, x1_err_norm, w_norm, e_norm):
    """k0 of eq. (8)."""
    num = a.kp_kd * x1_err_norm + a.sqrt_basis * (a.z_wo + w_norm) + a.eps_sum + e_norm
    den = a.den_scale * (x1_err_norm * x1_err_norm + a.nu)
    return (num / den) ** 2


@njit(cache=True)
def _distance(u, v):
    """‖u − v‖, summed in index order (as np.sum would)."""
    total = 0.0
    for i in range(u.shape[0]):
        d = u[i] - v[i]
        total += d * d
    return np.sqrt(total)


@njit(cache=True)
def _weights_times(W, sigma, out):
    """out = Ŵoᵀσo, as loops: a BLAS call per sub-step costs more than its 2·No·n flops."""
    for i in range(out.shape[0]):
        total = 0.0
        for b in range(sigma.shape[0]):
            total += W[b, i] * sigma[b]
        out[i] = total


@njit(cache=True, inline="always")
def _state(a):
    """Views of the observer's flat state: x̂1, ẑ2, q̂̈ (n each) and Ŵo (n_basis × n)."""
    n, n_basis, s = a.q_meas.shape[1], a.n_basis, a.state
    return s[0:n], s[n:2 * n], s[2 * n:3 * n], s[3 * n:3 * n + n_basis * n].reshape((n_basis, n))


@njit(cache=True)
def observer_step(k, a):
    """One step of the observer (5)–(10), (24): its sub-steps, gain and weight law in one
    body, which its speed needs (the sub-step loop shares its scratch and hoisted
    constants; split, numba would pass them through the calls)."""
    n = a.q_meas.shape[1]
    n_basis = a.n_basis
    kp = a.kp
    c = kp + a.kd
    x1, z2, qdd, W = _state(a)
    sigma, y, x1_err, x2, g = a.sigma, a.y, a.x1_err, a.x2, a.g  # scratch
    w_sq = 0.0  # ‖Ŵo‖², kept up to date by the weight law's loop below
    for b in range(n_basis):
        for i in range(n):
            w_sq += W[b, i] * W[b, i]
    if k == 0:  # x̂1(0) = y(0): x̃1(0) = 0; x̂2(0) as configured
        x1[:] = a.q_meas[0]
        z2[:] = a.initial_velocity
    else:  # integrate over [t_{k-1}, t_k] under the torque held over that interval
        y0 = a.q_meas[k - 1]
        y1 = a.q_meas[k]
        torque_term = a.torque_term
        for i in range(n):
            torque_term[i, 0] = a.tau[k - 1, i] - a.tau_d[i]
        solve(a.M_model[k - 1], torque_term, a.lu)  # M̂⁻¹(τ − τ_d), held over the step
        e_norm = _distance(a.q_d[k - 1], y0)
        h = a.dt / a.substeps
        # What no sub-step changes, once: the implicit part's coefficients h(kp + kD), h², and
        # the weight law's decay factor e^{−Fo h} (24) or its gains h Fo, h κo Fo.
        hc = h * c
        hh = h * h
        w_decay = np.exp(-a.fo * h)
        h_fo = h * a.fo
        h_kappa_fo = h * a.kappa_o * a.fo
        for j in range(a.substeps):
            frac = (j + 1) / a.substeps
            err_sq = 0.0
            for i in range(n):
                y[i] = y0[i] + (y1[i] - y0[i]) * frac
                x1_err[i] = y[i] - x1[i]
                err_sq += x1_err[i] * x1_err[i]
                x2[i] = z2[i] + kp * x1_err[i]
            x1_err_norm = np.sqrt(err_sq)
            k0 = _gain(a, x1_err_norm, np.sqrt(w_sq), e_norm)
            _basis(x1, x2, qdd, a.basis, sigma)
            _weights_times(W, sigma, g)
            # backward Euler of the linear part: (1 + h(kp + kD) + h²k0) x̂1⁺ = x̂1 + h ẑ2
            # + h² g + (h(kp + kD) + h²k0) y, then ẑ2⁺ = ẑ2 + h(g + k0 (y − x̂1⁺))
            denom = 1.0 + hc + hh * k0
            gain_y = hc + hh * k0
            for i in range(n):
                g[i] += torque_term[i, 0]
                x1_new = (x1[i] + h * z2[i] + hh * g[i] + gain_y * y[i]) / denom
                z2_new = z2[i] + h * (g[i] + k0 * (y[i] - x1_new))
                qdd[i] = (z2_new + kp * (y[i] - x1_new) - x2[i]) / h
                x1[i] = x1_new
                z2[i] = z2_new
            w_sq = 0.0
            if a.law == 0:  # (24): exact solution of Ŵo' = Fo(κo·1 − Ŵo) over h
                for b in range(n_basis):
                    for i in range(n):
                        W[b, i] = a.kappa_o + (W[b, i] - a.kappa_o) * w_decay
                        w_sq += W[b, i] * W[b, i]
            else:  # error-driven, decay term implicit so it never overshoots
                shrink = 1.0 + h_kappa_fo * x1_err_norm
                for b in range(n_basis):
                    for i in range(n):
                        W[b, i] = (W[b, i] + h_fo * (sigma[b] * x1_err[i])) / shrink
                        w_sq += W[b, i] * W[b, i]
    return _publish(k, a, w_sq)


@njit(cache=True, inline="always")
def _publish(k, a, w_sq):
    """The observer's outputs at t_k from its state there (``w_sq``: ‖Ŵo‖²): x̂1, x̂2, k0,
    ‖Ŵo‖, the certified bound ε(t) and the envelope's centre, and x̂2's drift; False where
    the state is not finite."""
    n = a.q_meas.shape[1]
    kp = a.kp
    x1, z2, qdd, W = _state(a)
    sigma, x1_err, g = a.sigma, a.x1_err, a.g  # scratch
    y_k = a.q_meas[k]
    err_sq = 0.0
    for i in range(n):
        x1_err[i] = y_k[i] - x1[i]
        err_sq += x1_err[i] * x1_err[i]
    w_norm = np.sqrt(w_sq)
    k0 = _gain(a, np.sqrt(err_sq), w_norm, _distance(a.q_d[k], y_k))
    qdot_hat = a.qdot_hat[k]
    for i in range(n):
        a.q_hat[k, i] = x1[i]
        qdot_hat[i] = z2[i] + kp * x1_err[i]
    a.k0[k] = k0
    a.W_o_norm[k] = w_norm
    # ε(t) from the certified envelope q̇(t_k) ∈ [lo, hi] (cosim.paper.envelope): whatever x̂2
    # is, |q̇ − x̂2| ≤ |x̂2 − c| + r with c, r the interval's centre and half-width.
    env = a.env
    interval = env.hull
    if k == 0:  # the declared initial error around x̂2(0), every payload cell alive
        envelope_position(env, y_k, 0)
        for i in range(n):
            interval[0, i] = qdot_hat[i] - a.initial_error
            interval[1, i] = qdot_hat[i] + a.initial_error
        for cell in range(env.alive.shape[0]):
            env.alive[cell] = 1.0
            env.since[cell] = 0
            for i in range(n):
                env.interval[cell, 0, i] = interval[0, i]
                env.interval[cell, 1, i] = interval[1, i]
                env.rho[cell, i] = 0.0
    else:
        envelope_step(k, a.dt, a.q_meas, a.tau[k - 1], a.tau_d, a.noise_bound, env)
    for i in range(n):
        low, high = interval[0, i], interval[1, i]
        if np.isfinite(low) and np.isfinite(high):
            centre = 0.5 * (low + high)
            a.error_bound[k, i] = abs(qdot_hat[i] - centre) + 0.5 * (high - low)
        else:  # no enclosure confirmed: nothing is known of q̇ (ε infinite, never NaN)
            centre = qdot_hat[i]
            a.error_bound[k, i] = np.inf
        a.envelope_centre[k, i] = centre
    # dx̂2/dt = Ŵoᵀσo + M̂⁻¹(τ − τ_d) + (k0 − kp kD) x̃1 + kp x̃2: all but M̂⁻¹τ and the
    # unknown kp x̃2 (|·| ≤ kp ε) is the drift the filter's rows on x̂2 need.
    _basis(x1, qdot_hat, qdd, a.basis, sigma)
    _weights_times(W, sigma, g)
    disturbance = a.torque_term  # the step's M̂⁻¹(τ − τ_d) is spent: its array is free
    for i in range(n):
        disturbance[i, 0] = a.tau_d[i]
    solve(a.M_model[k], disturbance, a.lu)  # M̂⁻¹τ_d
    finite = 0.0
    for i in range(n):
        a.drift[k, i] = g[i] - disturbance[i, 0] + (k0 - kp * a.kd) * x1_err[i]
        finite += qdot_hat[i] + x1[i]
    return np.isfinite(finite + w_norm)
