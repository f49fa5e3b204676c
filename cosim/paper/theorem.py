"""Theorem 1's quantities and barrier functions H1 (28), H2 (29), from a run's rows
(vectorised): E1, E2, M_R, M_r and R of (14)-(15), the barriers and their condition
Ḣ + αH ≥ 0, and the controller's effective feedback gain.

Ground truth (true q̇, true observer error) is used here for evaluation only, never for control.
The ideal NN weights in (28)–(29) are unknown; W̃ = W_ideal − Ŵ is evaluated with
W_ideal = 0, so tr(W̃ᵀF⁻¹W̃) = ‖Ŵ‖²_F / F for the scalar gains F, G, Fo used here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..evaluate.safety import SafeSet, Signals
from .barrier_bounds import barrier_bounds


@dataclass
class Gains:
    """The controller/observer gains the barriers need."""

    Lambda: np.ndarray  # (n,)
    F: float
    G: float
    Fo: float
    output_feedback: bool  # proposed (x̂2) or full state (q̇)


def theorem1(trace: Signals, safe: SafeSet, lam: np.ndarray) -> dict[str, float]:
    """E1, E2 by their formulas in (14), and R = M_R − M_r, the bound on ‖r̂‖ of (15)
    under which ‖e‖ ≤ E1 and ‖ė‖ ≤ E2 (our reading: ‖e‖ ≤ R/λmin(Λ), ‖ė‖ ≤ R + λmax‖e‖)."""
    dq = np.linalg.norm(trace["q_s"] - trace["q_d"], axis=1).max()
    dv = np.linalg.norm(trace["qdot_s"] - trace["qdot_d"], axis=1).max()
    lmin, lmax = float(np.min(lam)), float(np.max(lam))
    m_big = min(lmax * safe.error_bound, safe.error_rate_bound)  # M_R of (15), as printed
    r_bound = min(lmin * safe.error_bound, safe.error_rate_bound * lmin / (lmin + lmax))
    return {"E1_formula": abs(safe.position_bound - dq),
            "E2_formula": abs(safe.velocity_bound - dv), "E1": safe.error_bound,
            "E2": safe.error_rate_bound, "M_R": m_big,
            "M_r": m_big - r_bound, "R": r_bound}


BARRIERS = ("H1", "H2", "H")
# What each barrier series in a trace file is; the paper's barriers mix units (k0·ε², ‖Ŵ‖²/F,
# rᵀMr), so they carry none.
BARRIER_MEANINGS = {"H1": "H1 of (28): the observer's barrier (mixed units)",
                    "H2": "H2 of (29): the controller's barrier (mixed units)",
                    "H": "H = H1 + H2 (mixed units)",
                    "condition": "dH/dt + α·H per row, ≥ 0 where the condition holds (1/s × H)"}


def barriers(trace: Signals, safe: SafeSet, gains: Gains,
             r_bound: float | None = None) -> dict[str, np.ndarray]:
    """H1 (28), H2 (29) and H = H1 + H2 per row (``r_bound``: R of Theorem 1, default: from
    these rows' reference)."""
    bounds = barrier_bounds(safe)
    eps = bounds.observer_error_bound
    x1_err = np.sum((trace["q"] - trace["q_hat"]) ** 2, axis=1)
    x2_err = np.sum((trace["qdot"] - trace["qdot_hat"]) ** 2, axis=1)
    k0 = trace["k0"]
    h1 = 0.5 * ((k0 * eps**2 - k0 * x1_err) + (eps**2 - x2_err)
                + (bounds.z_wo_tilde**2 - trace["W_o_norm"] ** 2) / gains.Fo)
    r = trace["r_hat"]
    # The plant's own M(q) when its FMU outputs it, else the controller's model of it.
    mass = trace["M"] if np.isfinite(trace["M"]).all() else trace["M_model"]
    sigma_max = np.linalg.eigvalsh(mass)[:, -1]
    r_m_r = np.einsum("ki,kij,kj->k", r, mass, r)
    if r_bound is None:
        r_bound = theorem1(trace, safe, gains.Lambda)["R"]
    h2 = 0.5 * ((safe.error_bound**2 - np.sum(trace["e"] ** 2, axis=1))
                + (sigma_max * r_bound**2 - r_m_r)
                + (bounds.z_wc_tilde**2 - trace["W_norm"] ** 2) / gains.F
                + (bounds.z_vc_tilde**2 - trace["V_norm"] ** 2) / gains.G)
    return {"H1": h1, "H2": h2, "H": h1 + h2}


def barrier_condition(h: np.ndarray, previous: float, dt: float, alpha: float) -> np.ndarray:
    """Ḣ + α·H per row, Ḣ the backward difference (H_k − H_k−1)/h; ``previous`` is the row
    before the first (NaN at the start of a run: that row has no condition)."""
    before = np.concatenate(([previous], h[:-1]))
    return (h - before) / dt + alpha * h


def condition_summary(condition: np.ndarray, alpha: float) -> dict:
    """The barrier condition Ḣ + α·H ≥ 0 over the rows that have one."""
    valid = condition[np.isfinite(condition)]
    return {"alpha": alpha, "worst": float(np.min(valid)) if len(valid) else None,
            "fraction_failing": float(np.mean(valid < 0)) if len(valid) else None}


def barrier_terms_failing(trace: Signals, h: Mapping[str, np.ndarray], safe: SafeSet) -> dict:
    """The barrier condition per term: Ḣ1 + αH1 and Ḣ2 + αH2 on their own, and H's without
    the rate of the observer gain k0 in H1's ½k0(ε² − ‖x̃1‖²), i.e. ½k̇0(ε² − ‖x̃1‖²): the
    term that makes H's condition fail when k0 moves (fractions of steps failing)."""
    bounds = barrier_bounds(safe)
    dt, alpha = trace.dt, bounds.barrier_alpha
    if len(h["H"]) < 2:
        return {}

    def failing(values: np.ndarray) -> float | None:
        values = values[np.isfinite(values)]
        return float(np.mean(values < 0)) if len(values) else None

    def condition(series: np.ndarray) -> np.ndarray:
        return np.diff(series) / dt + alpha * series[1:]

    x1_err = np.sum((trace["q"] - trace["q_hat"]) ** 2, axis=1)
    k0_rate = np.diff(trace["k0"]) / dt * 0.5 * (bounds.observer_error_bound**2 - x1_err[1:])
    return {"H1": failing(condition(h["H1"])), "H2": failing(condition(h["H2"])),
            "H_without_k0_rate": failing(condition(h["H"]) - k0_rate),
            "k0_rate_term": "½·dk0/dt·(ε_max² − ‖x̃1‖²), of H1's ½k0(ε_max² − ‖x̃1‖²)"}


def gain_summary(trace: Signals) -> dict | None:
    """The controller's effective feedback gain on r̂, ‖τ_feedback‖/‖r̂‖ (N·m·s/rad), over
    the rows where ‖r̂‖ is not negligible: how much of a result is gain."""
    if "feedback_gain" not in trace:
        return None
    r = np.linalg.norm(trace["r_hat"], axis=1)
    gain = trace["feedback_gain"][r > 1e-6 * max(float(np.max(r, initial=0.0)), 1e-300)]
    if not len(gain):
        return None
    return {"median": float(np.median(gain)), "p95": float(np.percentile(gain, 95)),
            "max": float(np.max(gain))}
