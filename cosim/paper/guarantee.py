"""Whether a run is one the safety filter's guarantee speaks for, and whether it held.

The guarantee: a filtered run that starts inside the filter's *viable* set (the states from
which its torque limits can still keep every hard set under the declared uncertainty) and
whose plant and signals stay within what is declared (``[uncertainty]``, and the nominal
model for everything not declared uncertain) never leaves a hard set, finds the state
viable (a verified torque) at every step, keeps the observer bound ε(t) it rests on and the
premises of its check, and never exceeds its torque limit. Each run is classified on the
true state:

- ``starts_inside``: every joint's position and true velocity inside its set at t = 0 (the
  box); ``starts_viable``: the filter's ``cbf_viable`` flag at t = 0 (without one: the box),
  and ``not_viable``, why a start inside the box is not viable (else None); apart,
  ``starts_inside_observer_set``: |q̇(0) − x̂2(0)| ≤ ε_max of Theorem 2;
- ``within_bounds`` / ``outside``: the payload, every other plant parameter against the
  nominal model (gravity, friction, disturbance, links), a system's components beside the
  arm (a drive's rotor inertia, and the torque its lag or limit kept from the arm within
  the declared disturbance), and what the filter reads — the noise if it reads the
  measured position, the initial observer error if it reads the observer's velocity — as
  declared (``outside`` names each one that is not; :mod:`.within_bounds`);
- ``feasible`` / ``infeasible_steps``: no step where the filter found the state not viable
  (``cbf_infeasible``: no torque verified, the backup acted) (None: no filter);
- ``hard_kept`` / ``first_exit``: whether, and where first, a hard set was left, and the
  recovery: ``returned``, ``time_to_return_s``, ``back_within_1s``, ``excursions``;
- ``covered``: a filtered run that starts inside and is within bounds, and either starts
  viable or, reading the observer's velocity, was not viable at t = 0 only because of the
  velocity's declared initial error and became viable later with no hard set left before:
  covered from then on (``covered_from_s``, :func:`covered_from`) (a start outside a set is
  one to recover from, reported, not kept); ``violations``: what the guarantee promised a
  covered run that did not hold (a hard set left, ε(t) exceeded, |τ| above the limit; from
  the step it is covered from, a step not viable and a failed premise of the check:
  :func:`measured_premises`); ``broken``: covered with a violation;
- ``torque``: where each joint's largest |τ| comes from (:func:`torque_peaks`): at
  start-up, before the filter first found the state viable, or later, and how much of it
  was the braking backup's.

What a run's filter does not read never excuses it: a filter reading the true velocity is
not excused by the observer's error, nor one reading the true position by the noise. An
exceedance of ε(t) while its inputs (noise, initial error, payload) are as declared is a
violation, not "outside": the bound is the filter's own claim.

Ground truth is used here, for evaluation only. SI units, radians.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from .. import interface as io
from ..declared import Uncertainty
from ..evaluate import Check, Kind, Part, register_evaluator
from ..evaluate.safety import SafeSet, Signals
from ..signals import Trace
from .cbf_filter.assumptions import (
    BACKUP,
    FILTER_ASSUMES,
    KEPT_CHECKS,
    VIABLE,
    FilterAssumptions,
)
from .premises import between_samples, interval_exceedances, tube_exceedances
from .viable_start import position_and_velocity_sets, velocity_uncertain, viability
from .within_bounds import (
    declared_inputs,
    disturbance_differences,
    plant_model_difference,
    plant_payload,
    rigid_chain_parameters,
    system_differences,
    undeclared_differences,
)

# |τ_i| ≤ limit·(1 + this) is within the limit: the filter clips to the limit exactly, and
# only the last bits may differ.
TORQUE_TOLERANCE = 1e-9
RETURN_WITHIN = 1.0  # s: how soon a run that left a set should be back inside (issue 30)
INFEASIBLE = "cbf_infeasible"  # the filter's flag: no torque verified (not viable) this step
ACTIVE = "cbf_active"  # the filter's flag: it changed the torque at this step
OBSERVER_TAU_D = "tau_d_model"  # the observer's constant: the τ_d its model assumes, N·m


KEPT_SETS = frozenset(KEPT_CHECKS.values())  # the hard sets a filter may keep or not


def hard_checks(checks: Mapping[str, Check]) -> dict[str, Check]:
    """The run's hard sets, per joint (their declarations say so), that hold values."""
    return {name: c for name, c in checks.items()
            if c.declared is not None and c.joint is not None
            and c.declared.kind_of(c.joint) == Kind.HARD and np.isfinite(c.value).any()}


