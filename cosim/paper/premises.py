"""The premises of the filter's check, measured along a run on the true state (the
classifier's, cosim/paper/guarantee.py): what the check takes as given and no declared bound
makes true by itself, each compared at every step from the one the guarantee covers the run
from. A covered run where the velocity's interval or the motion between samples fails is a
broken guarantee, whatever the sets did (cosim.paper.guarantee.measured_premises names it
among the violations). The plan's tube is held where the filter followed its plan
(``plan_tube_exceeded_steps``, ``plan_tube_slack``): those steps rest on the plan's proof. On
every row it is measured and reported (``tube_exceeded_steps``, ``tube_slack``,
``tube_left``): a row verified afresh rests on its own check, from the velocity's interval
(docs/safety/measurements.md, "The tube premise").

- **The velocity's interval** (:func:`interval_exceedances`): the check rolls its backup out
  from every velocity in the interval the filter holds (the observer's certified one,
  intersected with the filter's own prediction from the step before): the true q̇ must lie
  in it.
- **The tube** (:func:`tube_exceedances`): the check's rollout puts the true state within a
  tube about its nominal trajectory, widened by TUBE_SAFETY = 1.5 times D and by q̈'s drift
  over a held step (cosim/paper/cbf_filter/check.py). The filter records at
  every step the box the plan in force at the step before puts the state in
  (``cbf_tube_*``); the true state may leave it by at most what the check leaves between
  its sets and the bounds (half of ``bound_margin``), or the rollout's proof of the sets
  does not hold. A violation on the rows where the filter followed the plan (above).
- **Between samples** (:func:`between_samples`): the sets are judged at the samples; between
  two, under the torque held, q̈ lies within the check's bound [lo, hi] for that step
  (``cbf_acceleration_low``, ``_high``), so that x(t) lies below both parabolas of
  curvature hi from either sample, and q̇(t) below v_k + hi τ and v_k+1 − lo (h − τ)
  (likewise from below): the largest of each, from the true state at the samples, must
  stay within the set between them (Ā of docs/safety/filter.md, per step).

SI units, radians. Ground truth, for evaluation only.
"""

from __future__ import annotations

import numpy as np

from ..evaluate.safety import Signals

TOLERANCE = 1e-9  # relative: rounding in the trace's arithmetic


def _rows(mask: np.ndarray, dt: float) -> tuple[int, float | None]:
    """(how many rows of ``mask`` (rows, joints) hold anywhere, the first one's time)."""
    rows = np.flatnonzero(mask.any(axis=1))
    return len(rows), (float(rows[0] * dt) if len(rows) else None)



def _first_outside(outside: list[np.ndarray], dt: float) -> tuple[int, float | None, str, str]:
    """(the rows where the position's or the velocity's mask holds, the first one's time,
    which of the two is named — the position where it fails at all — and its unit)."""
    count, first = _rows(outside[0] | outside[1], dt)
    which = "position" if outside[0].any() else "velocity"
    return count, first, which, ("rad" if which == "position" else "rad/s")

def interval_exceedances(trace: Signals, start: int) -> tuple[int | None, str | None]:
    """(rows from ``start`` on where the true q̇ lies outside the filter's interval
    ``cbf_velocity_centre`` ± ``cbf_velocity_spread``, what failed); None counts without
    the signals."""
    if not all(name in trace for name in ("qdot", "cbf_velocity_centre",
                                          "cbf_velocity_spread")):
        return None, None
    done = trace.rows_done
    truth = np.asarray(trace["qdot"], float)[start:done]
    centre = np.asarray(trace["cbf_velocity_centre"], float)[start:done]
    spread = np.asarray(trace["cbf_velocity_spread"], float)[start:done]
    excess = np.abs(truth - centre) - spread
    outside = excess > TOLERANCE * (1.0 + np.abs(centre))
    count, first = _rows(outside, trace.dt)
    if not count:
        return 0, None
    j = int(np.argmax(np.max(np.where(outside, excess, -np.inf), axis=0)))
    return count, (f"the true q̇ outside the velocity interval the filter held at {count} "
                   f"steps (first t = {first + start * trace.dt:.4g} s; joint {j + 1} up to "
                   f"{np.max(excess[:, j]):.3g} rad/s past it)")


def tube_exceedances(trace: Signals, start: int, allowance: np.ndarray,
                     followed_only: bool = False
                     ) -> tuple[int | None, dict | None, str | None]:
    """(rows from ``start`` on where the true state left the box the plan in force put it
    in by more than ``allowance`` (2, n: rad, rad/s per joint, what the check leaves between
    its sets and the bounds), the least slack allowance − excess per quantity, what
    failed); None without the signals. ``followed_only``: only the rows where the filter
    followed that plan (``cbf_planned``: no torque verified afresh, so the step rests on the
    plan's proof; a row verified afresh rests on its own check, from the velocity's
    interval); None without that signal."""
    names = [f"cbf_tube_{q}{p}" for q in ("position", "velocity") for p in ("", "_spread")]
    needed = (*names, "q", "qdot", *(["cbf_planned"] if followed_only else []))
    if not all(name in trace for name in needed):
        return None, None, None
    done = trace.rows_done
    followed = np.ones(done - start, bool)
    if followed_only:
        planned = np.asarray(trace["cbf_planned"], float)
        followed = planned.reshape(len(planned), -1)[start:done, 0] > 0.5
    slack, outside = {}, []
    for quantity, truth in (("position", "q"), ("velocity", "qdot")):
        row = 0 if quantity == "position" else 1
        centre = np.asarray(trace[f"cbf_tube_{quantity}"], float)[start:done]
        half = np.asarray(trace[f"cbf_tube_{quantity}_spread"], float)[start:done]
        excess = np.abs(np.asarray(trace[truth], float)[start:done] - centre) - half
        room = allowance[row] - excess  # NaN where no plan said where the state goes
        judged = np.isfinite(room) & followed[:, None]
        slack[quantity] = float(np.min(room[judged])) if judged.any() else None
        outside.append(judged & (room < -TOLERANCE * (1.0 + np.abs(np.nan_to_num(centre)))))
    count, first, which, unit = _first_outside(outside, trace.dt)
    if not count:
        return 0, slack, None
    return count, slack, (
        f"the true state outside the check's tube by more than the room it leaves to the "
        f"bounds at {count} steps (first t = {first + start * trace.dt:.4g} s; the "
        f"{which} by up to {-slack[which]:.3g} {unit} past that room)")


