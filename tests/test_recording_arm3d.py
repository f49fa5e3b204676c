"""The arm in 3-D (cosim/outputs/recording/arm3d.py): a Panda, from example-robot-data's
URDF (a test extra, never copied into the repo), run as the URDF plant FMU (plant.urdf) by
`cosim run`'s own runner under a PD controller along two waypoint references, and the
recording read back with rerun-sdk's reader: its links' meshes are there, each moving joint
has one transform per drawn row, and composing the recorded transforms from the root link
to the hand gives the hand's pose that Pinocchio computes from the same URDF at the joint
angles of the run's trace. The two runs' arms stay apart (frames per run)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from cli_helpers import here
from rerun.chunk import RrdReader

from cosim.config import load_pipeline
from cosim.outputs.recording.layout import ARM_RATE_HZ, blueprint
from cosim.runner import run as run_pipeline
from plant_fmu.urdf import package_dirs, read_urdf

PANDA = package_dirs("example-robot-data")[0] / "robots/panda_description/urdf/panda.urdf"
DT, ROWS = 1e-3, 1001  # 1 s at 1 kHz
READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]  # rad, the Panda's "ready" pose
RUNS = {"out": 1.0, "back": -1.0}  # run -> the direction it moves every joint from READY
# Rerun stores transforms in single precision: ~1e-7 relative per joint, composed over the
# chain's ten joints (7 moving, 3 fixed) of a metre-sized arm.
POSITION_TOL = 1e-5  # m
ROTATION_TOL = 1e-5  # the rotation matrices' entries

PIPELINE = """
name = "panda_view"
[simulation]
duration = 1.0
[plant]
urdf = "{urdf}"
[plant.parameters]
{start}
[reference]
safe_centre = {zeros}
safe_velocity_centre = {zeros}
[inertia_model]
source = "fmu"
[pd_controller]   # without gravity compensation: the arm sags, which the view must show
kp = [200.0, 200.0, 200.0, 200.0, 50.0, 50.0, 50.0]
kd = [20.0, 20.0, 20.0, 20.0, 2.0, 2.0, 2.0]
gravity_compensation = false
velocity = "plant"
"""
RUN = """
[runs.{name}]
blocks = ["reference", "sensor", "inertia_model", "pd_controller"]
[runs.{name}.reference.waypoints]
times = [0.0, 1.0]
positions = [{ready}, {goal}]
"""


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """The two runs' recording, the Panda's chain, and each run's traces of q and q_d."""
    folder = tmp_path_factory.mktemp("arm3d")
    start = "\n".join(f'"q0[{i + 1}]" = {v}' for i, v in enumerate(READY))
    text = PIPELINE.format(urdf=PANDA, start=start, zeros=[0.0] * 7)
    for name, sign in RUNS.items():
        goal = [v + sign * 0.3 for v in READY]
        text += RUN.format(name=name, ready=READY, goal=goal)
    (folder / "panda.toml").write_text(text)
    results = run_pipeline(load_pipeline(folder / "panda.toml"), folder / "out",
                           progress=False, figures=False)
    assert all(result.complete for result in results.values())
    angles = {(name, kind): results[name].trace[key] for name in RUNS
              for kind, key in (("arm", "q"), ("desired", "q_d"))}
    return folder / "out" / "recording.rrd", read_urdf(PANDA), angles


def transforms(path) -> dict[str, dict]:
    """Per joint entity of /<run>/arm3d/ (the arm's and the desired pose's, and the desired
    pose's base): its parent and child frames, and its transforms (times or None if
    static, translations, xyzw quaternions)."""
    out = {}
    for chunk in RrdReader(path).stream():
        entity = str(chunk.entity_path)
        if "/arm3d/" not in entity or not ("/joints/" in entity or entity.endswith("/base")):
            continue
        batch = chunk.to_record_batch()
        column = {name.split(":")[-1]: batch.column(name).to_pylist()
                  for name in batch.schema.names}
        times = (np.array(batch.column("sim_time").cast("int64").to_pylist()) * 1e-9
                 if "sim_time" in batch.schema.names else None)
        out[entity] = {"parent": column["parent_frame"][0][0],
                       "child": column["child_frame"][0][0], "time": times,
                       "translation": np.array([row[0] for row in column["translation"]]),
                       "quaternion": np.array([row[0] for row in column["quaternion"]])}
    return out


