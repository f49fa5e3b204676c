"""The filter's guarantee, classified honestly (cosim/paper/guarantee.py, issue 30): a start
inside means inside the filter's viable set; every plant parameter not declared uncertain
is compared with the nominal model; what a filter does not read never excuses it; an
exceeded observer bound, an infeasible step or a torque above the limit in a covered run is
a broken guarantee; a run that left a set reports how it came back. Small synthetic traces
for each rule, then two real runs of the issue's reproducers. SI units, radians."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from cli_helpers import cosim_cli

from cosim.config import load_pipeline
from cosim.declared import Uncertainty, safety_section
from cosim.evaluate import Evaluator
from cosim.evaluate.reports import wilson
from cosim.paper.cbf_filter.assumptions import BACKUP, FILTER_ASSUMES, VIABLE, FilterAssumptions
from cosim.paper.guarantee import RETURN_WITHIN, Guarantee, classify
from cosim.paper.inertia import Chain
from cosim.paper.sweep_report import format_guarantee_table, guarantee_table
from cosim.paper.within_bounds import COMPARED, NOT_MODEL
from cosim.runner import run
from cosim.signals import Signal, Trace
from cosim.sweep.worker import flat
from plant_fmu.models.planar_arm import LINK_PARAMETERS
from plant_fmu.models.planar_arm import variables as rigid_arm_variables

DT, ROWS = 1e-3, 2001  # 2 s at 1 ms
SAFE = safety_section()(position_bound=2.0, velocity_bound=3.0, observer_error_bound=0.5)
DECLARED = Uncertainty(payload=[0.0, 1.0], noise_bound=1e-3, initial_velocity_error=0.5,
                       disturbance=0.3)
LIMIT = 100.0  # N·m, the filters' torque limit here
# what a filter reads: the output-feedback one (measured q, observer's x̂2) and the
# full-state one (the true q and q̇), with the plant's default τ_d = 0.01 N·m as its model
OUTPUT_FEEDBACK = FilterAssumptions("q_meas", "qdot_hat", np.full(2, LIMIT), np.full(2, 0.01))
FULL_STATE = FilterAssumptions("q", "qdot", np.full(2, LIMIT), np.full(2, 0.01))
PER_JOINT = ("q", "qdot", "q_s", "qdot_s", "q_d", "qdot_d", "e", "edot", "q_meas", "qdot_hat",
             "qdot_hat_bound", "tau")
FLAGS = ("cbf_infeasible", VIABLE, BACKUP)


def make_trace(drop: tuple[str, ...] = ()) -> Trace:
    """A filtered run that stays well inside every set and every declared bound: |q| ≤ 0.5
    (bound 2 rad), |q̇| ≤ 1 (3 rad/s), exact measurement, x̂2 = q̇ with ε = 0.1 rad/s,
    |τ| ≤ 50 N·m (limit 100), viable and feasible throughout. Tests edit its arrays."""
    signals = {name: Signal("n", "SI", name) for name in PER_JOINT if name not in drop}
    signals.update({name: Signal("1", "-", name) for name in FLAGS if name not in drop})
    trace = Trace(signals, 2, ROWS - 1, DT)
    t = trace.time[:, None]
    q, qdot = 0.5 * np.sin(2 * t + [0.0, 1.0]), np.cos(2 * t + [0.0, 1.0])
    values = {"q": q, "qdot": qdot, "q_s": 0.0, "qdot_s": 0.0, "q_d": q, "qdot_d": qdot,
              "e": 0.0, "edot": 0.0, "q_meas": q, "qdot_hat": qdot, "qdot_hat_bound": 0.1,
              "tau": 50 * np.sin(t + [0.0, 2.0]), "cbf_infeasible": 0.0, VIABLE: 1.0,
              BACKUP: 0.0}
    for name in trace.arrays:
        trace.arrays[name][:] = values[name]
    trace.rows_done = ROWS
    return trace


def place(trace: Trace, signal: str, index, value) -> None:
    """Set the true position (velocity) and what the filter reads of it alike (q_meas,
    x̂2), so that an edit moves the state without adding noise or observer error."""
    for name in {"q": ("q", "q_meas"), "qdot": ("qdot", "qdot_hat")}[signal]:
        trace[name][index] = value


def report_line(g: dict) -> str | None:
    return Guarantee(make_trace(), SAFE, {}).report({"guarantee": g})[0]


def judge(trace: Trace, assumes: FilterAssumptions | None = OUTPUT_FEEDBACK,
          uncertainty: Uncertainty = DECLARED, payload: float | None = 0.5) -> dict:
    return classify(trace, SAFE, uncertainty, payload, [], assumes=assumes)


def test_a_run_inside_everything_declared_is_covered_and_holds():
    g = judge(make_trace())
    assert g["starts_inside"] is g["starts_viable"] is g["covered"] is True
    assert g["within_bounds"] is g["hard_kept"] is g["feasible"] is True
    assert g["outside"] == [] and g["violations"] == [] and g["broken"] is False
    assert g["observer_bound_exceeded_steps"] == 0 and g["torque_over_limit_steps"] == 0
    assert g["returned"] is None and g["time_to_return_s"] is None and g["excursions"] == []
    assert report_line(g) == (
        "kept every hard set; guarantee covers this run")


# 1. Starts inside = inside the viable set

def test_a_start_in_the_box_the_filter_cannot_keep_is_not_viable_and_says_why():
    """Joint 1 at 1.9 rad (bound 2) moving out at 2.5 rad/s (bound 3): in the box, but the
    filter flags t = 0 not viable. Not covered, so its exit is never a broken guarantee;
    the reason names the joint, side and the deceleration v²/(2d) stopping needs."""
    trace = make_trace()
    place(trace, "q", 0, [1.9, -1.5])
    place(trace, "qdot", 0, [2.5, -2.0])
    trace[VIABLE][0] = 0.0
    place(trace, "q", (slice(50, None), 0), 2.2)  # then leaves the position set
    g = judge(trace)
    assert g["starts_inside"] is True and g["starts_viable"] is False
    need = 2.5**2 / (2 * (2.0 - 1.9))  # joint 2: 2²/(2·0.5) = 4 rad/s², less
    assert g["not_viable"] == (
        "the filter found no torque that keeps the hard sets from this start (joint 1 moves "
        f"toward its upper position bound at 2.5 rad/s, 0.1 rad from it: stopping needs at "
        f"least {need:.3g} rad/s²)")
    assert g["within_bounds"] is True and g["hard_kept"] is False
    assert g["covered"] is False and g["broken"] is False and g["violations"] == []
    line = report_line(g)
    assert "guarantee does not cover this run: not viable: the filter found no torque" in line
    assert "BROKEN" not in line


def test_the_hardest_joint_to_stop_is_named_on_either_side():
    trace = make_trace()
    place(trace, "q", 0, [0.0, -1.9])
    place(trace, "qdot", 0, [0.5, -2.5])
    trace[VIABLE][0] = 0.0
    assert "joint 2 moves toward its lower position bound at 2.5 rad/s, 0.1 rad from it" in (
        judge(trace)["not_viable"])


def test_the_robots_own_limits_are_the_sets_the_reasons_measure_against():
    """With safety.limits = "urdf" the sets are per-joint boxes, not radii about q_s: joint 1
    at 2.9 rad in its [-1, 3] box moving up at 2.5 rad/s is 0.1 rad from its bound (about
    q_s = 0 with the 2 rad radius it would be outside, and not named); the velocity the
    filter holds is judged against each joint's own limit."""
    boxes = SAFE.model_copy(update={"limits": "urdf", "position_lower": [-1.0, -3.0],
                                    "position_upper": [3.0, 1.0],
                                    "velocity_limit": [3.5, 2.0]})
    trace = make_trace()
    place(trace, "q", 0, [2.9, -1.5])
    place(trace, "qdot", 0, [2.5, -1.5])
    trace[VIABLE][0] = 0.0
    g = classify(trace, boxes, DECLARED, 0.5, [], assumes=OUTPUT_FEEDBACK)
    assert g["starts_inside"] is True and g["starts_viable"] is False
    assert g["not_viable"].endswith(
        "(joint 1 moves toward its upper position bound at 2.5 rad/s, 0.1 rad from it: "
        f"stopping needs at least {2.5**2 / 0.2:.3g} rad/s²)")
    # the interval the filter holds: joint 1's inside its 3.5 rad/s (past the radius, 3),
    # joint 2's past its own 2 rad/s
    trace.arrays["cbf_velocity_centre"] = np.array([[3.2, 2.5]] * ROWS)
    trace.arrays["cbf_velocity_spread"] = np.zeros((ROWS, 2))
    trace.signals.update({name: Signal("n", "rad/s", name) for name in
                          ("cbf_velocity_centre", "cbf_velocity_spread")})
    assert "(joint 2: 2.5 ± 0 rad/s against 2;" in classify(
        trace, boxes, DECLARED, 0.5, [], assumes=OUTPUT_FEEDBACK)["not_viable"]


