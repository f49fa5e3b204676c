"""The blocks on real arms (issue 32): the nominal rigid-body model of a URDF's chain
(cosim.dynamics: M̂ by CRBA, b̂ by RNEA, the payload as a point mass at the tip) against
Pinocchio on the same URDF, the planar chain as one instance of the same record, and a
spatial arm's pipeline run end to end through the real FMU with every joint checked."""

from __future__ import annotations

import importlib.metadata
import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import cosim_cli, error_line

from cosim.dynamics.model import (
    chain_model,
    model_bias,
    model_geometry,
    model_mass,
    model_payload,
    model_point_forms,
    model_velocity_forms,
    own_scratch,
    planar_model,
)
from cosim.paper.inertia import planar_bias, planar_mass_matrix

pin = pytest.importorskip("pinocchio")
urdf = pytest.importorskip("plant_fmu.urdf")

# (URDF under example-robot-data's robots/, tip link): five real arms, revolute joints about
# aligned and unaligned axes, a 7-joint one with its hand's fingers folded in
ARMS = {
    "ur5": ("ur_description/urdf/ur5_robot.urdf", "tool0"),
    "ur10": ("ur_description/urdf/ur10_robot.urdf", "tool0"),
    "panda": ("panda_description/urdf/panda.urdf", "panda_hand"),
    "z1": ("z1_description/urdf/z1.urdf", None),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", None),
}


def robot_urdf(relative: str):
    """A URDF of example-robot-data (a test extra; never copied into the repository)."""
    root = importlib.metadata.distribution("example-robot-data").locate_file(
        "cmeel.prefix/share/example-robot-data/robots")
    return root / relative


def pinocchio_model(chain, path):
    """Pinocchio's model of the same URDF, the joints our chain does not move locked where
    the reader holds them (fingers at 0), so that both fold the same bodies in."""
    model = pin.buildModelFromUrdf(str(path))
    moving = set(chain.joints)
    locked = [model.getJointId(name) for name in model.names[1:] if name not in moving]
    if locked:
        model = pin.buildReducedModel(model, locked, pin.neutral(model))
    assert [model.names[j] for j in range(1, model.njoints)] == list(chain.joints)
    return model


@pytest.mark.parametrize("arm", sorted(ARMS))
def test_the_nominal_model_is_pinocchios(arm):
    """M̂(q) (CRBA), b̂(q, v) = C v + G (RNEA), and with a payload Δm at the tip link's origin
    M̂ + Δm JᵀJ and b̂ + Δm Jᵀγ (J, γ = J̇v − g of that point), each as the model computes them
    in one call, equal Pinocchio's crba and rnea on the same URDF (the payload added to the
    last body as a point inertia there) to 1e-12 relative, at 200 random states."""
    relative, tip = ARMS[arm]
    path = robot_urdf(relative)
    chain = urdf.read_urdf(path, tip=tip)
    model = own_scratch(chain_model(chain))
    reference = pinocchio_model(chain, path)
    data = reference.createData()
    loaded = reference.copy()
    payload = 2.5  # kg
    loaded.inertias[chain.n] = loaded.inertias[chain.n] + pin.Inertia(
        payload, chain.tip[:3, 3], np.zeros((3, 3)))
    loaded_data = loaded.createData()
    n = chain.n
    rng = np.random.default_rng(32)
    mass, bias = np.zeros((n, n)), np.zeros(n)
    mass_loaded, bias_loaded = np.zeros((n, n)), np.zeros(n)
    jac, gamma = np.zeros((3, n)), np.zeros(3)
    for _ in range(200):
        q, v = rng.uniform(-np.pi, np.pi, n), rng.uniform(-4, 4, n)
        model_geometry(model, q)
        model_mass(model, 1.0, 0.0, mass)
        model_bias(model, v, 1.0, 0.0, 1.0, bias)
        model_mass(model, 1.0, payload, mass_loaded)
        model_bias(model, v, 1.0, payload, 1.0, bias_loaded)
        model_payload(model, v, 1.0, jac, gamma)
        expected = pin.crba(reference, data, q)
        expected = np.triu(expected) + np.triu(expected, 1).T
        expected_bias = pin.rnea(reference, data, q, v, np.zeros(n))
        loaded_mass = pin.crba(loaded, loaded_data, q)
        loaded_mass = np.triu(loaded_mass) + np.triu(loaded_mass, 1).T
        loaded_bias = pin.rnea(loaded, loaded_data, q, v, np.zeros(n))
        for ours, theirs in ((mass, expected), (bias, expected_bias),
                             (mass_loaded, loaded_mass), (bias_loaded, loaded_bias),
                             (mass + payload * jac.T @ jac, loaded_mass),
                             (bias + payload * jac.T @ gamma, loaded_bias)):
            np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12 * np.abs(theirs).max())


