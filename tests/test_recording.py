"""The Rerun recording: written from the paper's runs, read back with rerun-sdk's own reader,
checked against the trace and summary.json, and rendered in the real viewer (headless)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from cli_helpers import LOW_GAIN_LAGGED, PAPER, cosim_cli, table_gains
from rerun.chunk import RrdReader

from cosim.assemble import assemble_run, safe_set
from cosim.config import load_pipeline
from cosim.engine import Diverged
from cosim.outputs.recording.layout import (
    BOUND_COLOR,
    JOINT_COLORS,
    VIOLATION_COLOR,
    derived_entities,
)
from cosim.outputs.viewer import (
    ViewerError,
    headless_renderer_available,
    headless_viewer,
    screenshot,
    viewer_binary,
    wait_for_recording,
)
from cosim.paper.theorem import BARRIERS, barriers

STEPS = 20_000  # the paper's 20 s at 1 kHz
RUNS = ("baseline", "proposed")
from cosim.runner import run  # noqa: E402


class _TwoLinkArm:  # what assembly needs to know of the paper's plant
    links, mapped = 2, frozenset({"q", "qdot", "M"})


# Recording entity -> (trace signal, series stem), derived from the blocks' declarations.
_PROPOSED = assemble_run(load_pipeline(PAPER), "proposed", _TwoLinkArm())
TRACE_ENTITIES = _PROPOSED.entities()
# The observer's errors, recorded beside its estimates (x̃1 = q − x̂1, x̃2 = q̇ − x̂2).
DERIVED_ENTITIES = derived_entities(_PROPOSED.signals, set(_PROPOSED.signals))
assert DERIVED_ENTITIES == {"observer/q_err": ("q", "q_hat", "q_err"),
                            "observer/qdot_err": ("qdot", "qdot_hat", "qdot_err")}


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    """The paper pipeline, run once into a run folder: (folder, results, summary.json)."""
    out = tmp_path_factory.mktemp("paper")
    results = run(load_pipeline(PAPER), out, progress=False)
    summary = json.loads((out / "summary.json").read_text())
    return out, results, summary


def read_store(path):
    return RrdReader(path).stream().collect()


@pytest.fixture(scope="module")
def store(paper):
    return read_store(paper[0] / "recording.rrd")


@pytest.fixture(scope="module")
def tables(store):
    """One table per run on the sim_time index (one query per run is much faster than one
    per entity)."""
    return {name: store.reader("sim_time", contents=f"/{name}/**").to_arrow_table()
            for name in RUNS}


def scalars(table, entity: str) -> np.ndarray:
    """The entity's Scalars as (rows, width), rows where it has no value dropped."""
    column = table.column(f"{entity}:Scalars:scalars")
    values = [v for v in column.to_pylist() if v is not None]
    return np.array(values, dtype=float)


def times(table, entity: str) -> np.ndarray:
    """sim_time (s) of the entity's rows; none if it never got a value."""
    if f"{entity}:Scalars:scalars" not in table.column_names:
        return np.zeros(0)
    column = table.column(f"{entity}:Scalars:scalars").to_pylist()
    ns = np.array(table.column("sim_time").cast("int64").to_pylist())
    return ns[[v is not None for v in column]] / 1e9


def properties(store) -> dict:
    table = store.reader(None, contents="/__properties/**").to_arrow_table()
    out = {}
    for name in table.column_names:
        if name.startswith("property:"):
            value = table.column(name).to_pylist()[0]
            out[name.removeprefix("property:")] = value[0] if isinstance(value, list) else value
    return out


def per_step_entities(checks) -> list[str]:
    families = dict.fromkeys(e["family"] for e in checks.values())
    return ([*TRACE_ENTITIES, *DERIVED_ENTITIES]
            + [f"safety/{f}/value" for f in families] + [f"barrier/{b}" for b in BARRIERS])


def check_column(checks: dict, check: str) -> tuple[str, int]:
    """A check's family entity and its series there (the family's checks in order)."""
    family = checks[check]["family"]
    return family, [c for c, e in checks.items() if e["family"] == family].index(check)


