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
are quintic Hermite segments in SciPy's Bernstein form (``BPoly``; the coefficients
written at once for every segment, which ``BPoly.from_derivatives`` would make one segment
at a time in Python: minutes for a CSV of 10⁶ rows), which also gives the exact extremes
the limit check needs (:mod:`.reference_limits`). A segment whose q_d, q̇_d or q̈_d does not
fit in double precision (positions of 1e308, a segment of 1e-300 s) is refused
(:class:`SegmentOverflow`), not handed to SciPy's root finding, which fails inside.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # SciPy's interpolate takes ~1 s to import: only a run that has a
    # trajectory of waypoints or samples loads it, not every command that starts
    from scipy.interpolate import BPoly, PPoly


@dataclass(frozen=True, eq=False)
class Trajectory:
    """q_d(t) for t in [0, end], one column per joint; after ``end`` it holds q_d(end) at
    rest (q̇_d = q̈_d = 0)."""

    curve: BPoly  # vector-valued: curve(t) has shape (len(t), n)
    end: float  # s, the last knot
    source: str  # what it was built from, for messages and summary.json
    # what the limit check found of it, kept with it (a long CSV's roots take seconds, and
    # every run of a pipeline checks the same trajectory against its own limits)
    extremes: dict = field(default_factory=dict, repr=False)

    @property
    def knots(self) -> np.ndarray:
        return self.curve.x

    @functools.cached_property
    def derivatives(self) -> tuple[BPoly, BPoly]:
        """q̇_d and q̈_d's curves, made once (a long CSV's take a fraction of a second)."""
        return self.curve.derivative(1), self.curve.derivative(2)

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q_d, q̇_d, q̈_d at the times t (shape (len(t), n) each)."""
        held = np.asarray(t, float) > self.end
        inside = np.minimum(t, self.end)
        q = self.curve(inside)
        qd = self.derivatives[0](inside)
        qdd = self.derivatives[1](inside)
        qd[held] = 0.0
        qdd[held] = 0.0
        return q, qd, qdd

    def joint(self, j: int, order: int = 0, until: float | None = None) -> PPoly:
        """Joint j's position (order 0) or one of its derivatives as a scalar piecewise
        polynomial in the power basis, whose ``roots`` SciPy finds exactly per segment;
        ``until``: only the segments that start before that time (s)."""
        from scipy.interpolate import BPoly, PPoly

        segments = len(self.curve.x) - 1 if until is None else \
            max(1, int(np.searchsorted(self.curve.x, until, side="left")))
        scalar = BPoly(self.curve.c[:, :segments, j], self.curve.x[:segments + 1])
        return PPoly.from_bernstein_basis(scalar.derivative(order) if order else scalar)


class SegmentOverflow(ValueError):
    """Segment ``segment`` (0-based: from knot ``segment`` to the next) has a q_d, q̇_d or
    q̈_d, or a power-basis form of them, that may not fit in double precision."""

    def __init__(self, segment: int):
        super().__init__(f"segment {segment} is beyond double precision")
        self.segment = segment


# A bound on a segment's coefficients in every form the reference and its limit check use:
# q̇_d's Bernstein coefficients are 5·Δc/h, q̈_d's 20·Δ²c/h² (≤ 10 and 80 times max|c|
# over h and h²), and the power basis's k-th coefficient C(5,k)·Σ±C(k,j)c_j/h^k (≤ 320
# max|c|/h^k): all of them stay below 1e300 if log10(max|c|·80·320) − 7·log10(min(h, 1)) does.
LARGEST_LOG10 = 300.0
SHORTEST, LONGEST = 1e-60, 1e60  # s: h⁵ (the power basis divides by it) a normal number


def _first_overflow(curve: BPoly) -> int | None:
    """The first segment of ``curve`` that :class:`SegmentOverflow` would name, or None."""
    return _first_too_large(curve.x, np.max(np.abs(curve.c), axis=(0, 2)))


def _first_too_large(times: np.ndarray, biggest: np.ndarray) -> int | None:
    """The first segment too short or too long for h⁵, or whose largest value ``biggest``
    (per segment) makes the bound LARGEST_LOG10 (a sufficient condition, one pass) not
    below 1e300; None if there is none."""
    h = np.diff(times)
    with np.errstate(all="ignore"):
        scale = np.log10(biggest * 80 * 320) - 7 * np.log10(np.minimum(h, 1.0))
    bad = ~(scale < LARGEST_LOG10) | ~np.isfinite(biggest) | ~((h >= SHORTEST) & (h <= LONGEST))
    return int(np.argmax(bad)) if bad.any() else None


def quintic_through(times: np.ndarray, q: np.ndarray, qdot: np.ndarray, qddot: np.ndarray,
                    source: str) -> Trajectory:
    """The piecewise quintic through (q, q̇, q̈) at each of ``times`` (strictly increasing,
    from 0), arrays of shape (len(times), n); :class:`SegmentOverflow` for a segment that
    does not fit in double precision.

    The Bernstein coefficients of the quintic on [t0, t1] (h = t1 − t0) with q, q̇, q̈
    given at both ends: a degree-5 Bernstein polynomial's derivative at t0 is 5(c1 − c0)/h
    and its second 20(c2 − 2c1 + c0)/h², and symmetrically at t1."""
    from scipy.interpolate import BPoly

    h = np.diff(times)[:, None]
    with np.errstate(all="ignore"):  # an overflow is found and named below
        c = np.stack([q[:-1], q[:-1] + h * qdot[:-1] / 5,
                      q[:-1] + 2 * h * qdot[:-1] / 5 + h**2 * qddot[:-1] / 20,
                      q[1:] - 2 * h * qdot[1:] / 5 + h**2 * qddot[1:] / 20,
                      q[1:] - h * qdot[1:] / 5, q[1:]])
        curve = BPoly(c, times)
        overflow = _first_overflow(curve)
    if overflow is not None:
        raise SegmentOverflow(overflow)
    return Trajectory(curve, float(times[-1]), source)


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
    from scipy.interpolate import CubicSpline

    given = np.abs(np.concatenate([a for a in (q, qdot, qddot) if a is not None], axis=1))
    too_large = _first_too_large(times, np.maximum(given[:-1], given[1:]).max(axis=1))
    if too_large is not None:  # SciPy's spline would fail on it, naming nothing
        raise SegmentOverflow(too_large)
    with np.errstate(all="ignore"):
        if qdot is None:
            spline = CubicSpline(times, q, axis=0)
            qdot, qddot = spline(times, 1), spline(times, 2)
        elif qddot is None:
            qddot = CubicSpline(times, qdot, axis=0)(times, 1)
    return quintic_through(times, q, qdot, qddot, source)
