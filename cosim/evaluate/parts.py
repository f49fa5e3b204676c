"""The evaluators: each part of a run's evaluation declares the signals and the block
constants it reads, and runs only when the run has them (a run whose chain has no observer
is evaluated without the observer's check and Theorem 1's barriers, and its summary says
why). Like a block, a new evaluator is one class plus :func:`register_evaluator`.

The constants read here are duck-typed: ``nn_gains`` has ``Lambda`` (per joint, 1/s), ``F``
and ``G``; ``observer_gain`` is Fo; ``velocity_source`` is "plant", "observer" or another
estimate.

A part may give, per chunk of rows, safety checks (:class:`Check`, bounded values) and
series (the barriers), and at the end of the run metrics from the completed rows. SI units,
radians. Ground truth (true q̇) is read here for evaluation only, never for control.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from .checks import Check, Declaration, Kind
from .safety import (
    Gains,
    SafeSet,
    Signals,
    barrier_terms_failing,
    barriers,
    condition_summary,
    gain_summary,
    theorem1,
    torque_reversals,
)


class Part:
    """One evaluator. ``inputs``: the trace signals it reads; ``constants``: the constants
    (published by blocks, :attr:`cosim.blocks.Block.publishes`) it needs. Built once the
    blocks are reset (the reference, so every bound, is known)."""

    name: ClassVar[str]
    meaning: ClassVar[str]  # what it evaluates, for the summary
    inputs: ClassVar[tuple[str, ...]]
    constants: ClassVar[tuple[str, ...]] = ()
    # The checks it may make: each family declared once (name, quantity, unit, kind,
    # figure); the evaluation refuses a check made by a declaration not listed here.
    declarations: ClassVar[tuple[Declaration, ...]] = ()

    def __init__(self, trace: Signals, safe: SafeSet, constants: Mapping[str, Any],
                 available: frozenset[str] = frozenset()):
        self.safe = safe
        self.given = constants
        self.available = available  # the run's signals that hold values
        self.note: str | None = None  # what summary.json adds to "ran" (a part left out)

    def checks(self, rows: Signals) -> dict[str, Check]:
        """Safety checks of these rows (each joint and the norm against their bounds), each
        made by a :class:`Declaration` (:meth:`Declaration.joints_and_norm`)."""
        return {}

    def references(self, trace: Signals) -> dict[str, np.ndarray]:
        """The reference trajectory's own value of the checks that have one."""
        return {}

    def series(self, rows: Signals) -> dict[str, np.ndarray]:
        """Other per-row values of these rows (the barriers)."""
        return {}

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        """What summary.json's ``metrics`` gets from the completed rows."""
        return {}


EVALUATORS: dict[str, type[Part]] = {}


def register_evaluator(cls: type[Part]) -> type[Part]:
    """Class decorator: evaluate every run with ``cls`` where its inputs exist."""
    if cls.name in EVALUATORS and EVALUATORS[cls.name] is not cls:
        raise ValueError(f"an evaluator named {cls.name!r} is registered already")
    EVALUATORS[cls.name] = cls
    return cls


def evaluated_signals() -> frozenset[str]:
    """Every signal some evaluator reads (an output only they read is not unused)."""
    return frozenset(s for cls in EVALUATORS.values() for s in cls.inputs)


def select(trace: Signals, constants: Mapping[str, Any],
           unmapped: frozenset[str] = frozenset()
           ) -> tuple[list[type[Part]], dict[str, str]]:
    """(the evaluators whose inputs this run has, why each other one does not run);
    ``unmapped``: plant outputs in the trace that the plant does not map (NaN, absent)."""
    chosen, skipped = [], {}
    for name, cls in EVALUATORS.items():
        signals = [s for s in cls.inputs if s not in trace]
        ports = [s for s in cls.inputs if s in unmapped]
        missing = [c for c in cls.constants if c not in constants]
        if not signals and not ports and not missing:
            chosen.append(cls)
            continue
        why = []
        if signals:
            why.append(f"needs {_listed('signal', signals)}, which no block in the chain "
                       "produces")
        if ports:
            why.append(f"needs {_listed('plant output', ports)}, which the plant does not "
                       "map")
        if missing:
            why.append(f"needs {_listed('constant', missing)}, which no block in the chain "
                       "publishes")
        skipped[name] = "; ".join(why)
    return chosen, skipped


def _listed(what: str, names: list[str]) -> str:
    quoted = ", ".join(f"'{n}'" for n in names)
    return f"the {what}{'s' * (len(names) > 1)} {quoted}"


# The paper's safe sets (13)-(16), every joint and the norm; the figures are the paper's
# Figs. 2 and 3.
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
FILTERED_ERROR = Declaration("filtered_error", "filtered error r̂ (Theorem 1's R)", "rad/s",
                             Kind.SUFFICIENT, norm_kind=Kind.SUFFICIENT)