@pytest.mark.parametrize("arm", sorted(ARMS))
def test_the_velocity_forms_are_pinocchios(arm):
    """b's velocity part as the blocks' bounds take it, vᵀΓ_l v: the bodies' Γ (polarised
    RNEA) and a unit payload's (closed form, Jᵀ times the tip point's forms P_r), equal
    Pinocchio's rnea at zero gravity and q̈ = 0 without and with a payload at the tip; and
    vᵀP_r v equals the tip point's classical acceleration at q̈ = 0 in Pinocchio (a frame
    there), to 1e-12 relative at 50 random states."""
    relative, tip = ARMS[arm]
    path = robot_urdf(relative)
    chain = urdf.read_urdf(path, tip=tip)
    model = own_scratch(chain_model(chain))
    reference = pinocchio_model(chain, path)
    reference.gravity.linear[:] = 0.0
    n = chain.n
    frame = reference.addFrame(pin.Frame("payload point", n, len(reference.frames) - 1,
                                         pin.SE3(np.eye(3), chain.tip[:3, 3]),
                                         pin.FrameType.OP_FRAME))
    loaded = reference.copy()
    loaded.inertias[n] = loaded.inertias[n] + pin.Inertia(1.0, chain.tip[:3, 3], np.zeros((3, 3)))
    data, loaded_data = reference.createData(), loaded.createData()
    bodies, payload, forms = np.zeros((n, n, n)), np.zeros((n, n, n)), np.zeros((3, n, n))
    scratch = np.zeros(n), np.zeros(n)
    rng = np.random.default_rng(7)
    for _ in range(50):
        q, v = rng.uniform(-np.pi, np.pi, n), rng.uniform(-4, 4, n)
        model_geometry(model, q)
        model_velocity_forms(model, 1.0, 0.0, *scratch, bodies)
        model_velocity_forms(model, 0.0, 1.0, *scratch, payload)
        model_point_forms(model, np.zeros(n), np.zeros((3, n)), np.zeros(3), forms, np.zeros(3))
        zero = np.zeros(n)
        alone = pin.rnea(reference, data, q, v, zero)
        with_payload = pin.rnea(loaded, loaded_data, q, v, zero)
        pin.forwardKinematics(reference, data, q, v, zero)
        point = pin.getFrameClassicalAcceleration(reference, data, frame,
                                                  pin.LOCAL_WORLD_ALIGNED).linear
        for ours, theirs in ((np.einsum("lij,i,j->l", bodies, v, v), alone),
                             (np.einsum("lij,i,j->l", payload, v, v), with_payload - alone),
                             (np.einsum("rij,i,j->r", forms, v, v), point)):
            np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12 * np.abs(theirs).max())