def test_only_the_viable_flag_at_the_start_matters_and_without_it_the_box_stands_in():
    trace = make_trace()
    trace[VIABLE][1:] = 0.0  # later steps not viable: the start still is
    assert judge(trace)["starts_viable"] is True
    without = make_trace(drop=(VIABLE,))
    g = judge(without)
    assert g["starts_viable"] is True and g["covered"] is True and g["not_viable"] is None
    place(without, "qdot", (0, 1), 3.5)  # outside the velocity box at t = 0
    g = judge(without)
    assert g["starts_inside"] is g["starts_viable"] is g["covered"] is False
    assert g["not_viable"] is None  # a start outside the box is its own class
    assert "does not cover this run: started outside" in report_line(g)


def test_a_start_outside_the_box_is_never_covered_even_if_the_filter_can_bring_it_back():
    """The filter's flag at t = 0 for a start outside a set says its backup brings the state
    back (recovery), not that it keeps the sets: such a run is not covered, and its exit at
    t = 0 is nobody's broken promise; its return is reported."""
    trace = make_trace()
    place(trace, "q", (slice(0, 30), 0), 2.1)
    g = judge(trace)
    assert g["starts_inside"] is False and g["starts_viable"] is True
    assert g["covered"] is False and g["broken"] is False and g["violations"] == []
    assert g["returned"] is True and g["time_to_return_s"] > 0