OBSERVER_ERROR = Declaration("observer_error", "observer velocity error q̇ − x̂2 (ε_max of (16))",
                             "rad/s", Kind.SOFT)


def _estimates_velocity(constants: Mapping[str, Any]) -> bool:
    """Whether the controller's ė is not the true one: it says so (``velocity_source``),
    and a controller that does not say is assumed to estimate it."""
    return constants.get("velocity_source") != "plant"


@register_evaluator
class SafeSets(Part):
    """The safe sets (13)–(16) on the true state and on the velocity the controller used:
    position, velocity (estimated, true), error, error rate (and the true error rate when
    the controller estimates it); the reference's own values beside them."""

    name = "safe_sets"
    meaning = "safe sets (13)-(16): position, velocity, error and error rate"
    # and the true velocity q̇: where the plant does not map it (NaN), the true-velocity
    # sets are reported unavailable (safety.safety_entries), never as kept
    inputs = ("q", "q_s", "qdot_s", "q_d", "qdot_d", "e", "edot")
    declarations = (POSITION, VELOCITY_ESTIMATED, VELOCITY_TRUE, ERROR, ERROR_RATE,
                    ERROR_RATE_TRUE)

    def __init__(self, trace: Signals, safe: SafeSet, constants: Mapping[str, Any],
                 available: frozenset[str] = frozenset()):
        super().__init__(trace, safe, constants, available)
        if "qdot" not in available:
            self.note = ("the true-velocity sets unavailable: the plant does not map its "
                         "joint velocities qdot")

    def _sets(self, rows: Signals, with_signals: bool):
        safe = self.safe
        ref_pos = rows["q_d"] - rows["q_s"]
        ref_vel = rows["qdot_d"] - rows["qdot_s"]
        out = [(POSITION, safe.position_bound, ref_pos),
               (VELOCITY_ESTIMATED, safe.velocity_bound, ref_vel),
               (VELOCITY_TRUE, safe.velocity_bound, ref_vel),
               (ERROR, safe.error_bound, None),
               (ERROR_RATE, safe.error_rate_bound, None)]
        if _estimates_velocity(self.given):
            out.append((ERROR_RATE_TRUE, safe.error_rate_bound, None))
        if not with_signals:
            return [(declared, None, bound, ref) for declared, bound, ref in out]
        signals = {
            "position": rows["q"] - rows["q_s"],
            # x̂2 (output feedback) or q̇ (full state): the velocity the controller used
            "velocity_estimated": rows["qdot_d"] - rows["edot"] - rows["qdot_s"],
            "velocity_true": rows["qdot"] - rows["qdot_s"],
            "error": rows["e"],
            "error_rate": rows["edot"],
            "error_rate_true": rows["qdot_d"] - rows["qdot"],
        }
        return [(declared, signals[declared.family], bound, ref)
                for declared, bound, ref in out]

    def checks(self, rows: Signals) -> dict[str, Check]:
        out = {}
        for declared, signal, bound, ref in self._sets(rows, True):
            out.update(declared.joints_and_norm(signal, bound, ref))
        return out

    def references(self, trace: Signals) -> dict[str, np.ndarray]:
        out = {}
        for declared, _, _, ref in self._sets(trace, False):
            if ref is not None:
                for j in range(ref.shape[1]):
                    out[declared.name(j + 1)] = ref[:, j]
                out[declared.name(None)] = np.linalg.norm(ref, axis=1)
        return out


@register_evaluator
class FilteredError(Part):
    """‖r̂‖ against R of Theorem 1 (15), the bound on the filtered error under which the
    error sets hold; R depends on the whole reference and on the controller's Λ."""

    name = "filtered_error"
    meaning = "Theorem 1: ‖r̂‖ ≤ R of (15)"
    inputs = ("r_hat", "q_s", "qdot_s", "q_d", "qdot_d")
    constants = ("nn_gains",)
    declarations = (FILTERED_ERROR,)

    def __init__(self, trace: Signals, safe: SafeSet, constants: Mapping[str, Any],
                 available: frozenset[str] = frozenset()):
        super().__init__(trace, safe, constants, available)
        self.lam = constants["nn_gains"].Lambda
        self.r_bound = theorem1(trace, safe, self.lam)["R"]

    def checks(self, rows: Signals) -> dict[str, Check]:
        return {FILTERED_ERROR.name(None): FILTERED_ERROR.norm(
            np.linalg.norm(rows["r_hat"], axis=1), self.r_bound)}

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        return {"theorem1": theorem1(trace, self.safe, self.lam)}


