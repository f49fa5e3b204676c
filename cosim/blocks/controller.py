"""Two-layer NN tracking controller, eqs. (21)–(26), in two variants:

- ``baseline`` (Lewis 1999): full state, ė = q̇_d − q̇ with the true q̇ from the plant,
  robust term v = −Kz(‖Ẑ‖_F + Z_B) r;
- ``proposed`` (Theorem 2): output feedback, ė̂ = q̇_d − x̂2 from the observer, and v_c of
  (27), whose scalar middle term multiplies r̂ (a smooth sign):

    v_c = −Kz(‖Ẑ‖_F + Z_Wc) r̂ − [κ(Z_Wc + C1/κ)²/4 + C0] r̂ / √(δ + ‖r̂‖²) − e
          − ψ_B² r̂ / (δ + ‖r̂‖²).

τ = Ŵᵀσ̂(V̂ᵀξ) + Kv r̂ − v, ξ = [1; e; ė; q_d; q̇_d; q̈_d], σ̂ = [1; σ(V̂ᵀξ)] (logistic),
σ̂' = [0; diag(σ(1 − σ))]. Weights follow (25)–(26) with σ̂' in (26) (as in Lewis; the
printed σ̂ does not make the dimensions agree), integrated by Euler at the master rate with
the κ‖r̂‖ decay terms implicit so that they never overshoot. Weights start at zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..trace import Trace

VARIANTS = ("baseline", "proposed")


@njit(cache=True)
def _controller_step(k, dt, proposed, p, lam, kv, s, hidden, y, vel, q_d, qd_d, qdd_d,
                     tau, e_out, edot_out, r_out, nn_out, v_out, w_norm_out, v_norm_out):
    n = y.shape[1]
    f_gain, g_gain, kappa, kz, z_w, c0, c1, delta, psi_b = (p[0], p[1], p[2], p[3], p[4],
                                                            p[5], p[6], p[7], p[8])
    n_in = 1 + 5 * n
    W = s[0:(hidden + 1) * n].reshape((hidden + 1, n))
    V = s[(hidden + 1) * n:(hidden + 1) * n + n_in * hidden].reshape((n_in, hidden))

    e = q_d[k] - y[k]
    edot = qd_d[k] - vel[k]
    r = edot + lam * e
    xi = np.empty(n_in)
    xi[0] = 1.0
    xi[1:1 + n] = e
    xi[1 + n:1 + 2 * n] = edot
    xi[1 + 2 * n:1 + 3 * n] = q_d[k]
    xi[1 + 3 * n:1 + 4 * n] = qd_d[k]
    xi[1 + 4 * n:1 + 5 * n] = qdd_d[k]
    a = V.T @ xi
    sig = 1.0 / (1.0 + np.exp(-a))
    sig_hat = np.empty(hidden + 1)
    sig_hat[0] = 1.0
    sig_hat[1:] = sig
    dsig = sig * (1.0 - sig)  # σ̂' without its zero bias row
    f_hat = W.T @ sig_hat

    w_norm = np.sqrt(np.sum(W**2))
    v_norm = np.sqrt(np.sum(V**2))
    z_norm = np.sqrt(w_norm**2 + v_norm**2)  # ‖Ẑ‖_F, Ẑ = diag(V̂, Ŵ)
    r_sq = np.sum(r**2)
    r_norm = np.sqrt(r_sq)
    v = -kz * (z_norm + z_w) * r
    if proposed:  # eq. (27)
        v -= (kappa * (z_w + c1 / kappa) ** 2 / 4.0 + c0) / np.sqrt(delta + r_sq) * r
        v -= e
        v -= psi_b**2 / (delta + r_sq) * r
    torque = f_hat + kv * r - v

    tau[k] = torque
    e_out[k] = e
    edot_out[k] = edot
    r_out[k] = r
    nn_out[k] = f_hat
    v_out[k] = v
    w_norm_out[k] = w_norm
    v_norm_out[k] = v_norm

    # (25)-(26) over [t_k, t_k+1)
    s_prime_a = np.zeros(hidden + 1)
    s_prime_a[1:] = dsig * a  # σ̂' V̂ᵀ ξ
    w_r = W @ r
    back = dsig * w_r[1:]  # σ̂'ᵀ Ŵ r̂
    W[:, :] = (W + dt * f_gain * np.outer(sig_hat - s_prime_a, r)) / (1.0 + dt * kappa
                                                                      * f_gain * r_norm)
    V[:, :] = (V + dt * g_gain * np.outer(xi, back)) / (1.0 + dt * kappa * g_gain * r_norm)
    return np.isfinite(np.sum(torque) + w_norm + v_norm)


@dataclass
class NnController:
    """Parameters: Kv [N·m·s/rad], Λ [1/s], F, G (scalars × I), κ, Kz, Z_B or Z_Wc, C0, C1,
    δ, ψ_B, hidden width. Vectors may be given per joint or as one scalar."""

    variant: str = "proposed"
    kv: float | list[float] = 20.0
    lam: float | list[float] = 5.0  # Λ
    f: float = 10.0  # F
    g: float = 12.0  # G
    kappa: float = 0.1
    kz: float = 5.0
    z_b: float = 10.0  # baseline's bound on ‖Z‖ (Lewis)
    z_wc: float = 10.0  # proposed's Z_Wc in (27)
    c0: float = 150.0
    c1: float = 0.1
    delta: float = 1.0
    psi_b: float = 20.0
    hidden: int = 10
    name: str = "controller"

    def reset(self, trace: Trace) -> None:
        n = trace.links
        self._lam = np.broadcast_to(np.asarray(self.lam, float), (n,)).copy()
        self._kv = np.broadcast_to(np.asarray(self.kv, float), (n,)).copy()
        z_w = self.z_b if self.variant == "baseline" else self.z_wc
        self._p = np.array([self.f, self.g, self.kappa, self.kz, z_w, self.c0, self.c1,
                            self.delta, self.psi_b])
        n_in = 1 + 5 * n
        self._s = np.zeros((self.hidden + 1) * n + n_in * self.hidden)
        velocity = trace["qdot"] if self.variant == "baseline" else trace["qdot_hat"]
        position = trace["q"] if self.variant == "baseline" else trace["q_meas"]
        self._proposed = self.variant == "proposed"
        self._dt = trace.dt
        self._args = (position, velocity, trace["q_d"], trace["qdot_d"], trace["qddot_d"],
                      trace["tau"], trace["e"], trace["edot"], trace["r_hat"],
                      trace["nn_output"], trace["v_c"], trace["W_norm"], trace["V_norm"])

    def step(self, k: int) -> bool:
        return _controller_step(k, self._dt, self._proposed, self._p, self._lam, self._kv,
                                self._s, self.hidden, *self._args)
