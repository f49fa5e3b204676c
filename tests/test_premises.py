"""The check's premises measured along a run (cosim/paper/premises.py, issue 52 item 4) and
the guarantee from the first milliseconds (covered_from, item 1): each rule in both
directions on synthetic traces (tests/test_guarantee.py's) and the motion between samples
against brute force. Real runs whose premises are measured: tests/test_steps.py. SI units,
radians."""

from __future__ import annotations

import numpy as np
import pytest
from test_guarantee import DT, OUTPUT_FEEDBACK, judge, make_trace, place

from cosim.paper.cbf_filter.assumptions import VIABLE
from cosim.paper.premises import _upper_between, _upper_rate, between_samples
from cosim.signals import Signal

# the check's sets: half of a 0.2 % margin left to the bounds (2 rad, 3 rad/s)
CHECK = np.array([[2.0 * (1 - 1e-3)] * 2, [3.0 * (1 - 1e-3)] * 2])
ALLOWANCE = np.array([[2e-3] * 2, [3e-3] * 2])
WITH_CHECK = OUTPUT_FEEDBACK._replace(check_bounds=CHECK)


def add(trace, name: str, values, unit: str = "-") -> None:
    trace.signals[name] = Signal("n", unit, name)
    trace.arrays[name] = np.broadcast_to(np.asarray(values, float),
                                         trace["q"].shape).copy()


def measured_trace():
    """make_trace's run with what the filter records for its premises: the interval about
    the true q̇ (half-width 0.05), the plan's box about the true state (half-widths 0.01 rad,
    0.02 rad/s) and a band on q̈ that holds the run's (|q̈| ≤ 4 rad/s²: ±10)."""
    trace = make_trace()
    add(trace, "cbf_velocity_centre", trace["qdot"])
    add(trace, "cbf_velocity_spread", 0.05)
    add(trace, "cbf_tube_position", trace["q"])
    add(trace, "cbf_tube_position_spread", 0.01)
    add(trace, "cbf_tube_velocity", trace["qdot"])
    add(trace, "cbf_tube_velocity_spread", 0.02)
    add(trace, "cbf_acceleration_low", -10.0)
    add(trace, "cbf_acceleration_high", 10.0)
    return trace


def test_a_run_whose_premises_hold_is_covered_with_room_to_spare():
    g = judge(measured_trace(), WITH_CHECK)
    assert g["covered"] is True and g["broken"] is False and g["violations"] == []
    assert g["interval_exceeded_steps"] == 0 and g["tube_exceeded_steps"] == 0
    assert g["between_samples_exceeded_steps"] == 0
    assert g["tube_slack"]["position"] == pytest.approx(2e-3 + 0.01)
    assert g["tube_slack"]["velocity"] == pytest.approx(3e-3 + 0.02)
    assert 0 < g["between_samples_room"]["position"] < 2.0 - 0.5 + 1e-3


@pytest.mark.parametrize("joint", (0, 1))
@pytest.mark.parametrize("side", (1.0, -1.0))
def test_the_true_velocity_outside_the_filters_interval_breaks_it(joint, side):
    trace = measured_trace()
    trace["cbf_velocity_centre"][500, joint] -= side * (0.05 - 1e-6)
    assert judge(trace, WITH_CHECK)["interval_exceeded_steps"] == 0
    trace["cbf_velocity_centre"][500, joint] -= side * 2e-6
    g = judge(trace, WITH_CHECK)
    assert g["interval_exceeded_steps"] == 1 and g["broken"] is True
    assert g["violations"] == [
        "the true q̇ outside the velocity interval the filter held at 1 steps (first t = "
        f"0.5 s; joint {joint + 1} up to 1e-06 rad/s past it)"]


@pytest.mark.parametrize("joint", (0, 1))
@pytest.mark.parametrize(("quantity", "half", "room"), [("position", 0.01, 2e-3),
                                                        ("velocity", 0.02, 3e-3)])
def test_the_tube_may_be_left_by_the_room_the_check_leaves_and_no_more(quantity, half,
                                                                       room, joint):
    """Past the plan's box by less than the half-margin the check leaves to the bound: the
    premise holds; past it by more (either side, at either joint): reported, naming it, on
    the run's line. (Held against the guarantee only where the filter followed the plan:
    the next test.)"""
    trace = measured_trace()
    trace[f"cbf_tube_{quantity}"][800, joint] += half + room - 1e-6
    g = judge(trace, WITH_CHECK)
    assert g["tube_exceeded_steps"] == 0 and g["tube_left"] is None
    assert g["tube_slack"][quantity] == pytest.approx(1e-6, abs=1e-9)
    trace[f"cbf_tube_{quantity}"][800, joint] -= 2 * (half + room)
    g = judge(trace, WITH_CHECK)
    assert g["tube_exceeded_steps"] == 1
    assert g["tube_slack"][quantity] == pytest.approx(-1e-6, abs=1e-9)
    assert g["tube_left"].startswith(
        "the true state outside the check's tube by more than the room it leaves to the "
        f"bounds at 1 steps (first t = 0.8 s; the {quantity} by up to 1e-06")
    assert g["broken"] is False and g["violations"] == []
    from test_guarantee import report_line

    assert report_line(g).endswith(" (the tube, measured where a torque was verified afresh, "
                                   f"not held against it: {g['tube_left']})")


