"""Position sensor: q_meas = quantise(q + noise), seeded. The proposed controller sees only
this; the baseline reads the true velocity from the plant."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..trace import Trace


@dataclass
class PositionSensor:
    noise_std: float = 0.0  # rad, white Gaussian per sample
    resolution: float = 0.0  # rad, quantisation step (0: none)
    seed: int = 0
    name: str = "sensor"

    def reset(self, trace: Trace) -> None:
        self._q = trace["q"]
        self._out = trace["q_meas"]
        rng = np.random.default_rng(self.seed)
        self._noise = rng.normal(0.0, self.noise_std, self._q.shape) if self.noise_std else None

    def step(self, k: int) -> bool:
        y = self._q[k] if self._noise is None else self._q[k] + self._noise[k]
        if self.resolution:
            y = np.round(y / self.resolution) * self.resolution
        self._out[k] = y
        return True
