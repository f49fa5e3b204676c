"""The plant FMU, run for real through FMPy and checked against things we did not write:
FMPy's validator, Pinocchio's rigid-body algorithms, SciPy's integrators, finite differences."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from fmu_helpers import (
    FmuInstance,
    chain_parameters,
    fmu_parameters,
    pinocchio_chain,
    pinocchio_terms,
)
from scipy.integrate import solve_ivp

from plant_fmu import BuildError, build_fmu

VERSIONS = [2, 3]
PAPER = dict(m=[0.8, 2.3], l=[1.0, 1.0], g=9.8)


@pytest.mark.parametrize("links", [2, 3])
@pytest.mark.parametrize("fmi_version", VERSIONS)
def test_fmpy_validate_finds_no_problems(plant_fmu, links, fmi_version):
    path = plant_fmu(links, fmi_version)
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    assert md.coSimulation is not None and md.modelExchange is not None
    names = {v.name for v in md.modelVariables}
    assert {"tau[1]", f"q[{links}]", f"qdot[{links}]", f"M[{links},{links}]", "energy"} <= names
    units = {v.name: v.unit for v in md.modelVariables}
    assert (units["q[1]"], units["qdot[1]"], units["tau[1]"]) == ("rad", "rad/s", "N.m")
    displays = {u.name: [d.name for d in u.displayUnits] for u in md.unitDefinitions}
    assert displays["rad"] == ["deg"] and displays["rad/s"] == ["deg/s"]


def test_archive_carries_sources_for_fmpy_compile(plant_fmu):
    with zipfile.ZipFile(plant_fmu(2, 3)) as archive:
        names = set(archive.namelist())
    assert {"sources/buildDescription.xml", "sources/model.c", "sources/planar_chain.h",
            "sources/rk4.h", "sources/model.h", "sources/fmu_instance.c",
            "sources/fmi3.c", "sources/variables.c", "modelDescription.xml"} <= names
    assert any(n.startswith("binaries/") and n.endswith("PlanarArm.so") for n in names)


def test_build_is_cached_and_safe_to_repeat(fmu_cache, tmp_path):
    first = build_fmu(2, 2, cache_dir=fmu_cache)
    mtime = first.stat().st_mtime_ns
    again = build_fmu(2, 2, cache_dir=fmu_cache, output=tmp_path / "arm.fmu")
    assert first.stat().st_mtime_ns == mtime  # not rebuilt
    assert again.read_bytes() == first.read_bytes()


@pytest.mark.parametrize("bad", [dict(links=0), dict(links=8), dict(fmi_version=1)])
def test_build_rejects_bad_options(bad, fmu_cache):
    with pytest.raises(BuildError, match="links|fmi_version"):
        build_fmu(cache_dir=fmu_cache, **bad)


@pytest.mark.parametrize("links", [2, 3, 5])
@pytest.mark.parametrize("fmi_version", VERSIONS)
def test_dynamics_agree_with_pinocchio(plant_fmu, links, fmi_version):
    """M(q), C(q, q̇)q̇ and G(q) at random states of chains with non-trivial lc and I."""
    rng = np.random.default_rng(links)
    params = chain_parameters(links, rng)
    g = 9.81
    model = pinocchio_chain(params["m"], params["l"], params["lc"], params["I"], g)
    inst = FmuInstance(plant_fmu(links, fmi_version), "ModelExchange",
                       fmu_parameters(params, g=g, tau_d=np.zeros(links)))
    try:
        for _ in range(10):
            q, v = rng.uniform(-np.pi, np.pi, links), rng.uniform(-5, 5, links)
            M_ref, Cv_ref, G_ref = pinocchio_terms(model, q, v)
            # FMU's bias from its derivatives at zero torque: q̈ = -M⁻¹ (C v + G).
            inst.set_states(np.concatenate([q, v]))
            M = inst.get(inst.names("M")).reshape(links, links)
            bias = -M @ inst.derivatives()[links:]
            inst.set_states(np.concatenate([q, np.zeros(links)]))
            G = -M @ inst.derivatives()[links:]
            scale = np.abs(M_ref).max()
            assert np.abs(M - M_ref).max() <= 1e-10 * scale
            assert np.abs(G - G_ref).max() <= 1e-10 * np.abs(G_ref).max()
            assert np.abs((bias - G) - Cv_ref).max() <= 1e-10 * max(1.0, np.abs(Cv_ref).max())
    finally:
        inst.free()


def paper_closed_form(q, qd, m1=0.8, m2=2.3, a1=1.0, a2=1.0, g=9.8):
    """The paper's arm: Lewis's two-link arm with point masses at the tips."""
    c2, s2 = np.cos(q[1]), np.sin(q[1])
    M = np.array([[(m1 + m2) * a1**2 + m2 * a2**2 + 2 * m2 * a1 * a2 * c2,
                   m2 * a2**2 + m2 * a1 * a2 * c2],
                  [m2 * a2**2 + m2 * a1 * a2 * c2, m2 * a2**2]])
    Vm_qd = np.array([-m2 * a1 * a2 * (2 * qd[0] * qd[1] + qd[1] ** 2) * s2,
                      m2 * a1 * a2 * qd[0] ** 2 * s2])
    G = np.array([(m1 + m2) * g * a1 * np.cos(q[0]) + m2 * g * a2 * np.cos(q[0] + q[1]),
                  m2 * g * a2 * np.cos(q[0] + q[1])])
    return M, Vm_qd, G


@pytest.mark.parametrize("fmi_version", VERSIONS)
def test_default_arm_is_the_papers_closed_form(plant_fmu, fmi_version):
    """Defaults alone (no parameters set) reproduce the paper's arm, disturbance 0.01 N·m
    included."""
    inst = FmuInstance(plant_fmu(2, fmi_version), "ModelExchange")
    rng = np.random.default_rng(7)
    try:
        assert np.allclose(inst.state(), [0.1, 0.1, 10.0, 10.0])
        for _ in range(10):
            q, qd = rng.uniform(-np.pi, np.pi, 2), rng.uniform(-10, 10, 2)
            tau = rng.uniform(-50, 50, 2)
            inst.set_states(np.concatenate([q, qd]))
            inst.set({"tau[1]": tau[0], "tau[2]": tau[1]})
            M, Vm_qd, G = paper_closed_form(q, qd)
            qdd_ref = np.linalg.solve(M, tau - Vm_qd - G - 0.01)
            assert np.allclose(inst.get(inst.names("M")).reshape(2, 2), M, rtol=0, atol=1e-12)
            assert np.allclose(inst.derivatives()[2:], qdd_ref, rtol=1e-11, atol=1e-11)
    finally:
        inst.free()


@pytest.mark.parametrize("fmi_version", VERSIONS)
def test_energy_is_conserved_without_friction_or_disturbance(plant_fmu, fmi_version):
    inst = FmuInstance(plant_fmu(3, fmi_version), "CoSimulation",
                       fmu_parameters({"tau_d": np.zeros(3), "lc": [0.5, 0.6, 0.4],
                                       "I": [0.1, 0.05, 0.02]}))
    try:
        energy = [inst.get(["energy"])[0]]
        h = 1e-3
        for k in range(10_000):
            inst.do_step(k * h, h)
            energy.append(inst.get(["energy"])[0])
        energy = np.array(energy)
        assert np.abs(energy - energy[0]).max() <= 1e-6 * abs(energy[0])
        assert np.ptp(inst.state()) > 0  # it did move
    finally:
        inst.free()


def pinocchio_rhs(model, tau_d):
    import pinocchio as pin

    data = model.createData()

    def rhs(t, x, tau):
        n = len(x) // 2
        qdd = pin.aba(model, data, x[:n], x[n:], tau - tau_d)
        return np.concatenate([x[n:], qdd])

    return rhs


def piecewise_torque(t_switch: np.ndarray, values: np.ndarray, t: float) -> np.ndarray:
    return values[np.searchsorted(t_switch, t, side="right") - 1]


@pytest.mark.parametrize("comm_step", [1e-3, 1e-2])
@pytest.mark.parametrize("fmi_version", VERSIONS)
def test_cosimulation_agrees_with_solve_ivp(plant_fmu, fmi_version, comm_step):
    """Piecewise-constant torque; reference: DOP853 at rtol 1e-12 over Pinocchio's ABA."""
    rng = np.random.default_rng(3)
    t_switch = np.arange(0.0, 2.0, 0.1)
    torques = rng.uniform(-20, 20, (len(t_switch), 2))
    rhs = pinocchio_rhs(pinocchio_chain([0.8, 2.3], [1, 1], [1, 1], [0, 0], 9.8), 0.01)
    inst = FmuInstance(plant_fmu(2, fmi_version))
    x_ref = np.array([0.1, 0.1, 10.0, 10.0])
    worst = 0.0
    try:
        steps = int(round(2.0 / comm_step))
        for k in range(steps):
            t0 = k * comm_step
            tau = piecewise_torque(t_switch, torques, t0 + 1e-12)
            inst.set({"tau[1]": tau[0], "tau[2]": tau[1]})
            inst.do_step(t0, comm_step)
            sol = solve_ivp(rhs, (t0, t0 + comm_step), x_ref, method="DOP853", rtol=1e-12,
                            atol=1e-12, args=(tau,))
            x_ref = sol.y[:, -1]
            worst = max(worst, np.abs(inst.state()[:2] - x_ref[:2]).max())
        assert worst <= 1e-7, f"max |q - q_ref| = {worst:.2e} rad"
    finally:
        inst.free()