# 2. Every plant parameter not declared uncertain is compared with the nominal model

NOMINAL = Chain(np.array([0.8, 2.3]), np.ones(2), np.ones(2), np.zeros(2), 9.8)
DEFAULTS = {v.name: v.start for v in rigid_arm_variables(2) if v.causality == "parameter"}


def conclude(trace: Trace, changes: dict, assumes: FilterAssumptions | None = OUTPUT_FEEDBACK,
             uncertainty: Uncertainty = DECLARED, **constants) -> dict:
    """The evaluator's own path: the plant's parameters (the rigid arm's defaults, a
    0.5 kg payload, ``changes``) against the nominal chain and what the filter publishes."""
    given = {"plant_parameters": {**DEFAULTS, "m[2]": 2.8, **changes}, "nominal_chain": NOMINAL,
             "uncertainty": uncertainty, **constants}
    if assumes is not None:
        given[FILTER_ASSUMES] = assumes
    checks = Evaluator(trace, SAFE, {}).result().checks
    part = Guarantee(trace, SAFE, given, frozenset(trace.arrays))
    return part.conclude(trace, checks)["guarantee"]


def test_the_nominal_chain_here_is_the_rigid_arms_defaults():
    g = conclude(make_trace(), {})
    assert g["outside"] == [] and g["covered"] is True