@register_evaluator
class ObserverError(Part):
    """The observer's velocity error q̇ − x̂2: against ε_max of (16) when the controller
    feeds back x̂2, and its RMS after the first second."""

    name = "observer_error"
    meaning = "the observer's velocity error q̇ − x̂2 against ε_max of (16)"
    # and the true q̇: where the plant does not map it, the check is unavailable (as the
    # true-velocity sets) and the RMS is None
    inputs = ("qdot_hat",)
    declarations = (OBSERVER_ERROR,)

    def __init__(self, trace: Signals, safe: SafeSet, constants: Mapping[str, Any],
                 available: frozenset[str] = frozenset()):
        super().__init__(trace, safe, constants, available)
        self.true_velocity = "qdot" in available
        if not self.true_velocity:
            self.note = "its check unavailable: the plant does not map qdot"
        elif "velocity_source" not in constants:
            self.note = ("no check against ε_max: no block publishes velocity_source = "
                         "\"observer\" (a controller that feeds back x̂2 says so)")

    def checks(self, rows: Signals) -> dict[str, Check]:
        if self.given.get("velocity_source") != "observer":
            return {}
        return {OBSERVER_ERROR.name(None): OBSERVER_ERROR.norm(
            np.linalg.norm(rows["qdot"] - rows["qdot_hat"], axis=1),
            self.safe.observer_error_bound)}

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        after_1s = trace.time >= 1.0
        if not (self.true_velocity and after_1s.any()):
            return {"observer_velocity_error_rms_after_1s": None}
        error = (trace["qdot"] - trace["qdot_hat"])[after_1s]
        return {"observer_velocity_error_rms_after_1s": [
            float(v) for v in np.sqrt(np.mean(error**2, axis=0))]}


@register_evaluator
class Barriers(Part):
    """Theorem 1's barrier functions H1 (28), H2 (29), H = H1 + H2 and the condition
    Ḣ + αH ≥ 0 per row, and per term what fails."""

    name = "barriers"
    meaning = "Theorem 1's barriers H1 (28), H2 (29) and Ḣ + αH ≥ 0"
    # M(q) is the plant's where it maps it, else the controller's model M̂ (safety.barriers)
    inputs = ("q", "qdot", "q_hat", "qdot_hat", "k0", "W_o_norm", "r_hat", "e", "W_norm",
              "V_norm", "M_model", "q_s", "qdot_s", "q_d", "qdot_d")
    constants = ("nn_gains", "observer_gain")

    def __init__(self, trace: Signals, safe: SafeSet, constants: Mapping[str, Any],
                 available: frozenset[str] = frozenset()):
        super().__init__(trace, safe, constants, available)
        nn = constants["nn_gains"]
        self.gains = Gains(nn.Lambda, nn.F, nn.G, constants["observer_gain"],
                           constants.get("velocity_source") == "observer")
        self.r_bound = theorem1(trace, safe, nn.Lambda)["R"]

    def series(self, rows: Signals) -> dict[str, np.ndarray]:
        return barriers(rows, self.safe, self.gains, self.r_bound)

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        def lowest(x: np.ndarray) -> float:
            return float(np.min(x)) if len(x) else float("nan")

        return {"min_barrier_H": lowest(series["H"]), "min_barrier_H1": lowest(series["H1"]),
                "min_barrier_H2": lowest(series["H2"]),
                "barrier_condition": condition_summary(series["condition"],
                                                       self.safe.barrier_alpha),
                "barrier_condition_terms": barrier_terms_failing(trace, series, self.safe)}


def _per_joint(x: np.ndarray) -> list[float]:
    return [float(v) for v in x]


@register_evaluator
class Tracking(Part):
    """RMS and largest tracking error e and error rate ė per joint."""

    name = "tracking"
    meaning = "tracking error e and error rate ė (RMS, largest)"
    inputs = ("e", "edot")

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        e, edot = trace["e"], trace["edot"]
        return {"rms_error": _per_joint(np.sqrt(np.mean(e**2, axis=0))),
                "max_error": _per_joint(np.max(np.abs(e), axis=0)),
                "rms_error_rate": _per_joint(np.sqrt(np.mean(edot**2, axis=0))),
                "max_error_rate": _per_joint(np.max(np.abs(edot), axis=0))}


@register_evaluator
class Torque(Part):
    """Peak and RMS torque per joint, and how often it reverses (chattering)."""

    name = "torque"
    meaning = "torque τ (peak, RMS, reversals per second)"
    inputs = ("tau",)

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        tau = trace["tau"]
        return {"peak_torque": _per_joint(np.max(np.abs(tau), axis=0)),
                "rms_torque": _per_joint(np.sqrt(np.mean(tau**2, axis=0))),
                "torque_reversals_per_s": _per_joint(torque_reversals(tau, trace.dt))}


@register_evaluator
class FeedbackGain(Part):
    """The controller's effective feedback gain on r̂ (median, 95th percentile, largest)."""

    name = "feedback_gain"
    meaning = "the effective feedback gain ‖τ_feedback‖/‖r̂‖"
    inputs = ("feedback_gain", "r_hat")

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        return {"feedback_gain": gain_summary(trace)}