def homogeneous(translation: np.ndarray, xyzw: np.ndarray) -> np.ndarray:
    x, y, z, w = xyzw
    pose = np.eye(4)
    pose[:3, :3] = pin.Quaternion(w, x, y, z).normalized().toRotationMatrix()
    pose[:3, 3] = translation
    return pose


def recorded_pose(joints: dict[str, dict], frames: str, link: str, row: int,
                  times: np.ndarray) -> np.ndarray:
    """The frame ``<frames>/<link>`` in the run's root link frame, composed from the
    recorded joint transforms at ``times[row]`` (the drawn rows' times)."""
    by_child = {j["child"]: j for j in joints.values()}
    pose, frame = np.eye(4), f"{frames}/{link}"
    while frame in by_child:
        joint = by_child[frame]
        k = 0 if joint["time"] is None else int(np.flatnonzero(
            np.isclose(joint["time"], times[row]))[0])
        pose = homogeneous(joint["translation"][k], joint["quaternion"][k]) @ pose
        frame = joint["parent"]
    assert frame == f"{frames.split('/')[0]}/panda_link0", frame  # the run's root link
    return pose


def test_the_recorded_joint_transforms_give_pinocchios_hand_pose(recorded):
    """At five drawn rows of each run, the hand's pose composed from the recording equals
    Pinocchio's forward kinematics of the same URDF at the trace's joint angles (fingers at
    0, as the plant holds them), for the arm (q) and for the desired pose (q_d, on the same
    base). Every moving joint has one transform per drawn row (50 Hz), at the drawn times."""
    path, chain, q = recorded
    joints = transforms(path)
    model = pin.buildModelFromUrdf(str(PANDA))
    data = model.createData()
    hand = model.getFrameId("panda_hand")
    stride = round(1 / (ARM_RATE_HZ * DT))
    drawn = np.arange(0, ROWS, stride) * DT
    for (run, kind), angles in q.items():
        frames = run if kind == "arm" else f"{run}/desired"
        entity = f"/{run}/arm3d" + ("" if kind == "arm" else "/desired")
        for name in chain.joints:
            times = joints[f"{entity}/joints/{name}"]["time"]
            np.testing.assert_allclose(times, drawn, atol=1e-9)
        for row in (0, 7, 20, 33, 50):  # drawn rows: 0.14 s apart, the last at 1 s
            full = pin.neutral(model)
            full[:chain.n] = angles[row * stride]  # Pinocchio's q: the arm's 7, the fingers
            pin.framesForwardKinematics(model, data, full)
            expected = data.oMf[hand].homogeneous
            got = recorded_pose(joints, frames, "panda_hand", row, drawn)
            assert np.max(np.abs(got[:3, 3] - expected[:3, 3])) <= POSITION_TOL, (run, row)
            assert np.max(np.abs(got[:3, :3] - expected[:3, :3])) <= ROTATION_TOL, (run, row)
    # the two runs' arms are apart: at 1 s their hands are ~0.3 m from each other
    last = {run: recorded_pose(joints, run, "panda_hand", 50, drawn)[:3, 3] for run in RUNS}
    assert np.linalg.norm(last["out"] - last["back"]) > 0.1
    # and the arm lags its reference (no gravity compensation): the desired hand is elsewhere
    desired = recorded_pose(joints, "out/desired", "panda_hand", 20, drawn)[:3, 3]
    assert np.linalg.norm(desired - recorded_pose(joints, "out", "panda_hand", 20, drawn)[:3, 3]
                          ) > 1e-3


