"""References a user gives (cosim/paper/trajectory.py, trajectory_file.py, reference_limits.py):
joint-space waypoints joined by minimum-jerk segments against the closed form (Flash & Hogan),
q, q̇ and q̈ continuous at the knots; a CSV trajectory against the function it samples; the
check against the limits before the run against the closed-form peaks; and every bad CSV
refused with one message. SI units, radians.

Tolerances: the closed form and SciPy's Bernstein polynomials are a few dozen operations on
O(1–100) numbers: 1e-9 relative to the quantity's scale (measured ≤ 2e-13)."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import cosim_cli, error_line

from cosim.assemble import assemble_run
from cosim.config import PipelineError, load_pipeline
from cosim.paper.reference_limits import JointLimits, breaches
from cosim.paper.trajectory import minimum_jerk, through_samples
from cosim.runner import run

RTOL = 1e-9
PD = Path("pipelines/pd_control.toml").resolve()


class _TwoLinkArm:  # what assembly needs to know of the paper's plant
    links, mapped = 2, frozenset({"q", "qdot", "M"})


def close(actual, expected, rtol: float = RTOL) -> bool:
    actual, expected = np.asarray(actual, float), np.asarray(expected, float)
    scale = max(1.0, float(np.max(np.abs(expected), initial=0.0)))
    return bool(np.all(np.abs(actual - expected) <= rtol * scale))


def minimum_jerk_closed_form(t: float, t0: float, t1: float, q0: np.ndarray, q1: np.ndarray
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rest-to-rest minimum-jerk segment (Flash & Hogan 1985), written out:
    q = q0 + Δ(10s³ − 15s⁴ + 6s⁵), q̇ = Δ/T (30s² − 60s³ + 30s⁴), q̈ = Δ/T² (60s − 180s² + 120s³)."""
    duration, delta = t1 - t0, q1 - q0
    s = (t - t0) / duration
    return (q0 + delta * (10 * s**3 - 15 * s**4 + 6 * s**5),
            delta / duration * (30 * s**2 - 60 * s**3 + 30 * s**4),
            delta / duration**2 * (60 * s - 180 * s**2 + 120 * s**3))


