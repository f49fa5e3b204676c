"""The paper's evaluators: Theorem 1's bound on ‖r̂‖ (a sufficient condition), the
observer's velocity error against ε_max of (16), the barriers H1 (28), H2 (29) and their
condition, and the controller's effective feedback gain. Registered like a user's
evaluators. SI units, radians; ground truth read for evaluation only."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from .. import interface as io
from ..evaluate import Check, Declaration, Kind, Part, SafeSet, register_evaluator
from ..evaluate.safety import Signals
from .barrier_bounds import barrier_bounds
from .theorem import (
    BARRIER_MEANINGS,
    Gains,
    barrier_condition,
    barrier_terms_failing,
    barriers,
    condition_summary,
    gain_summary,
    theorem1,
)

FILTERED_ERROR = Declaration("filtered_error", "filtered error r̂ (Theorem 1's R)", "rad/s",
                             Kind.SUFFICIENT, norm_kind=Kind.SUFFICIENT)
OBSERVER_ERROR = Declaration("observer_error", "observer velocity error q̇ − x̂2 (ε_max of (16))",
                             "rad/s", Kind.SOFT)
OBSERVER = "observer"  # the controller's velocity_source when it feeds back x̂2


@register_evaluator
class FilteredError(Part):
    """‖r̂‖ against R of Theorem 1 (15), the bound on the filtered error under which the
    error sets hold; R depends on the whole reference and on the controller's Λ."""

    name = "filtered_error"
    meaning = "Theorem 1: ‖r̂‖ ≤ R of (15)"
    inputs = ("r_hat", io.SAFE_CENTRE, io.SAFE_VELOCITY_CENTRE, io.DESIRED_POSITION,
              io.DESIRED_VELOCITY)
    constants = ("nn_gains",)
    declarations = (FILTERED_ERROR,)
    metric_units = {"theorem1.E1_formula": "rad", "theorem1.E1": "rad",
                    "theorem1.E2_formula": "rad/s", "theorem1.E2": "rad/s",
                    "theorem1.M_R": "rad/s", "theorem1.M_r": "rad/s", "theorem1.R": "rad/s"}

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
    metric_units = {"observer_velocity_error_rms_after_1s": "rad/s"}

    def __init__(self, trace: Signals, safe: SafeSet, constants: Mapping[str, Any],
                 available: frozenset[str] = frozenset()):
        super().__init__(trace, safe, constants, available)
        self.bound = barrier_bounds(safe).observer_error_bound  # ε_max, rad/s
        self.true_velocity = "qdot" in available
        if not self.true_velocity:
            self.note = "its check unavailable: the plant does not map qdot"
        elif io.VELOCITY_SOURCE not in constants:
            self.note = ("no check against ε_max: no block publishes velocity_source = "
                         "\"observer\" (a controller that feeds back x̂2 says so)")

    def checks(self, rows: Signals) -> dict[str, Check]:
        if self.given.get(io.VELOCITY_SOURCE) != OBSERVER:
            return {}
        return {OBSERVER_ERROR.name(None): OBSERVER_ERROR.norm(
            np.linalg.norm(rows["qdot"] - rows["qdot_hat"], axis=1),
            self.bound)}

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        after_1s = trace.time >= 1.0
        if not (self.true_velocity and after_1s.any()):
            return {"observer_velocity_error_rms_after_1s": None}
        error = (trace["qdot"] - trace["qdot_hat"])[after_1s]
        return {"observer_velocity_error_rms_after_1s": [
            float(v) for v in np.sqrt(np.mean(error**2, axis=0))]}

    def report(self, metrics: Mapping[str, Any]) -> tuple[str | None, list[str]]:
        rms = metrics.get("observer_velocity_error_rms_after_1s")
        if not rms:
            return None, []
        return None, ["observer velocity RMS error after 1 s "
                      f"[{', '.join(f'{x:.3f}' for x in rms)}] rad/s"]


