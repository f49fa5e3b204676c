"""The URDF plant (plant_fmu/urdf.py, plant_fmu/models/spatial_chain, `cosim build-fmu
--urdf`, ``plant.urdf``), checked against what we did not write: Pinocchio's URDF parser and
its CRBA, RNEA and ABA on real arms from example-robot-data (a test extra, never copied into
the repo) and on our own test robot, SciPy's solve_ivp, FMPy's validator. The 1000-state
figures and the speed are benchmarks/bench_urdf.py's."""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from fmu_helpers import FmuInstance
from urdf_helpers import (
    ARMS,
    OWN_ROBOT,
    ROBOTS,
    SWING_Q0,
    configuration,
    dynamics_errors,
    panda_swing,
    pinocchio_model,
)

from cosim.cli import main
from cosim.config import PipelineError, load_pipeline
from cosim.plant.fmu import Fmu
from cosim.plant_source import plant_path
from plant_fmu import build_urdf_fmu
from plant_fmu.build import _build_key
from plant_fmu.models.spatial_chain import SpatialChainModel
from plant_fmu.urdf import UrdfError, read_urdf, resolve_uri

# Five arms of example-robot-data and our own robot, built for FMI 2 or 3 (UR10 and SO-101
# too in benchmarks/bench_urdf.py).
DYNAMICS = {"ur5": 2, "kinova": 2, "z1": 2, "panda": 3, "xarm7": 3, "own": 2}
PAYLOAD = 0.7  # kg at the tip frame, so that its placement is checked too
STATES = 50


def urdf_of(name: str):
    return OWN_ROBOT if name == "own" else ARMS[name]


@pytest.fixture(scope="module")
def fmus(fmu_cache):
    """name -> the plant FMU of that URDF (built once, on demand)."""
    built = {}

    def fmu(name: str, fmi_version: int | None = None):
        key = (name, fmi_version or DYNAMICS[name])
        if key not in built:
            built[key] = build_urdf_fmu(urdf_of(name), fmi_version=key[1], cache_dir=fmu_cache)
        return built[key]

    return fmu


@pytest.mark.parametrize("arm", sorted(ARMS))
def test_reader_matches_pinocchio_parser(arm):
    path = ARMS[arm]
    chain = read_urdf(path)
    model = pinocchio_model(path, chain)
    assert tuple(model.names[1:]) == chain.joints
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    for i in range(chain.n):
        s = np.asarray(data.joints[i + 1].S).reshape(6, -1)[:, 0]  # [v; ω] in Pinocchio
        prismatic = np.linalg.norm(s[3:]) == 0
        assert chain.kind[i] == int(prismatic)
        np.testing.assert_allclose(chain.axis[i], s[:3] if prismatic else s[3:], atol=1e-15)
        np.testing.assert_allclose(chain.placement[i], model.jointPlacements[i + 1].homogeneous,
                                   atol=1e-14)
        body = model.inertias[i + 1]
        np.testing.assert_allclose(chain.mass[i], body.mass, rtol=1e-14)
        np.testing.assert_allclose(chain.com[i], body.lever, atol=1e-14)
        np.testing.assert_allclose(chain.inertia[i], body.inertia, atol=1e-14)
        assert chain.parent[i] == model.parents[i + 1] - 1
        if not chain.continuous[i]:
            assert chain.lower[i] == model.lowerPositionLimit[model.idx_qs[i + 1]]
            assert chain.upper[i] == model.upperPositionLimit[model.idx_qs[i + 1]]
        assert chain.effort[i] == model.effortLimit[model.idx_vs[i + 1]]
        assert chain.velocity[i] == model.velocityLimit[model.idx_vs[i + 1]]


def test_panda_chain_stops_at_the_hand_with_the_fingers_folded():
    chain = read_urdf(ARMS["panda"])
    assert chain.n == 7 and chain.base_link == "panda_link0" and chain.tip_link == "panda_hand"
    assert dict(chain.held) == {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}
    # link7 0.735522 kg + hand 0.73 kg + two fingers 0.015 kg each
    assert chain.mass[-1] == pytest.approx(0.735522 + 0.73 + 0.03, rel=1e-14)
    np.testing.assert_allclose(chain.gravity, [0, 0, -9.81])
    np.testing.assert_allclose(chain.lower[3], -3.0718)
    np.testing.assert_allclose(chain.effort, [87] * 4 + [12] * 3)
    # --tip and --fix: the UR5 to its flange, its wrist held at 0.5 rad
    ur5 = read_urdf(ARMS["ur5"], tip="tool0", fixed={"wrist_3_joint": 0.5})
    assert ur5.joints[-1] == "wrist_2_joint" and ur5.tip_link == "tool0"
    assert ur5.held == (("wrist_3_joint", 0.5),)


