"""The framework's own evaluators, on the plant's ports and the declared interface
(:mod:`cosim.interface`): the safe sets of position, velocity, tracking error and its rate
(the paper's (13)-(16), every joint and the norm), the tracking metrics and the torque.
SI units, radians."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from .. import interface as io
from ..declared import joint_boxes
from .checks import Check, Declaration, Kind
from .parts import Part, register_evaluator
from .safety import SafeSet, Signals, torque_reversals

POSITION = Declaration("position", "position x1 − q_s", "rad", Kind.HARD,
                       figure="fig2_position_velocity")
VELOCITY_ESTIMATED = Declaration("velocity_estimated", "velocity the controller used x̂2 − q̇_s",
                                 "rad/s", Kind.SOFT, figure="fig2_position_velocity")
VELOCITY_TRUE = Declaration("velocity_true", "true velocity q̇ − q̇_s", "rad/s", Kind.HARD)
ERROR = Declaration("error", "position error e", "rad", Kind.SOFT, figure="fig3_errors")
ERROR_RATE = Declaration("error_rate", "velocity error ė", "rad/s", Kind.SOFT,
                         figure="fig3_errors")
ERROR_RATE_TRUE = Declaration("error_rate_true", "true velocity error q̇_d − q̇", "rad/s",
                              Kind.SOFT)
# The robot's own limits (safety.limits = "urdf"): the position set's centre is the middle of
# the joint's limits (the margin kept), the velocity's 0, and the torque within the effort.
EFFORT = Declaration("effort", "torque τ within the joint's effort limit", "N·m", Kind.HARD)


def estimates_velocity(constants: Mapping[str, Any]) -> bool:
    """Whether the controller's ė is not the true one: it says so (``velocity_source``),
    and a controller that does not say is assumed to estimate it."""
    return constants.get(io.VELOCITY_SOURCE) != io.TRUE_VELOCITY


@register_evaluator
class SafeSets(Part):
    """The safe sets (13)–(16) on the true state and on the velocity the controller used:
    position, velocity (estimated, true), error, error rate (and the true error rate when
    the controller estimates it); the reference's own values beside them."""

    name = "safe_sets"
    meaning = "safe sets (13)-(16): position, velocity, error and error rate"
    # and the true velocity q̇: where the plant does not map it (NaN), the true-velocity
    # sets are reported unavailable (checks.safety_entries), never as kept
    inputs = ("q", io.SAFE_CENTRE, io.SAFE_VELOCITY_CENTRE, io.DESIRED_POSITION,
              io.DESIRED_VELOCITY, io.TRACKING_ERROR, io.TRACKING_ERROR_RATE)
    declarations = (POSITION, VELOCITY_ESTIMATED, VELOCITY_TRUE, ERROR, ERROR_RATE,
                    ERROR_RATE_TRUE)

    def __init__(self, trace: Signals, safe: SafeSet, constants: Mapping[str, Any],
                 available: frozenset[str] = frozenset()):
        super().__init__(trace, safe, constants, available)
        if "qdot" not in available:
            self.note = ("the true-velocity sets unavailable: the plant does not map its "
                         "joint velocities qdot")

    def _centres(self, rows: Signals) -> tuple[np.ndarray, np.ndarray, Any, Any]:
        """The position and velocity sets' centres and bounds: the paper's radii around
        q_s, q̇_s, or the robot's own limits per joint (safety.limits = "urdf")."""
        safe = self.safe
        n = rows[io.DESIRED_POSITION].shape[1]
        boxes = joint_boxes(safe, n)
        if boxes is None:
            return (rows[io.SAFE_CENTRE], rows[io.SAFE_VELOCITY_CENTRE], safe.position_bound,
                    safe.velocity_bound)
        return (boxes.position_centre, boxes.velocity_centre, boxes.position_half,
                boxes.velocity_half)

    def _sets(self, rows: Signals, with_signals: bool):
        safe = self.safe
        position_centre, velocity_centre, position_bound, velocity_bound = self._centres(rows)
        ref_pos = rows[io.DESIRED_POSITION] - position_centre
        ref_vel = rows[io.DESIRED_VELOCITY] - velocity_centre
        out = [(POSITION, position_bound, ref_pos),
               (VELOCITY_ESTIMATED, velocity_bound, ref_vel),
               (VELOCITY_TRUE, velocity_bound, ref_vel),
               (ERROR, safe.error_bound, None),
               (ERROR_RATE, safe.error_rate_bound, None)]
        if estimates_velocity(self.given):
            out.append((ERROR_RATE_TRUE, safe.error_rate_bound, None))
        if not with_signals:
            return [(declared, None, bound, ref) for declared, bound, ref in out]
        desired = rows[io.DESIRED_VELOCITY]
        signals = {
            "position": rows["q"] - position_centre,
            # x̂2 (output feedback) or q̇ (full state): the velocity the controller used
            "velocity_estimated": desired - rows[io.TRACKING_ERROR_RATE] - velocity_centre,
            "velocity_true": rows["qdot"] - velocity_centre,
            "error": rows[io.TRACKING_ERROR],
            "error_rate": rows[io.TRACKING_ERROR_RATE],
            "error_rate_true": desired - rows["qdot"],
        }
        return [(declared, signals[declared.family], bound, ref)
                for declared, bound, ref in out]

    def checks(self, rows: Signals) -> dict[str, Check]:
        out = {}
        position_centre = self._centres(rows)[0]
        for declared, signal, bound, ref in self._sets(rows, True):
            if np.ndim(bound):  # per-joint bounds: a box of the robot's limits, no norm
                centres = position_centre if declared is POSITION else None
                out.update(declared.joints(signal, bound, ref, centres))
            else:
                out.update(declared.joints_and_norm(signal, bound, ref))
        return out

    def references(self, trace: Signals) -> dict[str, np.ndarray]:
        out = {}
        for declared, _, bound, ref in self._sets(trace, False):
            if ref is not None:
                for j in range(ref.shape[1]):
                    out[declared.name(j + 1)] = ref[:, j]
                if not np.ndim(bound):
                    out[declared.name(None)] = np.linalg.norm(ref, axis=1)
        return out


