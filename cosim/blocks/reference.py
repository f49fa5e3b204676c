"""Desired trajectory q_d(t) as sums of sinusoids, with analytic derivatives, and the safe
trajectories q_s, q̇_s of Remark 1 (case i: q_s = q_d; case ii: constant midpoints)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..trace import Trace


@dataclass
class SinusoidReference:
    """q_d,i(t) = offset_i + Σ_j amplitude_ij sin(frequency_ij t + phase_ij), rad, rad/s."""

    offset: np.ndarray  # (n,)
    amplitude: np.ndarray  # (n, m)
    frequency: np.ndarray  # (n, m), rad/s
    phase: np.ndarray  # (n, m), rad
    safe_case: str = "midpoint"  # "tracking" (case i) or "midpoint" (case ii)
    name: str = "reference"

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q_d, q̇_d, q̈_d at the times t (shape (len(t), n) each)."""
        arg = t[:, None, None] * self.frequency[None] + self.phase[None]
        a, w = self.amplitude[None], self.frequency[None]
        q = self.offset[None] + (a * np.sin(arg)).sum(-1)
        qd = (a * w * np.cos(arg)).sum(-1)
        qdd = -(a * w**2 * np.sin(arg)).sum(-1)
        return q, qd, qdd

    def reset(self, trace: Trace) -> None:
        # The reference is open-loop: the whole run is computed here, vectorised.
        q, qd, qdd = self.evaluate(trace.time)
        trace["q_d"][:], trace["qdot_d"][:], trace["qddot_d"][:] = q, qd, qdd
        if self.safe_case == "tracking":
            trace["q_s"][:], trace["qdot_s"][:] = q, qd
        else:  # (max_t + min_t) / 2 over the run, as in the paper's Sec. IV
            trace["q_s"][:] = (q.max(0) + q.min(0)) / 2
            trace["qdot_s"][:] = (qd.max(0) + qd.min(0)) / 2

    def step(self, k: int) -> bool:
        return True
