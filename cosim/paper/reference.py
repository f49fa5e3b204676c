"""Desired trajectory q_d(t) with its derivatives: the paper's sums of sinusoids (analytic
derivatives), or a user's joint-space waypoints or CSV trajectory (piecewise quintics,
:mod:`.trajectory`), checked against the limits before the run (:mod:`.reference_limits`);
and the safe trajectories q_s, q̇_s of Remark 1 (case i: q_s = q_d; case ii: constant
midpoints)."""

from __future__ import annotations

import functools
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from ..blocks.base import Block, BlockContext, Ports, register_block
from ..declared import joint_boxes
from ..schema import FileName, FiniteFloat, NonNegativeFloat, PipelineError, PositiveFloat, Section
from ..signals import Signal
from .reference_limits import JointLimits, breaches, refusal, safe_set_limits
from .trajectory import SegmentOverflow, Trajectory, minimum_jerk
from .trajectory_file import read_trajectory


class Waypoints(Section):
    """Joint positions the arm moves through and stops at (q̇ = q̈ = 0 at each), joined by
    minimum-jerk segments; after the last it stays there."""

    # the waypoints' times, from 0, strictly increasing, s
    times: Annotated[list[NonNegativeFloat], Field(min_length=2)]
    # the joint positions at each time, one row per waypoint with one entry per joint, rad
    # (m for a prismatic joint)
    positions: list[list[FiniteFloat]]

    @model_validator(mode="after")
    def _shapes(self) -> Waypoints:
        t = self.times
        if t[0] != 0.0:
            raise ValueError(f"reference.waypoints.times starts at {t[0]:g} s; the first "
                             "waypoint is at t = 0 s, the run's start")
        for k in range(1, len(t)):
            if t[k] <= t[k - 1]:
                raise ValueError(f"reference.waypoints.times[{k}] = {t[k]:g} s does not "
                                 f"increase (times[{k - 1}] = {t[k - 1]:g} s); times must "
                                 "increase strictly")
        if len(self.positions) != len(t):
            raise ValueError(f"reference.waypoints.positions has {len(self.positions)} rows, "
                             f"times has {len(t)}: one row of joint positions per time")
        widths = {len(row) for row in self.positions}
        if len(widths) != 1 or 0 in widths:
            raise ValueError("reference.waypoints.positions: every row has one entry per "
                             f"joint (rows of {sorted(widths)} entries given)")
        return self


class ReferenceParams(Section):
    """q_d,i(t) = offset_i + Σ_j amplitude_ij sin(frequency_ij t + phase_ij), the paper's;
    or, when ``waypoints`` or ``csv`` is given, that trajectory (the sinusoids' keys are then
    not used)."""

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
    # joint-space waypoints joined by minimum-jerk segments, a table: times (s) and one row
    # of joint positions per time (rad); given, they replace the sinusoids, mixed units
    waypoints: Waypoints | None = None
    # a CSV trajectory: rows of t, q_1…q_n, optionally q̇_1…q̇_n and q̈_1…q̈_n (s, rad,
    # rad/s, rad/s²), joined by quintic segments; relative to the pipeline file; given, it
    # replaces the sinusoids, a path
    csv: FileName | None = None
    # a reference that leaves a joint's limits (today the safe sets per joint, |q_d − q_s| ≤
    # safety.position_bound and |q̇_d − q̇_s| ≤ safety.velocity_bound), a name: "refuse" it
    # before the run, naming the joint, time and value; "report" it (summary.json lists it,
    # the evaluation marks those sets unattainable) and run. Unset: "refuse" for waypoints
    # and a CSV; for the sinusoids, the evaluation's report only (the paper's reference
    # touches its own position bound)
    limits: Literal["refuse", "report"] | None = None

    @model_validator(mode="after")
    def _shapes(self) -> ReferenceParams:
        if self.waypoints is not None and self.csv is not None:
            raise ValueError("give reference.waypoints or reference.csv, not both")
        if self.source != "sinusoids":
            return self  # their joint count is checked against the plant's
        n = len(self.offset)
        for key in ("amplitude", "frequency", "phase"):
            value = getattr(self, key)
            if value is None:
                continue
            if len(value) != n:
                raise ValueError(f"reference.{key} has {len(value)} rows, offset has {n} joints")
            if any(len(row) != len(self.amplitude[i]) for i, row in enumerate(value)):
                raise ValueError(f"reference.{key} rows must match reference.amplitude's")
        return self  # the centres' lengths are checked against the plant's joints

    @property
    def source(self) -> str:
        """What q_d is: "waypoints", "csv" or "sinusoids"."""
        return ("waypoints" if self.waypoints is not None
                else "csv" if self.csv is not None else "sinusoids")