@pytest.mark.parametrize("joint", (0, 1))
def test_the_plans_tube_is_judged_apart_where_the_filter_followed_the_plan(joint):
    """A row the filter verified afresh rests on its own check; a row where it followed the
    plan in force (``cbf_planned``) rests on that plan's proof, and its tube is judged
    apart there (``plan_tube_*``) and held: a box left at a fresh row counts in the tube's
    figures only, at a followed row in both and breaks the guarantee, naming it. Without the
    filter's flag, not judged (None)."""
    trace = measured_trace()
    assert judge(trace, WITH_CHECK)["plan_tube_exceeded_steps"] is None
    trace.signals["cbf_planned"] = Signal("1", "-", "cbf_planned")
    trace.arrays["cbf_planned"] = np.zeros(trace["q"].shape[0])
    trace.arrays["cbf_planned"][600:700] = 1.0
    trace["cbf_tube_velocity"][500, joint] += 1.0  # verified afresh there
    g = judge(trace, WITH_CHECK)
    assert g["tube_exceeded_steps"] == 1 and g["plan_tube_exceeded_steps"] == 0
    assert g["plan_tube_slack"]["velocity"] == pytest.approx(3e-3 + 0.02)
    assert g["broken"] is False and g["violations"] == []
    trace["cbf_tube_velocity"][650, joint] += 1.0  # the plan followed there
    g = judge(trace, WITH_CHECK)
    assert g["tube_exceeded_steps"] == 2 and g["plan_tube_exceeded_steps"] == 1
    assert g["plan_tube_slack"]["velocity"] == pytest.approx(3e-3 + 0.02 - 1.0)
    assert g["broken"] is True and g["violations"] == [
        "where the filter followed its plan, the true state outside the check's tube by more "
        "than the room it leaves to the bounds at 1 steps (first t = 0.65 s; the velocity by "
        "up to 0.977 rad/s past that room)"]


def test_no_plan_no_tube_and_a_filter_that_does_not_say_its_sets_is_not_judged():
    trace = measured_trace()
    trace["cbf_tube_velocity"][300:400] = np.nan  # not viable at the step before: no plan
    trace["cbf_tube_velocity"][300:400] += 1.0
    assert judge(trace, WITH_CHECK)["tube_exceeded_steps"] == 0
    trace["cbf_tube_position"][600] += 1.0
    assert judge(trace, OUTPUT_FEEDBACK)["tube_exceeded_steps"] is None
    assert judge(trace, WITH_CHECK)["tube_exceeded_steps"] == 1


def test_between_samples_the_bound_covers_every_admissible_motion():
    """Brute force: random pairs of samples joined by motions whose q̈ stays within the band
    (piecewise constant, 200 pieces): no motion passes the bound on x or on q̇."""
    rng = np.random.default_rng(5)
    h = 1e-3
    for _ in range(300):
        low, high = sorted(rng.uniform(-3000.0, 3000.0, 2))
        x0, v0 = rng.uniform(-1, 1), rng.uniform(-5, 5)
        pieces = rng.uniform(low, high, 200) if rng.random() < 0.5 else \
            np.where(np.arange(200) < rng.integers(0, 201), high, low)
        tau = h / 200
        v = v0 + np.concatenate(([0.0], np.cumsum(pieces) * tau))
        x = x0 + np.concatenate(([0.0], np.cumsum(v[:-1] * tau + 0.5 * pieces * tau * tau)))
        bound_x = _upper_between(x0, x[-1], v0, v[-1], high, h)
        bound_v = _upper_rate(v0, v[-1], low, high, h)
        assert x.max() <= bound_x + 1e-12 and v.max() <= bound_v + 1e-12
    # exact where the band is one value: a joint braking at 2000 rad/s² past its turning
    # point between the samples reaches x0 + v0²/4000, above both samples
    x0, v0, a = 0.0, 1.0, -2000.0
    x1, v1 = x0 + v0 * h + 0.5 * a * h * h, v0 + a * h
    assert _upper_between(x0, x1, v0, v1, a, h) == pytest.approx(v0 * v0 / (2 * -a))
    assert _upper_rate(v0, v1, a, a, h) == pytest.approx(v0)