@pytest.mark.parametrize("fmi_version", VERSIONS)
def test_model_exchange_with_cvode_agrees_with_solve_ivp(plant_fmu, fmi_version):
    tau = np.array([5.0, -2.0])
    rhs = pinocchio_rhs(pinocchio_chain([0.8, 2.3], [1, 1], [1, 1], [0, 0], 9.8), 0.01)
    t_out = np.linspace(0, 2, 201)
    ref = solve_ivp(rhs, (0, 2), [0.1, 0.1, 10, 10], method="DOP853", rtol=1e-12, atol=1e-12,
                    t_eval=t_out, args=(tau,))
    result = simulate_fmu(str(plant_fmu(2, fmi_version)), fmi_type="ModelExchange",
                          solver="CVode", relative_tolerance=1e-10, stop_time=2.0,
                          output_interval=0.01, start_values={"tau[1]": 5.0, "tau[2]": -2.0},
                          output=["q[1]", "q[2]"])
    q = np.column_stack([np.interp(t_out, result["time"], result[f"q[{i}]"]) for i in (1, 2)])
    assert np.abs(q - ref.y[:2].T).max() <= 1e-5


@pytest.mark.parametrize("fmi_version", VERSIONS)
def test_state_restore_and_serialization_are_bit_exact(plant_fmu, fmi_version):
    inst = FmuInstance(plant_fmu(2, fmi_version))
    fmu = inst.fmu
    h = 1e-3

    def run(k0, count):
        out = []
        for k in range(k0, k0 + count):
            inst.set({"tau[1]": np.sin(k * h), "tau[2]": 0.5})
            inst.do_step(k * h, h)
            out.append(np.concatenate([inst.state(), inst.get(["energy"])]))
        return np.array(out)

    get_state = fmu.getFMUstate if fmi_version == 2 else fmu.getFMUState
    set_state = fmu.setFMUstate if fmi_version == 2 else fmu.setFMUState
    serialize = fmu.serializeFMUstate if fmi_version == 2 else fmu.serializeFMUState
    deserialize = fmu.deSerializeFMUstate if fmi_version == 2 else fmu.deserializeFMUState
    try:
        run(0, 100)
        state = get_state()
        blob = bytes(serialize(state))
        first = run(100, 200)
        set_state(state)
        assert np.array_equal(run(100, 200), first)
        set_state(deserialize(blob))
        assert np.array_equal(run(100, 200), first)
    finally:
        inst.free()