def first_exit(hard: Mapping[str, Check], dt: float) -> dict | None:
    """Where a hard set was first left: its name, time (s), |value| and bound in the set's
    unit (rad or rad/s, named); None if never. In declaration order: the lowest joint first
    at a tie."""
    first = None
    for name, check in hard.items():
        rows = np.flatnonzero(check.outside)
        if len(rows) and (first is None or rows[0] * dt < first["t"]):
            first = {"set": name, "t": float(rows[0] * dt),
                     "value": float(check.magnitude[rows[0]]), "bound": float(check.upper),
                     "unit": check.declared.unit}
    return first


def recovery(hard: Mapping[str, Check], dt: float) -> dict:
    """How the run came back into the hard sets it left (or started outside): per set, its
    excursions, each from its first row outside to the first row back inside. ``returned``:
    every excursion ended before the trace did; ``time_to_return_s``: the longest excursion,
    s (while still outside at the end, how long it had lasted: a lower bound);
    ``back_within_1s``: returned, every excursion within :data:`RETURN_WITHIN`;
    ``excursions``: one line per set left. None (and []) when no hard set was ever left."""
    longest, returned, lines = None, True, []
    for name, check in hard.items():
        outside = check.outside
        if not outside.any():
            continue
        edges = np.diff(np.concatenate(([0], outside.astype(np.int8), [0])))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        ended = bool(ends[-1] < len(outside))  # else outside at the last row
        worst = float(np.max(ends - starts) * dt)
        longest = worst if longest is None else max(longest, worst)
        returned = returned and ended
        lines.append(f"{name}: {len(starts)} excursion(s), the longest {worst:.3f} s"
                     + ("" if ended else ", still outside at the end"))
    if longest is None:
        return {"returned": None, "time_to_return_s": None, "back_within_1s": None,
                "excursions": []}
    return {"returned": returned, "time_to_return_s": longest,
            "back_within_1s": bool(returned and longest <= RETURN_WITHIN),
            "excursions": lines}


def torque_violation(trace: Signals, assumes: FilterAssumptions | None
                     ) -> tuple[int | None, str | None]:
    """(steps where some |τ_i| exceeded the filter's torque limit, what was exceeded); None
    counts when the filter declares no limit (or the trace has no τ)."""
    if assumes is None or "tau" not in trace:
        return None, None
    tau = np.abs(trace["tau"])
    limit = np.broadcast_to(np.asarray(assumes.torque_limit, float), tau.shape[1:])
    over = tau > limit * (1.0 + TORQUE_TOLERANCE)
    rows = np.flatnonzero(over.any(axis=1))
    if not len(rows):
        return 0, None
    j = int(np.argmax(np.max(np.where(over, tau - limit, 0.0), axis=0)))
    return len(rows), (f"|τ| above the filter's torque limit at {len(rows)} steps (first "
                       f"t = {rows[0] * trace.dt:.4g} s, joint {j + 1} up to "
                       f"{np.max(tau[:, j]):.4g} N·m > {limit[j]:g} N·m)")


def torque_peaks(trace: Signals, assumes: FilterAssumptions | None) -> dict | None:
    """Where each joint's largest |τ_i| comes from, for a filtered run: ``startup_steps``,
    the steps before the first the filter found viable (None: never); per joint, the peak's
    time ``peak_t`` (s), whether it fell in those steps ``peak_at_startup``, its share of the
    torque limit ``peak_of_limit`` (None: no limit), the backup's share of the torque there
    ``peak_backup_share``, and the largest |τ_i| before that first viable step
    ``peak_during_startup`` (None: viable at once) and from it on ``peak_after_startup``, N·m."""
    if "tau" not in trace or not len(trace["tau"]):
        return None
    tau = np.abs(np.asarray(trace["tau"], float))
    joints = tau.shape[1]
    limit = np.broadcast_to(np.asarray(assumes.torque_limit if assumes is not None
                                       else np.inf, float), (joints,))
    viable = np.asarray(trace[VIABLE], float) > 0.5 if VIABLE in trace else None
    first = int(np.argmax(viable)) if viable is not None and viable.any() else None
    backup = np.asarray(trace[BACKUP], float) if BACKUP in trace else None
    at = np.argmax(tau, axis=0)
    return {"startup_steps": first,
            "peak_t": [float(k * trace.dt) for k in at],
            "peak_at_startup": [bool(first is None or k < first) for k in at],
            "peak_of_limit": [float(tau[k, j] / limit[j]) if math.isfinite(limit[j]) else None
                              for j, k in enumerate(at)],
            "peak_backup_share": [float(backup[k]) if backup is not None else None
                                  for k in at],
            "peak_during_startup": [float(np.max(tau[:first, j])) if first != 0 else None
                                    for j in range(joints)],
            "peak_after_startup": [float(np.max(tau[first:, j])) if first is not None else None
                                   for j in range(joints)]}


