"""Evaluation that declares its inputs: a chain without an observer (PD control with
gravity compensation) assembles, runs and is evaluated by the evaluators whose inputs it
has; the others are reported as not run, with the signal or constant they miss."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cosim.config import load_pipeline
from cosim.evaluate import EVALUATORS, Evaluator, SafeSet
from cosim.runner import run
from cosim.signals import Signal, Trace

PD = "pipelines/pd_control.toml"
GRAVITY = 9.8  # m/s², the inertia model's default
MASSES, LENGTH = (0.8, 2.3), 1.0  # the nominal arm (paper): lc = l = 1 m, I = 0


@pytest.fixture(scope="module")
def pd_runs(tmp_path_factory):
    """Both PD runs, 2 s, into a run folder with its recording and figures."""
    out = tmp_path_factory.mktemp("pd") / "run"
    pipeline = load_pipeline(PD, ["simulation.duration=2.0"])
    return pipeline, run(pipeline, out, progress=False), out


def gravity_torque(q: np.ndarray) -> np.ndarray:
    """G(q) of the two-link arm in closed form (point masses at the link tips, link 1 from
    the horizontal, gravity along −y), written here apart from the block's Newton–Euler."""
    (m1, m2), g, l1 = MASSES, GRAVITY, LENGTH
    c1, c12 = np.cos(q[:, 0]), np.cos(q[:, 0] + q[:, 1])
    return np.column_stack([(m1 + m2) * g * l1 * c1 + m2 * g * LENGTH * c12,
                            m2 * g * LENGTH * c12])


@pytest.mark.parametrize("name", ["pd_full_state", "pd_finite_difference"])
def test_pd_torque_is_kp_e_plus_kd_edot_plus_the_nominal_gravity(pd_runs, name):
    pipeline, results, _ = pd_runs
    trace = results[name].trace
    kp, kd = pipeline.runs[name].pd_controller.kp, pipeline.runs[name].pd_controller.kd
    if name == "pd_full_state":
        q, velocity = trace["q"], trace["qdot"]
    else:  # the measured position and its backward difference (q̇_d at the first row)
        q = trace["q_meas"]
        velocity = np.vstack([trace["qdot_d"][:1], np.diff(q, axis=0) / trace.dt])
    e, edot = trace["q_d"] - q, trace["qdot_d"] - velocity
    np.testing.assert_allclose(trace["e"], e, rtol=0, atol=1e-12)
    np.testing.assert_allclose(trace["edot"], edot, rtol=1e-9, atol=1e-9)
    expected = kp * e + kd * edot + gravity_torque(q)
    np.testing.assert_allclose(trace["tau"], expected, rtol=1e-9, atol=1e-9)


def test_a_run_without_an_observer_is_evaluated_by_what_it_has(pd_runs):
    """Safe sets, tracking, torque and the filter's guarantee (which speaks of every run) are
    evaluated; the observer's check, Theorem 1's R and barriers and the NN's gain are
    reported as not run, naming what they miss."""
    _, results, out = pd_runs
    summary = json.loads((out / "summary.json").read_text())
    for name, result in results.items():
        said = summary["runs"][name]["evaluators"]
        assert list(said) == list(EVALUATORS)
        ran = {n for n, text in said.items() if text == "ran"}
        assert ran == {"safe_sets", "tracking", "torque", "guarantee"}, said
        assert said["barriers"] == (
            "not run: needs the signals 'q_hat', 'qdot_hat', 'k0', 'W_o_norm', 'r_hat', "
            "'W_norm', 'V_norm', which no block in the chain produces; needs the constants "
            "'nn_gains', 'observer_gain', which no block in the chain publishes")
        assert said["observer_error"] == ("not run: needs the signal 'qdot_hat', which no "
                                          "block in the chain produces")
        safety = summary["runs"][name]["safety"]
        assert "position_joint1" in safety and "error_rate_norm" in safety
        assert "filtered_error_norm" not in safety and "observer_error_norm" not in safety
        # the true error rate is checked apart only where ė is an estimate
        assert ("error_rate_true_norm" in safety) == (name == "pd_finite_difference")
        metrics = summary["runs"][name]["metrics"]
        e = result.trace["e"]
        np.testing.assert_allclose(metrics["rms_error"], np.sqrt(np.mean(e**2, axis=0)),
                                   rtol=1e-12)
        assert "min_barrier_H" not in metrics and "theorem1" not in metrics
        assert result.evaluation.barriers == {}
    files = {p.name for p in out.iterdir()}
    assert {"recording.rrd", "fig2_position_velocity.png", "fig4_torques.png"} <= files
    assert "fig5_barriers.png" not in files  # no run has barriers to draw


