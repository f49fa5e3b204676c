"""The safe sets' bounds and the torque's chattering measure, over a trace's rows
(vectorised). SI units, radians."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..signals import Trace

# What the checks and barriers read: a Trace, or any mapping of signal name -> rows (the
# evaluator passes one chunk of rows as a plain dict).
Signals = Trace | Mapping[str, np.ndarray]


@dataclass
class SafeSet:
    """Bounds, SI units. The paper's Sec. IV values are the defaults."""

    position_bound: float = 20.0  # α_max of ‖x1 − q_s‖, rad
    velocity_bound: float = 13.5  # α_max of ‖x̂2 − q̇_s‖, rad/s
    error_bound: float = 1.0  # E1 of ‖e‖, rad
    error_rate_bound: float = 5.0  # E2 of ‖ė‖, rad/s
    observer_error_bound: float = 1.0  # ε_max of (16), rad/s and rad
    Z_Wo_tilde: float = 20.0  # bounds of (17)-(18) used in H1, H2
    Z_Wc_tilde: float = 50.0
    Z_Vc_tilde: float = 50.0
    barrier_alpha: float = 1.0  # α of Ḣ + α·H ≥ 0, 1/s


def torque_reversals(tau: np.ndarray, dt: float, fraction: float = 0.01) -> np.ndarray:
    """Chattering, per joint: how often per second the torque's step-to-step change flips
    sign with both changes larger than ``fraction`` of that joint's peak torque. A smooth
    torque scores near 0; a loop that chatters at the sampling rate scores in the hundreds."""
    if len(tau) < 3:
        return np.zeros(tau.shape[1])
    change = np.diff(tau, axis=0)
    big = np.abs(change) > fraction * np.max(np.abs(tau), axis=0)
    flips = (np.sign(change[1:]) != np.sign(change[:-1])) & big[1:] & big[:-1]
    return flips.sum(axis=0) / (len(tau) * dt)