def classify(trace: Trace, safe: SafeSet, uncertainty: Uncertainty,
             payload: float | None, other_parameters: list[str],
             true_velocity: bool = True, checks: Mapping[str, Check] | None = None,
             assumes: FilterAssumptions | None = None) -> dict:
    """The run's class and outcome (module docstring); ``payload``: what the plant carries
    (None: unknown), ``other_parameters``: how the plant differs from the nominal model
    beyond what is declared (:func:`plant_payload`, :func:`undeclared_differences`);
    ``true_velocity``: whether the plant maps q̇ (if not, the velocity set cannot be judged
    and the run is outside what the guarantee speaks for); ``checks``: the run's evaluated
    checks (default: evaluated here), of which the hard ones are judged; ``assumes``: what
    the filter published it reads and keeps (None: an unfiltered run, or a filter that does
    not say: then its flags alone mark it filtered)."""
    if trace.rows_done == 0:
        return {}
    if checks is None:
        from ..evaluate import Evaluator

        checks = Evaluator(trace, safe, {}).result().checks
    hard = hard_checks(checks)
    if assumes is not None and assumes.keeps:  # a set it does not keep: not held against it
        hard = {name: c for name, c in hard.items()
                if c.declared.family in assumes.keeps or c.declared.family not in KEPT_SETS}
    starts_inside = not any(bool(c.outside[0]) for c in hard.values())
    check_bounds = None if assumes is None else assumes.check_bounds
    starts_viable, not_viable = viability(trace, safe, starts_inside, check_bounds)
    outside, facts, observer_violation = declared_inputs(
        trace, safe, uncertainty, payload, other_parameters, true_velocity, assumes)
    exit_ = first_exit(hard, trace.dt)
    out = {"starts_inside": starts_inside, "starts_viable": starts_viable,
           "not_viable": not_viable, **facts}
    feasible = None
    if INFEASIBLE in trace:
        steps = int(np.sum(trace[INFEASIBLE] > 0))
        feasible = steps == 0
        out["infeasible_steps"] = steps
    over_steps, over_limit = torque_violation(trace, assumes)
    # The guarantee speaks for filtered runs only: an unfiltered run promises nothing.
    # A filter that keeps no hard set (cbf_filter.hard = []) promises nothing either.
    filtered = (bool(assumes.keeps) if assumes is not None
                else INFEASIBLE in trace or VIABLE in trace)
    # A start outside a set is the filter's to bring back (recovery, reported), not to keep;
    # one whose velocity the filter could not tell inside at first is covered from the step
    # it could (covered_from).
    start = covered_from(trace, safe, starts_inside, starts_viable, hard, assumes)
    covered = bool(filtered and starts_inside and start is not None and not outside)
    premises = measured_premises(trace, safe, start if covered else 0, check_bounds)
    premises_failed = premises.pop("violations")
    infeasible_after = (int(np.sum(trace[INFEASIBLE][start:trace.rows_done] > 0))
                        if covered and INFEASIBLE in trace else 0)
    violations = [] if not covered else [
        *([f"left {exit_['set']} at {exit_['t']:.3f} s (|value| {exit_['value']:.4g} > "
           f"{exit_['bound']:g})"] if exit_ else []),
        *([f"{infeasible_after} infeasible step(s)"] if infeasible_after else []),
        *([observer_violation] if observer_violation else []),
        *([over_limit] if over_limit else []),
        *premises_failed]
    out.update(feasible=feasible, within_bounds=not outside, outside=outside,
               hard_kept=exit_ is None, first_exit=exit_, torque_over_limit_steps=over_steps,
               filtered=filtered, covered=covered,
               covered_from_s=float(start * trace.dt) if covered else None,
               **premises, violations=violations, broken=bool(violations),
               **recovery(hard, trace.dt),
               keeps=None if assumes is None else list(assumes.keeps))
    if not covered:
        out["tube_left"] = None  # judged from the step a covered run is covered from
    if filtered:
        out["torque"] = torque_peaks(trace, assumes)
    return out