@pytest.mark.parametrize("fmi_version", VERSIONS)
def test_directional_derivatives_agree_with_finite_differences(plant_fmu, fmi_version):
    links = 3
    inst = FmuInstance(plant_fmu(links, fmi_version), "ModelExchange",
                       fmu_parameters({"lc": [0.5, 0.4, 0.7], "I": [0.1, 0.2, 0.05],
                                       "b": [0.3, 0.2, 0.1], "fc": [0.5, 0.5, 0.5]}, fc_vel=0.5))
    rng = np.random.default_rng(11)
    knowns = inst.names("q") + inst.names("qdot") + inst.names("tau")
    unknowns = inst.names("qdot") + [f"der(qdot[{i + 1}])" for i in range(links)] \
        + inst.names("M") + ["energy"]
    x0 = np.concatenate([rng.uniform(-2, 2, links), rng.uniform(-3, 3, links)])
    tau0 = rng.uniform(-10, 10, links)

    def evaluate(z):
        inst.set_states(z[:2 * links])
        inst.set({f"tau[{i + 1}]": z[2 * links + i] for i in range(links)})
        return inst.get(unknowns)

    try:
        z0 = np.concatenate([x0, tau0])
        evaluate(z0)
        jac = np.column_stack([inst.directional_derivative(unknowns, knowns, e)
                               for e in np.eye(len(knowns))])
        eps = 1e-6
        fd = np.column_stack([(evaluate(z0 + eps * e) - evaluate(z0 - eps * e)) / (2 * eps)
                              for e in np.eye(len(knowns))])
        assert np.abs(jac - fd).max() <= 1e-6 * max(1.0, np.abs(fd).max())
        # A random seed is the same linear combination of the columns.
        evaluate(z0)
        seed = rng.normal(size=len(knowns))
        assert np.allclose(inst.directional_derivative(unknowns, knowns, seed), jac @ seed,
                           rtol=1e-12, atol=1e-9)
    finally:
        inst.free()