def test_every_entity_exists_with_one_row_per_step(paper, store, tables):
    _, _, summary = paper
    paths = set(store.schema().entity_paths())
    for name in RUNS:
        checks = summary["runs"][name]["safety"]
        for entity in per_step_entities(checks):
            values = scalars(tables[name], f"/{name}/{entity}")
            assert len(values) == STEPS + 1, entity
            assert np.all(np.isfinite(values)), entity
        for check in checks:
            family, _ = check_column(checks, check)
            for side in ("upper", "lower", f"violation/{check}"):
                assert f"/{name}/safety/{family}/{side}" in paths
        for part in ("links", "joints", "desired"):
            assert f"/{name}/arm/{part}" in paths
    t = times(tables["proposed"], "/proposed/plant/q")
    np.testing.assert_allclose(t, np.arange(STEPS + 1) * 1e-3, atol=1e-9)


def test_values_equal_the_trace(paper, tables):
    _, results, _ = paper
    for name in RUNS:
        trace = results[name].trace
        for entity, (signal_name, _) in TRACE_ENTITIES.items():
            recorded = scalars(tables[name], f"/{name}/{entity}")
            expected = trace[signal_name].reshape(len(recorded), -1)
            assert np.array_equal(recorded, expected), entity
        for entity, (true, estimate, _) in DERIVED_ENTITIES.items():
            recorded = scalars(tables[name], f"/{name}/{entity}")
            assert np.array_equal(recorded, trace[true] - trace[estimate]), entity
        pipeline = load_pipeline(PAPER)
        expected = barriers(trace, safe_set(pipeline), table_gains(pipeline.runs[name]))
        for b in BARRIERS:
            recorded = scalars(tables[name], f"/{name}/barrier/{b}")[:, 0]
            np.testing.assert_allclose(recorded, expected[b], rtol=1e-12)


def test_safety_entities_match_summary(paper, tables):
    """Worst |value| equals summary.json's worst; bounds are the summary's; a marker is at
    the start of every excursion and only outside the bound."""
    _, results, summary = paper
    for name in RUNS:
        table = tables[name]
        checks = summary["runs"][name]["safety"]
        for check, entry in checks.items():
            family, column = check_column(checks, check)
            base = f"/{name}/safety/{family}"
            value = scalars(table, f"{base}/value")[:, column]
            assert np.max(np.abs(value)) == pytest.approx(entry["worst"], rel=1e-12), check
            upper = scalars(table, f"{base}/upper")[:, column]
            lower = scalars(table, f"{base}/lower")[:, column]
            assert np.all(upper == entry["bound"])
            assert np.all(lower == (-entry["bound"] if "_joint" in check else 0.0))
            outside = (value > upper[0]) | (value < lower[0])
            marks = np.round(times(table, f"{base}/violation/{check}") * 1000).astype(int)
            assert np.all(outside[marks]), check
            starts = np.flatnonzero(outside & ~np.concatenate(([False], outside[:-1])))
            assert set(starts) <= set(marks), check
            assert (len(marks) == 0) == entry["satisfied"], check
    # The paper's claim as recorded: the recording's max |q̇1| for the baseline is the
    # summary's worst true velocity (q̇_s1, the sampled midpoint of q̇_d1, is 0 to ~1e-8).
    qdot1 = scalars(tables["baseline"], "/baseline/plant/qdot")[:, 0]
    assert np.max(np.abs(qdot1)) == pytest.approx(summary["runs"]["baseline"]["safety"][
        "velocity_true_joint1"]["worst"], rel=1e-8)
    assert np.max(np.abs(qdot1)) > 13.5


def test_arm_is_drawn_from_forward_kinematics(paper, tables):
    """Joint positions at 50 Hz against the two-link closed form (y negated: Rerun's 2D
    views are y-down)."""
    _, results, _ = paper
    q = results["proposed"].trace["q"]
    column = tables["proposed"].column("/proposed/arm/joints:Points2D:positions").to_pylist()
    rows = [(k, v) for k, v in enumerate(column) if v is not None]
    assert [k for k, _ in rows] == list(range(0, STEPS + 1, 20))
    for k, points in rows[::97]:
        q1, q2 = q[k]
        expected = [[0, 0], [np.cos(q1), -np.sin(q1)],
                    [np.cos(q1) + np.cos(q1 + q2), -np.sin(q1) - np.sin(q1 + q2)]]
        np.testing.assert_allclose(points, expected, atol=1e-5)  # stored as float32


