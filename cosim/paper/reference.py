"""Desired trajectory q_d(t) as sums of sinusoids, with analytic derivatives, and the safe
trajectories q_s, q̇_s of Remark 1 (case i: q_s = q_d; case ii: constant midpoints)."""

from __future__ import annotations

import functools
from typing import Literal

import numpy as np
from pydantic import model_validator

from ..blocks.base import Block, BlockContext, Ports, register_block
from ..schema import FiniteFloat, NonNegativeFloat, PipelineError, PositiveFloat, Section
from ..signals import Signal


class ReferenceParams(Section):
    """q_d,i(t) = offset_i + Σ_j amplitude_ij sin(frequency_ij t + phase_ij)."""

    offset: list[FiniteFloat] = [0.0, 0.0]  # constant part offset_i of each joint's q_d, rad
    # amplitude_ij of each joint's sine terms, one list per joint, rad
    amplitude: list[list[FiniteFloat]] = [[20.0], [10.0]]
    # angular frequency_ij of each joint's sine terms, one list per joint, rad/s
    frequency: list[list[NonNegativeFloat]] = [[0.5], [1.0]]
    # phase_ij of each joint's sine terms, one list per joint (unset: all 0), rad
    phase: list[list[FiniteFloat]] | None = None
    # the safe sets' centres q_s, q̇_s (a name): "tracking", Remark 1's case i, the reference
    # itself; "midpoint", case ii, constant midpoints of the reference
    safe_case: Literal["tracking", "midpoint"] = "midpoint"
    # the time over which case ii's centres are (max + min)/2 of q_d and q̇_d, whatever
    # simulation.duration is, so a shorter run is judged against the same sets, s
    safe_horizon: PositiveFloat = 20.0
    # the position set's centre q_s per joint, given instead of the midpoint, rad
    safe_centre: list[FiniteFloat] | None = None
    # the velocity set's centre q̇_s per joint, given instead of the midpoint, rad/s
    safe_velocity_centre: list[FiniteFloat] | None = None

    @model_validator(mode="after")
    def _shapes(self) -> ReferenceParams:
        n = len(self.offset)
        for key in ("amplitude", "frequency", "phase"):
            value = getattr(self, key)
            if value is None:
                continue
            if len(value) != n:
                raise ValueError(f"reference.{key} has {len(value)} rows, offset has {n} joints")
            if any(len(row) != len(self.amplitude[i]) for i, row in enumerate(value)):
                raise ValueError(f"reference.{key} rows must match reference.amplitude's")
        for key in ("safe_centre", "safe_velocity_centre"):
            value = getattr(self, key)
            if value is not None and len(value) != n:
                raise ValueError(f"reference.{key} has {len(value)} entries, offset has {n} "
                                 "joints")
        return self


