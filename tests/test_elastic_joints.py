"""The second built-in plant: the arm with elastic joints (Spong). Built by the same FMI glue
as the rigid arm (FMI 2 and 3, FMPy's validator clean), checked against an independent
integration of the same equations written here (the links' M, C and G from Pinocchio,
solve_ivp), and against the rigid arm as the joints stiffen."""

from __future__ import annotations

import numpy as np
import pytest
from fmpy.validation import validate_fmu
from fmu_helpers import (
    FmuInstance,
    chain_parameters,
    fmu_parameters,
    pinocchio_chain,
    pinocchio_terms,
)
from scipy.integrate import solve_ivp

from cosim.assemble import assemble
from cosim.blocks import Block, register_block
from cosim.config import PipelineError, Section, load_pipeline
from cosim.runner import run
from cosim.signals import Signal
from plant_fmu import build_fmu

STEP, DURATION = 1e-3, 2.0  # s
TAU_D = 0.01  # N·m, the models' default constant disturbance on every link


def torque(t: float) -> np.ndarray:
    """The motor torques applied, held over each step (N·m)."""
    return np.array([25.0 + 10.0 * np.sin(3.0 * t), 8.0 * np.cos(2.0 * t)])


@pytest.fixture(scope="module")
def elastic(fmu_cache):
    return {v: build_fmu(2, v, cache_dir=fmu_cache, model="elastic_joints") for v in (2, 3)}


@pytest.mark.parametrize("fmi_version", [2, 3])
def test_fmpy_validate_finds_no_problems_and_the_ports_are_the_rigid_arms(elastic, fmi_version):
    from fmpy import read_model_description

    path = elastic[fmi_version]
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    names = {v.name: v for v in md.modelVariables}
    # the rigid arm's interface, so a pipeline for it runs here unchanged, and the extra port
    for name in ("tau[1]", "q[2]", "qdot[2]", "M[2,2]", "theta[1]", "theta[2]"):
        assert name in names, name
    assert names["theta[1]"].causality == "output" and names["theta[1]"].unit == "rad"
    assert [names[n].unit for n in ("k[1]", "d[1]", "J[1]")] == ["N.m/rad", "N.m.s/rad",
                                                                 "kg.m2"]
    assert len(md.derivatives) == 8  # q, q̇, θ, θ̇ per joint
    assert "elastic joints" in md.description


def run_fmu(path, parameters: dict, names: list[str]) -> np.ndarray:
    """Rows of ``names`` at every step (t = 0 first), the torque held over each step."""
    fmu = FmuInstance(str(path), parameters=parameters)
    try:
        rows = [fmu.get(names)]
        for k in range(int(round(DURATION / STEP))):
            fmu.set({"tau[1]": torque(k * STEP)[0], "tau[2]": torque(k * STEP)[1]})
            fmu.do_step(k * STEP, STEP)
            rows.append(fmu.get(names))
        return np.array(rows)
    finally:
        fmu.free()


def reference(chain: dict, k: np.ndarray, d: np.ndarray, J: np.ndarray, x0: np.ndarray,
              g: float = 9.8) -> np.ndarray:
    """[q, q̇, θ] per step from solve_ivp of Spong's equations, written here:
    M q̈ + C q̇ + G + τ_d = k(θ − q) + d(θ̇ − q̇),  J θ̈ + k(θ − q) + d(θ̇ − q̇) = τ."""
    model = pinocchio_chain(chain["m"], chain["l"], chain["lc"], chain["I"], g)
    rows, x = [x0[:6]], x0.copy()
    for step in range(int(round(DURATION / STEP))):
        tau = torque(step * STEP)

        def rhs(_, s, tau=tau):
            q, qd, th, thd = s[:2], s[2:4], s[4:6], s[6:]
            spring = k * (th - q) + d * (thd - qd)
            M, coriolis, gravity = pinocchio_terms(model, q, qd)
            qdd = np.linalg.solve(M, spring - coriolis - gravity - TAU_D)
            return np.concatenate([qd, qdd, thd, (tau - spring) / J])

        x = solve_ivp(rhs, (step * STEP, (step + 1) * STEP), x, method="DOP853", rtol=1e-12,
                      atol=1e-12).y[:, -1]
        rows.append(x[:6])
    return np.array(rows)