def test_properties_blueprint_and_verification(paper, store):
    out, results, summary = paper
    props = properties(store)
    assert json.loads(props["pipeline:resolved"]) == summary["pipeline"]
    assert props["plant:model_name"] == "PlanarArm2"
    assert props["plant:instantiation_token"] == summary["plant"]["guid"]
    assert props["plant:fmi_version"] == "2.0"
    assert json.loads(props["plant:parameters"])["m[2]"] == 2.3
    assert props["versions:rerun-sdk"] == rr.__version__
    for name in RUNS:
        assert json.loads(props[f"run_{name}:metrics"])["peak_torque"] == \
            summary["runs"][name]["metrics"]["peak_torque"]
        assert props[f"run_{name}:complete"] is True
    assert props["status:complete"] is True
    assert props["RecordingInfo:name"].startswith("paper_two_link: baseline vs proposed")
    assert RrdReader(out / "recording.rrd").blueprints(), "no blueprint stored"
    verify = subprocess.run([str(viewer_binary()), "rrd", "verify",
                             str(out / "recording.rrd")], capture_output=True, text=True,
                            env={"RERUN_ANALYTICS": "0", "PATH": "/usr/bin:/bin"})
    assert verify.returncode == 0, verify.stderr[-2000:]


def test_recording_size_budget(paper):
    """Budget: the paper's two runs, 20 s at 1 kHz, in at most 40 MB."""
    assert (paper[0] / "recording.rrd").stat().st_size <= 40e6


def test_figures_are_written(paper):
    import matplotlib.image

    for name in ("fig2_position_velocity.png", "fig3_errors.png", "fig4_torques.png"):
        image = matplotlib.image.imread(paper[0] / name)
        assert image.shape[0] > 300 and image.shape[1] > 800
        assert image[..., :3].std() > 0.05, f"{name} looks blank"


def test_a_filtered_runs_torque_before_the_filter_is_found_from_the_wiring():
    """fig4 draws what a filter was asked for beside what it applied: the torque key the
    last block changing 'tau' read, from the chain's wiring (none for an unfiltered run)."""
    safety = load_pipeline("pipelines/paper_safety.toml")
    filtered = assemble_run(safety, "proposed_cbf", _TwoLinkArm())
    assert filtered.torque_before_filter() == ("tau_controller", "cbf_filter")
    assert filtered.plant_input == "tau" and "tau_controller" in filtered.signals
    assert assemble_run(safety, "proposed", _TwoLinkArm()).torque_before_filter() is None


def test_the_layout_puts_two_runs_side_by_side_and_gives_more_a_tab_each():
    import rerun.blueprint as rrb

    from cosim.outputs.recording.layout import blueprint

    pair = blueprint(["baseline", "proposed"]).root_container
    assert isinstance(pair, rrb.Horizontal)
    assert [c.name for c in pair.contents] == ["baseline", "proposed"]
    five = ["baseline", "proposed", "baseline_matched", "proposed_cbf", "baseline_cbf"]
    safety = load_pipeline("pipelines/paper_safety.toml")
    views = {run: assemble_run(safety, run, _TwoLinkArm()).views() for run in five}
    assert views["proposed_cbf"] == [("cbf_filter/h", "CBF barrier values β − |x| (≥ 0 inside)"),
                                     ("cbf_filter/correction", "‖τ − τ_nom‖ (N·m)")]
    assert views["proposed"] == [] and views["baseline_cbf"] == views["proposed_cbf"]
    pd = assemble_run(load_pipeline("pipelines/pd_control.toml"), "pd_full_state",
                      _TwoLinkArm())
    assert derived_entities(pd.signals, set(pd.signals)) == {}  # no observer: no error view
    assert len(blueprint(["pd"]).root_container.contents[0].contents[-1].contents) == 3
    assert len(blueprint(["proposed"], None, {"proposed": [("observer/qdot_err", "x̃2")]})
               .root_container.contents[0].contents[-1].contents) == 4
    tabs = blueprint(five, views).root_container
    assert isinstance(tabs, rrb.Tabs) and [c.name for c in tabs.contents] == five
    # a filtered run's tab adds the filter's row (barrier values, correction)
    assert len(tabs.contents[3].contents) == len(tabs.contents[0].contents) + 1