@register_block
class SinusoidReference(Block):
    kind = "reference"
    Params = ReferenceParams

    def __init__(self, params: ReferenceParams, context: BlockContext):
        super().__init__(params, context)
        n = context.links
        if len(params.offset) != n:
            raise PipelineError(f"reference.offset has {len(params.offset)} entries (one per "
                                f"joint, rad); the plant ({context.plant_file}) has {n} "
                                f"joint{'s' * (n != 1)}")
        self.outputs = {
            "q_d": Signal("n", "rad", "desired position q_d", "reference/q_d"),
            "qdot_d": Signal("n", "rad/s", "desired velocity q̇_d", "reference/qdot_d"),
            "qddot_d": Signal("n", "rad/s²", "desired acceleration q̈_d", "reference/qddot_d"),
            # The safe trajectories are drawn as the safety checks' bounds, not as series.
            "q_s": Signal("n", "rad", "safe-set centre q_s (Remark 1)"),
            "qdot_s": Signal("n", "rad/s", "safe-set centre q̇_s (Remark 1)"),
        }
        self.offset = np.array(params.offset, float)
        self.amplitude = np.array(params.amplitude, float)
        self.frequency = np.array(params.frequency, float)
        self.phase = (np.array(params.phase, float) if params.phase is not None
                      else np.zeros_like(self.amplitude))
        self._centres: tuple[np.ndarray, np.ndarray] | None = None  # centres(), once

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q_d, q̇_d, q̈_d at the times t (shape (len(t), n) each)."""
        return sinusoids(t, self.offset, self.amplitude, self.frequency, self.phase)

    def reset(self, ports: Ports) -> None:
        # The reference is open-loop: the whole run is computed here, vectorised.
        out = ports.outputs
        q, qd, qdd = self.evaluate(ports.trace.time)
        out["q_d"][:], out["qdot_d"][:], out["qddot_d"][:] = q, qd, qdd
        if self.params.safe_case == "tracking":
            out["q_s"][:], out["qdot_s"][:] = q, qd
        else:
            q_s, qdot_s = self.centres()
            out["q_s"][:], out["qdot_s"][:] = q_s, qdot_s

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Case ii's constant centres: given, else (max_t + min_t)/2 of q_d and q̇_d over the
        declared horizon (as in the paper's Sec. IV), sampled every 0.1 ms. Computed once
        (reset and describe both ask): 2e5 samples per joint over the paper's 20 s."""
        if self._centres is None:
            p = self.params
            q_s, qdot_s = _midpoints(*(_frozen(getattr(p, key)) for key in
                                       ("offset", "amplitude", "frequency", "phase")),
                                     p.safe_horizon)
            self._centres = (np.array(p.safe_centre, float) if p.safe_centre is not None
                             else q_s.copy(),
                             np.array(p.safe_velocity_centre, float)
                             if p.safe_velocity_centre is not None else qdot_s.copy())
        return self._centres

    def describe(self) -> dict:
        p = self.params
        if p.safe_case == "tracking":
            return {"safe_centre": "q_d (moves: Remark 1 case i)"}
        q_s, qdot_s = self.centres()
        sources = [("given" if given is not None else
                    f"midpoint of the reference over 0–{p.safe_horizon:g} s")
                   for given in (p.safe_centre, p.safe_velocity_centre)]
        return {"q_s": [float(v) for v in q_s], "q_s_source": sources[0],
                "qdot_s": [float(v) for v in qdot_s], "qdot_s_source": sources[1]}


def sinusoids(t: np.ndarray, offset: np.ndarray, amplitude: np.ndarray, frequency: np.ndarray,
              phase: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q_d, q̇_d, q̈_d of the sums of sinusoids at the times t (shape (len(t), n) each)."""
    arg = t[:, None, None] * frequency[None] + phase[None]
    a, w = amplitude[None], frequency[None]
    q = offset[None] + (a * np.sin(arg)).sum(-1)
    qd = (a * w * np.cos(arg)).sum(-1)
    qdd = -(a * w**2 * np.sin(arg)).sum(-1)
    return q, qd, qdd


def _frozen(value: list | None) -> tuple | None:
    """A list (of lists) as nested tuples: a cache key."""
    return None if value is None else tuple(_frozen(v) if isinstance(v, list) else v
                                            for v in value)


@functools.lru_cache(maxsize=16)
def _midpoints(offset: tuple, amplitude: tuple, frequency: tuple, phase: tuple | None,
               horizon: float) -> tuple[np.ndarray, np.ndarray]:
    """(max_t + min_t)/2 of q_d and q̇_d over 0..horizon, every 0.1 ms. Cached per process:
    every point of a sweep that leaves the reference alone asks for the same ones (30 ms
    each over the paper's 20 s, a fifth of a 5 s point's cost beyond its loop)."""
    a = np.array(amplitude, float)
    phases = np.array(phase, float) if phase is not None else np.zeros_like(a)
    t = np.linspace(0.0, horizon, int(round(horizon / 1e-4)) + 1)
    q, qd = sinusoids(t, np.array(offset, float), a, np.array(frequency, float), phases)[:2]
    # joint-major copies: numpy's max/min down the rows of a (2e5, n) array are ~20×
    # slower than along contiguous rows
    q, qd = np.ascontiguousarray(q.T), np.ascontiguousarray(qd.T)
    return (q.max(1) + q.min(1)) / 2, (qd.max(1) + qd.min(1)) / 2