class Sinusoids:
    """The paper's reference: sums of sinusoids per joint, with analytic derivatives."""

    def __init__(self, params: ReferenceParams):
        self.offset = np.array(params.offset, float)
        self.amplitude = np.array(params.amplitude, float)
        self.frequency = np.array(params.frequency, float)
        self.phase = (np.array(params.phase, float) if params.phase is not None
                      else np.zeros_like(self.amplitude))

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q_d, q̇_d, q̈_d at the times t (shape (len(t), n) each)."""
        return sinusoids(t, self.offset, self.amplitude, self.frequency, self.phase)


@register_block
class Reference(Block):
    kind = "reference"
    Params = ReferenceParams
    # reference_trajectory: q_d(t) as an object with ``evaluate(t) -> (q_d, q̇_d, q̈_d)``
    # (rad, rad/s, rad/s²), for the checks blocks make before the run (the sampled loop's
    # configurations, cosim.paper.sampled_loop)
    PUBLISHES = {"reference_trajectory": object}

    def __init__(self, params: ReferenceParams, context: BlockContext):
        super().__init__(params, context)
        self.outputs = {
            "q_d": Signal("n", "rad", "desired position q_d", "reference/q_d"),
            "qdot_d": Signal("n", "rad/s", "desired velocity q̇_d", "reference/qdot_d"),
            "qddot_d": Signal("n", "rad/s²", "desired acceleration q̈_d", "reference/qddot_d"),
            # The safe trajectories are drawn as the safety checks' bounds, not as series.
            "q_s": Signal("n", "rad", "safe-set centre q_s (Remark 1)"),
            "qdot_s": Signal("n", "rad/s", "safe-set centre q̇_s (Remark 1)"),
        }
        self.trajectory = trajectory(params, context)
        self.publishes = {"reference_trajectory": self.trajectory}
        self._centres: tuple[np.ndarray, np.ndarray] | None = None  # centres(), once
        self.limits_left = self._check_limits()

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q_d, q̇_d, q̈_d at the times t (shape (len(t), n) each)."""
        return self.trajectory.evaluate(t)

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
        if self._centres is not None:
            return self._centres
        p = self.params
        if p.source == "sinusoids":  # the same for every point of a sweep that keeps them
            q_mid, qd_mid = _midpoints(*(_frozen(getattr(p, key)) for key in
                                         ("offset", "amplitude", "frequency", "phase")),
                                       p.safe_horizon)
        else:  # a CSV is defined over its own span only
            horizon = (min(p.safe_horizon, self.trajectory.end) if p.source == "csv"
                       else p.safe_horizon)
            t = np.linspace(0.0, horizon, int(round(horizon / 1e-4)) + 1)
            q_mid, qd_mid = _middles(*self.trajectory.evaluate(t)[:2])
        q_s = np.array(p.safe_centre, float) if p.safe_centre is not None else q_mid.copy()
        qdot_s = (np.array(p.safe_velocity_centre, float) if p.safe_velocity_centre is not None
                  else qd_mid.copy())
        self._centres = q_s, qdot_s
        return self._centres

    def describe(self) -> dict:
        p = self.params
        out = {}
        if p.source != "sinusoids":  # the paper's summary stays as it was
            out = {"trajectory": p.source, "from": self.trajectory.source,
                   "end_s": self.trajectory.end}
        if self.limits_left:
            out["limits_left"] = [b.summary() for b in self.limits_left]
        if p.safe_case == "tracking":
            return {**out, "safe_centre": "q_d (moves: Remark 1 case i)"}
        q_s, qdot_s = self.centres()
        sources = [("given" if given is not None else
                    f"midpoint of the reference over 0–{p.safe_horizon:g} s")
                   for given in (p.safe_centre, p.safe_velocity_centre)]
        return {**out, "q_s": [float(v) for v in q_s], "q_s_source": sources[0],
                "qdot_s": [float(v) for v in qdot_s], "qdot_s_source": sources[1]}

    def headline(self) -> str | None:
        if not self.limits_left:
            return None
        return (f"the reference leaves {len(self.limits_left)} joint limit"
                f"{'s' * (len(self.limits_left) != 1)} (reference.limits = \"report\"): "
                f"{self.limits_left[0].describe()}; those sets are unattainable")

    def _check_limits(self) -> list:
        """The limits the reference leaves over the run; a :class:`PipelineError` if it
        leaves one and ``limits`` is "refuse". Not checked: the moving centres of case i
        (the reference is their centre) and, unless asked, the paper's sinusoids."""
        p = self.params
        mode = p.limits or ("refuse" if p.source != "sinusoids" else None)
        if mode is None or p.safe_case == "tracking":
            return []
        boxes = joint_boxes(self.context.safety, self.context.links)
        if boxes is None:
            q_s, qdot_s = self.centres()
            p = self.params
            computed = [name for name, given in (("safe_centre", p.safe_centre),
                                                 ("safe_velocity_centre",
                                                  p.safe_velocity_centre)) if given is None]
            centred = (f"the midpoints of the reference over 0–{p.safe_horizon:g} s "
                       "(reference.safe_horizon), beyond the run's end too; give "
                       f"{' and '.join(f'reference.{n}' for n in computed)} to fix them"
                       if computed else "")
            limits = safe_set_limits(self.context.safety, q_s, qdot_s, centred)
        else:  # the robot's own limits (safety.limits = "urdf"), the margin kept
            limits = JointLimits(boxes.position_centre - boxes.position_half,
                                 boxes.position_centre + boxes.position_half,
                                 boxes.velocity_half, boxes.velocity_centre, boxes.source)
        left = breaches(self.trajectory, limits, self.context.duration)
        if left and mode == "refuse":
            what = {"waypoints": "reference.waypoints", "sinusoids": "the reference",
                    "csv": f"reference.csv ({self.trajectory.source})"}[p.source]
            raise PipelineError(f"run '{self.context.run}': " + refusal(left, what, limits))
        return left


