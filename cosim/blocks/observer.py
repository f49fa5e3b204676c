"""FLNN velocity observer, eqs. (5)–(10), gain k0 from (8), weight law (24) or error-driven.

The observer is integrated in its z form (7)/(9), which needs only the measured position y:

    x̂1' = x̂2 + kD x̃1,   ẑ2' = Ŵoᵀ σo(x̂) + M⁻¹(τ − τ_d) + k0 x̃1,   x̂2 = ẑ2 + kp x̃1,

with x̃1 = y − x̂1. When ν is small k0 exceeds 10⁴ and the output injection is stiff, so each
sub-step treats the linear part (x̂1, ẑ2) by backward Euler, which is L-stable for every k0
(it cannot blow up, it only damps), and the NN and torque terms explicitly. y is interpolated
linearly between the two samples that bound the master step.

Basis choices for the printed σo = [q̂; q̂̇; q̂̈; |q̂|; |q̂̇|], whose q̂̈ closes an algebraic
loop: "lagged" uses q̂̈ from the previous sub-step; "no_acceleration" drops it.
Weight laws: "paper" is (24) as printed, Ŵo' = Fo(κo·1 − Ŵo), which has no error signal;
"error_driven" is Kim & Lewis's Ŵo' = Fo σo x̃1ᵀ − κo Fo ‖x̃1‖ Ŵo.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..trace import Trace

LAWS = {"paper": 0, "error_driven": 1}
BASES = {"lagged": 0, "no_acceleration": 1}


def basis_size(links: int, basis: str) -> int:
    return (5 if basis == "lagged" else 4) * links


@njit(cache=True)
def _basis(x1, x2, qdd, basis, out):
    n = x1.shape[0]
    out[0:n] = x1
    out[n:2 * n] = x2
    k = 2 * n
    if basis == 0:
        out[k:k + n] = qdd
        k += n
    out[k:k + n] = np.abs(x1)
    out[k + n:k + 2 * n] = np.abs(x2)


@njit(cache=True)
def _gain(p, n_basis, x1_err_norm, w_norm, e_norm):
    """k0 of eq. (8)."""
    kp, kd, nu, z_wo, eps_sum = p[0], p[1], p[2], p[3], p[4]
    num = kp * kd * x1_err_norm + np.sqrt(n_basis) * (z_wo + w_norm) + eps_sum + e_norm
    den = 2.0 * np.sqrt(kp * kd) * (x1_err_norm * x1_err_norm + nu)
    return (num / den) ** 2


@njit(cache=True)
def _observer_step(k, dt, substeps, law, basis, p, tau_d, s, n_basis, q_meas, tau, mass,
                   q_d, q_hat, qdot_hat, k0_out, w_norm_out):
    n = q_meas.shape[1]
    kp, kd, fo, kappa_o = p[0], p[1], p[5], p[6]
    c = kp + kd
    x1 = s[0:n]
    z2 = s[n:2 * n]
    qdd = s[2 * n:3 * n]
    W = s[3 * n:3 * n + n_basis * n].reshape((n_basis, n))
    sigma = np.empty(n_basis)
    if k > 0:  # integrate over [t_{k-1}, t_k] under the torque held over that interval
        y0 = q_meas[k - 1]
        dy = q_meas[k] - y0
        torque_term = np.linalg.solve(mass[k - 1], tau[k - 1] - tau_d)
        e_norm = np.sqrt(np.sum((q_d[k - 1] - y0) ** 2))
        h = dt / substeps
        for j in range(substeps):
            y = y0 + dy * ((j + 1) / substeps)
            x1_err = y - x1
            x1_err_norm = np.sqrt(np.sum(x1_err**2))
            x2 = z2 + kp * x1_err
            k0 = _gain(p, n_basis, x1_err_norm, np.sqrt(np.sum(W**2)), e_norm)
            _basis(x1, x2, qdd, basis, sigma)
            g = W.T @ sigma + torque_term
            denom = 1.0 + h * c + h * h * k0
            x1_new = (x1 + h * z2 + h * h * g + (h * c + h * h * k0) * y) / denom
            z2_new = z2 + h * (g + k0 * (y - x1_new))
            qdd[:] = (z2_new + kp * (y - x1_new) - x2) / h
            if law == 0:  # (24): exact solution of Ŵo' = Fo(κo·1 − Ŵo) over h
                decay = np.exp(-fo * h)
                W[:, :] = kappa_o + (W - kappa_o) * decay
            else:  # error-driven, decay term implicit so it never overshoots
                W[:, :] = (W + h * fo * np.outer(sigma, x1_err)) / (1.0 + h * kappa_o * fo
                                                                   * x1_err_norm)
            x1[:] = x1_new
            z2[:] = z2_new
    y = q_meas[k]
    x1_err = y - x1
    x1_err_norm = np.sqrt(np.sum(x1_err**2))
    w_norm = np.sqrt(np.sum(W**2))
    q_hat[k] = x1
    qdot_hat[k] = z2 + kp * x1_err
    k0_out[k] = _gain(p, n_basis, x1_err_norm, w_norm, np.sqrt(np.sum((q_d[k] - y) ** 2)))
    w_norm_out[k] = w_norm
    return np.isfinite(np.sum(qdot_hat[k]) + np.sum(x1) + w_norm)


@dataclass
class FlnnObserver:
    """Parameters: kp, kD [1/s], ν, Z_Wo, ε_oM, ζ_oM, Fo, κo; see eqs. (8) and (24)."""

    kp: float = 100.0
    kd: float = 100.0  # kD
    nu: float = 5e-4  # ν
    z_wo: float = 10.0  # Z_Wo
    eps_om: float = 1.0  # ε_oM
    zeta_om: float = 1.0  # ζ_oM
    fo: float = 1.0  # Fo
    kappa_o: float = 6.0  # κo
    law: str = "error_driven"
    basis: str = "no_acceleration"
    substeps: int = 10
    tau_d: tuple[float, ...] | float = 0.01  # disturbance assumed known in (7), N·m
    initial_velocity: str | list[float] = "desired"  # "desired" (q̇_d(0)), "zero", or values
    name: str = "observer"

    def reset(self, trace: Trace) -> None:
        n = trace.links
        self._n_basis = basis_size(n, self.basis)
        self._p = np.array([self.kp, self.kd, self.nu, self.z_wo, self.eps_om + self.zeta_om,
                            self.fo, self.kappa_o])
        self._tau_d = np.broadcast_to(np.asarray(self.tau_d, float), (n,)).copy()
        self._s = np.zeros(3 * n + self._n_basis * n)  # x̂1, ẑ2, q̂̈, Ŵo (weights start at 0)
        self._trace = trace
        self._modes = (trace.dt, self.substeps, LAWS[self.law], BASES[self.basis])
        self._args = (trace["q_meas"], trace["tau"], trace["M_model"], trace["q_d"], trace["q_hat"],
                      trace["qdot_hat"], trace["k0"], trace["W_o_norm"])
        self._started = False

    def _initialise(self, trace: Trace) -> None:
        n = trace.links
        self._s[0:n] = trace["q_meas"][0]  # x̂1(0) = y(0): x̃1(0) = 0
        if isinstance(self.initial_velocity, str):
            v0 = trace["qdot_d"][0] if self.initial_velocity == "desired" else np.zeros(n)
        else:
            v0 = np.asarray(self.initial_velocity, float)
        self._s[n:2 * n] = v0
        self._started = True

    def step(self, k: int) -> bool:
        if not self._started:
            self._initialise(self._trace)
        return _observer_step(k, *self._modes, self._p, self._tau_d, self._s, self._n_basis,
                              *self._args)
