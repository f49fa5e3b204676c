"""Whether a run starts in the filter's viable set, and why not: the guarantee's
``starts_viable`` and ``not_viable`` (cosim/paper/guarantee.py). A start inside the sets may
still not be viable: the velocity the filter holds may reach past a bound (the declared
initial observer error), the state may lie in the margin the check keeps to the bounds, or
the check found no torque that keeps the sets (with the least deceleration stopping needs).
The filter's own flag at t = 0 decides; these say which of those it was.

Ground truth is used here, for evaluation only. SI units, radians.
"""

from __future__ import annotations

import numpy as np

from .. import interface as io
from ..declared import joint_boxes
from ..evaluate.safety import SafeSet, Signals
from .cbf_filter.assumptions import VIABLE


def position_and_velocity_sets(trace: Signals, safe: SafeSet, row: int = 0
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Per joint at ``row``: the position set's centre and half-width (rad) and the velocity
    set's (rad/s): the robot's own limits (``safety.limits = "urdf"``), else the paper's
    radii about the recorded centres q_s, q̇_s (None where the trace lacks them)."""
    n = trace.links
    boxes = joint_boxes(safe, n)
    if boxes is not None:
        return (boxes.position_centre, boxes.position_half, boxes.velocity_centre,
                boxes.velocity_half)
    if not all(name in trace for name in (io.SAFE_CENTRE, io.SAFE_VELOCITY_CENTRE)):
        return None
    return (trace[io.SAFE_CENTRE][row], np.full(n, safe.position_bound),
            trace[io.SAFE_VELOCITY_CENTRE][row], np.full(n, safe.velocity_bound))


def stopping_need(trace: Signals, safe: SafeSet) -> str | None:
    """The joint hardest to stop inside its position bound from t = 0, from the true q(0),
    q̇(0) alone: moving toward a bound at speed v from a distance d, stopping needs a
    deceleration of at least v²/(2d) (rad/s²), whatever the torque. None when no joint moves
    toward a bound it is inside of (or the trace lacks the true state)."""
    sets = position_and_velocity_sets(trace, safe)
    if sets is None or not all(name in trace for name in ("q", "qdot")):
        return None
    centre, half = sets[0], sets[1]
    x, v = trace["q"][0] - centre, trace["qdot"][0]
    best = None
    for j in np.flatnonzero(np.isfinite(x) & np.isfinite(v) & (v != 0)):
        side = float(np.sign(v[j]))
        distance = float(half[j]) - side * float(x[j])
        if distance > 0:
            need = float(v[j]) ** 2 / (2 * distance)
            best = max(best or (need, j, side, distance), (need, j, side, distance))
    if best is None:
        return None
    need, j, side, distance = best
    return (f"joint {j + 1} moves toward its {'upper' if side > 0 else 'lower'} position "
            f"bound at {abs(float(v[j])):.3g} rad/s, {distance:.3g} rad from it: stopping "
            f"needs at least {need:.3g} rad/s²")


def viability(trace: Signals, safe: SafeSet, starts_inside: bool,
              check_bounds: np.ndarray | None = None) -> tuple[bool, str | None]:
    """(whether the run starts in the filter's viable set, why not for a start inside the
    box): the filter's ``cbf_viable`` flag at t = 0, where it wrote one; else the box, the
    set of an unfiltered run (or of a filter that does not say). ``check_bounds``: the
    half-widths of the sets the filter's check holds, where it says."""
    flag = np.asarray(trace[VIABLE][0], float) if VIABLE in trace else np.array(np.nan)
    if not np.isfinite(flag).all():
        return starts_inside, None
    viable = bool(np.all(flag > 0.5))  # 1 or 0; the trace holds floats
    if viable or not starts_inside:
        return viable, None
    uncertain = velocity_uncertain(trace, safe)
    if uncertain:
        return viable, uncertain
    band = in_the_margin(trace, safe, check_bounds)
    if band:
        return viable, band
    need = stopping_need(trace, safe)
    return viable, ("the filter found no torque that keeps the hard sets from this start"
                    + (f" ({need})" if need else ""))


def in_the_margin(trace: Signals, safe: SafeSet, check_bounds: np.ndarray | None
                  ) -> str | None:
    """Why a start inside the box is not viable when a joint starts between the set its
    filter's check holds and the bound (``check_bounds``, (2, n), the check's half-widths;
    the measured position within the noise bound, the velocity's interval): the check
    leaves that band to what its tube does not model, and never calls a state in it
    viable. None otherwise (or without the check's bounds)."""
    sets = position_and_velocity_sets(trace, safe)
    if sets is None or check_bounds is None or "q" not in trace:
        return None
    held = [np.abs(np.asarray(trace["q"][0], float) - sets[0])]
    if all(name in trace for name in ("cbf_velocity_centre", "cbf_velocity_spread")):
        held.append(np.abs(trace["cbf_velocity_centre"][0] - sets[2])
                    + trace["cbf_velocity_spread"][0])
    for row, (reach, quantity, unit) in enumerate(zip(held, ("position", "velocity"),
                                                      ("rad", "rad/s"), strict=False)):
        past = np.flatnonzero(reach > check_bounds[row])
        if len(past):
            j = int(past[np.argmax(reach[past] - check_bounds[row][past])])
            bound = sets[1 + 2 * row][j]
            return (f"joint {j + 1}'s {quantity} starts within the "
                    f"{bound - check_bounds[row][j]:.3g} {unit} the filter's check leaves "
                    f"between its set and the bound ({reach[j]:.5g} against its "
                    f"{check_bounds[row][j]:.5g}, the bound {bound:g}): never viable there")
    return None


def velocity_uncertain(trace: Signals, safe: SafeSet) -> str | None:
    """Why a start is not viable when the velocity the filter holds at t = 0 (its interval,
    x̂2 ± ε from the declared initial error) reaches past a joint's velocity bound: the
    filter cannot tell that start from one outside the set. None otherwise."""
    sets = position_and_velocity_sets(trace, safe)
    if sets is None or not all(name in trace for name in ("cbf_velocity_centre",
                                                          "cbf_velocity_spread")):
        return None
    centre, spread = trace["cbf_velocity_centre"][0], trace["cbf_velocity_spread"][0]
    reach = np.abs(centre - sets[2]) + spread
    over = np.flatnonzero(reach > sets[3])
    if not len(over):
        return None
    j = int(over[np.argmax(reach[over])])
    return ("the velocity the filter holds at t = 0 reaches past the velocity bound (joint "
            f"{j + 1}: {centre[j]:.3g} ± {spread[j]:.3g} rad/s against "
            f"{sets[3][j]:g}; the interval is what the declared initial observer "
            "error allows)")