@register_evaluator
class EffortLimits(Part):
    """|τ_i| ≤ the joint's effort limit, every joint, where the safe sets are the robot's own
    limits (safety.limits = "urdf"); nothing otherwise."""

    name = "effort_limits"
    meaning = "torque within each joint's effort limit (the robot's own limits)"
    inputs = ("tau",)
    declarations = (EFFORT,)

    @classmethod
    def undeclared(cls, safe: SafeSet) -> str | None:
        if getattr(safe, "limits", None) != "urdf":
            return ("no effort limits declared: they are the robot's own (safety.limits = "
                    '"urdf")')
        return None

    def checks(self, rows: Signals) -> dict[str, Check]:
        tau = rows["tau"]
        return EFFORT.joints(tau, joint_boxes(self.safe, tau.shape[1]).effort)


def per_joint(x: np.ndarray) -> list[float]:
    return [float(v) for v in x]


@register_evaluator
class Tracking(Part):
    """RMS and largest tracking error e and error rate ė per joint."""

    name = "tracking"
    meaning = "tracking error e and error rate ė (RMS, largest)"
    inputs = (io.TRACKING_ERROR, io.TRACKING_ERROR_RATE)
    metric_units = {"rms_error": "rad", "max_error": "rad", "rms_error_rate": "rad/s",
                    "max_error_rate": "rad/s"}

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        e, edot = trace[io.TRACKING_ERROR], trace[io.TRACKING_ERROR_RATE]
        return {"rms_error": per_joint(np.sqrt(np.mean(e**2, axis=0))),
                "max_error": per_joint(np.max(np.abs(e), axis=0)),
                "rms_error_rate": per_joint(np.sqrt(np.mean(edot**2, axis=0))),
                "max_error_rate": per_joint(np.max(np.abs(edot), axis=0))}


@register_evaluator
class Torque(Part):
    """Peak and RMS torque per joint, and how often it reverses (chattering)."""

    name = "torque"
    meaning = "torque τ (peak, RMS, reversals per second)"
    inputs = ("tau",)
    metric_units = {"peak_torque": "N·m", "rms_torque": "N·m", "torque_reversals_per_s": "1/s"}

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        tau = trace["tau"]
        return {"peak_torque": per_joint(np.max(np.abs(tau), axis=0)),
                "rms_torque": per_joint(np.sqrt(np.mean(tau**2, axis=0))),
                "torque_reversals_per_s": per_joint(torque_reversals(tau, trace.dt))}

    def report(self, metrics: Mapping[str, Any]) -> tuple[str | None, list[str]]:
        if "peak_torque" not in metrics:
            return None, []
        return None, [f"peak torque [{', '.join(f'{x:.1f}' for x in metrics['peak_torque'])}] "
                      "N·m"]