def covered_from(trace: Signals, safe: SafeSet, starts_inside: bool, starts_viable: bool,
                 hard: Mapping[str, Check], assumes: FilterAssumptions | None) -> int | None:
    """The row from which the guarantee speaks for the run: 0 for a start in the viable set;
    for a filter reading the observer's velocity whose start was not viable only because
    the velocity it held at t = 0 reached past a bound (what the declared initial observer
    error allows: :func:`velocity_uncertain`), the first row it found viable (its interval,
    tightened by the measured positions, inside the sets and a torque verified), provided
    no hard set was left up to it (the start-up, which promises nothing, kept them); else
    None."""
    if not starts_inside:
        return None
    if starts_viable:
        return 0
    reads = "qdot_hat" if assumes is None else assumes.velocity
    if reads != "qdot_hat" or VIABLE not in trace or velocity_uncertain(trace, safe) is None:
        return None
    viable = np.flatnonzero(np.asarray(trace[VIABLE][:trace.rows_done], float) > 0.5)
    if not len(viable):
        return None
    first = int(viable[0])
    if any(check.outside[:first + 1].any() for check in hard.values()):
        return None
    return first


def measured_premises(trace: Signals, safe: SafeSet, start: int,
                      check_bounds: np.ndarray | None) -> dict:
    """The check's premises measured from row ``start`` on (cosim/paper/premises.py): the
    steps where each failed (None: not measured, the signals or the check's bounds
    missing), the least room left (``tube_slack``, ``between_samples_room``: per quantity,
    rad and rad/s), ``violations``, what failed, and ``tube_left``, the tube's excess (on
    every row: reported); ``plan_tube_*`` the tube where the filter followed the plan in
    force (``cbf_planned``), the rows that rest on its proof: held, a violation."""
    out: dict[str, Any] = {"violations": []}
    out["interval_exceeded_steps"], text = interval_exceedances(trace, start)
    out["violations"] += [text] if text else []
    sets = position_and_velocity_sets(trace, safe)
    tube = followed = (None, None, None)
    if sets is not None and check_bounds is not None:
        allowance = np.array([sets[1], sets[3]]) - check_bounds
        tube = tube_exceedances(trace, start, allowance)
        followed = tube_exceedances(trace, start, allowance, followed_only=True)
    out["tube_exceeded_steps"], out["tube_slack"], out["tube_left"] = tube
    out["plan_tube_exceeded_steps"], out["plan_tube_slack"], text = followed
    out["violations"] += [f"where the filter followed its plan, {text}"] if text else []
    between = (None, None, None)
    if sets is not None:
        between = between_samples(trace, start, (sets[0], sets[2]), (sets[1], sets[3]))
    out["between_samples_exceeded_steps"], out["between_samples_room"], text = between
    out["violations"] += [text] if text else []
    return out


