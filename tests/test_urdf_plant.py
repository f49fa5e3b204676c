"""The URDF plant: the reader (plant_fmu/urdf.py) against Pinocchio's own URDF parser, on
real arms from example-robot-data (a test extra, never copied into the repo)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from plant_fmu.urdf import Chain, package_dirs, read_urdf

ROBOTS = package_dirs("example-robot-data")[0] / "robots"
ARMS = {
    "ur5": ROBOTS / "ur_description/urdf/ur5_robot.urdf",
    "ur10": ROBOTS / "ur_description/urdf/ur10_robot.urdf",
    "panda": ROBOTS / "panda_description/urdf/panda.urdf",
    "kinova": ROBOTS / "kinova_description/robots/kinova.urdf",
    "xarm7": ROBOTS / "xarm_description/urdf/xarm7.urdf",
    "z1": ROBOTS / "z1_description/urdf/z1.urdf",
    "so101": ROBOTS / "so_arm_description/urdf/so101.urdf",
}


def pinocchio_model(path, chain: Chain) -> pin.Model:
    """Pinocchio's model of the same URDF, with the joints the chain holds locked at the
    same values (Pinocchio lumps them into their parent, as our reader does)."""
    model = pin.buildModelFromUrdf(str(path))
    held = dict(chain.held)
    if not held:
        return model
    q_ref = pin.neutral(model)
    for name, value in held.items():
        q_ref[model.joints[model.getJointId(name)].idx_q] = value
    return pin.buildReducedModel(model, [model.getJointId(n) for n in held], q_ref)


def joint_axis(model: pin.Model, i: int) -> tuple[int, np.ndarray]:
    """(kind, unit axis) of Pinocchio's joint i from its motion subspace S."""
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    s = np.asarray(data.joints[i].S).reshape(6, -1)[:, 0]
    return (0, s[3:]) if np.linalg.norm(s[3:]) > 0 else (1, s[:3])


@pytest.mark.parametrize("arm", sorted(ARMS))
def test_reader_matches_pinocchio_parser(arm):
    path = ARMS[arm]
    chain = read_urdf(path)
    model = pinocchio_model(path, chain)
    assert tuple(model.names[1:]) == chain.joints
    for i in range(chain.n):
        kind, axis = joint_axis(model, i + 1)
        assert kind == chain.kind[i]
        np.testing.assert_allclose(chain.axis[i], axis, atol=1e-15)
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
    np.testing.assert_allclose(chain.lower[3:4], [-3.0718])
    np.testing.assert_allclose(chain.effort, [87] * 4 + [12] * 3)