@pytest.mark.parametrize("fmi_version", [2, 3])
def test_the_fmu_equals_an_independent_integration(elastic, fmi_version):
    """A chain with centre-of-mass offsets and inertias, springs soft enough to deflect
    (k = 2000, 800 N·m/rad), an initial deflection: q, q̇ and the motor angle θ within 1e-6
    of their range over 2 s."""
    chain = chain_parameters(2, np.random.default_rng(5))
    k, d, J = np.array([2000.0, 800.0]), np.array([8.0, 3.0]), np.array([0.05, 0.02])
    q0, qd0, deflection0 = np.array([0.3, -0.4]), np.array([1.0, -2.0]), np.array([0.02, 0.0])
    parameters = fmu_parameters(chain, k=k, d=d, J=J, q0=q0, qdot0=qd0,
                                deflection0=deflection0)
    names = ["q[1]", "q[2]", "qdot[1]", "qdot[2]", "theta[1]", "theta[2]"]
    fmu = run_fmu(elastic[fmi_version], parameters, names)
    expected = reference(chain, k, d, J, np.concatenate([q0, qd0, q0 + deflection0, qd0]))
    stretch = fmu[:, 4:] - fmu[:, :2]
    assert np.ptp(fmu[:, 0]) > 1.0 and np.abs(stretch).max() > 1e-3  # it moved and deflected
    for column, name in enumerate(names):
        scale = np.abs(expected[:, column]).max()
        error = np.abs(fmu[:, column] - expected[:, column]).max()
        assert error <= 1e-6 * scale, (name, error, scale)


def test_stiff_joints_approach_the_rigid_arm(elastic, plant_fmu):
    """Stiff joints and light motors (k → ∞, J → 0) make the rigid arm: with k = 1/J the
    link angles' gap to the rigid arm's (same links, same torque) falls tenfold per step and
    is below 1e-3 rad at k = 1e5 N·m/rad over 2 s. (At a fixed J the gap stays: the spring
    passes the motor torque less J θ̈, so the limit is the rigid arm with J added to M's
    diagonal; measured, the gap is proportional to J.)"""
    chain = {"m": np.array([0.8, 2.3]), "l": np.ones(2), "lc": np.ones(2), "I": np.zeros(2)}
    rigid = run_fmu(plant_fmu(2, 2), fmu_parameters(chain), ["q[1]", "q[2]"])
    gaps = []
    for stiffness in (1e3, 1e4, 1e5):
        J = 1.0 / stiffness
        damping = 1.4 * np.sqrt(stiffness * J)  # damping ratio 0.7
        step = 0.1 / np.sqrt(stiffness / J)  # RK4 at ω h = 0.1 of the spring mode
        parameters = fmu_parameters(chain, k=[stiffness] * 2, d=[damping] * 2, J=[J] * 2,
                                    rk4_step=step)
        elastic_q = run_fmu(elastic[2], parameters, ["q[1]", "q[2]"])
        gaps.append(float(np.abs(elastic_q - rigid).max()))
    assert np.ptp(rigid[:, 0]) > 1.0
    assert gaps[1] < 0.2 * gaps[0] and gaps[2] < 0.2 * gaps[1], gaps
    assert gaps[2] < 1e-3, gaps


class SpringDeflection(Block):
    """Reads the elastic arm's extra port by its name: θ − q per joint."""

    kind = "spring_deflection"
    Params = Section

    def __init__(self, params, context):
        super().__init__(params, context)
        self.inputs = ("theta", "q")
        self.outputs = {"deflection": Signal("n", "rad", "spring deflection θ − q",
                                             "spring/deflection")}

    def reset(self, ports):
        self.theta, self.q = ports.inputs["theta"], ports.inputs["q"]
        self.out = ports.outputs["deflection"]

    def step(self, k):
        self.out[k] = self.theta[k] - self.q[k]
        return True


def test_the_motor_angles_are_a_port_a_block_reads_by_name():
    """The elastic arm's motor angles θ are one port (cosim.plant.ports) and one variable
    family: a run maps them on its own, the trace holds them, a block reads them by name and
    the spring carries the torque (k (θ − q) follows τ); the rigid arm has no such port, and
    a block reading it there is refused naming the port."""
    register_block(SpringDeflection)
    chain = '["reference", "sensor", "inertia_model", "pd_controller", "spring_deflection"]'
    pipeline = load_pipeline("pipelines/elastic_joints.toml",
                             ["simulation.duration=1", f"runs.pd.blocks={chain}"])
    pipeline.runs = {"pd": pipeline.runs["pd"]}
    trace = run(pipeline, None, progress=False)["pd"].trace
    theta, q, tau = trace["theta"], trace["q"], trace["tau"]
    assert np.isfinite(theta).all()
    np.testing.assert_array_equal(trace["deflection"], theta - q)
    # The motor J θ̈ = τ − k (θ − q) − d (θ̇ − q̇): over the run the spring passes the motor
    # torque on, the mean of k (θ − q) is τ's, less J Δθ̇/T and d Δ(θ − q)/T (measured:
    # within 0.2 %, at PD torques of several kN·m).
    stiffness = 1e5  # N·m/rad, the pipeline's k
    spring = stiffness * (theta - q)
    np.testing.assert_allclose(spring[:-1].mean(axis=0), tau[:-1].mean(axis=0), rtol=0.01)
    assert np.abs(tau[:-1].mean(axis=0)).min() > 50  # a mean torque the check can see
    rigid = load_pipeline("pipelines/pd_control.toml",
                          ["simulation.duration=1", f"runs.pd_full_state.blocks={chain}"])
    with pytest.raises(PipelineError, match="reads 'theta', which nothing before it produces "
                       r"\(PlanarArm.*does not map it \(plant.variables.theta\)\)"):
        assemble(rigid)