@pytest.mark.parametrize(("name", "value", "named"), [
    ("g", 80.0, "plant g = 80 m/s² (the nominal chain's 9.8 m/s²): gravity is not declared"),
    ("tau_d_amp[1]", 200.0, "plant tau_d_amp[1] = 200 N·m at tau_d_freq[1] = 0 Hz (nominal 0): "
     "a disturbance error up to 200 N·m on joint 1 > the declared 0.3 N·m"),
    ("tau_d[2]", 0.5, "plant tau_d[2] = 0.5 N·m (model 0.01 N·m): a disturbance error up to "
     "0.49 N·m on joint 2"),
    ("b[2]", 0.3, "plant b[2] = 0.3 N·m·s/rad (nominal 0): viscous friction is not declared"),
    ("fc[1]", 1.0, "plant fc[1] = 1 N·m (nominal 0): Coulomb friction is not declared"),
    ("lc[1]", 0.9, "plant lc[1] = 0.9 (nominal 1)"),
])
def test_an_undeclared_plant_difference_is_outside_naming_it_never_broken(name, value, named):
    """Even when the run then leaves a hard set: the guarantee never spoke for it."""
    trace = make_trace()
    place(trace, "q", (slice(100, None), 0), 2.5)
    g = conclude(trace, {name: value})
    assert g["within_bounds"] is False and len(g["outside"]) == 1
    assert g["outside"][0].startswith(named), g["outside"]
    assert g["hard_kept"] is False and g["covered"] is False and g["broken"] is False


def test_the_disturbance_budget_is_the_constant_error_plus_the_amplitude():
    """|τ_d − τ_d,model| + |tau_d_amp| ≤ uncertainty.disturbance (0.3 N·m), each part by its
    magnitude: 0.2 + 0.09 is inside, 0.2 + 0.11 outside, on either sign."""
    assert conclude(make_trace(), {"tau_d[1]": 0.21, "tau_d_amp[1]": 0.09})["outside"] == []
    for tau_d, amp in ((0.21, 0.11), (-0.19, -0.11)):
        outside = conclude(make_trace(), {"tau_d[1]": tau_d, "tau_d_amp[1]": amp})["outside"]
        assert len(outside) == 1 and f"tau_d[1] = {tau_d:g} N·m (model 0.01 N·m)" in outside[0]
        assert f"tau_d_amp[1] = {amp:g} N·m" in outside[0]
        assert "up to 0.31 N·m on joint 1" in outside[0]


def test_the_disturbance_model_is_the_filters_else_the_observers():
    shifted = OUTPUT_FEEDBACK._replace(tau_d=np.array([0.5, 0.01]))
    assert conclude(make_trace(), {"tau_d[1]": 0.5}, shifted)["outside"] == []
    outside = conclude(make_trace(), {}, shifted)["outside"]  # the plant's τ_d[1] = 0.01
    assert len(outside) == 1 and outside[0].startswith("plant tau_d[1] = 0.01 N·m (model 0.5 N·m)")
    # no safety_filter published: the observer's tau_d_model is the model
    assert conclude(make_trace(), {"tau_d[1]": 0.5}, None,
                    tau_d_model=np.array([0.5, 0.01]))["outside"] == []
    assert "tau_d[1] = 0.5 N·m (model 0.01 N·m)" in conclude(
        make_trace(), {"tau_d[1]": 0.5}, None, tau_d_model=np.array([0.01, 0.01]))["outside"][0]


def test_the_observers_disturbance_model_is_compared_too_when_the_filter_has_its_own():
    """The issue's reproducer, as the classifier sees it: cbf_filter.tau_d right (the
    plant's 0.01 N·m) but observer.tau_d = 1000 N·m. The filter's margins rest on the
    observer's bound ε(t), which then does not hold: outside, naming the observer's key
    (not "covered — broken")."""
    right = OUTPUT_FEEDBACK._replace(tau_d=np.array([0.01, 0.01]))
    g = conclude(make_trace(), {}, right, tau_d_model=np.array([1000.0, 1000.0]))
    assert g["covered"] is False and g["broken"] is False
    assert g["outside"] == [
        f"plant tau_d[{i}] = 0.01 N·m (observer.tau_d 1000 N·m): a disturbance error up to "
        "999.99 N·m on joint {i} > the declared 0.3 N·m (uncertainty.disturbance); the bound "
        "ε(t) on the velocity's estimate, which the filter's margins rest on, assumes "
        "observer.tau_d".replace("{i}", str(i)) for i in (1, 2)]
    # the observer's model the same as the filter's: compared once
    assert conclude(make_trace(), {}, right,
                    tau_d_model=np.array([0.01, 0.01]))["outside"] == []


