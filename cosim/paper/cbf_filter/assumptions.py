"""What a filtered run's guarantee rests on, as the filter publishes it (constant
``safety_filter``) for the evaluation: which signals it reads, the actuator's limits it
keeps, and the disturbance its model assumes. SI units, radians."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

FILTER_ASSUMES = "safety_filter"  # the constant's name
VIABLE = "cbf_viable"  # per step: 1 where a verified torque existed (the state was viable)
BACKUP = "cbf_backup"  # per step: the share of the braking backup in the torque (0 … 1)
# a hard set of the filter (cbf_filter.hard) -> the evaluation's declaration of that set
KEPT_CHECKS = {"position": "position", "velocity": "velocity_true"}


class FilterAssumptions(NamedTuple):
    position: str  # the position signal the filter reads: "q_meas" (measured) or "q"
    velocity: str  # the velocity it reads: "qdot_hat" (the observer's x̂2) or "qdot"
    torque_limit: np.ndarray  # |τ_i| ≤ torque_limit[i], N·m (inf: none)
    tau_d: np.ndarray  # the disturbance torque its model assumes, per joint, N·m
    # the hard sets it keeps, as the evaluation's declarations name them (cbf_filter.hard:
    # "position" -> "position", "velocity" -> "velocity_true"): a hard set it does not keep
    # is never held against it, and a filter that keeps none promises nothing
    keeps: tuple[str, ...] = ("position", "velocity_true")
    # (2, n) the half-widths of the sets its check holds, position (rad) and velocity
    # (rad/s) per joint, about the sets' centres: what is left to the true bound is the
    # allowance for what its first-order tube does not model (None: a filter that does not
    # say)
    check_bounds: np.ndarray | None = None