def test_the_planar_chain_is_one_instance_bit_for_bit():
    """The planar chain through the model record (what the blocks now call) gives the planar
    kernels' M and b bit for bit, with and without a payload on the last link, and its
    payload's point (the last centre of mass) the Jacobian of the closed form."""
    m, lengths, lc, inertia = [0.8, 2.3, 1.1], [1.0, 1.0, 0.7], [1.0, 1.0, 0.4], [0.0, 0.1, 0.02]
    model = own_scratch(planar_model(m, lengths, lc, inertia, 9.8))
    arms = np.array([lengths[0], lengths[1], lc[2]])

    def point(angles):  # the last centre of mass in the plane
        return np.array([np.sum(arms * np.cos(np.cumsum(angles))),
                         np.sum(arms * np.sin(np.cumsum(angles)))])

    rng = np.random.default_rng(2)
    for _ in range(50):
        q, v = rng.uniform(-3, 3, 3), rng.uniform(-10, 10, 3)
        ours_mass, ours_bias = np.zeros((3, 3)), np.zeros(3)
        model_geometry(model, q)
        for payload in (0.0, 1.5):
            model_mass(model, 1.0, payload, ours_mass)
            model_bias(model, v, 1.0, payload, 1.0, ours_bias)
            masses = np.array(m) + np.array([0.0, 0.0, payload])
            mass, bias = np.zeros((3, 3)), np.zeros(3)
            planar_mass_matrix(q, masses, np.array(lengths), np.array(lc), np.array(inertia),
                               mass)
            planar_bias(q, v, masses, np.array(lengths), np.array(lc), np.array(inertia), 9.8,
                        bias)
            assert np.array_equal(ours_mass, mass) and np.array_equal(ours_bias, bias)
        jac, gamma = np.zeros((2, 3)), np.zeros(2)
        model_payload(model, v, 1.0, jac, gamma)
        numeric = np.column_stack([(point(q + h) - point(q - h)) / 2e-6
                                   for h in np.eye(3) * 1e-6])
        np.testing.assert_allclose(jac, numeric, atol=1e-8)


UR5 = "pipelines/ur5.toml"
ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def ur5_folder(tmp_path_factory) -> Path:
    """pipelines/ur5.toml's output-feedback and PD runs, 1.5 s, through `cosim run`: the
    spatial-chain FMU built from the URDF (FMPy), the blocks on its 6 joints."""
    out = tmp_path_factory.mktemp("ur5")
    result = cosim_cli("run", UR5, "--set", "simulation.duration=1.5", "--run", "proposed",
                       "--run", "pd", "--out", str(out), "--no-recording", "--no-figures")
    assert result.returncode == 0, result.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def ur5_runs(ur5_folder):
    """The runs' summary.json."""
    return json.loads((ur5_folder / "summary.json").read_text())


def test_a_urdf_arm_is_checked_on_every_joint_against_its_own_limits(ur5_runs):
    """Every joint's position (the URDF's limits less the declared margin), true velocity and
    effort are hard checks with the URDF's own bounds (read here by plant_fmu.urdf, not by the
    evaluation's code path), no norm of a box; both controllers keep them all, and the
    output-feedback controller tracks the waypoints (its error within 0.3 rad per joint)."""
    chain = urdf.read_urdf(robot_urdf(ARMS["ur5"][0]), tip="tool0")
    margin = 0.05
    for name in ("proposed", "pd"):
        safety = ur5_runs["runs"][name]["safety"]
        for j in range(chain.n):
            position = safety[f"position_joint{j + 1}"]
            half = 0.5 * (chain.upper[j] - chain.lower[j]) - margin
            assert position["kind"] == "hard" and position["bound"] == pytest.approx(half)
            velocity = safety[f"velocity_true_joint{j + 1}"]
            assert velocity["bound"] == pytest.approx(chain.velocity[j])
            effort = safety[f"effort_joint{j + 1}"]
            assert effort["kind"] == "hard" and effort["bound"] == pytest.approx(chain.effort[j])
            for entry in (position, velocity, effort):
                assert entry["satisfied"] is True, (name, j, entry)
            assert 0.0 < velocity["worst"] < chain.velocity[j]  # the arm moved
        assert not any(key.startswith(("position_norm", "velocity_true_norm", "effort_norm"))
                       for key in safety)
    errors = ur5_runs["runs"]["proposed"]["metrics"]["max_error"]
    assert len(errors) == chain.n and max(errors) < 0.3