def test_an_off_chain_joint_whose_limits_exclude_zero_is_held_at_its_nearest_limit(tmp_path):
    """The Panda with its fingers' range [0.01, 0.04] m: held at 0.01 (not 0), and the hand
    folded with them there, as Pinocchio's model locked at the held values."""
    robot = tmp_path / "panda.urdf"
    robot.write_text(ARMS["panda"].read_text().replace('lower="0.0" upper="0.04"',
                                                       'lower="0.01" upper="0.04"'))
    chain = read_urdf(robot)
    assert dict(chain.held) == {"panda_finger_joint1": 0.01, "panda_finger_joint2": 0.01}
    hand = pinocchio_model(ARMS["panda"], chain).inertias[chain.n]
    np.testing.assert_allclose(chain.com[-1], hand.lever, rtol=0, atol=1e-14)
    np.testing.assert_allclose(chain.inertia[-1], hand.inertia, rtol=0, atol=1e-14)


def test_a_held_prismatic_joint_folds_as_pinocchio_locks_it():
    """One finger held at 0.03 m (one only: the two are symmetric, so holding both would
    hide a sign)."""
    chain = read_urdf(ARMS["panda"], fixed={"panda_finger_joint1": 0.03})
    assert dict(chain.held)["panda_finger_joint1"] == 0.03
    hand = pinocchio_model(ARMS["panda"], chain).inertias[chain.n]
    np.testing.assert_allclose(chain.com[-1], hand.lever, rtol=0, atol=1e-14)
    np.testing.assert_allclose(chain.inertia[-1], hand.inertia, rtol=0, atol=1e-14)


@pytest.mark.parametrize("value", (-4.0, 4.0))
def test_a_held_value_outside_the_joints_limits_is_refused_on_either_side(value):
    with pytest.raises(UrdfError, match=r"elbow_joint=.*outside the joint's limits"):
        read_urdf(ARMS["ur5"], fixed={"elbow_joint": value})


def test_holding_a_joint_that_does_not_move_is_refused():
    with pytest.raises(UrdfError, match="panda_joint8: not a moving joint"):
        read_urdf(ARMS["panda"], fixed={"panda_joint8": 0.0})


def test_own_robot_prismatic_continuous_and_fixed_joints():
    chain = read_urdf(OWN_ROBOT)
    assert chain.joints == ("lift", "turret", "shoulder", "wrist")
    assert chain.kind.tolist() == [1, 0, 0, 0]
    assert chain.continuous.tolist() == [False, True, False, False]
    assert (chain.base_link, chain.tip_link) == ("world", "tool0")
    np.testing.assert_allclose(chain.mass, [2.0, 1.2, 1.5 + 0.8, 0.3])  # forearm folded in
    np.testing.assert_allclose(chain.axis[2], [0, 0.6, 0.8])
    np.testing.assert_allclose(chain.tip[:3, 3], [0.05, 0, 0])
    assert (chain.lower[1], chain.upper[1]) == (-np.inf, np.inf)
    np.testing.assert_allclose(chain.damping, [5.0, 0.1, 0.0, 0.02])
    np.testing.assert_allclose(chain.friction, [2.0, 0.0, 0.0, 0.1])


@pytest.mark.parametrize("arm", sorted(DYNAMICS))
def test_dynamics_match_pinocchio(fmus, arm):
    """M (CRBA), h (RNEA) and q̈ (ABA, with the URDF's friction and a payload) at random
    states, each within 1e-10 of Pinocchio's, relative to its largest entry."""
    path = urdf_of(arm)
    # a seed of the arm's name that stays the same from run to run (str's hash does not)
    rng = np.random.default_rng(zlib.crc32(arm.encode()))
    worst = dynamics_errors(path, fmus(arm), read_urdf(path), PAYLOAD, rng, STATES)
    assert worst.max() <= 1e-10, dict(zip(("M", "h", "qdd"), worst, strict=True))