def random_waypoints(rng: np.random.Generator, count: int, joints: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    times = np.concatenate(([0.0], np.cumsum(rng.uniform(0.2, 3.0, count - 1))))
    return times, rng.uniform(-3.0, 3.0, (count, joints))


def test_waypoints_are_minimum_jerk_segments():
    """At 200 random times in each segment of 20 random waypoint sets (up to 7 joints, 2 to 8
    waypoints, segments of 0.2–3 s): q_d, q̇_d, q̈_d equal the closed form; after the last
    waypoint the reference holds it at rest."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        times, positions = random_waypoints(rng, int(rng.integers(2, 9)), int(rng.integers(1, 8)))
        reference = minimum_jerk(times, positions, "test")
        for k in range(len(times) - 1):
            t = np.sort(rng.uniform(times[k], times[k + 1], 200))
            got = reference.evaluate(t)
            for row, time in enumerate(t):
                expected = minimum_jerk_closed_form(time, times[k], times[k + 1],
                                                    positions[k], positions[k + 1])
                for value, want in zip(got, expected, strict=True):
                    assert close(value[row], want), (k, time)
        q, qd, qdd = reference.evaluate(times[-1] + np.array([0.0, 0.5, 100.0]))
        assert close(q, np.tile(positions[-1], (3, 1))) and not qd.any() and not qdd.any()


def test_waypoints_are_continuous_in_q_qdot_and_qddot_at_the_knots():
    """Either side of every waypoint (1e-9 s away) q_d, q̇_d, q̈_d agree to their slopes
    times 2e-9 s, and at the waypoint they are (q_k, 0, 0); a jump in q̈_d (a cubic's,
    trapezoid's or linear interpolation's) would show as a difference ~|Δ|/T²."""
    rng = np.random.default_rng(5)
    times, positions = random_waypoints(rng, 6, 4)
    reference = minimum_jerk(times, positions, "test")
    eps = 1e-9
    for k, time in enumerate(times[1:-1], start=1):
        before, at, after = (reference.evaluate(np.array([time + d])) for d in (-eps, 0, eps))
        assert close(at[0][0], positions[k]) and close(at[1][0], 0) and close(at[2][0], 0)
        jerk_scale = 60 * np.max(np.abs(np.diff(positions, axis=0))) / np.min(np.diff(times))**3
        for order in range(3):
            assert np.max(np.abs(after[order] - before[order])) <= 2 * eps * jerk_scale + 1e-12


def test_a_sampled_trajectory_follows_the_function_it_samples():
    """The CSV reference through samples of q(t) = sin(1.3 t) + 0.2 t² every 20 ms (SciPy's
    quintic Hermite through the samples): with q, q̇, q̈ given it matches them at the samples
    (RTOL) and stays within 1e-8 of the function between them (error O(h⁶)); with q alone
    (derivatives from a not-a-knot cubic spline) within 1e-6 in q, 2e-4 rad/s in q̇ and
    2e-2 rad/s² in q̈ (O(h⁴), O(h³), O(h²)); q̈ continuous at the knots in both cases."""
    def f(t):
        return (np.sin(1.3 * t) + 0.2 * t**2, 1.3 * np.cos(1.3 * t) + 0.4 * t,
                -1.69 * np.sin(1.3 * t) + 0.4)

    times = np.arange(0.0, 2.0 + 1e-12, 0.02)
    q, qd, qdd = (x[:, None] for x in f(times))
    between = np.linspace(0.0, 2.0, 3001)
    truth = f(between)
    full = through_samples(times, q, qd, qdd, "test")
    for got, want in zip(full.evaluate(times), (q, qd, qdd), strict=True):
        assert close(got, want)
    for got, want in zip(full.evaluate(between), truth, strict=True):
        assert np.max(np.abs(got[:, 0] - want)) <= 1e-8
    positions_only = through_samples(times, q, None, None, "test")
    for got, want, tolerance in zip(positions_only.evaluate(between), truth, (1e-6, 2e-4, 2e-2),
                                    strict=True):
        assert np.max(np.abs(got[:, 0] - want)) <= tolerance
    for reference in (full, positions_only):
        knots = times[1:-1]
        left = reference.evaluate(knots - 1e-9)[2]
        right = reference.evaluate(knots + 1e-9)[2]
        assert np.max(np.abs(left - right)) <= 1e-5


def test_the_limit_check_finds_the_closed_form_peaks():
    """Each minimum-jerk segment's peak speed is 15/8·|Δ|/T at its middle and its positions
    are monotone between the waypoints. The check (exact: the roots of q̈_d per segment)
    finds, for speed bounds just below the largest peak, the segment's middle and that
    value; for bounds 1e-6 above it, nothing; for position limits just inside the extreme
    waypoints, the waypoint's time and position. Per joint, with per-joint arrays."""
    rng = np.random.default_rng(7)
    for _ in range(20):
        times, positions = random_waypoints(rng, 5, 3)
        reference = minimum_jerk(times, positions, "test")
        durations = np.diff(times)[:, None]
        peaks = 15 / 8 * np.abs(np.diff(positions, axis=0)) / durations  # (segments, n)
        worst = peaks.max(axis=0)
        wide = np.full(3, 1e3)
        speed = JointLimits(-wide, wide, worst * (1 - 1e-6), np.zeros(3), "test")
        found = breaches(reference, speed, times[-1])
        assert [b.joint for b in sorted(found, key=lambda b: b.joint)] == [1, 2, 3]
        for b in found:
            segment = int(np.argmax(peaks[:, b.joint - 1]))
            assert b.quantity == "velocity"
            assert b.t == pytest.approx((times[segment] + times[segment + 1]) / 2, rel=1e-9)
            assert abs(b.value) == pytest.approx(worst[b.joint - 1], rel=1e-9)
        assert not breaches(reference, JointLimits(-wide, wide, worst * (1 + 1e-6),
                                                    np.zeros(3), "test"), times[-1])
        top = positions.max(axis=0)
        position = JointLimits(positions.min(axis=0) - 1e-6, top - 1e-6, wide, np.zeros(3),
                               "test")
        for b in breaches(reference, position, times[-1]):
            assert b.quantity == "position" and b.value == pytest.approx(top[b.joint - 1])
            # (q̇_d's double root at a waypoint is found to ~1e-8 s)
            assert b.t == pytest.approx(times[int(np.argmax(positions[:, b.joint - 1]))],
                                        abs=1e-6)


def waypoint_pipeline(tmp_path: Path, table: str, *overrides: str):
    """pipelines/pd_control.toml over 3 s with the reference ``table`` (TOML), the safe
    sets centred at 0."""
    path = tmp_path / "user.toml"
    path.write_text(f'extends = "{PD}"\n[simulation]\nduration = 3.0\n[reference]\n'
                    f"safe_centre = [0.0, 0.0]\nsafe_velocity_centre = [0.0, 0.0]\n{table}\n")
    return path, load_pipeline(path, list(overrides))


WAYPOINTS = ("[reference.waypoints]\ntimes = [0.0, 1.0, 2.5]\n"
             "positions = [[0.1, 0.1], [1.0, -0.5], [0.5, 0.5]]")


def test_a_reference_outside_the_limits_is_refused_naming_joint_time_and_value(tmp_path):
    """Waypoints whose joint-1 segment peaks at 15/8·0.9/1 = 1.6875 rad/s, against a speed
    bound of 1.5 rad/s: `cosim run` ends with one message (exit 2) naming joint 1, the
    segment's middle t = 0.5 s and that speed; reference.limits = "report" runs it, listing
    the breach (summary.json's reference entry); over a run of 0.3 s (q̇_d(0.3 s) = 1.19 rad/s)
    there is none."""
    path, _ = waypoint_pipeline(tmp_path, WAYPOINTS)
    result = cosim_cli("run", str(path), "--out", str(tmp_path / "out"), "--no-figures",
                       "--set", "safety.velocity_bound=1.5")
    line = error_line(result)
    assert ("reference.waypoints leaves joint 1's velocity: q̇_d = 1.6875 rad/s at t = 0.5 s, "
            "above its upper limit 1.5 rad/s") in line
    assert not (tmp_path / "out").exists()  # refused before anything was written
    _, pipeline = waypoint_pipeline(tmp_path, WAYPOINTS, "safety.velocity_bound=1.5",
                                    'reference.limits="report"')
    plan = assemble_run(pipeline, "pd_full_state", _TwoLinkArm())
    (left,) = plan.block("reference").limits_left
    assert (left.joint, left.quantity, left.t) == (1, "velocity", pytest.approx(0.5))
    assert left.value == pytest.approx(1.6875, rel=1e-12)
    assert plan.block("reference").describe()["limits_left"] == [left.summary()]
    _, short = waypoint_pipeline(tmp_path, WAYPOINTS, "safety.velocity_bound=1.5",
                                 "simulation.duration=0.3")
    assert assemble_run(short, "pd_full_state", _TwoLinkArm()).block("reference").limits_left \
        == []


@pytest.mark.parametrize(("table", "message"), [
    ("times = [0.0, 2.0, 1.0]\npositions = [[0, 0], [1, 1], [0, 0]]",
     "reference.waypoints.times[2] = 1 s does not increase (times[1] = 2 s); times must "
     "increase strictly"),
    ("times = [0.5, 2.0]\npositions = [[0, 0], [1, 1]]",
     "reference.waypoints.times starts at 0.5 s; the first waypoint is at t = 0 s, the run's "
     "start"),
    ("times = [0.0, 2.0]\npositions = [[0, 0], [1, 1], [0, 0]]",
     "reference.waypoints.positions has 3 rows, times has 2: one row of joint positions per "
     "time"),
    ("times = [0.0, 2.0]\npositions = [[0, 0, 0], [1, 1, 1]]",
     "reference.waypoints.positions has rows of 3 entries (one per joint, rad); the plant "
     "(the plant) has 2 joints"),
])
def test_bad_waypoints_are_refused_naming_the_key(tmp_path, table, message):
    """Times that do not increase or do not start at 0, a row count other than the times',
    rows of the wrong joint count: one message naming the key (at load or assembly)."""
    with pytest.raises(PipelineError) as caught:
        _, pipeline = waypoint_pipeline(tmp_path, f"[reference.waypoints]\n{table}")
        assemble_run(pipeline, "pd_full_state", _TwoLinkArm())
    assert message in str(caught.value)


def write_csv(path: Path, rows: list[str], header: str = "t,q1,q2") -> Path:
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


@pytest.mark.parametrize(("rows", "message"), [
    (None, "reference.csv: {path} does not exist"),
    (["0,0.1,0.1", "1.0,0.2", "2.0,0.1,0.1"],
     "reference.csv: {path}, line 3: 2 columns; for the plant's 2 joints give 3 (t, q), "
     "5 (t, q, q̇), 7 (t, q, q̇, q̈)"),
    (["0,0.1,0.1", "1.0,0.2,0.2", "1.0,0.1,0.1"],
     "reference.csv: {path}, line 4: time 1 s does not increase (line 3: 1 s); times must "
     "increase strictly"),
    (["0,0.1,0.1", "1.0,nan,0.2", "2.0,0.1,0.1"],
     "reference.csv: {path}, line 3, column 2 (q_1): nan is not a finite number"),
    (["0,0.1,0.1", "1.0,0.2,abc", "2.0,0.1,0.1"],
     "reference.csv: {path}, line 3, column 3: 'abc' is not a number"),
    (["0;0.1;0.1", "2.0;0.1;0.1"],
     "reference.csv: {path}, line 2, column 1: '0;0.1;0.1' is not a number; the columns are "
     "separated by commas (',')"),
    (["0.5,0.1,0.1", "2.0,0.1,0.1"],
     "reference.csv: {path}, line 2: the first time is 0.5 s; the trajectory starts at "
     "t = 0 s, the run's start"),
    (["0,0.1,0.1", "1.0,0.1,0.1"],
     "reference.csv: {path} covers 0–1 s, shorter than the run (simulation.duration = 2 s): "
     "give samples up to the run's end, or shorten it"),
])
def test_bad_csv_files_are_refused_with_one_message(tmp_path, rows, message):
    """A missing file, a row of the wrong width, time not increasing, a NaN, a word (one with
    semicolons: the separator named), a start
    other than 0 and a file shorter than the run: each one PipelineError naming the file and
    line, raised when the run is assembled (before anything runs)."""
    csv = tmp_path / "trajectory.csv"
    if rows is not None:
        write_csv(csv, rows)
    _, pipeline = waypoint_pipeline(tmp_path, 'csv = "trajectory.csv"', "simulation.duration=2")
    with pytest.raises(PipelineError) as caught:
        assemble_run(pipeline, "pd_full_state", _TwoLinkArm())
    assert str(caught.value) == message.format(path=csv)


def assembled_reference(tmp_path: Path, table: str, *overrides: str):
    """The PD run's reference block, assembled from ``table`` (TOML under [reference])."""
    _, pipeline = waypoint_pipeline(tmp_path, table, *overrides)
    return assemble_run(pipeline, "pd_full_state", _TwoLinkArm()).block("reference")


@pytest.mark.parametrize(("rows", "message"), [
    # (SciPy's "Internal error in root finding" and "dydx must contain only finite values"
    # tracebacks, with LAPACK's "illegal value" lines)
    (["0,0,0", "1e-300,0.1,0.1", "3.0,0.2,0.2"],
     "reference.csv: {path}, lines 2 and 3: the segment from t = 0 s to 1e-300 s (1e-300 s, "
     "values up to 0.1) makes q_d, q̇_d or q̈_d too large for double precision: give samples "
     "of a robot's scale"),
    (["0,0,0", "1.0,1e308,0", "3.0,0,0"],
     "reference.csv: {path}, lines 2 and 3: the segment from t = 0 s to 1 s (1 s, values up "
     "to 1e+308) makes q_d, q̇_d or q̈_d too large for double precision: give samples of a "
     "robot's scale"),
    # (read as 10)
    (["0,0,0", "1_0,0,0"], "reference.csv: {path}, line 3, column 1: '1_0' is not a number"),
])
def test_a_csv_beyond_double_precision_or_python_syntax_is_refused(tmp_path, rows, message):
    csv = write_csv(tmp_path / "trajectory.csv", rows)
    with pytest.raises(PipelineError) as caught:
        assembled_reference(tmp_path, 'csv = "trajectory.csv"\nlimits = "report"',
                            "simulation.duration=2")
    assert str(caught.value) == message.format(path=csv)


def test_a_csv_that_is_a_named_pipe_is_said_to_be_one(tmp_path):
    """It was refused at once, but as "does not exist"."""
    import os

    os.mkfifo(tmp_path / "trajectory.csv")
    with pytest.raises(PipelineError) as caught:
        assembled_reference(tmp_path, 'csv = "trajectory.csv"')
    assert str(caught.value) == (f"reference.csv: {tmp_path / 'trajectory.csv'} is a named pipe "
                                 "(FIFO), not a CSV file")


def test_a_byte_order_mark_is_not_taken_for_a_header(tmp_path):
    """A file without a header whose first line starts with a byte-order mark: that line,
    a sample, was taken as a header ("the first time is 1 s")."""
    path = tmp_path / "trajectory.csv"
    path.write_bytes("\ufeff0,0.1,0.2\n1,0.1,0.2\n3,0.1,0.2\n".encode())
    block = assembled_reference(tmp_path, 'csv = "trajectory.csv"')
    assert close(block.evaluate(np.array([0.0]))[0], [[0.1, 0.2]])


def test_a_long_csv_is_read_only_as_far_as_the_run_uses_it(tmp_path):
    """The blow-up: 10⁶ rows for a 1 s run took 3 min 25 s and 1 GB, every row interpolated.
    Now reading stops 64 samples past the run's end (or the safe sets' horizon), what lies
    beyond is not even parsed (a word there passes), and the reference over the run is the
    whole file's to the last bits (the not-a-knot spline's dependence on a sample decays by
    ~3.7 times a sample); a mistake deep in the file is still named by its line."""
    from cosim.paper.trajectory_file import read_trajectory

    t = np.arange(0.0, 4.0, 0.002)  # 2000 samples: the blocks NumPy parses at once
    body = [f"{x:.3f},{np.sin(3 * x):.9f},{np.cos(2 * x):.9f}" for x in t]
    whole = write_csv(tmp_path / "whole.csv", body)
    cut = write_csv(tmp_path / "cut.csv", [*body, "abc,not,read"])
    read = read_trajectory(cut, 2, until=1.0)
    assert read.end == pytest.approx(1.0 + 65 * 0.002)
    assert read.source == f"cut.csv (its samples up to t = {read.end:g} s)"
    everything = read_trajectory(whole, 2)
    inside = np.linspace(0.0, 1.0, 5001)
    for got, want in zip(read.evaluate(inside), everything.evaluate(inside), strict=True):
        assert np.max(np.abs(got - want)) <= 1e-12 * max(1.0, np.max(np.abs(want)))
    with pytest.raises(PipelineError) as caught:
        read_trajectory(cut, 2)
    assert str(caught.value) == (f"reference.csv: {cut}, line 2002, column 1: 'abc' is not a "
                                 "number")
    bad = write_csv(tmp_path / "bad.csv", [*body[:1500], "2.5,0.1,0.1", *body[1500:]])
    with pytest.raises(PipelineError) as caught:
        read_trajectory(bad, 2)
    assert str(caught.value) == (f"reference.csv: {bad}, line 1502: time 2.5 s does not "
                                 "increase (line 1501: 2.998 s); times must increase strictly")


@pytest.mark.parametrize(("table", "message"), [
    ("times = [0.0, 1.0]\npositions = [[0, 0], [1e308, 0]]",
     "reference.waypoints: the segment from times[0] = 0 s to times[1] = 1 s (positions up to "
     "1e+308) makes q_d, q̇_d or q̈_d too large for double precision: give times and "
     "positions of a robot's scale"),
    ("times = [0.0, 1e308]\npositions = [[0, 0], [1, 0]]",
     "reference.waypoints: the segment from times[0] = 0 s to times[1] = 1e+308 s (positions "
     "up to 1) makes q_d, q̇_d or q̈_d too large for double precision: give times and "
     "positions of a robot's scale"),
    ("times = [0.0, 1.0]\npositions = [[true, false], [0, 0]]",
     "{path}: key 'reference.waypoints.positions.0.0': Input should be a valid number (got "
     "True)"),
    ('times = [0.0, 1.0]\npositions = [["0.1", "0"], [0, 0]]',
     "{path}: key 'reference.waypoints.positions.0.0': Input should be a valid number (got "
     "'0.1')"),
])
def test_waypoints_beyond_double_precision_or_not_numbers_are_refused(tmp_path, table,
                                                                      message):
    """SciPy's root-finding tracebacks; booleans and strings taken for numbers."""
    with pytest.raises(PipelineError) as caught:
        assembled_reference(tmp_path, f'limits = "report"\n[reference.waypoints]\n{table}')
    assert str(caught.value) == message.format(path=tmp_path / "user.toml")


def test_a_limit_left_because_the_reference_moves_the_centre_says_so(tmp_path):
    """A fast segment just after the run's end moves the velocity set's centre (the midpoint
    over 20 s): "q̇_d = 0 rad/s at t = 0 s, below its lower limit 155.25 rad/s" named a time
    where the trajectory is at rest without saying why; now the centres and their source."""
    path = tmp_path / "user.toml"
    path.write_text(f'extends = "{PD}"\n[simulation]\nduration = 1.0\n'
                    "[reference.waypoints]\ntimes = [0.0, 1.0, 1.1]\n"
                    "positions = [[0.0, 0.0], [0.0, 0.0], [10.0, 0.0]]\n")
    with pytest.raises(PipelineError) as caught:
        assemble_run(load_pipeline(path), "pd_full_state", _TwoLinkArm())
    assert str(caught.value) == (
        "run 'pd_full_state': reference.waypoints leaves joint 1's velocity: q̇_d = 0 rad/s at "
        "t = 0 s, below its lower limit 80.25 rad/s (the safe sets: |q − q_s| ≤ "
        "safety.position_bound = 20 rad, |q̇ − q̇_s| ≤ safety.velocity_bound = 13.5 rad/s; "
        "q_s = [5, 0] rad, q̇_s = [93.75, 0] rad/s, the midpoints of the reference over 0–20 s "
        "(reference.safe_horizon), beyond the run's end too; give reference.safe_centre and "
        "reference.safe_velocity_centre to fix them). Change the trajectory, or set "
        'reference.limits = "report" to run it anyway and have those sets reported unattainable')


def test_a_csv_trajectory_runs_relative_to_its_pipeline_and_the_loop_reads_it(tmp_path):
    """A CSV of t, q, q̇, q̈ sampled from the minimum-jerk waypoints every 10 ms, named
    relative to the pipeline file: the run's q_d, q̇_d, q̈_d rows equal the waypoints' own
    reference (the quintic through exact samples of a quintic is that quintic: 1e-9), in the
    fused loop that the PD runs use; and `cosim run` with a bad file ends with exit 2."""
    times = np.array([0.0, 1.0, 2.5])
    positions = np.array([[0.1, 0.1], [1.0, -0.5], [0.5, 0.5]])
    reference = minimum_jerk(times, positions, "test")
    t = np.round(np.arange(0.0, 3.0 + 1e-9, 0.01), 10)
    q, qd, qdd = reference.evaluate(t)
    rows = [",".join(f"{x:.17g}" for x in (ti, *a, *b, *c))
            for ti, a, b, c in zip(t, q, qd, qdd, strict=True)]
    (tmp_path / "data").mkdir()
    write_csv(tmp_path / "data" / "pick.csv", rows, "t,q1,q2,qd1,qd2,qdd1,qdd2")
    _, pipeline = waypoint_pipeline(tmp_path, 'csv = "data/pick.csv"')
    results = run(pipeline, tmp_path / "out", progress=False, record=False, figures=False,
                  engine="fused")
    trace = results["pd_full_state"].trace
    assert results["pd_full_state"].complete
    # the run folder's provenance: each file the pipeline names, by key, with its digest
    files = json.loads((tmp_path / "out" / "summary.json").read_text())["provenance"]["files"]
    assert [(e["key"], e["path"], e["sha256"]) for e in files] == [
        (key, str(path), hashlib.sha256(path.read_bytes()).hexdigest()) for key, path in sorted(
            [("reference.csv", tmp_path / "data" / "pick.csv"), ("extends", Path(PD)),
             ("the pipeline file", tmp_path / "user.toml")], key=lambda item: str(item[1]))]
    expected = reference.evaluate(trace.time)
    for key, want in zip(("q_d", "qdot_d", "qddot_d"), expected, strict=True):
        assert close(trace[key], want), key
    (tmp_path / "data" / "pick.csv").write_text("t,q1,q2\n0,0,0\n0,1,1\n")
    result = cosim_cli("run", str(tmp_path / "user.toml"), "--out", str(tmp_path / "bad"))
    assert "line 3: time 0 s does not increase" in error_line(result)


def test_the_papers_sinusoids_are_unchanged():
    """The paper's reference, q_d = [20 sin(0.5 t), 10 sin(t)] rad, from its pipeline's
    block: the same closed form at 1000 random times (its numbers are also pinned by
    tests/test_paper_scenario_results.py), and no limit check beyond the evaluation's."""
    plan = assemble_run(load_pipeline("pipelines/paper_two_link.toml"), "proposed",
                        _TwoLinkArm())
    block = plan.block("reference")
    t = np.random.default_rng(9).uniform(0, 20, 1000)
    q, qd, qdd = block.evaluate(t)
    assert close(q, np.column_stack([20 * np.sin(0.5 * t), 10 * np.sin(t)]))
    assert close(qd, np.column_stack([10 * np.cos(0.5 * t), 10 * np.cos(t)]))
    assert close(qdd, np.column_stack([-5 * np.sin(0.5 * t), -10 * np.sin(t)]))
    assert block.limits_left == [] and "trajectory" not in block.describe()
    assert math.isclose(block.centres()[0][0], 0.0, abs_tol=1e-6)