def test_the_links_meshes_and_skeleton_are_in_the_recording(recorded):
    """Every link with a <visual> has its geometry under /<run>/arm3d/panda/visual_geometries
    (the meshes resolved from package://); the skeleton is drawn; the collision meshes are
    left out; every joint's signals are beside it; the layout puts a URDF run's arm in a 3-D
    view and a planar run's in 2-D."""
    path, _, _ = recorded
    entities = {}
    for chunk in RrdReader(path).stream():
        names = chunk.to_record_batch().schema.names
        entities.setdefault(str(chunk.entity_path), set()).update(
            name.split(":")[0] for name in names if ":" in name)
    visual_links = {link.get("name") for link in ElementTree.parse(PANDA).getroot().iter("link")
                    if link.find("visual") is not None}
    for run in RUNS:
        geometry = {e.split("/")[5] for e in entities
                    if e.startswith(f"/{run}/arm3d/panda/visual_geometries/")}
        assert geometry == visual_links, run
        meshes = [e for e in entities if e.startswith(f"/{run}/arm3d/panda/visual_geometries/")
                  and entities[e] & {"Asset3D", "Mesh3D"}]
        assert len(meshes) >= len(visual_links), run
        assert f"/{run}/arm3d/skeleton/panda_link0" in entities
        assert f"/{run}/arm3d/desired/skeleton/panda_link0" in entities
        assert {f"/{run}/plant/q", f"/{run}/plant/tau", f"/{run}/reference/q_d"} <= set(entities)
        assert f"/{run}/arm/links" not in entities  # no planar drawing of a spatial arm
    assert not [e for e in entities if "collision" in e]
    import rerun.blueprint as rrb

    columns = blueprint(list(RUNS), spatial=["out"]).root_container.contents
    arms = [column.contents[-1].contents[-1] for column in columns]  # the row's last view
    assert isinstance(arms[0], rrb.Spatial3DView) and arms[0].origin == "/out/arm3d"
    assert isinstance(arms[1], rrb.Spatial2DView) and arms[1].origin == "/back/arm"


def test_urdf_names_with_slashes_are_one_entity_each(tmp_path):
    """A link 'a/b' and joints 'j/1', 'j 2': their entities were not escaped (skeleton/a/b a
    child of a link 'a', joints/j/1 of a joint 'j'), while run names are checked for exactly
    this. Each name is now one part of its path, escaped as Rerun's own loader escapes it."""
    import rerun as rr

    from cosim.outputs.recording.arm3d import log_model, log_pose
    from cosim.outputs.recording.layout import UrdfArm

    inertial = ('<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" '
                'ixz="0" iyz="0"/></inertial>')
    joint = ('<joint name="{name}" type="revolute"><parent link="{parent}"/><child '
             'link="{child}"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-1" '
             'upper="1" effort="1" velocity="1"/></joint>')
    urdf = tmp_path / "slashes.urdf"
    urdf.write_text(f'<robot name="s"><link name="base"/><link name="a/b">{inertial}</link>'
                    f'<link name="c">{inertial}</link>'
                    + joint.format(name="j/1", parent="base", child="a/b")
                    + joint.format(name="j 2", parent="a/b", child="c") + "</robot>")
    arm = UrdfArm(str(urdf), ("j/1", "j 2"))
    recording = tmp_path / "arm.rrd"
    rec = rr.RecordingStream("slashes")
    rec.save(str(recording))
    trees = log_model(rec, "run", arm)
    log_pose(rec, "run", arm, trees, np.array([0.0, 0.1]), np.zeros((2, 2)), np.zeros((2, 2)))
    rec.flush()
    rec.disconnect()
    entities = {str(chunk.entity_path) for chunk in RrdReader(recording).stream()}
    for prefix in ("/run/arm3d", "/run/arm3d/desired"):
        assert {f"{prefix}/joints/j\\/1", f"{prefix}/joints/j\\ 2",
                f"{prefix}/skeleton/a\\/b", f"{prefix}/skeleton/base"} <= entities
    assert not [e for e in entities if "/joints/j/" in e or "/skeleton/a/" in e]


@pytest.mark.parametrize("arm", ["panda", "ur5"])
def test_a_shipped_arms_filtered_run_is_the_plant_its_guarantee_declares(arm, tmp_path):
    """pipelines/panda.toml's and ur5.toml's filtered runs, 50 ms: the classifier finds the
    plant that the nominal model and the declared uncertainty describe, friction included
    (panda.toml once zeroed its plant's URDF damping, which the nominal model carries: every
    filtered Panda run was outside its guarantee, "plant b[i] = 0 (nominal 0.003)"), and
    the run covered from its first step."""
    pipeline = Path(__file__).resolve().parents[1] / "pipelines" / f"{arm}.toml"
    done = here("run", str(pipeline), "--run", "proposed_cbf", "--set",
                "simulation.duration=0.05", "--out", str(tmp_path / "out"), "--quiet",
                "--no-recording", "--no-figures")
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    guarantee = summary["runs"]["proposed_cbf"]["metrics"]["guarantee"]
    assert guarantee["outside"] == [] and guarantee["covered"], guarantee["outside"]
    assert guarantee["covered_from_s"] == 0.0 and not guarantee["broken"]