@register_evaluator
class Guarantee(Part):
    """The filter's guarantee on a run (:func:`classify`), from its evaluated hard sets, the
    plant's parameters against the nominal chain a block publishes, what the filter
    publishes it assumes (``safety_filter``), and the declared uncertainty; the line
    `cosim run` prints of it for a filtered run; and how often the filter changed the
    torque."""

    name = "guarantee"
    meaning = "whether the safety filter's guarantee covers the run, and whether it held"
    inputs = ("q",)
    constants = (io.PLANT_PARAMETERS, io.UNCERTAINTY)
    metric_units = {"filter_active_fraction": "1",
                    "guarantee.observer_bound_exceeded_steps": "steps",
                    "guarantee.torque_over_limit_steps": "steps",
                    "guarantee.infeasible_steps": "steps", "guarantee.first_exit.t": "s",
                    "guarantee.time_to_return_s": "s",
                    "guarantee.torque.startup_steps": "steps", "guarantee.torque.peak_t": "s",
                    "guarantee.torque.peak_of_limit": "1",
                    "guarantee.torque.peak_backup_share": "1",
                    "guarantee.torque.peak_during_startup": "N·m",
                    "guarantee.torque.peak_after_startup": "N·m", "guarantee.covered_from_s": "s",
                    "guarantee.interval_exceeded_steps": "steps",
                    "guarantee.tube_exceeded_steps": "steps",
                    "guarantee.plan_tube_exceeded_steps": "steps",
                    "guarantee.plan_tube_slack.position": "rad",
                    "guarantee.plan_tube_slack.velocity": "rad/s",
                    "guarantee.tube_slack.position": "rad",
                    "guarantee.tube_slack.velocity": "rad/s",
                    "guarantee.between_samples_exceeded_steps": "steps",
                    "guarantee.between_samples_room.position": "rad",
                    "guarantee.between_samples_room.velocity": "rad/s"}

    def metrics(self, trace: Signals, series: Mapping[str, np.ndarray]) -> dict:
        if ACTIVE not in trace or not len(trace[ACTIVE]):
            return {}
        return {"filter_active_fraction": float(np.mean(trace[ACTIVE] > 0))}

    def conclude(self, trace: Signals, checks: Mapping[str, Check]) -> dict:
        chain = self.given.get(io.PLANT_MODEL)
        assumes = self.given.get(FILTER_ASSUMES)
        parameters, uncertainty = self.given[io.PLANT_PARAMETERS], self.given[io.UNCERTAINTY]
        payload, other = plant_payload(parameters, chain, rigid_chain_parameters(trace.links),
                                       urdf="nominal_urdf" in self.given)
        # the τ_d the filter's model assumes: its own, else the observer's (its default)
        tau_d = assumes.tau_d if assumes is not None else self.given.get(OBSERVER_TAU_D)
        model = self.given.get("nominal_model")
        other += undeclared_differences(parameters, chain, uncertainty, tau_d, trace.links,
                                        getattr(model, "friction", None))
        observer = self.given.get(OBSERVER_TAU_D)
        if assumes is not None and observer is not None \
                and not np.array_equal(np.asarray(observer), np.asarray(assumes.tau_d)):
            # the filter has a disturbance model of its own: the observer's is compared too
            other += disturbance_differences(parameters, uncertainty, observer, trace.links,
                                             "observer.tau_d")
        system = self.given.get(io.PLANT_SYSTEM)
        if system:
            other += system_differences(trace, system, parameters, uncertainty, tau_d)
        if chain is None and "nominal_urdf" in self.given:  # no parameters to compare
            difference = plant_model_difference(trace, self.given.get("nominal_model"),
                                                payload)
            other += [difference] if difference else []
        return {"guarantee": classify(trace, self.safe, uncertainty, payload, other,
                                      true_velocity="qdot" in self.available,
                                      checks=checks, assumes=assumes)}

    def report(self, metrics: Mapping[str, Any]) -> tuple[str | None, list[str]]:
        g = metrics.get("guarantee") or {}
        if not g.get("filtered"):  # not a filtered run: nothing to say
            return ("the safety filter keeps no hard set (cbf_filter.hard = []): no "
                    "guarantee" if g.get("keeps") == [] else None), []
        keeps = g.get("keeps")
        kept = ("kept every hard set" if keeps is None or KEPT_SETS <= set(keeps)
                else f"kept the hard sets it keeps ({', '.join(keeps)})")
        exit_text = (f"left {g['first_exit']['set']} at {g['first_exit']['t']:.3f} s"
                     if g["first_exit"] else kept)
        if g["time_to_return_s"] is not None:
            exit_text += (f", back inside (the longest excursion {g['time_to_return_s']:.3f} s)"
                          if g["returned"] else
                          f", still outside at the end ({g['time_to_return_s']:.3f} s)")
        why = [*(["started outside"] if not g["starts_inside"] else []),
               *([f"not viable: {g['not_viable']}"] if g["not_viable"] else []),
               *g["outside"]]
        later = g.get("covered_from_s")
        return (f"{exit_text}; guarantee "
                + (("covers this run" + (f" from {later:.3g} s (its start-up, the velocity "
                                         "not yet shown inside)" if later else ""))
                   if g["covered"] else "does not cover this run: " + "; ".join(why))
                + (" — BROKEN: " + "; ".join(g["violations"]) if g["broken"] else "")
                + (f" (the tube, measured where a torque was verified afresh, not held "
                   f"against it: {g['tube_left']})"
                   if g.get("tube_left") and not g.get("plan_tube_exceeded_steps") else "")), []
