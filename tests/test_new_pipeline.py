"""`cosim new --urdf` (cosim/paper/scaffold.py) and the ``[robot]`` table: the chain printed,
a pipeline written that names the robot once and loads as the plant, the nominal model and
the safe sets; its motion inside every limit; its gains stable at its 1 ms step on every
arm of example-robot-data we test (the sampled loop of each configuration the motion visits,
without building a plant); and one generated pipeline run for real, its three runs
finishing with every limit kept."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from cli_helpers import assert_message, cosim_cli, error_line
from urdf_helpers import ARMS, OWN_ROBOT, ROBOTS

from cosim.blocks.base import BlockContext
from cosim.cli import main
from cosim.config import load_pipeline
from cosim.dynamics.model import chain_model
from cosim.paper.controller import NnController
from cosim.paper.pd_controller import PdController
from cosim.paper.sampled_loop import cases, worst_case
from cosim.paper.scaffold import MAX_SWING, pipeline_text, plan
from plant_fmu.urdf import read_urdf

# Light and heavy, 2 to 7 joints (besides ARMS: UR5, UR10, Panda, Kinova, xArm7, Z1, SO-101)
MORE_ARMS = {"twodof": ROBOTS / "asr_twodof_description/urdf/TwoDofs.urdf",
             "finger": ROBOTS / "finger_edu_description/robots/finger_edu.urdf"}


@pytest.fixture(scope="module")
def own(tmp_path_factory):
    """`cosim new` on our own robot (prismatic, continuous, skew axis): what it printed and
    the pipeline file."""
    folder = tmp_path_factory.mktemp("new")
    out = folder / "turret.toml"
    result = cosim_cli("new", "--urdf", str(OWN_ROBOT), "--out", str(out))
    assert result.returncode == 0, result.stderr
    return result.stdout, out


def test_new_prints_the_chain_and_names_the_robot_once(own):
    printed, out = own
    chain = read_urdf(OWN_ROBOT)
    assert printed.splitlines()[0] == (f"slider_turret: 4 moving joints from link 'world' to "
                                       f"'{chain.tip_link}' (SI units, radians)")
    rows = {line.split()[0]: line.split()[1] for line in printed.splitlines()[2:6]}
    assert rows == {"lift": "prismatic", "turret": "continuous", "shoulder": "revolute",
                    "wrist": "revolute"}
    assert f"wrote {out}: run it with" in printed
    text = out.read_text()
    assert text.count(".urdf") == 1  # the URDF named once, in [robot]
    pipeline = load_pipeline(out)
    urdf = str(OWN_ROBOT.resolve())
    assert pipeline.robot.file == urdf and pipeline.plant.urdf.file == urdf
    assert pipeline.plant.urdf.tip == chain.tip_link == pipeline.inertia_model.tip
    assert pipeline.inertia_model.urdf == urdf and pipeline.safety.urdf == urdf
    assert pipeline.safety.limits == "urdf" and pipeline.safety.urdf_tip == chain.tip_link
    # the continuous turret gets ±π about its start (the safe sets need finite limits)
    start = pipeline.plant.parameters["q0[2]"]
    assert pipeline.safety.position_lower[1] == pytest.approx(start - math.pi, abs=1e-3)
    assert pipeline.safety.position_upper[1] == pytest.approx(start + math.pi, abs=1e-3)


def test_new_refuses_to_replace_a_file_and_a_name_that_is_not_toml(own, tmp_path):
    _, out = own
    before = out.read_text()
    assert_message(error_line(cosim_cli("new", "--urdf", str(OWN_ROBOT), "--out", str(out))),
                   f"--out {out}: a file is already there; give --force to replace it, or "
                   "another --out; nothing was written")
    assert out.read_text() == before
    assert_message(error_line(cosim_cli("new", "--urdf", str(OWN_ROBOT), "--out",
                                        str(tmp_path / "arm.yaml"))),
                   f"--out {tmp_path / 'arm.yaml'}: a pipeline file's name ends in .toml (e.g. "
                   f"{tmp_path / 'arm.toml'}); nothing was written")
    assert not (tmp_path / "arm.yaml").exists()


@pytest.mark.parametrize("arm", [*sorted(ARMS), *sorted(MORE_ARMS)])
def test_the_generated_motion_and_gains_fit_every_arm_at_1_khz(arm, tmp_path):
    """The start and every waypoint within each joint's position set less its margin, the
    motion's peak speed within half its velocity limit, and the generated controller's and
    PD's gains (their own linear_gains, as the blocks build them from the file) stable at
    its 1 ms step at every configuration the motion passes and both ends of the payload
    range: the check `cosim run` makes, here without building the plant."""
    path = ARMS.get(arm) or MORE_ARMS[arm]
    chain = read_urdf(path)
    p = plan(chain)
    for row in (p.start, p.start + p.swing, p.start - p.swing):
        assert np.all(row >= p.lower + 0.05 - 1e-12) and np.all(row <= p.upper - 0.05 + 1e-12)
    assert np.all(p.swing <= MAX_SWING) and np.all(p.swing > 0.0)
    assert np.all(1.875 * 2 * p.swing / 2.0 <= 0.5 * p.velocity + 1e-12)
    (tmp_path / "arm.toml").write_text(pipeline_text(chain, str(path), "arm"))
    pipeline = load_pipeline(tmp_path / "arm.toml")
    assert pipeline.simulation.step == 1e-3
    context = BlockContext(chain.n, 1e-3, "proposed", frozenset({"q", "qdot"}),
                           pipeline.safety, pipeline.uncertainty)
    positions = [p.start + s * p.swing for s in np.linspace(-1.0, 1.0, 9)]
    loop = cases(chain_model(chain), positions, pipeline.uncertainty.payload, True)
    run = pipeline.runs["proposed_cbf"]
    for block in (NnController(run.controller, context),
                  PdController(pipeline.runs["pd"].pd_controller, context)):
        gains = block.linear_gains()
        assert gains.inertia_scaled
        assert worst_case(loop, gains, 1e-3).radius < 1.0, block.kind


def test_a_generated_pipeline_runs_as_written(own, tmp_path):
    """The generated pipeline of our own robot, shortened: its three runs finish, every
    joint's limits kept, the filtered run covered by its guarantee."""
    _, out = own
    folder = tmp_path / "run"
    result = cosim_cli("run", str(out), "--out", str(folder), "--no-figures", "--no-recording",
                       "--set", "simulation.duration=1.0")
    assert result.returncode == 0, result.stderr
    runs = json.loads((folder / "summary.json").read_text())["runs"]
    assert set(runs) == {"proposed", "proposed_cbf", "pd"}
    for name, summary in runs.items():
        assert summary["complete"], name
        hard = {c: e for c, e in summary["safety"].items() if e.get("kind") == "hard"}
        assert hard and all(e["satisfied"] for e in hard.values()), (name, hard)
    assert runs["proposed_cbf"]["metrics"]["guarantee"]["covered"] is True
    assert "limits kept (every joint's position, velocity, effort)" in result.stdout


def test_the_robot_table_fills_only_what_the_pipeline_leaves_unset(tmp_path):
    """An explicit plant, nominal model or safe-set source wins over [robot]."""
    urdf = str(OWN_ROBOT.resolve())
    (tmp_path / "p.toml").write_text(
        f'robot = "{urdf}"\n[safety]\nlimits = "radii"\n[inertia_model]\nurdf = "{urdf}"\n'
        'tip = "tool0"\n')
    pipeline = load_pipeline(tmp_path / "p.toml")
    assert pipeline.plant.urdf.file == urdf and pipeline.safety.limits == "radii"
    assert pipeline.safety.urdf is None and pipeline.inertia_model.tip == "tool0"
    assert main(["params", str(tmp_path / "p.toml"), "--grep", "robot.file"]) == 0