INVALID_PARAMETERS = [
    ("m[1]", 0.0), ("m[2]", -1.0), ("l[1]", 0.0), ("l[2]", float("nan")),
    ("lc[1]", float("inf")), ("I[2]", -0.1), ("b[1]", -1.0), ("fc[2]", -0.5),
    ("fc_vel", 0.0), ("tau_d[1]", float("nan")), ("tau_d_freq[1]", -1.0), ("g", float("inf")),
    ("q0[2]", float("nan")), ("qdot0[1]", float("-inf")), ("rk4_step", 0.0),
]


@pytest.mark.parametrize("name,value", INVALID_PARAMETERS)
@pytest.mark.parametrize("fmi_version", VERSIONS)
def test_invalid_parameter_is_refused_with_its_name(plant_fmu, fmi_version, name, value):
    inst = FmuInstance(plant_fmu(2, fmi_version), initialize=False)
    try:
        inst.fmu.enterInitializationMode()
        with pytest.raises(FMICallException):
            inst.set({name: value})
        assert any(name in m and "not valid" in m for m in inst.messages), inst.messages
        inst.fmu.exitInitializationMode()  # the bad value was not taken
        inst.do_step(0.0, 1e-3)
        assert np.all(np.isfinite(inst.state()))
    finally:
        inst.free()


@pytest.mark.parametrize("fmi_version", VERSIONS)
def test_non_finite_torque_is_refused_and_trajectory_stays_finite(plant_fmu, fmi_version):
    inst = FmuInstance(plant_fmu(2, fmi_version))
    try:
        inst.set({"tau[1]": 3.0})
        with pytest.raises(FMICallException):
            inst.set({"tau[2]": float("nan")})
        assert any("tau[2]" in m for m in inst.messages), inst.messages
        inst.do_step(0.0, 1e-3)
        assert np.all(np.isfinite(inst.state()))
        assert inst.get(["tau[1]", "tau[2]"]).tolist() == [3.0, 0.0]
    finally:
        inst.free()


@pytest.mark.parametrize("fmi_version", VERSIONS)
def test_massless_tip_is_refused_at_initialization(plant_fmu, fmi_version):
    inst = FmuInstance(plant_fmu(2, fmi_version), initialize=False)
    try:
        inst.fmu.enterInitializationMode()
        inst.set({"lc[2]": 0.0, "I[2]": 0.0})
        with pytest.raises(FMICallException):
            inst.fmu.exitInitializationMode()
        assert any("singular" in m for m in inst.messages), inst.messages
    finally:
        inst.free()


def test_cosimulation_lands_on_variable_communication_points(plant_fmu):
    inst = FmuInstance(plant_fmu(2, 3))
    try:
        t = 0.0
        for h in [1e-3, 2.5e-4, 7e-3, 1e-2, 3.3e-5]:
            inst.do_step(t, h)
            t += h
        assert inst.get(["time"])[0] == pytest.approx(t, abs=1e-15)
        with pytest.raises(FMICallException):
            inst.do_step(t + 0.5, 1e-3)  # not the FMU's current time
        assert any("communication point" in m for m in inst.messages)
    finally:
        inst.free()


def test_a_variable_family_whose_c_name_is_taken_is_refused_naming_both():
    """der(qdot) is VR_qddot in C: an output family named qddot would define the macro again
    and one of the two would silently read the other's values (gcc only warns)."""
    from types import SimpleNamespace

    from plant_fmu.description import variables_header
    from plant_fmu.models import planar_arm
    from plant_fmu.variables import VariableFamily, expand

    acceleration = VariableFamily("qddot", "n", "output", "continuous", "rad/s2",
                                  "Joint acceleration, as an output")
    model = SimpleNamespace(MODEL_IDENTIFIER="ArmWithAcceleration",
                            variables=lambda n: expand((*planar_arm.FAMILIES, acceleration), n))
    with pytest.raises(ValueError, match=r"ArmWithAcceleration: the variable families "
                       r"'der\(qdot\)' and 'qddot' both make the C name VR_qddot; rename one"):
        variables_header(model, 2, "{token}")
    assert "#define VR_qddot" in variables_header(planar_arm, 2, "{token}")
