"""A check is declared once (cosim/evaluate/checks.py) and every reader follows: the run table
and summary.md, summary.json, the trace file's units, the recording, `cosim compare` and the
sweep. "Safe" is one function of the declarations, and every joint is checked: a 3-link run
whose third joint alone leaves its sets is UNSAFE everywhere. Real runs through the CLI."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from cli_helpers import cosim_cli

from cosim.evaluate import Declaration, Kind, is_safe, kept, left_sets
from cosim.outputs.table import verdict
from cosim.schema import PipelineError

# A user's evaluator, in a plugin file: one declaration, a torque check in N·m.
TORQUE_CHECK = textwrap.dedent('''
    from cosim.evaluate import Declaration, Kind, Part, register_evaluator

    TORQUE = Declaration("torque_limit", "joint torque τ", "N·m", Kind.SOFT)


    @register_evaluator
    class TorqueLimit(Part):
        name = "torque_limit"
        meaning = "|τ| within 400 N·m"
        inputs = ("tau",)
        declarations = (TORQUE,)

        def checks(self, rows):
            return TORQUE.joints_and_norm(rows["tau"], 400.0)
''')


@pytest.fixture(scope="module")
def declared_check(tmp_path_factory) -> Path:
    """The paper's proposed run for 1 s with the plugin's torque check, in ``a``."""
    root = tmp_path_factory.mktemp("declared")
    (root / "torque_check.py").write_text(TORQUE_CHECK)
    (root / "p.toml").write_text(f'extends = "{Path("pipelines/paper_two_link.toml").resolve()}"\n'
                                 'plugins = ["torque_check.py"]\n')
    result = cosim_cli("run", str(root / "p.toml"), "--out", str(root / "a"), "--run",
                       "proposed", "--set", "simulation.duration=1", "--no-figures")
    assert result.returncode == 0, result.stderr[-2000:]
    return root


def test_a_check_declared_once_appears_in_every_output(declared_check):
    run = declared_check / "a"
    summary = json.loads((run / "summary.json").read_text())
    entries = summary["runs"]["proposed"]["safety"]
    assert {n for n in entries if n.startswith("torque_limit")} == {
        "torque_limit_joint1", "torque_limit_joint2", "torque_limit_norm"}
    entry = entries["torque_limit_joint2"]
    assert (entry["unit"], entry["kind"], entry["joint"], entry["family"],
            entry["quantity"], entry["bound"]) == ("N·m", "soft", 2, "torque_limit",
                                                   "joint torque τ", 400.0)
    tau = np.load(run / "trace_proposed.npz")["tau"]
    assert entry["worst"] == pytest.approx(np.max(np.abs(tau[:, 1])), rel=1e-12)
    # the table and summary.md: the check with its unit, in the verdict
    table = (run / "summary.md").read_text()
    assert "| torque_limit_joint2 ≤ 400 N·m |" in table
    if not entries["torque_limit_joint1"]["satisfied"]:
        assert "torque_limit" in verdict(summary["runs"]["proposed"])
    # the trace file's units
    units = json.loads(str(np.load(run / "trace_proposed.npz")["_units"]))
    assert units["check_torque_limit_norm"]["unit"] == "N·m"
    assert units["check_torque_limit_norm"]["description"].startswith(
        "joint torque τ, norm (N·m)")
    # the recording: the family is one entity, a series per joint and the norm
    from rerun.chunk import RrdReader

    store = RrdReader(run / "recording.rrd").stream().collect()
    paths = set(store.schema().entity_paths())
    for side in ("value", "upper", "lower"):
        assert f"/proposed/safety/torque_limit/{side}" in paths
    table = store.reader("sim_time", contents="/proposed/safety/torque_limit/value"
                         ).to_arrow_table()
    values = np.array([v for v in table.column(
        "/proposed/safety/torque_limit/value:Scalars:scalars").to_pylist() if v is not None])
    np.testing.assert_array_equal(values[:, :2], tau)
    # compare: the check, its unit, both folders' values
    compared = cosim_cli("compare", str(run), str(run))
    assert compared.returncode == 0, compared.stderr
    assert any(line.split()[:2] == ["torque_limit_joint2", "(N·m)"]
               for line in compared.stdout.splitlines())
    # the sweep: the check's columns in every row, its family a column of the rate table
    out = declared_check / "sweep"
    done = cosim_cli("sweep", str(declared_check / "p.toml"), "--runs", "proposed", "--grid",
                     "controller.kv=20", "--set", "simulation.duration=0.2", "--out", str(out),
                     "--workers", "1", "--quiet")
    assert done.returncode == 0, done.stderr[-2000:]
    row = pq.read_table(out / "results.parquet").to_pylist()[0]
    assert (row["torque_limit_joint2.unit"], row["torque_limit_joint2.kind"],
            row["torque_limit_joint2.bound"]) == ("N·m", "soft", 400.0)
    table = json.loads((out / "sweep.json").read_text())["safety"][0]
    assert table["torque_limit"][0] == float(row["torque_limit_joint1.satisfied"]
                                             and row["torque_limit_joint2.satisfied"]
                                             and row["torque_limit_norm.satisfied"])


def test_an_evaluator_check_must_come_from_its_declarations():
    """A Part that makes a check from a declaration it does not list is refused, naming it."""
    from cosim.evaluate import Evaluator, Part, SafeSet
    from cosim.evaluate.parts import EVALUATORS
    from cosim.signals import Signal, Trace

    undeclared = Declaration("stray", "a stray value", "rad", Kind.SOFT)

    class Stray(Part):
        name = "stray"
        meaning = "a check not in its declarations"
        inputs = ("q",)

        def checks(self, rows):
            return {"stray_norm": undeclared.norm(np.abs(rows["q"][:, 0]), 1.0)}

    EVALUATORS["stray"] = Stray
    try:
        trace = Trace({"q": Signal("n", "rad", "q")}, 2, 3, 0.001)
        trace.rows_done = 2
        with pytest.raises(PipelineError, match="evaluator 'stray': check 'stray_norm' is not "
                                                "made by one of its declarations"):
            Evaluator(trace, SafeSet(), {}).update(2)
    finally:
        del EVALUATORS["stray"]


def test_a_plugin_cannot_replace_a_built_in_check():
    """An evaluator declaring a family another one declares (a plugin's "error" with zeros
    for values) is refused naming both, not merged over the built-in check."""
    from cosim.evaluate import Evaluator, Part, SafeSet
    from cosim.evaluate.parts import EVALUATORS
    from cosim.signals import Signal, Trace

    class Shadow(Part):
        name = "shadow"
        meaning = "declares the built-in error family again"
        inputs = ("q",)
        declarations = (Declaration("error", "nothing", "N·m", Kind.SUFFICIENT),)

    class Again(Shadow):
        name = "again"

    EVALUATORS.update(shadow=Shadow, again=Again)
    try:
        trace = Trace({"q": Signal("n", "rad", "q")}, 2, 3, 0.001)
        with pytest.raises(PipelineError, match="evaluators 'shadow' and 'again' both declare "
                                                "'error'"):
            Evaluator(trace, SafeSet(), {})
    finally:
        del EVALUATORS["shadow"], EVALUATORS["again"]


def test_safe_is_one_function_of_the_declarations():
    """Hard and soft sets count, unattainable sets and sufficient conditions do not; the
    guarantee's hard sets are every joint's, attainable or not."""
    def entry(kind, satisfied, attainable=None, t=0.0):
        out = {"kind": kind, "worst": 1.0, "satisfied": satisfied, "first_violation_s": t}
        if attainable is not None:
            out["attainable"] = attainable
        return out

    kept_all = {"position_joint3": entry("hard", True), "r_norm": entry("sufficient", False)}
    assert is_safe(kept_all) and kept(kept_all, [Kind.HARD])
    unattainable = {**kept_all, "position_joint2": entry("hard", False, attainable=False)}
    assert is_safe(unattainable) and not kept(unattainable, [Kind.HARD])
    soft = {**kept_all, "error_joint3": entry("soft", False, t=0.5),
            "velocity_joint2": entry("hard", False, t=0.2)}
    assert not is_safe(soft) and not kept(soft, [Kind.HARD])
    assert [name for name, _ in left_sets(soft)] == ["velocity_joint2", "error_joint3"]
    assert [name for name, _ in left_sets(soft, [Kind.SOFT])] == ["error_joint3"]


@pytest.fixture(scope="module")
def third_joint(tmp_path_factory) -> dict[str, Path]:
    """The 3-link proposed run for 1 s, started on the reference's position (joint 3 0.1 rad
    off, inside its 0.2 rad error set) and 0.3 rad off (outside it at t = 0)."""
    root = tmp_path_factory.mktemp("third_joint")
    out = {}
    for label, q3 in (("inside", 0.1), ("off", 0.3)):
        out[label] = root / label
        result = cosim_cli("run", "pipelines/three_link.toml", "--out", str(out[label]),
                           "--run", "proposed", "--set", "simulation.duration=1",
                           "--set", f'plant.parameters."q0[3]"={q3}')
        assert result.returncode == 0, result.stderr[-2000:]
        out[f"{label}_stdout"] = result.stdout
    return out


def test_a_three_link_run_whose_third_joint_leaves_its_set_is_unsafe_everywhere(third_joint):
    summary = json.loads((third_joint["off"] / "summary.json").read_text())["runs"]["proposed"]
    safety = summary["safety"]
    # joints 1 and 2 keep every set; joint 3 leaves its error set from the start
    for joint in (1, 2):
        assert all(e["satisfied"] for n, e in safety.items() if n.endswith(f"_joint{joint}"))
    assert safety["error_joint3"]["satisfied"] is False
    assert safety["error_joint3"]["first_violation_s"] == 0.0
    assert not is_safe(safety)
    line = verdict(summary)
    assert line.startswith("limits kept (every joint's position, velocity); tracking: left "
                           "error_joint3 at 0.00 s")
    lines = third_joint["off_stdout"].splitlines()
    first = next(i for i, s in enumerate(lines) if s.startswith("  proposed "))
    limits, tracking = line.split("; ", 1)  # printed on two lines: it is wider than 100
    assert lines[first:first + 2] == [f"  proposed  {limits};", f"            {tracking}"]
    assert "tracking: left error_joint3" in (third_joint["off"] / "summary.md").read_text()
    assert "error_joint3 ≤ 0.2 rad" in third_joint["off_stdout"]
    # the figures draw joint 3 (a row per joint): taller than a two-joint figure
    import matplotlib.image

    image = matplotlib.image.imread(third_joint["off"] / "fig3_errors.png")
    assert image.shape[0] > 1100
    # compare: the run that started on the reference held error_joint3, this one did not
    compared = cosim_cli("compare", str(third_joint["inside"]), str(third_joint["off"]))
    assert compared.returncode == 1
    assert "proposed/error_joint3: held in A" in compared.stdout
    # a sufficient condition is shown, never a regression, as in the verdict
    regressions = compared.stdout.split("regression(s):")[1]
    assert "filtered_error_norm" not in regressions
    assert not any("REGRESSED" in line for line in compared.stdout.splitlines()
                   if line.strip().startswith("filtered_error_norm"))


def test_compare_does_not_judge_plants_of_other_joint_counts(declared_check, third_joint):
    """Two joints against three: judged like with like before (only a note that the plants
    differ), and a check only B has was never counted; now named and not judged."""
    import re

    from cli_helpers import assert_message, error_line, here

    a, b = declared_check / "a", third_joint["inside"]
    assert_message(error_line(here("compare", str(a), str(b))), re.compile(
        rf"A {re.escape(str(a))} and B {re.escape(str(b))} do not compare like with like, so "
        r"no verdict: the plant has 2 joints in A, 3 in B \(a joint's checks compare only "
        r"with the same joint's, a norm only over the same joints\); .+; compare runs of the "
        r"same duration and bounds that both ran to their end"))


def test_the_sweep_judges_safe_as_the_run_does(third_joint, tmp_path):
    """The same two starts as a sweep: each row's safe column and per-check columns are the
    run's verdict and entries, and the table's rates follow (the third joint's error set
    kept in one of two points)."""
    out = tmp_path / "sweep"
    done = cosim_cli("sweep", "pipelines/three_link.toml", "--runs", "proposed", "--grid",
                     'plant.parameters."q0[3]"=0.1,0.3', "--set", "simulation.duration=1",
                     "--out", str(out), "--workers", "1", "--quiet")
    assert done.returncode == 0, done.stderr[-2000:]
    rows = {r['set:plant.parameters."q0[3]"']: r
            for r in pq.read_table(out / "results.parquet").to_pylist()}
    for q3, label in ((0.1, "inside"), (0.3, "off")):
        run = json.loads((third_joint[label] / "summary.json").read_text())["runs"]["proposed"]
        row = rows[q3]
        assert row["safe"] is is_safe(run["safety"])
        assert row["hard_sets_kept"] is kept(run["safety"], [Kind.HARD])
        for check, entry in run["safety"].items():
            assert row[f"{check}.satisfied"] is entry["satisfied"], check
            assert row[f"{check}.kind"] == entry["kind"], check
    assert rows[0.3]["safe"] is False
    table = json.loads((out / "sweep.json").read_text())["safety"][0]
    assert table["error"][0] == 0.5 and table["position"][0] == 1.0
    assert table["all sets"][0] == [r["safe"] for r in rows.values()].count(True) / 2
    tables = [line for line in done.stdout.splitlines() if str(out) not in line]
    assert max(len(line) for line in tables) <= 100  # paged by family


def test_an_entry_is_kept_exactly_when_no_row_is_outside_its_bounds():
    """One test of [lower, upper] for "satisfied", the excursions and the verdict, also for
    a one-sided set; rows without a value (NaN) are counted apart, not turned into NaN."""
    from cosim.evaluate import Check
    from cosim.evaluate.checks import safety_entries

    positive = Declaration("tau_positive", "torque τ ≥ 0", "N·m", Kind.SOFT)
    left = Check(np.array([1.0, np.nan, -0.5, 2.0]), 5.0, 0.0, None, positive, 1)
    entry = safety_entries({"tau_positive_joint1": left}, 0.5)["tau_positive_joint1"]
    assert (entry["satisfied"], entry["first_violation_s"], entry["time_outside_s"],
            entry["worst"], entry["rows_unknown"]) == (False, 1.0, 0.5, 2.0, 1)
    assert verdict({"safety": {"tau_positive_joint1": entry}}) == (
        "no limits (no hard set); tracking: left tau_positive_joint1 at 1.00 s (0.50 s out)")
    kept_ = Check(np.array([1.0, np.nan, 0.5]), 5.0, 0.0, None, positive, 1)
    entry = safety_entries({"c": kept_}, 0.5)["c"]
    assert entry["satisfied"] is True and entry["first_violation_s"] is None