def test_the_initial_state_and_the_integrator_are_not_model_differences():
    changes = {"q0[1]": 1.0, "qdot0[2]": -3.0, "rk4_step": 1e-5, "fc_vel": 0.5,
               "tau_d_freq[1]": 3.0}
    g = conclude(make_trace(), changes)
    assert g["outside"] == [] and g["covered"] is True


def test_every_parameter_of_the_rigid_arm_is_either_compared_or_not_a_model_difference():
    """A parameter added to the arm must be placed, never silently ignored."""
    families = {family.base for family in LINK_PARAMETERS}
    assert families == COMPARED | NOT_MODEL and not COMPARED & NOT_MODEL


# 3. What a filter does not read never excuses it

def misleading_signals() -> Trace:
    """Noise 0.05 rad (declared 1e-3), an initial observer error of 2 rad/s (declared 0.5)
    and ε(t) exceeded: none of which a full-state filter reads; then joint 1 leaves."""
    trace = make_trace()
    trace["q_meas"][:] += 0.05
    trace["qdot_hat"][:] += 2.0
    place(trace, "q", (slice(300, 400), 0), 2.4)
    return trace


def test_a_filter_reading_the_true_state_is_not_excused_by_noise_or_the_observer():
    g = judge(misleading_signals(), FULL_STATE)
    assert g["outside"] == [] and g["covered"] is True and g["broken"] is True
    assert g["violations"] == ["left position_joint1 at 0.300 s (|value| 2.4 > 2)"]
    assert g["observer_bound_exceeded_steps"] is None


def test_what_the_filter_reads_is_judged():
    g = judge(misleading_signals(), OUTPUT_FEEDBACK)
    assert [text.split(" ")[0] for text in g["outside"]] == ["noise", "initial"]
    assert g["covered"] is False and g["broken"] is False
    g = judge(misleading_signals(), FilterAssumptions("q_meas", "qdot", np.full(2, LIMIT),
                                                      np.full(2, 0.01)))
    assert [text.split(" ")[0] for text in g["outside"]] == ["noise"]
    g = judge(misleading_signals(), FilterAssumptions("q", "qdot_hat", np.full(2, LIMIT),
                                                      np.full(2, 0.01)))
    assert [text.split(" ")[0] for text in g["outside"]] == ["initial"]


# 4. An exceeded observer bound inside the declared ranges is a violation

def test_the_observer_bound_exceeded_within_the_declared_ranges_breaks_the_guarantee():
    trace = make_trace()
    trace["qdot_hat"][400:500, 1] += 0.3  # ε = 0.1 rad/s
    for assumes in (OUTPUT_FEEDBACK, None):  # None: a filter that does not say, read as both
        g = judge(trace, assumes)
        assert g["outside"] == [] and g["covered"] is True and g["hard_kept"] is True
        assert g["observer_bound_exceeded_steps"] == 100 and g["broken"] is True
        assert g["violations"] == [
            "observer error |q̇ − x̂2| above its bound ε(t) at 100 steps (first t = 0.4 s)"]


def test_the_observer_bound_exceeded_with_its_inputs_outside_is_outside():
    trace = make_trace()
    trace["qdot_hat"][400:500, 1] += 0.3
    g = judge(trace, payload=1.5)
    assert g["outside"] == ["payload 1.5 kg outside [0, 1]"]
    assert g["observer_bound_exceeded_steps"] == 100
    assert g["covered"] is False and g["broken"] is False


# 5. Covered, and what breaks it

def test_covered_does_not_need_every_step_feasible_an_infeasible_step_breaks_it():
    trace = make_trace()
    trace["cbf_infeasible"][10:13] = 1.0
    g = judge(trace)
    assert g["covered"] is True and g["feasible"] is False and g["infeasible_steps"] == 3
    assert g["broken"] is True and g["violations"] == ["3 infeasible step(s)"]
    line = report_line(g)
    assert line == ("kept every hard set; guarantee covers this run — BROKEN: 3 infeasible "
                    "step(s)")