def test_an_evaluator_whose_inputs_are_missing_does_not_run():
    """Straight on the Evaluator: a trace with only a torque is evaluated for torque alone,
    and every other evaluator says which signals it misses."""
    signals = {"tau": Signal("n", "N·m", "torque")}
    trace = Trace(signals, 2, 10, 1e-3)
    trace["tau"][:] = np.linspace(-1.0, 1.0, 22).reshape(11, 2)
    trace.rows_done = 11
    result = Evaluator(trace, SafeSet(), {}).result()
    assert result.evaluators["torque"] == "ran"
    assert result.metrics["peak_torque"] == [1.0, 1.0]
    assert result.checks == {} and result.safety == {} and result.barriers == {}
    for name, text in result.evaluators.items():
        if name == "effort_limits":  # it needs only τ, and declared effort limits
            assert text == ("not run: no effort limits declared: they are the robot's own "
                            '(safety.limits = "urdf")'), text
        elif name != "torque":
            assert text.startswith("not run: needs the signal"), (name, text)
            assert "'tau'" not in text


def test_a_plant_output_the_fmu_does_not_map_is_absent_to_evaluation_and_the_guarantee():
    """Without qdot (plant.variables.qdot = []) the trace keeps q̇ as NaN, and NaN must not
    pass for a kept set: the true-velocity checks are unavailable (said so), Theorem 1's
    barriers (which need q̇) do not run, naming the plant output, and the filter's
    guarantee does not cover the run, instead of a 'kept every hard set' that compared
    nothing."""
    pipeline = load_pipeline("pipelines/paper_safety.toml",
                             ["plant.variables.qdot=[]", "simulation.duration=0.5"])
    pipeline.runs = {"proposed_cbf": pipeline.runs["proposed_cbf"]}
    result = run(pipeline, None, progress=False)["proposed_cbf"]
    assert result.complete and np.isnan(result.trace["qdot"]).all()
    said = result.evaluation.evaluators
    assert said["safe_sets"] == ("ran (the true-velocity sets unavailable: the plant does not "
                                 "map its joint velocities qdot)")
    assert said["observer_error"] == ("ran (its check unavailable: the plant does not map "
                                      "qdot)")
    assert said["barriers"] == ("not run: needs the plant output 'qdot', which the plant does "
                                "not map")
    assert "min_barrier_H" not in result.metrics
    assert result.metrics["observer_velocity_error_rms_after_1s"] is None
    checks = result.safety
    assert checks["position_joint1"]["satisfied"] is True
    for name in ("velocity_true_joint1", "error_rate_true_norm", "observer_error_norm"):
        assert checks[name]["satisfied"] is None and "no qdot" in checks[name]["unavailable"]
    guarantee = result.metrics["guarantee"]
    assert guarantee["within_bounds"] is False and "velocity_true" not in str(
        guarantee["first_exit"])
    assert ("true velocity unknown (the plant does not map qdot): the velocity set cannot be "
            "judged") in guarantee["outside"]
    assert guarantee["broken"] is False and "starts_inside_observer_set" not in guarantee


def test_an_evaluators_series_figure_is_its_own_declaration(tmp_path):
    """The framework names no evaluator's figure: the paper's barriers declare theirs
    (fig5_barriers), and an evaluator of a plugin that names one gets its series drawn
    there, its condition beside them, for the runs that have its series only; the run
    folder counts the file as its own (what --force may replace)."""
    from cosim.evaluate import Part, register_evaluator
    from cosim.outputs.figures import figure_files, figure_jobs, write_figures

    assert {"fig2_position_velocity.png", "fig3_errors.png", "fig4_torques.png",
            "fig5_barriers.png"} <= set(figure_files())  # (loads the paper's evaluators)
    assert EVALUATORS["barriers"].series_figure == "fig5_barriers"
    assert "wear.png" not in figure_files()

    @register_evaluator
    class Wear(Part):
        name = "wear_for_this_test"
        meaning = "a plugin's series and its condition"
        inputs = ("tau",)
        series_meanings = {"wear": "accumulated wear (1)", "margin": "wear left (≥ 0, 1)"}
        conditions = ("margin",)
        series_figure = "wear"

    try:
        assert "wear.png" in figure_files()
        time = {"a": np.linspace(0.0, 1.0, 11), "b": np.linspace(0.0, 1.0, 11)}
        torques = {run: np.zeros((11, 2)) for run in time}
        series = {"a": {"wear": np.linspace(0, 1, 11), "margin": np.linspace(1, -1, 11)},
                  "b": {"H": np.ones(11)}}  # run b has no wear: not in its figure
        jobs = {name: (kind, data) for name, kind, data in
                figure_jobs(time, {}, torques, series)}
        kind, (times, drawn, conditions) = jobs["wear.png"]
        assert kind == "series" and list(drawn) == ["a"] and list(times) == ["a"]
        assert set(drawn["a"]) == {"wear", "margin"} and conditions == ["margin"]
        assert "fig5_barriers.png" not in jobs  # no run has the paper's barriers
        written = write_figures(tmp_path, time, {}, torques, series)
        assert set(written) == {"fig4_torques.png", "wear.png"}
        assert (tmp_path / "wear.png").stat().st_size > 1000
    finally:
        del EVALUATORS["wear_for_this_test"]
    assert "wear.png" not in figure_files()
