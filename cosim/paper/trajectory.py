"""Joint-space trajectories a user gives: waypoints joined by minimum-jerk segments, and
sampled trajectories (a CSV file's rows) joined by quintic Hermite segments. Both are one
piecewise quintic in each joint, so q, q̇ and q̈ are continuous everywhere. SI units,
radians (metres for a prismatic joint).

Why quintic: a trajectory the controller tracks enters its torque through q̈_d (the NN's
input and the feedforward), so q̈_d must not jump; a quintic segment is the lowest degree
that can match position, velocity and acceleration at both ends. Between waypoints at rest
(q̇ = q̈ = 0 at each, what a pick-and-place stops at) the quintic with those six conditions
is the minimum-jerk segment (Flash & Hogan 1985: it minimises ∫ jerk² dt),

    q(s) = q0 + Δ (10 s³ − 15 s⁴ + 6 s⁵),  s = (t − t0)/T,  Δ = q1 − q0,

monotone between its waypoints, with peak speed 15/8 · |Δ|/T at its middle. The segments
are SciPy's ``BPoly.from_derivatives`` (quintic Hermite in Bernstein form), which also
gives the exact extremes the limit check needs (:mod:`.reference_limits`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BPoly, CubicSpline, PPoly


@dataclass(frozen=True)
class Trajectory:
    """q_d(t) for t in [0, end], one column per joint; after ``end`` it holds q_d(end) at
    rest (q̇_d = q̈_d = 0)."""

    curve: BPoly  # vector-valued: curve(t) has shape (len(t), n)
    end: float  # s, the last knot
    source: str  # what it was built from, for messages and summary.json

    @property
    def knots(self) -> np.ndarray:
        return self.curve.x

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q_d, q̇_d, q̈_d at the times t (shape (len(t), n) each)."""
        held = np.asarray(t, float) > self.end
        inside = np.minimum(t, self.end)
        q = self.curve(inside)
        qd = self.curve.derivative(1)(inside)
        qdd = self.curve.derivative(2)(inside)
        qd[held] = 0.0
        qdd[held] = 0.0
        return q, qd, qdd

    def joint(self, j: int, order: int = 0) -> PPoly:
        """Joint j's position (order 0) or one of its derivatives as a scalar piecewise
        polynomial in the power basis, whose ``roots`` SciPy finds exactly per segment."""
        curve = self.curve.derivative(order) if order else self.curve
        scalar = BPoly(curve.c[:, :, j], curve.x)
        return PPoly.from_bernstein_basis(scalar)


def quintic_through(times: np.ndarray, q: np.ndarray, qdot: np.ndarray, qddot: np.ndarray,
                    source: str) -> Trajectory:
    """The piecewise quintic through (q, q̇, q̈) at each of ``times`` (strictly increasing,
    from 0), arrays of shape (len(times), n)."""
    stacked = np.stack([q, qdot, qddot], axis=1)  # (knots, 3, n): value and 2 derivatives
    return Trajectory(BPoly.from_derivatives(times, stacked), float(times[-1]), source)


def minimum_jerk(times: np.ndarray, positions: np.ndarray, source: str) -> Trajectory:
    """Rest-to-rest minimum-jerk segments through ``positions`` (one row per waypoint) at
    ``times``."""
    rest = np.zeros_like(positions, dtype=float)
    return quintic_through(times, positions, rest, rest, source)


def through_samples(times: np.ndarray, q: np.ndarray, qdot: np.ndarray | None,
                    qddot: np.ndarray | None, source: str) -> Trajectory:
    """The piecewise quintic through sampled positions, with the derivatives the samples
    lack taken from a cubic spline (SciPy's ``CubicSpline``, not-a-knot ends) through what
    they have: q̇ and q̈ from the spline through q when only q is given; q̈ from the spline
    through q̇ when q and q̇ are. Given derivatives are matched exactly at the samples."""
    if qdot is None:
        spline = CubicSpline(times, q, axis=0)
        qdot, qddot = spline(times, 1), spline(times, 2)
    elif qddot is None:
        qddot = CubicSpline(times, qdot, axis=0)(times, 1)
    return quintic_through(times, q, qdot, qddot, source)