def test_a_torque_above_the_filters_limit_breaks_it():
    trace = make_trace()
    trace["tau"][200, 1] = LIMIT * (1 + 1e-10)  # rounding: within
    g = judge(trace)
    assert g["torque_over_limit_steps"] == 0 and g["broken"] is False
    trace["tau"][300:302, 1] = -101.0
    g = judge(trace)
    assert g["torque_over_limit_steps"] == 2 and g["broken"] is True
    assert g["violations"] == ["|τ| above the filter's torque limit at 2 steps (first "
                               "t = 0.3 s, joint 2 up to 101 N·m > 100 N·m)"]
    unlimited = OUTPUT_FEEDBACK._replace(torque_limit=np.full(2, np.inf))
    assert judge(trace, unlimited)["broken"] is False
    assert judge(trace, None)["torque_over_limit_steps"] is None  # no limit published


def test_where_each_joints_peak_torque_comes_from():
    """A start the filter brakes hard: 30 steps not viable, joint 1 at 95 N·m (the backup's)
    at 10 ms; from the first viable step on, the run's own 50 N·m sine."""
    trace = make_trace()
    trace[VIABLE][:30] = 0.0
    trace[BACKUP][:30] = 1.0
    trace["tau"][10, 0] = -95.0
    torque = judge(trace)["torque"]
    assert torque["startup_steps"] == 30
    # joint 2's 50 sin(t + 2) is largest at t = 0, in the start-up too
    assert torque["peak_t"] == [pytest.approx(0.01), 0.0]
    assert torque["peak_at_startup"] == [True, True]
    assert torque["peak_of_limit"] == pytest.approx([0.95, 0.5 * np.sin(2.0)])
    assert torque["peak_backup_share"] == [1.0, 1.0]
    assert torque["peak_after_startup"] == pytest.approx(
        np.abs(trace["tau"][30:]).max(axis=0).tolist())
    assert torque["peak_after_startup"][0] < 50.0 + 1e-9
    assert torque["peak_during_startup"] == pytest.approx(
        [95.0, np.abs(trace["tau"][:30, 1]).max()])
    trace[VIABLE][:] = 1.0  # viable at once: no start-up
    assert judge(trace)["torque"]["peak_during_startup"] == [None, None]
    trace[VIABLE][:] = 0.0  # never viable: no "after start-up", the whole run is start-up
    assert judge(trace)["torque"]["startup_steps"] is None
    assert judge(trace)["torque"]["peak_during_startup"] == pytest.approx(
        np.abs(trace["tau"]).max(axis=0).tolist())
    assert judge(trace)["torque"]["peak_after_startup"] == [None, None]
    assert judge(trace)["torque"]["peak_at_startup"] == [True, True]
    unlimited = OUTPUT_FEEDBACK._replace(torque_limit=np.full(2, np.inf))
    assert judge(trace, unlimited)["torque"]["peak_of_limit"] == [None, None]
    assert "torque" not in judge(make_trace(drop=FLAGS), None)  # an unfiltered run


def test_a_hard_set_the_filter_does_not_keep_is_never_held_against_it():
    """cbf_filter.hard = ["position"]: the velocity set left from an inside start is the
    evaluation's verdict (UNSAFE), not the filter's broken guarantee; its position set still
    is. A filter that keeps no hard set (hard = []) promises nothing and says so."""
    trace = make_trace()
    place(trace, "qdot", (slice(50, 80), 0), 3.2)  # leaves the velocity set, comes back
    positions_only = OUTPUT_FEEDBACK._replace(keeps=("position",))
    assert judge(trace)["broken"] is True  # against a filter that keeps it: broken
    g = judge(trace, positions_only)
    assert g["covered"] is True and g["hard_kept"] is True and g["broken"] is False
    assert g["keeps"] == ["position"]
    assert report_line(g) == (
        "kept the hard sets it keeps (position); guarantee covers this run")
    place(trace, "q", (slice(100, 120), 1), -2.1)  # the position set it keeps: broken
    g = judge(trace, positions_only)
    assert g["broken"] is True and g["first_exit"]["set"] == "position_joint2"
    g = judge(trace, OUTPUT_FEEDBACK._replace(keeps=()))
    assert g["filtered"] is g["covered"] is g["broken"] is False
    # what it did is still reported, as for an unfiltered run: both sets left
    assert g["hard_kept"] is False and g["first_exit"]["set"] == "velocity_true_joint1"
    assert g["time_to_return_s"] is not None
    assert report_line(g) == ("the safety filter keeps no hard set (cbf_filter.hard = []): "
                              "no guarantee")


