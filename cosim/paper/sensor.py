"""Position sensor: q_meas = quantise(q + noise), seeded. The proposed controller sees only
this; the baseline reads the true velocity from the plant."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ..blocks.base import Block, BlockContext, Ports, register_block
from ..blocks.binding import parameter, reads, writes
from ..records import kernel_record
from ..schema import NonNegativeFloat, Section, Seed
from ..signals import Signal


class SensorParams(Section):
    # standard deviation of the white Gaussian noise added to each position sample, rad
    noise_std: NonNegativeFloat = 0.0
    # quantisation step of the measured position (0: none), rad
    resolution: NonNegativeFloat = 0.0
    seed: Seed = 0  # seed of the noise's random generator, dimensionless


@kernel_record
class SensorArgs(NamedTuple):
    q: reads()  # true position, rows
    noise: np.ndarray  # rows × n, drawn in reset (zeros without noise)
    resolution: parameter()  # rad
    q_meas: writes()


@njit(cache=True)
def sensor_step(k, a):
    for i in range(a.q.shape[1]):
        y = a.q[k, i] + a.noise[k, i]
        if a.resolution > 0.0:
            y = np.round(y / a.resolution) * a.resolution
        a.q_meas[k, i] = y
    return True


@register_block
class PositionSensor(Block):
    kind = "sensor"
    Params = SensorParams
    kernel = sensor_step

    def __init__(self, params: SensorParams, context: BlockContext):
        super().__init__(params, context)
        self.inputs = ("q",)
        self.outputs = {"q_meas": Signal("n", "rad", "measured position y", "sensor/q_meas")}

    def reset(self, ports: Ports) -> None:
        q = ports.inputs["q"]
        p = self.params
        rng = np.random.default_rng(p.seed)
        noise = rng.normal(0.0, p.noise_std, q.shape) if p.noise_std else np.zeros(q.shape)
        self.args = self.bind(SensorArgs, ports, noise=noise)