@register_evaluator
class Barriers(Part):
    """Theorem 1's barrier functions H1 (28), H2 (29), H = H1 + H2 and the condition
    Ḣ + αH ≥ 0 per row, and per term what fails."""

    name = "barriers"
    meaning = "Theorem 1's barriers H1 (28), H2 (29) and Ḣ + αH ≥ 0"
    # M(q) is the plant's where it maps it, else the controller's model M̂ (safety.barriers)
    inputs = ("q", "qdot", "q_hat", "qdot_hat", "k0", "W_o_norm", "r_hat", io.TRACKING_ERROR,
              "W_norm", "V_norm", "M_model", io.SAFE_CENTRE, io.SAFE_VELOCITY_CENTRE,
              io.DESIRED_POSITION, io.DESIRED_VELOCITY)
    constants = ("nn_gains", "observer_gain")
    series_meanings = {**BARRIER_MEANINGS}
    conditions = ("condition",)
    series_figure = "fig5_barriers"  # the paper's Fig. 5
    # the paper's barriers mix units (theorem.BARRIER_MEANINGS); the shares are fractions
    metric_units = {"min_barrier_H": "mixed", "min_barrier_H1": "mixed",
                    "min_barrier_H2": "mixed", "barrier_condition": "1",
                    "barrier_condition.alpha": "1/s", "barrier_condition.worst": "1/s × H",
                    "barrier_condition_terms": "1"}

    def __init__(self, trace: Signals, safe: SafeSet, constants: Mapping[str, Any],
                 available: frozenset[str] = frozenset()):
        super().__init__(trace, safe, constants, available)
        nn = constants["nn_gains"]
        self.gains = Gains(nn.Lambda, nn.F, nn.G, constants["observer_gain"],
                           constants.get(io.VELOCITY_SOURCE) == OBSERVER)
        self.r_bound = theorem1(trace, safe, nn.Lambda)["R"]
        self.alpha = barrier_bounds(safe).barrier_alpha
        self.dt = trace.dt
        self.last_h = np.nan  # H of the row before the next chunk (none before the first)

    def series(self, rows: Signals) -> dict[str, np.ndarray]:
        h = barriers(rows, self.safe, self.gains, self.r_bound)
        h["condition"] = barrier_condition(h["H"], self.last_h, self.dt,
                                           self.alpha)
        if len(h["H"]):
            self.last_h = h["H"][-1]
        return h

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        def lowest(x: np.ndarray) -> float:
            return float(np.min(x)) if len(x) else float("nan")

        return {"min_barrier_H": lowest(series["H"]), "min_barrier_H1": lowest(series["H1"]),
                "min_barrier_H2": lowest(series["H2"]),
                "barrier_condition": condition_summary(series["condition"],
                                                       self.alpha),
                "barrier_condition_terms": barrier_terms_failing(trace, series, self.safe)}

    def report(self, metrics: Mapping[str, Any]) -> tuple[str | None, list[str]]:
        condition = metrics["barrier_condition"]
        return None, [f"min H {metrics['min_barrier_H']:.3g} (H1 {metrics['min_barrier_H1']:.3g}, "
                      f"H2 {metrics['min_barrier_H2']:.3g}); dH/dt + {condition['alpha']:g} H < 0 "
                      f"in {100 * (condition['fraction_failing'] or 0):.1f} % of steps"]


@register_evaluator
class FeedbackGain(Part):
    """The controller's effective feedback gain on r̂ (median, 95th percentile, largest)."""

    name = "feedback_gain"
    meaning = "the effective feedback gain ‖τ_feedback‖/‖r̂‖"
    inputs = ("feedback_gain", "r_hat")
    metric_units = {"feedback_gain": "N·m·s/rad"}

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        return {"feedback_gain": gain_summary(trace)}

    def report(self, metrics: Mapping[str, Any]) -> tuple[str | None, list[str]]:
        gain = metrics.get("feedback_gain")
        if not gain:
            return None, []
        return None, [f"effective gain on r̂ (median) {gain['median']:.1f} N·m·s/rad"]