def _upper_between(x0, x1, v0, v1, high, dt):
    """The largest x(t) between two samples (x0, v0) and (x1, v1) with q̈ ≤ ``high``: below
    both parabolas from either end, f1 = x0 + v0 τ + ½ high τ² and f2 = x1 − v1 σ + ½ high
    σ² (σ = dt − τ). They have the same curvature, so f1 − f2 is linear in τ and min(f1,
    f2) is f1 on one side of where they meet and f2 on the other: its largest value is at
    an end, where they meet, or at a vertex of either (for high < 0)."""
    x0, x1, v0, v1, high = (np.asarray(x, float) for x in (x0, x1, v0, v1, high))
    with np.errstate(divide="ignore", invalid="ignore"):
        meet = (x1 - x0 - v1 * dt + 0.5 * high * dt * dt) / (v0 - v1 + high * dt)
        first_top = -v0 / high
        second_top = dt - v1 / high
    best = np.maximum(x0, x1)  # the samples themselves
    for tau in (meet, first_top, second_top):
        tau = np.clip(np.where(np.isfinite(tau), tau, 0.0), 0.0, dt)
        sigma = dt - tau
        best = np.maximum(best, np.minimum(x0 + v0 * tau + 0.5 * high * tau * tau,
                                           x1 - v1 * sigma + 0.5 * high * sigma * sigma))
    return best


def _upper_rate(v0, v1, low, high, dt):
    """The largest q̇(t) between two samples with low ≤ q̈ ≤ high: min(v0 + high τ,
    v1 − low (dt − τ)), two lines, at the ends or where they cross."""
    v0, v1, low, high = (np.asarray(x, float) for x in (v0, v1, low, high))
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = (v1 - v0 - low * dt) / (high - low)
    cross = np.clip(np.where(np.isfinite(cross), cross, 0.0), 0.0, dt)
    ends = np.maximum(np.minimum(v0, v1 - low * dt), np.minimum(v0 + high * dt, v1))
    return np.maximum(ends, np.minimum(v0 + high * cross, v1 - low * (dt - cross)))


def between_samples(trace: Signals, start: int, centres: tuple[np.ndarray, np.ndarray],
                    bounds: tuple[np.ndarray, np.ndarray]
                    ) -> tuple[int | None, dict | None, str | None]:
    """(steps from ``start`` on where the state between two samples may pass a bound, given
    the check's bound on q̈ over that step, the least room left per quantity (rad, rad/s),
    what failed); None without the signals. ``centres``, ``bounds``: the position and
    velocity sets' centres and half-widths per joint."""
    if not all(name in trace for name in ("q", "qdot", "cbf_acceleration_low",
                                          "cbf_acceleration_high")):
        return None, None, None
    done, dt = trace.rows_done, trace.dt
    if done - start < 2:
        return 0, None, None
    q = np.asarray(trace["q"], float)[start:done] - centres[0]
    v = np.asarray(trace["qdot"], float)[start:done] - centres[1]
    low = np.asarray(trace["cbf_acceleration_low"], float)[start:done - 1]
    high = np.asarray(trace["cbf_acceleration_high"], float)[start:done - 1]
    judged = np.isfinite(low) & np.isfinite(high)
    low, high = np.where(judged, low, 0.0), np.where(judged, high, 0.0)
    reach = {"position": np.maximum(
                 _upper_between(q[:-1], q[1:], v[:-1], v[1:], high, dt),
                 _upper_between(-q[:-1], -q[1:], -v[:-1], -v[1:], -low, dt)),
             "velocity": np.maximum(_upper_rate(v[:-1], v[1:], low, high, dt),
                                    _upper_rate(-v[:-1], -v[1:], -high, -low, dt))}
    room, outside = {}, []
    for row, (quantity, value) in enumerate(reach.items()):
        left = np.where(judged, bounds[row] - value, np.inf)
        room[quantity] = float(np.min(left)) if judged.any() else None
        outside.append(left < -TOLERANCE * (1.0 + bounds[row]))
    count, first, which, unit = _first_outside(outside, dt)
    if not count:
        return 0, room, None
    return count, room, (
        f"between samples the {which} may pass its bound by up to {-room[which]:.3g} {unit} "
        f"at {count} steps (first t = {first + start * dt:.4g} s), with q̈ within the "
        "check's bound for the step")
