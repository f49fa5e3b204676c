"""Whether a run is one the safety filter's guarantee speaks for, and whether it held.

The guarantee: a run that starts inside the hard (physical) sets, whose hard QP is
feasible at every step and whose plant and signals stay within the declared uncertainty
(``[uncertainty]``) never leaves a hard set. Each run is classified on the true state:

- ``starts_inside``: every joint's position and true velocity inside its set at t = 0
  (and, apart, ``starts_inside_observer_set``: |q̇(0) − x̂2(0)| ≤ ε_max of Theorem 2);
- ``feasible``: no step where the filter's hard part was infeasible (None: no filter);
- ``within_bounds``: the payload, the noise, the initial observer error and the observer
  bound ε(t) stay as declared (``outside`` names each one that did not);
- ``hard_kept`` / ``first_exit``: whether, and where first, a hard set was left;
- ``broken``: left a hard set while all three held — a broken guarantee.

Ground truth is used here, for evaluation only. SI units, radians.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from plant_fmu.models.planar_arm import MAX_LINKS
from plant_fmu.models.planar_arm import variables as rigid_arm_variables

from .. import interface as io
from ..declared import Uncertainty
from ..evaluate import Check, Kind, Part, register_evaluator
from ..evaluate.safety import SafeSet, Signals
from ..signals import Trace

# A tolerance for comparing declared and actual parameter values (rounding in TOML, FMI).
PARAMETER_TOLERANCE = 1e-9
INFEASIBLE = "cbf_infeasible"  # the filter's flag: its hard QP was infeasible at this step
ACTIVE = "cbf_active"  # the filter's flag: it changed the torque at this step


def rigid_chain_parameters(links: int) -> frozenset[str] | None:
    """The parameter names of the rigid arm's FMU: the model the filter's guarantee
    assumes (None beyond the built-in arm's link count)."""
    if links > MAX_LINKS:
        return None
    return frozenset(v.name for v in rigid_arm_variables(links) if v.causality == "parameter")


def plant_payload(parameters: dict, chain, modelled: frozenset[str] | None = None
                  ) -> tuple[float | None, list[str]]:
    """The payload the plant carries against the nominal chain (m[n] − m_n, kg), and what
    else sets the plant apart from it: link parameters that differ, and parameters the
    rigid chain's model does not have (``modelled``: its parameter names; the joint
    springs of the elastic-joint arm, say). (None, []) when the plant does not expose the
    chain's parameters (a foreign FMU)."""
    if chain is None:
        return None, []
    n = len(chain.m)
    names = {"m": chain.m, "l": chain.l, "lc": chain.lc, "I": chain.inertia}
    if not all(f"{key}[{i}]" in parameters for key in names for i in range(1, n + 1)):
        return None, []
    differ = [f"{key}[{i + 1}] = {parameters[f'{key}[{i + 1}]']:g} (nominal {values[i]:g})"
              for key, values in names.items() for i in range(n)
              if not (key == "m" and i == n - 1)
              and abs(parameters[f"{key}[{i + 1}]"] - values[i]) > PARAMETER_TOLERANCE]
    if modelled is not None:
        extra = [name for name in parameters if name not in modelled]
        if extra:
            shown = ", ".join(extra[:6]) + (f" and {len(extra) - 6} more" if len(extra) > 6
                                            else "")
            differ.append(f"has parameters the nominal rigid chain does not ({shown}): it is "
                          "another model")
    return float(parameters[f"m[{n}]"] - chain.m[n - 1]), differ


def hard_checks(checks: Mapping[str, Check]) -> dict[str, Check]:
    """The run's hard sets, per joint (their declarations say so), that hold values."""
    return {name: c for name, c in checks.items()
            if c.declared is not None and c.joint is not None
            and c.declared.kind_of(c.joint) == Kind.HARD and np.isfinite(c.value).any()}


def classify(trace: Trace, safe: SafeSet, uncertainty: Uncertainty,
             payload: float | None, other_parameters: list[str],
             true_velocity: bool = True, checks: Mapping[str, Check] | None = None) -> dict:
    """The run's class and outcome (module docstring); ``payload``: what the plant carries
    (None: unknown), ``other_parameters``: plant link parameters off the nominal chain;
    ``true_velocity``: whether the plant maps q̇ (if not, the velocity set cannot be judged
    and the run is outside what the guarantee speaks for); ``checks``: the run's evaluated
    checks (default: evaluated here), of which the hard ones are judged."""
    if trace.rows_done == 0:
        return {}
    if checks is None:
        from ..evaluate import Evaluator

        checks = Evaluator(trace, safe, {}).result().checks
    hard = hard_checks(checks)
    starts_inside = not any(bool(c.outside[0]) for c in hard.values())
    first_exit = None
    for name, check in hard.items():  # declaration order: the lowest joint first at a tie
        rows = np.flatnonzero(check.outside)
        if len(rows) and (first_exit is None or rows[0] * trace.dt < first_exit["t"]):
            first_exit = {"set": name, "t": float(rows[0] * trace.dt),
                          "value": float(check.magnitude[rows[0]]),
                          "bound": float(check.upper)}
    outside = []
    low, high = uncertainty.payload
    if payload is None:
        outside.append("payload unknown (the plant does not expose the nominal chain's "
                       "parameters)")
    elif not low - PARAMETER_TOLERANCE <= payload <= high + PARAMETER_TOLERANCE:
        outside.append(f"payload {payload:g} kg outside [{low:g}, {high:g}]")
    outside += [f"plant {text}" for text in other_parameters]
    if not true_velocity:
        outside.append("true velocity unknown (the plant does not map qdot): the velocity set "
                       "cannot be judged")
    if "q_meas" in trace:
        noise = float(np.max(np.abs(trace["q_meas"] - trace["q"])))
        if noise > uncertainty.noise_bound:
            outside.append(f"noise {noise:.3g} rad > {uncertainty.noise_bound:g}")
    out = {"starts_inside": starts_inside}
    if true_velocity and "qdot_hat" in trace and np.isfinite(trace["qdot_hat"][0]).all():
        error = np.abs(trace["qdot"] - trace["qdot_hat"])
        out["starts_inside_observer_set"] = bool(
            np.linalg.norm(error[0]) <= safe.observer_error_bound)
        if np.max(error[0]) > uncertainty.initial_velocity_error:
            outside.append(f"initial observer error {np.max(error[0]):.3g} rad/s > "
                           f"{uncertainty.initial_velocity_error:g}")
        if "qdot_hat_bound" in trace:
            over = error > trace["qdot_hat_bound"]
            if over.any():
                rows = np.flatnonzero(over.any(axis=1))
                outside.append(f"observer error above ε(t) at {len(rows)} steps (first "
                               f"t = {rows[0] * trace.dt:.4g} s): the declared "
                               "observer_residual_rate was exceeded")
    feasible = None
    if INFEASIBLE in trace:
        steps = int(np.sum(trace[INFEASIBLE] > 0))
        feasible = steps == 0
        out["infeasible_steps"] = steps
    out.update(feasible=feasible, within_bounds=not outside, outside=outside,
               hard_kept=first_exit is None, first_exit=first_exit)
    out["broken"] = bool(starts_inside and feasible is True and not outside
                         and first_exit is not None)
    return out


@register_evaluator
class Guarantee(Part):
    """The filter's guarantee on a run (:func:`classify`), from its evaluated hard sets, the
    plant's parameters against the nominal chain a block publishes, and the declared
    uncertainty; the line `cosim run` prints of it for a filtered run; and how often the
    filter changed the torque."""

    name = "guarantee"
    meaning = "whether the safety filter's guarantee covers the run, and whether it held"
    inputs = ("q",)
    constants = (io.PLANT_PARAMETERS, io.UNCERTAINTY)

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        if ACTIVE not in trace or not len(trace[ACTIVE]):
            return {}
        return {"filter_active_fraction": float(np.mean(trace[ACTIVE] > 0))}

    def conclude(self, trace: Signals, checks: Mapping[str, Check]) -> dict:
        chain = self.given.get(io.PLANT_MODEL)
        payload, other = plant_payload(self.given[io.PLANT_PARAMETERS], chain,
                                       rigid_chain_parameters(trace.links))
        return {"guarantee": classify(trace, self.safe, self.given[io.UNCERTAINTY], payload,
                                      other, true_velocity="qdot" in self.available,
                                      checks=checks)}

    def report(self, metrics: Mapping[str, Any]) -> tuple[str | None, list[str]]:
        g = metrics.get("guarantee") or {}
        if g.get("feasible") is None:  # not a filtered run: nothing to say
            return None, []
        covered = g["starts_inside"] and g["feasible"] and g["within_bounds"]
        exit_text = (f"left {g['first_exit']['set']} at {g['first_exit']['t']:.3f} s"
                     if g["first_exit"] else "kept every hard set")
        why = [*(["started outside"] if not g["starts_inside"] else []),
               *([f"{g['infeasible_steps']} infeasible step(s)"] if not g["feasible"] else []),
               *g["outside"]]
        return (f"{exit_text}; guarantee "
                + ("covers this run" if covered else "does not cover this run: "
                   + "; ".join(why))
                + (" — BROKEN" if g["broken"] else "")), []
