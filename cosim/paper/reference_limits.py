"""A reference checked against the limits before the run: per joint, a position interval
[lower, upper] and a speed bound |q̇_d − velocity_centre| ≤ velocity. Today's limits are the
pipeline's safe sets (``[safety]``'s radii around the reference's centres q_s, q̇_s); a
robot's own joint limits are the same three arrays. SI units, radians.

The check is exact for a piecewise-polynomial reference (waypoints, a CSV trajectory): a
joint's extremes on a segment are at its ends or where its derivative vanishes, and SciPy
finds those roots per segment. Other references are checked on a 0.1 ms grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..declared import Safety
from .trajectory import Trajectory

# A value this close to its bound is on it (round-off of the centres and the polynomials).
TOLERANCE = 1e-9
SAMPLE_STEP = 1e-4  # s, the grid of a reference that is not piecewise polynomial


@dataclass(frozen=True)
class JointLimits:
    """What a reference must stay within, per joint ((n,) arrays)."""

    lower: np.ndarray  # q_d ≥ lower, rad
    upper: np.ndarray  # q_d ≤ upper, rad
    velocity: np.ndarray  # |q̇_d − velocity_centre| ≤ velocity, rad/s
    velocity_centre: np.ndarray  # rad/s
    source: str  # where the limits come from, for the message

    def __post_init__(self) -> None:
        sizes = {len(np.atleast_1d(a)) for a in (self.lower, self.upper, self.velocity,
                                                 self.velocity_centre)}
        if len(sizes) != 1:
            raise ValueError(f"joint limits of different lengths: {sorted(sizes)}")


def safe_set_limits(safety: Safety, q_s: np.ndarray, qdot_s: np.ndarray,
                    centred: str = "") -> JointLimits:
    """The pipeline's safe sets as joint limits: |q − q_s| ≤ position_bound and
    |q̇ − q̇_s| ≤ velocity_bound, per joint; ``centred``: where the centres come from, when
    not given (said in the message: a centre the reference itself moves explains a limit
    the reference leaves where it is at rest)."""
    alpha, beta = safety.position_bound, safety.velocity_bound
    centres = (f"; q_s = {_shown(q_s)} rad, q̇_s = {_shown(qdot_s)} rad/s, {centred}"
               if centred else "")
    return JointLimits(q_s - alpha, q_s + alpha, np.full(len(q_s), beta), np.asarray(qdot_s),
                       f"the safe sets: |q − q_s| ≤ safety.position_bound = {alpha:g} rad, "
                       f"|q̇ − q̇_s| ≤ safety.velocity_bound = {beta:g} rad/s{centres}")


def _shown(values: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.6g}" for v in values) + "]"


@dataclass(frozen=True)
class Breach:
    """A joint's reference outside one of its limits: where it is furthest outside."""

    joint: int  # 1-based
    quantity: str  # "position" or "velocity"
    t: float  # s
    value: float  # q_d in rad or q̇_d in rad/s
    lower: float
    upper: float

    def describe(self, names: tuple[str, ...] | None = None) -> str:
        name = f"joint {self.joint}" + (f" ({names[self.joint - 1]})" if names else "")
        symbol, unit = ("q_d", "rad") if self.quantity == "position" else ("q̇_d", "rad/s")
        side = (f"above its upper limit {self.upper:.6g}" if self.value > self.upper
                else f"below its lower limit {self.lower:.6g}")
        return (f"{name}'s {self.quantity}: {symbol} = {self.value:.6g} {unit} at "
                f"t = {self.t:.6g} s, {side} {unit}")

    def summary(self) -> dict:
        return {"joint": self.joint, "quantity": self.quantity, "t": self.t,
                "value": self.value, "lower": self.lower, "upper": self.upper}


def breaches(reference, limits: JointLimits, end: float) -> list[Breach]:
    """Each (joint, limit) the reference leaves over [0, end] s, at its worst point, in
    order of time. ``reference``: a :class:`~.trajectory.Trajectory` (checked exactly), or
    anything with ``evaluate(t) -> (q, q̇, q̈)`` (checked on a 0.1 ms grid)."""
    if isinstance(reference, Trajectory):
        times = [_candidate_times(reference, j, end) for j in range(len(limits.lower))]
    else:
        grid = np.linspace(0.0, end, int(np.ceil(end / SAMPLE_STEP)) + 1)
        times = [grid] * len(limits.lower)
    found = []
    for j, t in enumerate(times):
        q, qd, _ = reference.evaluate(t)
        position, speed = q[:, j], qd[:, j] - limits.velocity_centre[j]
        for quantity, value, low, high, offset in (
                ("position", position, limits.lower[j], limits.upper[j], 0.0),
                ("velocity", speed, -limits.velocity[j], limits.velocity[j],
                 limits.velocity_centre[j])):
            slack = TOLERANCE * max(1.0, abs(low), abs(high))
            excess = np.maximum(value - high, low - value)
            if excess.max() > slack:
                k = int(np.argmax(excess))
                found.append(Breach(j + 1, quantity, float(t[k]), float(value[k] + offset),
                                    float(low + offset), float(high + offset)))
    return sorted(found, key=lambda b: (b.t, b.joint))


def _candidate_times(reference: Trajectory, j: int, end: float) -> np.ndarray:
    """Where joint j's position or speed can be extreme on [0, end]: the knots, the roots of
    q̇_d and of q̈_d, and ``end``. Found once per trajectory (``reference.extremes``: SciPy
    takes ~6 µs a segment)."""
    if (j, end) not in reference.extremes:
        roots = [reference.joint(j, order, until=end).roots(extrapolate=False)
                 for order in (1, 2)]
        t = np.concatenate([reference.knots[reference.knots <= end], *roots, [end]])
        reference.extremes[j, end] = np.unique(t[np.isfinite(t) & (t >= 0.0) & (t <= end)])
    return reference.extremes[j, end]


def refusal(breach_list: list[Breach], what: str, limits: JointLimits,
            names: tuple[str, ...] | None = None) -> str:
    """One message for a reference that leaves its limits: the earliest (joint, limit) left,
    at its worst point, then how many more are left."""
    first = breach_list[0]
    rest = len(breach_list) - 1
    more = f"; and {rest} more (joint, limit) pair{'s' * (rest != 1)}" if rest else ""
    return (f"{what} leaves {first.describe(names)} ({limits.source}){more}. Change the "
            "trajectory, or set reference.limits = \"report\" to run it anyway and have "
            "those sets reported unattainable")
