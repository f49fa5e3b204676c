"""The safe sets' bounds and the torque's chattering measure, over a trace's rows
(vectorised). SI units, radians."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..declared import Safety
from ..signals import Trace

# What the checks and barriers read: a Trace, or any mapping of signal name -> rows (the
# evaluator passes one chunk of rows as a plain dict).
Signals = Trace | Mapping[str, np.ndarray]


# The safe sets' bounds are the pipeline's [safety] section, declared once.
SafeSet = Safety


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