def test_a_plant_that_is_not_the_nominal_arm_is_outside_the_guarantee(ur5_runs, ur5_folder,
                                                                    tmp_path):
    """The plant's URDF and the nominal model's are one arm in ur5.toml: no difference is
    named. Against a nominal arm whose upper arm is 2 kg heavier, the run's recorded M(q)
    departs; a plant built with its base turned on its side (gravity along another axis of
    the arm: M(q) the same) departs in h(q, q̇), and the guarantee files the run outside,
    naming it (it was once "covered", then "BROKEN", blamed on the filter)."""
    from cosim.dynamics.model import chain_model
    from cosim.paper.within_bounds import plant_model_difference
    from cosim.signals import Signal, Trace

    for name in ("proposed", "pd"):
        outside = ur5_runs["runs"][name]["metrics"]["guarantee"]["outside"]
        assert not any("nominal arm" in text for text in outside), outside
    text = robot_urdf(ARMS["ur5"][0]).read_text()
    upper_arm = '<mass value="8.393"/>'
    assert text.count(upper_arm) == 1
    heavier = tmp_path / "ur5_heavier.urdf"
    heavier.write_text(text.replace(upper_arm, '<mass value="10.393"/>'))
    recorded = np.load(ur5_folder / "trace_proposed.npz")

    def trace_of(keys: tuple[str, ...]) -> Trace:  # the run's recorded plant outputs
        trace = Trace({key: Signal("nn" if key == "M" else "n", "SI", key) for key in keys},
                      6, len(recorded["q"]) - 1, 1e-3)
        for key in keys:
            trace.arrays[key][:] = recorded[key]
        trace.rows_done = len(recorded["q"])
        return trace

    payload = ur5_runs["plant"]["parameters"]["payload"]
    same = chain_model(urdf.read_urdf(robot_urdf(ARMS["ur5"][0]), tip="tool0"))
    other = chain_model(urdf.read_urdf(heavier, tip="tool0"))
    assert plant_model_difference(trace_of(("q", "qdot", "M", "h")), same, payload) is None
    for keys, what in ((("q", "qdot", "M"), "M(q)"), (("q", "qdot", "M", "h"), "h(q, q̇)")):
        assert plant_model_difference(trace_of(keys), other, payload).startswith(
            f"{what} differs"), keys  # h's gravity part departs the more
    turned = '<origin rpy="0.0 0.0 0.0" xyz="0.0 0.0 0.0"/>\n  </joint>'
    assert text.count(turned) == 1
    tilted = tmp_path / "ur5_tilted.urdf"
    tilted.write_text(text.replace(turned, turned.replace('rpy="0.0', 'rpy="1.5708')))
    out = tmp_path / "tilted"
    result = cosim_cli("run", UR5, "--set", "simulation.duration=0.2", "--run", "proposed_cbf",
                       "--set", f'plant.urdf.file="{tilted}"', "--out", str(out),
                       "--no-recording", "--no-figures")
    assert result.returncode == 0, result.stderr[-3000:]
    guarantee = json.loads((out / "summary.json").read_text())[
        "runs"]["proposed_cbf"]["metrics"]["guarantee"]
    named = [entry for entry in guarantee["outside"] if "nominal arm" in entry]
    assert len(named) == 1 and named[0].startswith("plant h(q, q̇) differs"), named
    assert guarantee["covered"] is False and guarantee["broken"] is False


def test_every_urdf_a_pipeline_file_names_is_relative_to_that_file(tmp_path, monkeypatch):
    """plant.urdf, safety.urdf and inertia_model.urdf all from the pipeline file's folder,
    whatever the working folder holds (a copy there with ten times the velocity limits was
    once read for the safe sets and the nominal model: a run judged against another
    file's limits); given by --set, from the working folder."""
    from cosim.config import load_pipeline
    from cosim.declared import joint_boxes

    original = robot_urdf(ARMS["ur5"][0]).read_text()
    mine, elsewhere = tmp_path / "mine", tmp_path / "elsewhere"
    mine.mkdir()
    elsewhere.mkdir()
    (mine / "arm.urdf").write_text(original)
    assert original.count('velocity="3.15"') >= 1
    (elsewhere / "arm.urdf").write_text(original.replace('velocity="3.15"', 'velocity="31.5"'))
    text = (ROOT / UR5).read_text()
    package = "package://example-robot-data/robots/ur_description/urdf/ur5_robot.urdf"
    assert text.count(f'"{package}"') == 3
    (mine / "p.toml").write_text(text.replace(f'"{package}"', '"arm.urdf"'))
    monkeypatch.chdir(elsewhere)
    pipeline = load_pipeline(mine / "p.toml")
    assert pipeline.plant.urdf.file == str(mine / "arm.urdf")
    assert pipeline.safety.urdf == str(mine / "arm.urdf")
    assert pipeline.runs["proposed"].inertia_model.urdf == str(mine / "arm.urdf")
    assert joint_boxes(pipeline.safety, 6).velocity_half[0] == pytest.approx(3.15)
    given = load_pipeline(mine / "p.toml", ['safety.urdf="arm.urdf"'])
    assert joint_boxes(given.safety, 6).velocity_half[0] == pytest.approx(31.5)