def test_between_samples_a_bound_passed_only_between_them_breaks_it():
    """Joint 1 reaches 1.9995 rad at two samples 1 ms apart, moving out then in at 1 rad/s:
    with q̈ ≥ −2000 rad/s² it may not have passed 2 rad between them; with a band that lets
    it brake only at 100 rad/s² it may have (x = 1.9995 + 1 · 0.0005 ... > 2): broken."""
    trace = measured_trace()
    for name in ("q", "q_meas"):
        trace[name][1000, 0], trace[name][1001, 0] = 1.9995, 1.9995
    for name in ("qdot", "qdot_hat"):
        trace[name][1000, 0], trace[name][1001, 0] = 1.0, -1.0
    trace["cbf_velocity_centre"][:] = trace["qdot"]
    trace["cbf_tube_position"][:], trace["cbf_tube_velocity"][:] = trace["q"], trace["qdot"]
    trace["cbf_acceleration_low"][1000, 0] = -2000.0
    trace["cbf_acceleration_high"][1000, 0] = -2000.0
    g = judge(trace, WITH_CHECK)
    assert g["between_samples_exceeded_steps"] == 0, g["between_samples_room"]
    trace["cbf_acceleration_high"][1000, 0] = 10.0
    g = judge(trace, WITH_CHECK)
    assert g["between_samples_exceeded_steps"] == 1 and g["broken"] is True
    assert g["violations"][0].startswith("between samples the position may pass its bound")


def test_between_samples_without_the_band_is_not_judged():
    trace = measured_trace()
    trace["cbf_acceleration_low"][:] = np.nan
    assert between_samples(trace, 0, (np.zeros(2), np.zeros(2)),
                           (np.full(2, 2.0), np.full(2, 3.0)))[:2] == (0, {"position": None,
                                                                           "velocity": None})


# covered_from: an output-feedback start whose velocity the filter could not tell inside

def uncertain_start(first_viable: int):
    """Inside the box, the filter's interval at t = 0 past the 3 rad/s bound (x̂2(0) ± the
    declared error), viable from row ``first_viable`` on."""
    trace = measured_trace()
    trace["cbf_velocity_spread"][0] = 2.5
    trace[VIABLE][:first_viable] = 0.0
    return trace


def test_an_uncertain_start_is_covered_from_the_first_viable_step():
    g = judge(uncertain_start(4), WITH_CHECK)
    assert g["starts_inside"] is True and g["starts_viable"] is False
    assert g["not_viable"].startswith("the velocity the filter holds at t = 0 reaches past")
    assert g["covered"] is True and g["covered_from_s"] == pytest.approx(4 * DT)
    assert g["broken"] is False
    from test_guarantee import report_line

    assert report_line(g) == ("kept every hard set; guarantee covers this run from 0.004 s "
                              "(its start-up, the velocity not yet shown inside)")


def test_from_then_on_what_breaks_it_breaks_it_and_not_before():
    trace = uncertain_start(4)
    trace["cbf_infeasible"][:4] = 1.0  # the start-up: not held against it
    trace["cbf_tube_velocity"][2] += 1.0  # a box before the guarantee began: not judged
    g = judge(trace, WITH_CHECK)
    assert g["covered"] is True and g["broken"] is False and g["infeasible_steps"] == 4
    trace["cbf_infeasible"][10] = 1.0
    g = judge(trace, WITH_CHECK)
    assert g["violations"] == ["1 infeasible step(s)"] and g["broken"] is True


def test_a_set_left_during_the_start_up_means_the_guarantee_never_began():
    trace = uncertain_start(30)
    place(trace, "q", (slice(10, 20), 0), 2.1)
    g = judge(trace, WITH_CHECK)
    assert g["covered"] is False and g["broken"] is False and g["covered_from_s"] is None


def test_a_set_left_at_the_first_viable_step_means_the_guarantee_never_began():
    """The start-up runs up to the first viable step inclusive: a set left at that very step
    is left before the guarantee began (not covered, not broken)."""
    trace = uncertain_start(30)
    place(trace, "q", (30, 0), 2.1)
    g = judge(trace, WITH_CHECK)
    assert g["covered"] is False and g["broken"] is False and g["covered_from_s"] is None


@pytest.mark.parametrize("joint", (0, 1))
def test_an_uncertain_start_below_the_velocity_bound_starts_later_at_either_joint(joint):
    """The filter's interval at t = 0 reaching past the lower velocity bound (−1 ± 2.5
    against −3 rad/s), the other joint's well inside: not viable as seen, named at that
    joint, and covered from the first viable step."""
    trace = uncertain_start(4)
    trace["cbf_velocity_spread"][0] = 0.05
    place(trace, "qdot", (0, joint), -1.0)
    trace["cbf_velocity_centre"][0, joint] = -1.0
    trace["cbf_velocity_spread"][0, joint] = 2.5
    g = judge(trace, WITH_CHECK)
    assert g["not_viable"].startswith("the velocity the filter holds at t = 0 reaches past "
                                      f"the velocity bound (joint {joint + 1}:")
    assert g["covered"] is True and g["covered_from_s"] == pytest.approx(4 * DT)


def test_only_an_uncertain_velocity_and_only_an_output_feedback_filter_start_later():
    trace = uncertain_start(4)
    trace["cbf_velocity_spread"][0] = 0.05  # not viable for another reason: never covered
    assert judge(trace, WITH_CHECK)["covered"] is False
    full_state = WITH_CHECK._replace(position="q", velocity="qdot")
    assert judge(uncertain_start(4), full_state)["covered"] is False
    never = uncertain_start(4)
    never[VIABLE][:] = 0.0
    assert judge(never, WITH_CHECK)["covered"] is False