def test_an_unfiltered_run_is_never_covered_nor_broken():
    trace = make_trace(drop=FLAGS)
    place(trace, "q", (slice(100, None), 0), 2.5)
    g = judge(trace, None)
    assert g["filtered"] is False and g["covered"] is False and g["broken"] is False
    assert g["hard_kept"] is False and g["feasible"] is None
    assert report_line(g) is None


@pytest.mark.parametrize(("excursions", "returned", "longest"), [
    ({("q", 0): [(100, 350)], ("qdot", 1): [(600, 1800)]}, True, 1.2),
    ({("q", 0): [(100, 350)], ("qdot", 1): [(600, 1400)]}, True, 0.8),
    ({("q", 0): [(100, 150), (300, 500)]}, True, 0.2),
    ({("q", 1): [(0, 50)]}, True, 0.05),  # starts outside
    ({("q", 0): [(100, 150), (1900, ROWS)]}, False, 0.101),  # still outside at the end
])
def test_the_time_to_return_from_every_set_left(excursions, returned, longest):
    """Rows [a, b) outside (joint 1's position at 2.5 rad, joint 2's velocity at 3.5 rad/s):
    every excursion lasts (b − a)·dt; returned when none lasts to the end."""
    trace = make_trace()
    for (signal, joint), spans in excursions.items():
        for a, b in spans:
            place(trace, signal, (slice(a, b), joint), 2.5 if signal == "q" else 3.5)
    g = judge(trace)
    assert g["returned"] is returned
    assert g["time_to_return_s"] == pytest.approx(longest, rel=1e-12)
    assert g["back_within_1s"] is (returned and longest <= RETURN_WITHIN)
    assert len(g["excursions"]) == len(excursions)
    line = report_line(g)
    assert (f"back inside (the longest excursion {longest:.3f} s)" if returned
            else f"still outside at the end ({longest:.3f} s)") in line


def test_every_reason_survives_a_sweeps_rows():
    """A sweep joins a list of texts with "; " (cosim/sweep/worker.py's flat), and its
    reports split them again: no reason may hold "; " itself."""
    g = conclude(misleading_signals(), {"g": 80.0, "tau_d_amp[1]": 200.0, "b[1]": 1.0,
                                        "fc[2]": 2.0, "tau_d[2]": 1.0, "l[2]": 1.5})
    trace = misleading_signals()
    trace["cbf_infeasible"][7] = 1.0
    trace["tau"][20, 0] = 150.0
    trace["qdot_hat_bound"][:] = 0.0
    broken = judge(trace, FULL_STATE._replace(velocity="qdot_hat"),
                   DECLARED.model_copy(update={"initial_velocity_error": 5.0}))
    assert len(g["outside"]) == 8 and len(broken["violations"]) == 4
    for key, texts in (("outside", g["outside"]), ("violations", broken["violations"])):
        assert flat({"guarantee": {key: texts}})[f"guarantee.{key}"].split("; ") == texts


# 7. The sweep's classes