def test_a_waypoint_past_a_joint_limit_is_refused_naming_it():
    """A waypoint past the elbow's limit (π rad, less the margin) is refused before the run:
    exit 2, one message naming the joint and the URDF's limits."""
    result = cosim_cli("run", UR5, "--dry-run", "--set",
                       "reference.waypoints.positions=[[0,-1.571,1.571,-1.571,-1.571,0],"
                       "[0,-1.571,3.12,-1.571,-1.571,0]]",
                       "--set", "reference.waypoints.times=[0,2]")
    message = error_line(result)
    assert "joint 3" in message and "ur5_robot.urdf's <limit>" in message, message


def test_a_negative_payload_at_a_urdf_arms_flange_is_refused():
    """The payload of a URDF arm is a point mass of its own at the tip frame: a declared
    range below 0 kg would have the robust margins take mass matrices that are not positive
    definite. Refused before the run, naming the key and the tip link; 0 kg is accepted."""
    result = cosim_cli("run", UR5, "--dry-run", "--set", "uncertainty.payload=[-0.5,1]")
    assert result.returncode == 2
    assert error_line(result) == (
        "cosim: error: uncertainty.payload = [-0.5, 1] (run 'proposed'): the low end allows a "
        "plant with a negative mass: the payload is a point mass of its own at the tip "
        "frame's origin (link 'tool0'), which cannot be negative; give low ≥ 0 kg")
    assert cosim_cli("run", UR5, "--dry-run", "--set",
                     "uncertainty.payload=[0,1]").returncode == 0


def test_the_safe_sets_urdf_holds_the_joints_the_plant_holds():
    """safety.urdf_fixed holds a joint of the limits' URDF as plant.urdf.fixed holds the
    plant's: its chain then has the plant's joints, the held one's limits not among the safe
    sets. Without it, the message names the key that would fix the count."""
    from cosim.declared import Safety, joint_boxes
    from cosim.schema import PipelineError

    package = "package://example-robot-data/robots/panda_description/urdf/panda.urdf"
    whole = joint_boxes(Safety(limits="urdf", urdf=package, urdf_tip="panda_hand"), 7)
    held = joint_boxes(Safety(limits="urdf", urdf=package, urdf_tip="panda_hand",
                              urdf_fixed={"panda_joint4": -1.5}), 6)
    kept = [0, 1, 2, 4, 5, 6]  # joint 4's range, (-3.07, -0.07) rad, is the one unlike others
    for field in ("position_centre", "position_half", "velocity_half", "effort"):
        assert np.array_equal(getattr(held, field), getattr(whole, field)[kept]), field
    assert len(set(whole.position_centre)) > 2
    with pytest.raises(PipelineError, match=r"its chain has 7 moving joints .*, the plant 6: "
                       r"hold the joints the plant holds with safety.urdf_fixed"):
        joint_boxes(Safety(limits="urdf", urdf=package, urdf_tip="panda_hand"), 6)
    with pytest.raises(PipelineError, match=r"safety.urdf_fixed.panda_joint44: not a moving "
                       "joint below base link"):
        joint_boxes(Safety(limits="urdf", urdf=package, urdf_fixed={"panda_joint44": 0.0}), 6)