@pytest.mark.parametrize("damping", ["0.1", "urdf"])
def test_trajectory_matches_solve_ivp(fmus, damping):
    """The Panda (FMI 3, Co-Simulation, RK4 at its defaults) swinging freely (τ = 0) for 2 s
    from a pose away from its neutral one, against SciPy's DOP853 on Pinocchio's ABA:
    ≤ 1e-6 rad, with the joints' damping 0.1 N·m·s/rad in both, or the URDF's own 0.003.
    With the URDF's the wrist whips up to 71 rad/s (30 times its limit): the sub-steps
    shorten past 40 rad/s (rk4_motion = 4 mrad a sub-step); RK4 at 1e-4 s throughout would
    be 1.3e-6 rad off (benchmarks/bench_urdf.py reports both)."""
    chain = read_urdf(ARMS["panda"])
    trace, reference, _ = panda_swing(fmus("panda", 3), chain,
                                      chain.damping if damping == "urdf" else np.full(7, 0.1))
    assert np.abs(trace - reference).max() <= 1e-6
    assert np.abs(reference[-1] - SWING_Q0).max() > 5.0  # it did swing


def test_fast_joints_take_shorter_sub_steps(fmus):
    """Without the motion limit (rk4_motion far beyond any sub-step's motion) the URDF's
    swing is integrated at 1e-4 s throughout and misses the 1e-6 rad; an arm within its
    velocity limits keeps rk4_step's sub-steps, bit for bit (its motion per sub-step is
    < 4 mrad), so a limit too large to bind changes nothing there."""
    chain = read_urdf(ARMS["panda"])
    trace, reference, qdot = panda_swing(fmus("panda", 3), chain, chain.damping,
                                         rk4_motion=1e9)
    assert np.abs(trace - reference).max() > 1e-6
    assert np.abs(qdot).max() * 1e-4 > 4e-3  # it did go past the motion limit
    slow = np.full(7, 20.0)  # heavily damped: < 40 rad/s throughout
    limited, _, qdot = panda_swing(fmus("panda", 3), chain, slow)
    unlimited, _, _ = panda_swing(fmus("panda", 3), chain, slow, rk4_motion=1e9)
    assert np.abs(qdot).max() * 1e-4 < 4e-3
    assert np.array_equal(limited, unlimited)