def trajectory(params: ReferenceParams, context: BlockContext) -> Sinusoids | Trajectory:
    """The reference's q_d(t), sized for the plant's joints (a :class:`PipelineError`
    naming the key otherwise)."""
    n = context.links
    joints = f"the plant ({context.plant_file}) has {n} joint{'s' * (n != 1)}"
    for key in ("safe_centre", "safe_velocity_centre"):
        value = getattr(params, key)
        if value is not None and len(value) != n:
            raise PipelineError(f"reference.{key} has {len(value)} entries (one per joint); "
                                f"{joints}")
    if params.source == "waypoints":
        positions = np.array(params.waypoints.positions, float)
        if positions.shape[1] != n:
            raise PipelineError(f"reference.waypoints.positions has rows of "
                                f"{positions.shape[1]} entries (one per joint, rad); {joints}")
        times = np.array(params.waypoints.times, float)
        try:
            return minimum_jerk(times, positions, f"{len(positions)} waypoints")
        except SegmentOverflow as exc:
            k = exc.segment
            raise PipelineError(
                f"reference.waypoints: the segment from times[{k}] = {times[k]:g} s to "
                f"times[{k + 1}] = {times[k + 1]:g} s (positions up to "
                f"{np.max(np.abs(positions[k:k + 2])):g}) makes q_d, q̇_d or q̈_d too large for "
                "double precision: give times and positions of a robot's scale") from None
    if params.source == "csv":
        path = params.csv
        # the samples it uses: up to the run's end, or the safe sets' horizon (centres)
        found = read_trajectory(path, n, max(context.duration, params.safe_horizon))
        if found.end < context.duration - 1e-9:
            raise PipelineError(f"reference.csv: {path} covers 0–{found.end:g} s, shorter "
                                f"than the run (simulation.duration = {context.duration:g} "
                                "s): give samples up to the run's end, or shorten it")
        return found
    if len(params.offset) != n:
        raise PipelineError(f"reference.offset has {len(params.offset)} entries (one per "
                            f"joint, rad); {joints}")
    return Sinusoids(params)


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
    return _middles(*sinusoids(t, np.array(offset, float), a, np.array(frequency, float),
                               phases)[:2])


def _middles(q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(max_t + min_t)/2 per joint of q_d and q̇_d sampled as (len(t), n)."""
    # joint-major copies: numpy's max/min down the rows of a (2e5, n) array are ~20×
    # slower than along contiguous rows
    q, qd = np.ascontiguousarray(q.T), np.ascontiguousarray(qd.T)
    return (q.max(1) + q.min(1)) / 2, (qd.max(1) + qd.min(1)) / 2