def test_the_sweep_report_counts_each_class_broken_and_the_recovery():
    """Seven synthetic runs of one sweep, each built to be one case; their rows flattened
    as a sweep flattens them."""
    cases = {}
    cases["covered, kept"] = judge(make_trace())
    trace = make_trace()
    trace["cbf_infeasible"][5] = 1.0
    place(trace, "q", (slice(100, 200), 0), 2.5)  # left, back in 0.1 s
    cases["covered, broken, back"] = judge(trace)
    trace = make_trace()
    place(trace, "qdot", (0, 0), 2.9)
    trace[VIABLE][0] = 0.0
    cases["inside, not viable"] = judge(trace)
    trace = make_trace()
    place(trace, "q", (slice(100, 1500), 0), 2.5)  # left for 1.4 s
    cases["outside bounds"] = judge(trace, payload=2.0)
    trace = make_trace()
    place(trace, "q", (slice(None), 1), -2.5)  # outside throughout
    trace[VIABLE][0] = 0.0
    cases["starts outside"] = judge(trace)
    cases["unfiltered"] = judge(make_trace(drop=FLAGS), None)
    rows = [{"run": "r", "status": "ok", "hard_sets_kept": g["hard_kept"], **flat({"guarantee": g})}
            for g in cases.values()]
    rows.append({"run": "r", "status": "failed"})
    (entry,) = guarantee_table(rows)
    assert entry["points"] == 7 and entry["failed"] == 1 and entry["broken"] == 1
    counts = {name: entry[name][0] for name in ("starts inside", "viable", "covered",
                                                "inside but not viable", "outside bounds",
                                                "starts outside")}
    # the unfiltered run: inside the box, its viable set (it has no other), never covered
    assert counts == {"starts inside": 5, "viable": 4, "covered": 2, "inside but not viable": 1,
                      "outside bounds": 1, "starts outside": 1}
    _, share, low, high = entry["covered"]  # one of the two left a set
    assert share == 0.5 and (low, high) == pytest.approx(wilson(1, 2))
    recovery = entry["recovery"]
    assert (recovery["left"], recovery["back_within_1s"]) == (3, 1)
    assert (recovery["low"], recovery["high"]) == pytest.approx(wilson(1, 3))
    assert recovery["longest_s"] == pytest.approx(2.001)  # the start outside, to the end
    text = format_guarantee_table([entry])
    assert "covered = starts inside the filter's viable set" in text
    assert "r               1/3:  33.3 % [" in text and "2.001 s" in text
    assert max(len(line) for line in text.splitlines()) <= 100


def test_the_sweep_report_reads_rows_from_before_the_viable_set():
    """Rows of an older sweep (no starts_viable, covered): the box and the old rule."""
    row = {"run": "r", "status": "ok", "hard_sets_kept": True, "guarantee.starts_inside": True,
           "guarantee.feasible": True, "guarantee.within_bounds": True}
    (entry,) = guarantee_table([row])
    assert entry["viable"][0] == entry["covered"][0] == 1
    assert entry["inside but not viable"][0] == 0 and entry["recovery"]["left"] == 0


# The reproducers, run for real (~20 s each)

PAPER_SAFETY = "pipelines/paper_safety.toml"


@pytest.fixture(scope="module")
def undeclared_disturbance(tmp_path_factory):
    """`cosim run` with an undeclared 200 N·m sinusoidal disturbance on joint 1 (issue 30:
    it was "covers this run — BROKEN", blaming the filter)."""
    out = tmp_path_factory.mktemp("disturbance") / "run"
    done = cosim_cli("run", PAPER_SAFETY, "--run", "proposed_cbf", "--out", str(out),
                     "--set", "simulation.duration=0.5",
                     "--set", 'plant.parameters."tau_d_amp[1]"=200',
                     "--set", 'plant.parameters."tau_d_freq[1]"=2.0')
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    return summary["runs"]["proposed_cbf"]["metrics"]["guarantee"], " ".join(done.stdout.split())


def test_an_undeclared_disturbance_is_outside_naming_it(undeclared_disturbance):
    g, printed = undeclared_disturbance
    named = ("plant tau_d_amp[1] = 200 N·m at tau_d_freq[1] = 2 Hz (nominal 0): a disturbance "
             "error up to 200 N·m on joint 1 > the declared 0 N·m (uncertainty.disturbance)")
    assert g["outside"] == [named]
    assert g["covered"] is False and g["broken"] is False
    assert f"guarantee does not cover this run: {named}" in printed and "BROKEN" not in printed


def test_an_undeclared_gravity_is_outside_naming_it_for_both_filters():
    pipeline = load_pipeline(PAPER_SAFETY, ["simulation.duration=0.5", "plant.parameters.g=80"])
    pipeline.runs = {name: pipeline.runs[name] for name in ("proposed_cbf", "baseline_cbf")}
    for name, result in run(pipeline, None, progress=False).items():
        g = result.metrics["guarantee"]
        assert g["outside"] == ["plant g = 80 m/s² (the nominal chain's 9.8 m/s²): gravity is "
                                "not declared uncertain"], name
        assert g["covered"] is False and g["broken"] is False, name
        assert not math.isnan(result.trace["q"][-1, 0]), name  # the run went to its end
