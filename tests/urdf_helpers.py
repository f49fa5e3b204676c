"""The URDF plant's references, shared by tests/test_urdf_plant.py and
benchmarks/bench_urdf.py: Pinocchio's model of the same URDF (its own parser, our folding of
held joints done by its buildReducedModel), random states within the joints' limits, the
plant FMU's M, h and q̈ at a state through FMPy's Model Exchange calls, and both compared:
at random states, and along the Panda's free swing against SciPy's solve_ivp."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
from fmu_helpers import FmuInstance
from scipy.integrate import solve_ivp

from plant_fmu.urdf import Chain, package_dirs

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
# cosim's own test robot: a prismatic, a continuous and two revolute joints (one about a skew
# axis), fixed joints at the base, mid-arm (with mass) and the flange.
OWN_ROBOT = Path(__file__).parent / "urdf" / "slider_turret.urdf"
FC_VEL = 0.01  # the FMU's default Coulomb smoothing velocity, rad/s (m/s)


def pinocchio_model(path, chain: Chain, payload: float = 0.0) -> pin.Model:
    """Pinocchio's model of the same URDF: the joints the chain holds locked at the same
    values (Pinocchio lumps them into their parent, as our reader does), the chain's gravity,
    and the payload as a point mass at the tip frame's origin."""
    model = pin.buildModelFromUrdf(str(path))
    held = dict(chain.held)
    if held:
        q_ref = pin.neutral(model)
        for name, value in held.items():
            q_ref[model.joints[model.getJointId(name)].idx_q] = value
        model = pin.buildReducedModel(model, [model.getJointId(n) for n in held], q_ref)
    model.gravity.linear = np.asarray(chain.gravity, float)
    if payload:
        model.inertias[model.njoints - 1] += pin.Inertia(payload, chain.tip[:3, 3],
                                                         np.zeros((3, 3)))
    return model


def configuration(model: pin.Model, q) -> np.ndarray:
    """Pinocchio's configuration vector of joint positions q (a continuous joint is its
    (cos, sin))."""
    parts = [[np.cos(x), np.sin(x)] if model.joints[i + 1].nq == 2 else [x]
             for i, x in enumerate(q)]
    return np.concatenate(parts)


def random_states(chain: Chain, rng: np.random.Generator, count: int):
    """``count`` rows of q (within the limits, at most ±π), q̇ (±2 rad/s or m/s, at most the
    velocity limit) and τ (±20 N·m or N, at most the effort limit)."""
    low, high = np.maximum(chain.lower, -np.pi), np.minimum(chain.upper, np.pi)
    q = rng.uniform(low, high, (count, chain.n))
    speed = np.minimum(chain.velocity, 2.0)
    effort = np.minimum(chain.effort, 20.0)
    return q, rng.uniform(-speed, speed, (count, chain.n)), rng.uniform(-effort, effort,
                                                                         (count, chain.n))


def losses(chain: Chain, qd) -> np.ndarray:
    """The joints' friction as the FMU models it: b q̇ + fc tanh(q̇ / fc_vel)."""
    return chain.damping * qd + chain.friction * np.tanh(np.asarray(qd) / FC_VEL)


def pinocchio_terms(model: pin.Model, data: pin.Data, chain: Chain, q, qd, tau):
    """M (CRBA), h (RNEA at q̈ = 0) and q̈ (ABA, with the FMU's friction) by Pinocchio."""
    x = configuration(model, q)
    M = pin.crba(model, data, x)
    M = np.triu(M) + np.triu(M, 1).T
    h = pin.rnea(model, data, x, qd, np.zeros(chain.n)).copy()
    qdd = pin.aba(model, data, x, qd, tau - losses(chain, qd)).copy()
    return M, h, qdd


class ChainFmu:
    """The plant FMU in Model Exchange: set a state and τ, read M, h and q̈."""

    def __init__(self, path, parameters: dict | None = None):
        self.instance = FmuInstance(path, "ModelExchange", parameters)
        i = self.instance
        self.n = i.n
        self.refs = {base: i.refs(i.names(base)) for base in ("M", "h", "tau")}

    def terms(self, q, qd, tau):
        i = self.instance
        i.set_states(np.concatenate([q, qd]))
        i.set(dict(zip(i.names("tau"), tau, strict=True)))
        M = i.get(i.names("M")).reshape(self.n, self.n)
        return M, i.get(i.names("h")), i.derivatives()[self.n:]

    def free(self):
        self.instance.free()


def relative_error(value, reference) -> float:
    """The largest difference relative to the reference's largest magnitude."""
    reference = np.asarray(reference)
    return float(np.abs(np.asarray(value) - reference).max() / np.abs(reference).max())


def dynamics_errors(path, fmu: Path, chain: Chain, payload: float, rng: np.random.Generator,
                    states: int) -> np.ndarray:
    """The largest relative error of the FMU's M, h and q̈ against Pinocchio's, carrying
    ``payload`` kg at the tip, over ``states`` random states."""
    model = pinocchio_model(path, chain, payload=payload)
    data = model.createData()
    plant = ChainFmu(fmu, {"payload": payload})
    worst = np.zeros(3)
    try:
        for q, qd, tau in zip(*random_states(chain, rng, states), strict=True):
            pairs = zip(plant.terms(q, qd, tau), pinocchio_terms(model, data, chain, q, qd, tau),
                        strict=True)
            worst = np.maximum(worst, [relative_error(a, b) for a, b in pairs])
    finally:
        plant.free()
    return worst


# The Panda's free swing (τ = 0) for 2 s from a pose away from its neutral one
SWING_Q0 = np.array([0.3, -0.5, 0.2, -1.8, 0.4, 1.2, -0.3])  # rad
SWING_QDOT0 = np.array([0.5, -0.3, 0.2, 0.4, -0.6, 0.3, 0.8])  # rad/s


def panda_swing(fmu: Path, chain: Chain, damping: np.ndarray, rk4_step: float | None = None,
                rk4_motion: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The Panda FMU's q every 10 ms over the swing (Co-Simulation, its RK4 at ``rk4_step``
    s and ``rk4_motion`` rad, or their defaults) and SciPy's DOP853 (tolerances 1e-13) on
    Pinocchio's ABA with the same joint ``damping`` (N·m·s/rad): (the FMU's q, the
    reference's q and q̇), rad, rad/s."""
    model = pinocchio_model(ARMS["panda"], chain)
    data = model.createData()

    def rhs(_, x):
        q, qd = x[:7], x[7:]
        return np.concatenate([qd, pin.aba(model, data, q, qd, -damping * qd)])

    times = np.linspace(0.0, 2.0, 201)
    reference = solve_ivp(rhs, (0.0, 2.0), np.concatenate([SWING_Q0, SWING_QDOT0]),
                          method="DOP853", t_eval=times, rtol=1e-13, atol=1e-13).y.T
    start = {key: value for key, value in (("rk4_step", rk4_step), ("rk4_motion", rk4_motion))
             if value is not None}
    for i in range(7):
        start.update({f"q0[{i + 1}]": SWING_Q0[i], f"qdot0[{i + 1}]": SWING_QDOT0[i],
                      f"b[{i + 1}]": damping[i]})
    plant = FmuInstance(fmu, "CoSimulation", start)
    try:
        trace = [plant.get(plant.names("q"))]
        for t in times[:-1]:
            plant.do_step(t, times[1] - times[0])
            trace.append(plant.get(plant.names("q")))
    finally:
        plant.free()
    return np.array(trace), reference[:, :7], reference[:, 7:]