def test_the_figures_zoom_is_the_second_around_the_worst_value_of_any_run():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cosim.evaluate import Check
    from cosim.outputs.figures import _zoom

    t = np.arange(0, 10.001, 0.001)
    near = Check(value=19.5 * np.sin(t), upper=20.0, lower=-20.0)
    # the worst value of any run: a dip to -21 at t = 3π/2, outside the lower bound
    dip = 3 * np.pi / 2
    out = Check(value=18 * np.sin(t) - 3.0 * np.exp(-((t - dip) / 0.05) ** 2), upper=20.0,
                lower=-20.0)
    k = int(np.argmax(np.abs(out.value)))
    assert abs(t[k] - dip) < 1e-3 and out.value[k] == pytest.approx(-21.0, abs=1e-3)
    fig, ax = plt.subplots()
    _zoom(ax, {"near": t, "out": t}, {"near": near, "out": out})
    assert ax.get_xlim() == pytest.approx((t[k] - 1.0, t[k] + 1.0))
    window = np.abs(t - t[k]) <= 1.0
    values = np.concatenate([near.value[window], out.value[window]])
    low, high = min(values.min(), -20.0), max(values.max(), -20.0)
    pad = 0.08 * (high - low)
    assert ax.get_ylim() == pytest.approx((low - pad, high + pad))
    assert ax.get_title() == (f"zoom: ±1 s around the worst value (out, {out.value[k]:.4g} at "
                              f"t = {t[k]:.3g} s; bound -20)")
    plt.close(fig)


def test_diverged_run_leaves_a_readable_recording_marked_incomplete(tmp_path):
    pipeline = load_pipeline(PAPER, [o for o in LOW_GAIN_LAGGED if o != "--set"])
    with pytest.raises(Diverged):
        run(pipeline, tmp_path, progress=False, figures=False)
    summary = json.loads((tmp_path / "summary.json").read_text())
    done = summary["runs"]["baseline"]["metrics"]["simulated_time_s"]
    store = read_store(tmp_path / "recording.rrd")
    props = properties(store)
    assert props["status:complete"] is False
    assert "diverged in the observer block" in props["status:reason"]
    assert props["RecordingInfo:name"].endswith("(incomplete)")
    table = store.reader("sim_time", contents="/baseline/**").to_arrow_table()
    q = scalars(table, "/baseline/plant/q")
    assert len(q) == round(done * 1000) + 1
    trace = np.load(tmp_path / "trace_baseline.npz")
    assert np.array_equal(q, trace["q"])


def test_interrupted_run_leaves_a_readable_recording_marked_incomplete(tmp_path):
    """Ctrl-C (SIGINT) a real `cosim run` part-way through: what was computed is recorded."""
    out = tmp_path / "run"
    process = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "run", PAPER, "--out", str(out), "--no-figures",
         "--set", "simulation.duration=200"], stderr=subprocess.PIPE, text=True)
    # Progress lines: interrupt at once when the loop is under way. No pause before the
    # signal: the compiled loop simulates these 350 s in about a second.
    for line in process.stderr:
        if "baseline: 25 %" in line:
            break
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 2
    # the reason itself (the run folder's path holds "interrupted" too)
    assert f"cosim: error: interrupted (Ctrl-C); what was computed is kept in {out}" in err
    assert "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False
    done = summary["runs"]["baseline"]["metrics"]["simulated_time_s"]
    assert 50 <= done < 200
    store = read_store(out / "recording.rrd")
    props = properties(store)
    assert props["status:complete"] is False
    table = store.reader("sim_time", contents="/baseline/plant/q").to_arrow_table()
    assert len(scalars(table, "/baseline/plant/q")) == round(done * 1000) + 1