def test_directional_derivative_is_the_inverse_inertia(fmus):
    """∂q̈/∂τ of the complex-step directional derivatives is M⁻¹, Pinocchio's."""
    chain = read_urdf(OWN_ROBOT)
    model = pinocchio_model(OWN_ROBOT, chain)
    plant = FmuInstance(fmus("own"), "ModelExchange")
    try:
        q, qd = np.array([0.2, 1.0, -0.4, 0.7]), np.array([0.1, -0.5, 0.8, 0.3])
        plant.set_states(np.concatenate([q, qd]))
        accelerations = [f"der(qdot[{i + 1}])" for i in range(chain.n)]
        columns = [plant.directional_derivative(accelerations, [f"tau[{j + 1}]"],
                                                [1.0]) for j in range(chain.n)]
    finally:
        plant.free()
    expected = pin.computeMinverse(model, model.createData(), configuration(model, q))
    np.testing.assert_allclose(np.array(columns).T, np.triu(expected) + np.triu(expected, 1).T,
                               rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("arm", ["own", "panda"])  # FMI 2, FMI 3
def test_fmpy_validate_finds_no_problems(fmus, arm):
    path = fmus(arm)
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    assert md.fmiVersion == f"{DYNAMICS[arm]}.0"
    assert md.coSimulation is not None and md.modelExchange is not None


def test_model_description_limits_and_units(fmus):
    md = read_model_description(str(fmus("own")))
    var = {v.name: v for v in md.modelVariables}
    # the lift is prismatic: metres and newtons; M mixes the two
    assert [var[n].unit for n in ("q[1]", "qdot[1]", "tau[1]", "b[1]", "M[1,2]", "M[1,1]")] \
        == ["m", "m/s", "N", "N.s/m", "kg.m", "kg"]
    assert [var[n].unit for n in ("q[2]", "tau[2]", "M[2,2]")] == ["rad", "N.m", "kg.m2"]
    # position limits on the start positions; none for the continuous turret
    assert (float(var["q0[1]"].min), float(var["q0[1]"].max)) == (0.0, 0.5)
    assert (var["q0[2]"].min, var["q0[2]"].max) == (None, None)
    assert (float(var["q0[3]"].min), float(var["q0[3]"].max)) == (-2.0, 2.0)
    # velocity and effort limits and friction as parameters a pipeline reads or sets
    assert [float(var[f"qdot_max[{i}]"].start) for i in range(1, 5)] == [0.3, 2.0, 3.0, 4.0]
    assert [float(var[f"tau_max[{i}]"].start) for i in range(1, 5)] == [200, 50, 30, 10]
    assert var["payload"].causality == "parameter" and var["payload"].unit == "kg"
    assert "slider_turret" in md.description and "lift" in md.description


def test_a_prismatic_joints_units_are_said_where_cosim_labels_them_otherwise(fmus):
    """cosim's signals carry one unit per port (rad, rad/s, N·m); the lift's are m, m/s and
    N: opening the plant says so, naming each variable (the revolute joints are not
    named: "N.m" is "N·m")."""
    from cosim.plant.mapping import unit_differences

    path = fmus("own")
    md = read_model_description(str(path))
    fmu = Fmu(path, {}, {})
    try:
        text = fmu.info()["unit_differences"]
    finally:
        fmu.close()
    assert text == unit_differences(md, fmu.variables)
    assert text.startswith("the FMU declares tau[1] in N, q[1] in m, qdot[1] in m/s, h[1] "
                           "in N, where cosim's interface has tau in N·m, q in rad, qdot in "
                           "rad/s, h in N·m"), text
    assert "[2]" not in text and "[3]" not in text


def test_start_outside_the_limits_is_refused(fmus):
    with pytest.raises(FMICallException):
        FmuInstance(fmus("own"), "CoSimulation", {"q0[1]": 0.6})  # the lift's range is 0..0.5 m


def test_build_is_cached_by_the_urdf_content(fmus, fmu_cache, tmp_path):
    first = fmus("own")
    assert build_urdf_fmu(OWN_ROBOT, cache_dir=fmu_cache) == first
    heavier = tmp_path / "slider_turret.urdf"
    heavier.write_text(OWN_ROBOT.read_text().replace('<mass value="0.3"/>',
                                                     '<mass value="0.4"/>'))
    (tmp_path / "meshes").symlink_to(OWN_ROBOT.parent / "meshes")
    keys = [_build_key(SpatialChainModel(read_urdf(urdf)), 4, 2, "cc")
            for urdf in (OWN_ROBOT, heavier, OWN_ROBOT)]
    assert keys[0] != keys[1] and keys[0] == keys[2]


# Each malformed URDF (our robot, edited) and the element its one message names.
MALFORMED = {
    "missing inertial": (
        lambda t: re.sub(r'(<link name="carriage">\s*)<inertial>.*?</inertial>', r"\1", t,
                         flags=re.S),
        "link 'carriage' has no <inertial> (with <mass>), but moving joint 'lift' carries it"),
    "zero mass": (
        lambda t: t.replace('<mass value="1.2"/>', '<mass value="0"/>'),
        "link 'turret_link' <inertial><mass value='0'>: a mass must be a finite positive "
        "number (kg): moving joint 'turret' carries it"),
    "NaN mass": (
        lambda t: t.replace('<mass value="1.2"/>', '<mass value="nan"/>'),
        "link 'turret_link' <inertial><mass value='nan'>: a mass must be a finite positive "
        "number (kg)"),
    "infinite inertia": (
        lambda t: t.replace('ixx="0.008"', 'ixx="inf"'),
        "link 'turret_link' <inertial><inertia>: ixx, ixy, ixz, iyy, iyz and izz must be "
        "finite numbers (kg m^2)"),
    "infinite inertial origin": (
        lambda t: t.replace('<origin xyz="0.02 0 0"/>', '<origin xyz="inf 0 0"/>'),
        "link 'hand' <inertial><origin>: its xyz (m) and rpy (rad) must be finite numbers"),
    "NaN joint origin": (
        lambda t: t.replace('rpy="1.5707963267948966 0 0.2"', 'rpy="nan 0 0.2"'),
        "joint 'shoulder' <origin>: its xyz (m) and rpy (rad) must be finite numbers"),
    "NaN axis": (
        lambda t: t.replace('<axis xyz="0 0.6 0.8"/>', '<axis xyz="0 nan 0.8"/>'),
        "joint 'shoulder' <axis xyz='0 nan 0.8'>: the axis must be a non-zero vector of three "
        "finite numbers"),
    "NaN lower limit": (
        lambda t: t.replace('lower="-1.5"', 'lower="nan"'),
        "joint 'wrist' <limit lower='nan'>: the lower limit must be a finite number (rad)"),
    "infinite velocity limit": (
        lambda t: t.replace('velocity="0.3"', 'velocity="inf"'),
        "joint 'lift' <limit velocity='inf'>: the velocity limit must be a finite number >= 0 "
        "(m/s)"),
    "NaN damping": (
        lambda t: t.replace('damping="0.02"', 'damping="nan"'),
        "joint 'wrist' <dynamics damping='nan'>: the damping must be a finite number >= 0 "
        "(N m s/rad)"),
    "limits the wrong way round": (
        lambda t: t.replace('lower="-1.5" upper="1.5"', 'lower="1.5" upper="-1.5"'),
        "joint 'wrist' <limit lower='1.5' upper='-1.5'>: lower must be <= upper (rad); no "
        "position lies within these limits"),
    "prismatic limits the wrong way round": (
        lambda t: t.replace('lower="0.0" upper="0.5"', 'lower="0.5" upper="0.0"'),
        "joint 'lift' <limit lower='0.5' upper='0'>: lower must be <= upper (m)"),
    "link defined twice": (
        lambda t: t.replace("</robot>", '<link name="hand"/></robot>'),
        "link 'hand' is defined twice: each <link> needs a name of its own"),
    "joint defined twice": (
        lambda t: t.replace("</robot>", '<joint name="wrist" type="fixed"><parent link="hand"/>'
                            '<child link="extra"/></joint><link name="extra"/></robot>'),
        "joint 'wrist' is defined twice: each <joint> needs a name of its own"),
    "not XML": (
        lambda t: "solid block\nendsolid block\n",  # an STL given for the URDF
        "not well-formed XML at line 1, column 1: Start tag expected, '<' not found"),
    "truncated XML": (
        lambda t: '<robot name="r">\n  <link name="a">\n',
        "not well-formed XML at line 3, column 1: Premature end of data in tag link line 2"),
    "not a robot": (
        lambda t: '<sdf version="1.6"/>',
        "the XML's root element is <sdf>, not <robot>: not a URDF"),
    "loop": (
        lambda t: t.replace("</robot>", '<joint name="strut" type="fixed"><parent '
                            'link="pedestal"/><child link="hand"/></joint></robot>'),
        "link 'hand' is the child of joints 'wrist' and 'strut': a loop"),
    "floating joint": (
        lambda t: t.replace('name="turret" type="continuous"', 'name="turret" type="floating"'),
        "joint 'turret' has type 'floating': the plant supports revolute, continuous, "
        "prismatic, fixed joints"),
    "planar joint": (
        lambda t: t.replace('name="wrist" type="revolute"', 'name="wrist" type="planar"'),
        "joint 'wrist' has type 'planar'"),
    "a robot without its name": (
        lambda t: t.replace('<robot name="slider_turret">', "<robot>"),
        "not a readable URDF (the attribute 'name' is missing); a URDF is a <robot name> "
        "whose every <link> and <joint> has its name, and every joint its <parent link> and "
        "<child link>"),
    "missing mesh": (
        lambda t: t.replace("meshes/block.stl", "meshes/gone.stl"),
        "link 'pedestal' <visual><mesh filename='meshes/gone.stl'>: no such file"),
    "mesh of an unknown package": (
        lambda t: t.replace("meshes/block.stl", "package://nopkg/meshes/x.stl"),
        "link 'pedestal' <visual><mesh filename='package://nopkg/meshes/x.stl'>: package "
        "'nopkg' was not found: no folder 'nopkg' above "),
}


def refusal(urdf: str, tmp_path, capsys, monkeypatch) -> str:
    """The one line `cosim build-fmu --urdf URDF` refuses URDF with (exit 2, nothing written,
    nothing cached), after "--urdf URDF: "."""
    monkeypatch.setenv("COSIM_CACHE", str(tmp_path / "cache"))
    assert main(["build-fmu", "--urdf", urdf, "--output", str(tmp_path / "x.fmu")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"cosim: error: --urdf {urdf}: ")
    assert not (tmp_path / "x.fmu").exists() and not (tmp_path / "cache").exists()
    return err


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_urdf_refused_with_one_message(case, tmp_path, capsys, fmu_cache,
                                                 monkeypatch):
    edit, expected = MALFORMED[case]
    robot = tmp_path / "robot.urdf"
    robot.write_text(edit(OWN_ROBOT.read_text()))
    (tmp_path / "meshes").symlink_to(OWN_ROBOT.parent / "meshes")
    assert expected in refusal(str(robot), tmp_path, capsys, monkeypatch)


# The catalogue's URDFs a user writes by hand or takes from a xacro (issue 49): each was a
# generic message ("not a readable URDF (ValueError: could not convert string to float…)"),
# one that named what the file does not say (<mass value='0'>, "symmetric positive
# semi-definite" of an <inertia> that is missing), or no message at all (1e300 kg).
TURRET_INERTIA = '<inertia ixx="0.008" ixy="0.0005" ixz="0" iyy="0.009" iyz="-0.0004" izz="0.006"/>'
BY_HAND = {
    "a mass in words": (lambda t: t.replace('<mass value="1.2"/>', '<mass value="heavy"/>'),
                        "link 'turret_link' <inertial><mass value='heavy'>: not a number (kg)"),
    "a mass without its value": (
        lambda t: t.replace('<mass value="1.2"/>', "<mass/>"),
        "link 'turret_link' <inertial><mass>: no value='…': give the link's mass in kg, e.g. "
        "<mass value='1.5'/>"),
    "an inertial without its inertia": (
        lambda t: t.replace(TURRET_INERTIA, ""),
        "link 'turret_link' <inertial> has no <inertia>: give ixx, ixy, ixz, iyy, iyz and izz "
        "(kg m^2) about its centre of mass"),
    "a limit in words": (lambda t: t.replace('lower="-1.5"', 'lower="minus three"'),
                         "joint 'wrist' <limit lower='minus three'>: not a number (rad or m)"),
    "a xacro expression": (
        lambda t: t.replace('<mass value="1.2"/>', '<mass value="${m}"/>'),
        "link 'turret_link' <inertial><mass value='${m}'>: a xacro expression, not a number: "
        "expand the xacro first (ROS's xacro makes the URDF)"),
    "a mass of 1e300 kg": (
        lambda t: t.replace('<mass value="1.2"/>', '<mass value="1e300"/>'),
        "link 'turret_link' <inertial><mass value='1e+300'>: outside 1e-12 to 1e+12 kg, the "
        "masses the plant simulates (double precision makes nothing of the dynamics beyond "
        "them); a massless frame has mass 0"),
    "a mass of 1e-300 kg": (
        lambda t: t.replace('<mass value="1.2"/>', '<mass value="1e-300"/>'),
        "link 'turret_link' <inertial><mass value='1e-300'>: outside 1e-12 to 1e+12 kg, the "
        "masses the plant simulates (double precision makes nothing of the dynamics beyond "
        "them); a massless frame has mass 0"),
    "a xacro file": (
        lambda t: t.replace('<robot name="slider_turret">', '<robot name="slider_turret" '
                            'xmlns:xacro="http://www.ros.org/wiki/xacro">\n<xacro:property '
                            'name="m" value="1.2"/>'),
        "a xacro file (<xacro:property> at line 7), not a URDF: expand it first (ROS's xacro: "
        "xacro robot.urdf > robot.urdf) and give the URDF it makes"),
}


@pytest.mark.parametrize("case", sorted(BY_HAND))
def test_a_urdf_written_by_hand_is_refused_naming_the_element(case, tmp_path, capsys,
                                                              monkeypatch):
    edit, expected = BY_HAND[case]
    robot = tmp_path / "robot.urdf"
    robot.write_text(edit(OWN_ROBOT.read_text()))
    (tmp_path / "meshes").symlink_to(OWN_ROBOT.parent / "meshes")
    assert refusal(str(robot), tmp_path, capsys, monkeypatch) == (
        f"cosim: error: --urdf {robot}: {expected}; nothing was written")


def chain(joints: int, fixed_below: int = 0) -> str:
    """A URDF of ``joints`` revolute joints in a row, then ``fixed_below`` fixed links one
    below the other."""
    inertial = ('<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" '
                'ixz="0" iyz="0"/></inertial>')
    parts = ['<robot name="row">', '<link name="l0"/>']
    for i in range(1, joints + 1):
        parts += [f'<link name="l{i}">{inertial}</link>',
                  f'<joint name="j{i}" type="revolute"><parent link="l{i - 1}"/><child '
                  f'link="l{i}"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-3" '
                  'upper="3" effort="10" velocity="2"/></joint>']
    for i in range(fixed_below):
        parts += [f'<link name="f{i}"/>', f'<joint name="x{i}" type="fixed"><parent '
                  f'link="{f"f{i - 1}" if i else f"l{joints}"}"/><child link="f{i}"/></joint>']
    return "\n".join([*parts, "</robot>"])


def test_more_joints_than_the_plant_holds_is_one_message(tmp_path, capsys, monkeypatch):
    """33 moving joints: a ValueError traceback of the chain model, by build-fmu and by a
    pipeline's plant.urdf (each names its own way to shorten the chain)."""
    robot = tmp_path / "row.urdf"
    robot.write_text(chain(33))
    assert refusal(str(robot), tmp_path, capsys, monkeypatch) == (
        f"cosim: error: --urdf {robot}: 33 joints move between base link 'l0' and tip "
        "link 'l33', more than the 32 a URDF plant has: choose a nearer tip (--tip) or hold "
        "joints (--fix NAME=VALUE); nothing was written")
    pipeline = tmp_path / "p.toml"
    pipeline.write_text(f'extends = "{Path("pipelines/pd_control.toml").resolve()}"\n'
                        '[plant]\nurdf = "row.urdf"\n')
    assert main(["run", str(pipeline), "--dry-run"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"cosim: error: plant.urdf: {robot}: 33 joints move between base link 'l0' and tip "
        "link 'l33', more than the 32 a URDF plant has: choose a nearer tip (plant.urdf.tip) "
        "or hold joints (plant.urdf.fixed.NAME = VALUE)")


def test_thousands_of_fixed_links_below_the_last_joint_are_read(tmp_path):
    """3000 fixed links one below the other past the last moving joint, no tip given: a
    RecursionError (the search for the tip recursed once a link); now the tip is the last."""
    robot = tmp_path / "deep.urdf"
    robot.write_text(chain(1, fixed_below=3000))
    read = read_urdf(robot)
    assert (read.joints, read.tip_link) == (("j1",), "f2999")


def test_an_inertia_no_body_has_is_said_and_simulated(tmp_path, capsys):
    """Principal moments that break the triangle inequality (0.001, 0.001, 1): accepted
    silently before. Said now (real URDFs have such links: example-robot-data's Allegro
    hand, PR2 and ANYmal do), and read as given."""
    robot = tmp_path / "robot.urdf"
    robot.write_text(OWN_ROBOT.read_text().replace(
        TURRET_INERTIA, '<inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="1"/>'))
    (tmp_path / "meshes").symlink_to(OWN_ROBOT.parent / "meshes")
    capsys.readouterr()
    read = read_urdf(robot)
    read_urdf(robot)  # said once
    assert capsys.readouterr().err == (
        f"cosim: warning: {robot}: link 'turret_link' <inertial><inertia>: its principal "
        "moments 0.001, 0.001, 1 kg m^2 break the triangle inequality (the two smaller sum to "
        "less than the largest): no rigid body has this inertia; simulated as given\n")
    assert read.n == 4


@pytest.mark.parametrize("given", ["", "folder"])
def test_a_urdf_that_is_a_folder_or_no_name_is_said_to_be(given, tmp_path, capsys,
                                                          monkeypatch):
    """Both said "no such URDF file" (the empty name read as the working folder)."""
    monkeypatch.setenv("COSIM_CACHE", str(tmp_path / "cache"))
    name = str(tmp_path) if given else ""
    assert main(["build-fmu", "--urdf", name, "--output", str(tmp_path / "x.fmu")]) == 2
    assert capsys.readouterr().err == (
        f"cosim: error: --urdf {tmp_path}: is a folder, not a URDF file; nothing "
        "was written\n" if given else
        "cosim: error: --urdf '': an empty name; give the robot's URDF file\n")


@pytest.mark.parametrize(("uri", "expected"), [
    ("package://nosuchpkg/robot.urdf",
     "package 'nosuchpkg' was not found: no folder 'nosuchpkg' above {cwd}, in "
     "$ROS_PACKAGE_PATH ({ws}), in share/ under $AMENT_PREFIX_PATH (not set) or in the Python "
     "environment's cmeel.prefix/share ({cmeel}), and there is no {cwd}/robot.urdf; install "
     "the package, or add the folder that holds it to $ROS_PACKAGE_PATH"),
    ("package://example-robot-data/robots/nosuch.urdf",
     "no such file in package 'example-robot-data' (looked for {robots}/nosuch.urdf)"),
    ("package:///robots/robot.urdf", "the package name is empty (package://NAME/PATH)"),
], ids=["unknown package", "no such file in the package", "no package name"])
def test_unknown_package_refused_saying_where_it_was_looked_for(uri, expected, tmp_path,
                                                                capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "ws"))
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    (tmp_path / "ws").mkdir()
    err = refusal(uri, tmp_path, capsys, monkeypatch)
    assert err.removeprefix(f"cosim: error: --urdf {uri}: ") == expected.format(
        cwd=Path.cwd(), ws=tmp_path / "ws", cmeel=ROBOTS.parent.parent, robots=ROBOTS) + \
        "; nothing was written"


def test_packages_resolve_as_before(tmp_path):
    """example-robot-data's URDFs (pipelines/panda.toml, ur5.toml), and a package that is not
    found but whose path is there in the folder given."""
    panda = "package://example-robot-data/robots/panda_description/urdf/panda.urdf"
    assert resolve_uri(panda, tmp_path) == ARMS["panda"]
    (tmp_path / "robot.urdf").write_text(OWN_ROBOT.read_text())
    assert resolve_uri("package://nosuchpkg/robot.urdf", tmp_path) == tmp_path / "robot.urdf"


def test_equal_limits_are_a_joint_with_one_start_position(tmp_path):
    """lower == upper is read as given (URDFs write 0 and 0 for no limits); the plant bounds
    only q0, so the joint starts there."""
    robot = tmp_path / "robot.urdf"
    robot.write_text(OWN_ROBOT.read_text().replace('lower="-1.5" upper="1.5"',
                                                   'lower="0.2" upper="0.2"'))
    (tmp_path / "meshes").symlink_to(OWN_ROBOT.parent / "meshes")
    chain = read_urdf(robot)
    assert (chain.lower[-1], chain.upper[-1]) == (0.2, 0.2)


def test_pipeline_names_a_urdf_plant(tmp_path, monkeypatch, fmu_cache):
    monkeypatch.setenv("COSIM_CACHE", str(fmu_cache))
    (tmp_path / "robots").mkdir()
    (tmp_path / "robots" / "meshes").symlink_to(OWN_ROBOT.parent / "meshes")
    robot = tmp_path / "robots" / "robot.urdf"
    robot.write_text(OWN_ROBOT.read_text())
    pipeline = tmp_path / "p.toml"
    pipeline.write_text('[plant]\nurdf = { file = "robots/robot.urdf", tip = "hand", '
                        'fixed = { wrist = 0.2 } }\n')
    loaded = load_pipeline(pipeline)
    assert loaded.plant.builtin is None and loaded.plant.urdf.file == str(robot)
    fmu = plant_path(loaded)
    assert fmu == build_urdf_fmu(robot, tip="hand", fixed={"wrist": 0.2}, cache_dir=fmu_cache)
    assert sum(v.name.startswith("q[") for v in read_model_description(fmu).modelVariables) == 3
    # package:// addresses, --set swapping the plant, and one plant at a time
    panda = "package://example-robot-data/robots/panda_description/urdf/panda.urdf"
    swapped = load_pipeline(pipeline, [f'plant.urdf="{panda}"'])
    assert swapped.plant.urdf.file == panda and swapped.plant.urdf.tip is None
    assert load_pipeline(pipeline, ['plant.builtin={links=3}']).plant.urdf is None
    with pytest.raises(PipelineError, match="give one of plant.builtin, plant.fmu or "
                       "plant.urdf, not plant.builtin and plant.urdf"):
        load_pipeline(None, ['plant={builtin={links=3}, urdf="robot.urdf"}'])
    robot.write_text(OWN_ROBOT.read_text().replace('type="continuous"', 'type="floating"'))
    with pytest.raises(PipelineError, match=r"^plant.urdf: .*joint 'turret' has type"):
        plant_path(load_pipeline(pipeline))