def _renderer_or_skip():
    reason = headless_renderer_available()
    if reason:
        pytest.skip(f"cannot render headless here: {reason}")


def colour_pixels(image: np.ndarray, rgb, tolerance: int = 40) -> int:
    return int(np.sum(np.all(np.abs(image[..., :3].astype(int) - rgb) < tolerance, axis=-1)))


def test_recording_renders_in_the_real_viewer(paper, tmp_path):
    """The stored blueprint opens with its plots drawn: the bounds (green), joint-1 series
    (blue) and the baseline's violation markers (red) are all on screen."""
    _renderer_or_skip()
    import matplotlib.image

    png = screenshot(paper[0] / "recording.rrd", tmp_path / "viewer.png")
    image = (matplotlib.image.imread(png) * 255).astype(np.uint8)
    assert image.shape[:2] == (1000, 1600)
    assert colour_pixels(image, BOUND_COLOR) > 2000
    assert colour_pixels(image, JOINT_COLORS[0]) > 2000
    assert colour_pixels(image, VIOLATION_COLOR) > 100


def _running(pid: str) -> bool:
    """Whether process ``pid`` still runs (a zombie's command line is empty)."""
    try:
        return bool((Path("/proc") / pid / "cmdline").read_bytes())
    except OSError:
        return False


def test_a_viewer_that_dies_while_rendering_is_one_message_and_no_png(paper, tmp_path,
                                                                      monkeypatch):
    """The real viewer, killed once it shows the recording: its client's ConnectionError
    becomes one message naming what happened, and no screenshot is left behind."""
    _renderer_or_skip()
    import cosim.outputs.viewer as viewer

    shown = viewer.wait_for_recording

    def shown_then_killed(client, timeout: float = 60.0) -> None:
        shown(client, timeout)
        for pid in (p.name for p in Path("/proc").iterdir() if p.name.isdigit()):
            try:
                command = (Path("/proc") / pid / "cmdline").read_bytes().split(b"\0")
                parent = (Path("/proc") / pid / "stat").read_text().rsplit(")", 1)[1].split()[1]
            except OSError:
                continue
            if int(parent) == os.getpid() and b"--headless" in command:
                os.kill(int(pid), signal.SIGKILL)
                while _running(pid):
                    time.sleep(0.05)

    monkeypatch.setattr(viewer, "wait_for_recording", shown_then_killed)
    png = tmp_path / "viewer.png"
    with pytest.raises(ViewerError) as error:
        screenshot(paper[0] / "recording.rrd", png)
    assert str(error.value).startswith("the viewer stopped answering while rendering (")
    assert str(error.value).endswith("); nothing was saved"), error.value
    assert not png.exists()


def test_live_viewer_follows_a_run(tmp_path):
    """`--connect URL`: a viewer already running receives the recording while it is written,
    with the same layout; the file is written too."""
    _renderer_or_skip()
    try:
        with headless_viewer() as (client, url):
            result = cosim_cli("run", PAPER, "--out", str(tmp_path), "--no-figures",
                               "--connect", url, "--set", "simulation.duration=2")
            assert result.returncode == 0, result.stderr
            wait_for_recording(client)
            state = client.get_state()
            assert state.active_recording
    except ViewerError as exc:
        pytest.fail(str(exc))
    store = read_store(tmp_path / "recording.rrd")
    table = store.reader("sim_time", contents="/proposed/plant/q").to_arrow_table()
    assert len(scalars(table, "/proposed/plant/q")) == 2001


def test_view_without_display_says_how(tmp_path, paper):
    env_free = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "view", str(paper[0])], capture_output=True,
        text=True, env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)})
    assert env_free.returncode == 2
    assert "no display" in env_free.stderr and "--serve-web" in env_free.stderr
    missing = cosim_cli("view", str(tmp_path))
    assert missing.returncode == 2 and "has no recording.rrd" in missing.stderr


def test_spawn_without_display_is_refused_before_running(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "run", PAPER, "--out", str(tmp_path), "--spawn"],
        capture_output=True, text=True, env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)})
    assert result.returncode == 2
    assert "--spawn needs a display" in result.stderr and "nothing was run" in result.stderr
    assert "Traceback" not in result.stderr
