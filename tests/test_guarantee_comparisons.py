"""Every parameter the filter's guarantee rests on, compared with the plant (issue 52, item
2): each rule of the classifier (cosim/paper/guarantee.py) in both directions (just within
what is declared: covered; just past it, above or below: outside, naming the key and both
values), at every joint and at several at once; and the URDF reader's held joints at angles
other than zero against Pinocchio's own reduced model. Synthetic traces (tests/
test_guarantee.py's), the classifier's own path. SI units, radians."""

from __future__ import annotations

import numpy as np
import pytest
from test_guarantee import DECLARED, DEFAULTS, NOMINAL, OUTPUT_FEEDBACK, conclude, make_trace

from cosim.declared import Uncertainty
from cosim.dynamics.model import friction_table, planar_model
from cosim.paper.within_bounds import (
    plant_payload,
    rigid_chain_parameters,
    system_differences,
    undeclared_differences,
)
from cosim.signals import Signal, Trace

DELTA = 1e-6  # past or short of a declared bound by this much
EXACT = 2e-9  # past the classifier's tolerance for a parameter not declared uncertain (1e-9)
LINKS = (1, 2)
# the nominal model's friction (b̂, f̂c, smoothing) and the declared bounds on the plant's
# departure from it, per joint: different at each joint, so that a rule reading the wrong
# joint's row is caught
DAMPING, COULOMB, SMOOTHING = np.array([0.5, 0.7]), np.array([1.0, 2.0]), np.array([0.05, 0.1])
DAMPING_ERROR, COULOMB_ERROR = np.array([0.1, 0.2]), np.array([0.3, 0.4])


def smoothing_model():
    """The nominal model with the friction above, one smoothing velocity for both joints
    (the planar plant has one fc_vel)."""
    return planar_model([0.8, 2.3], [1.0, 1.0], [1.0, 1.0], [0.0, 0.0], 9.8,
                        friction_table(2, DAMPING, COULOMB, SMOOTHING[0], DAMPING_ERROR,
                                       COULOMB_ERROR))


def with_friction(changes: dict) -> dict:
    """The classifier on a plant with the nominal friction (b, fc, fc_vel the nominal's
    unless ``changes`` says otherwise)."""
    plant = {**{f"b[{i}]": DAMPING[i - 1] for i in LINKS},
             **{f"fc[{i}]": COULOMB[i - 1] for i in LINKS}, "fc_vel": SMOOTHING[0]}
    return conclude(make_trace(), {**plant, **changes}, nominal_model=smoothing_model())


@pytest.mark.parametrize("joint", LINKS)
@pytest.mark.parametrize("side", (1.0, -1.0))
@pytest.mark.parametrize(("name", "nominal", "declared", "key"), [
    ("b", DAMPING, DAMPING_ERROR, "uncertainty.viscous_friction"),
    ("fc", COULOMB, COULOMB_ERROR, "uncertainty.coulomb_friction"),
])
def test_friction_within_its_declared_bound_is_covered_and_past_it_outside(
        name, nominal, declared, key, side, joint):
    within = nominal[joint - 1] + side * (declared[joint - 1] - DELTA)
    g = with_friction({f"{name}[{joint}]": within})
    assert g["outside"] == [] and g["covered"] is True
    past = nominal[joint - 1] + side * (declared[joint - 1] + DELTA)
    g = with_friction({f"{name}[{joint}]": past})
    assert len(g["outside"]) == 1 and g["covered"] is False
    assert g["outside"][0].startswith(
        f"plant {name}[{joint}] = {past:.7g} ")
    assert f"(nominal {nominal[joint - 1]:g} ± {declared[joint - 1]:g})" in g["outside"][0]
    assert key in g["outside"][0]


def test_friction_past_its_bound_at_both_joints_names_both():
    g = with_friction({"b[1]": DAMPING[0] + 1.0, "b[2]": DAMPING[1] - 0.5})
    assert [text.split(" = ")[0] for text in g["outside"]] == ["plant b[1]", "plant b[2]"]


def test_a_coulomb_law_of_another_smoothing_velocity_is_outside():
    for value, named in ((SMOOTHING[0] * (1 + 1e-12), False),
                         (SMOOTHING[0] + EXACT, True), (SMOOTHING[0] - EXACT, True)):
        g = with_friction({"fc_vel": value})
        assert (g["outside"] != []) is named, (value, g["outside"])
        if named:
            assert g["outside"] == [f"plant fc_vel = {value:.10g} rad/s (the nominal model's "
                                    f"{SMOOTHING[0]:g} rad/s, inertia_model.fc_vel): another "
                                    "Coulomb friction law"]


@pytest.mark.parametrize("joint", LINKS)
@pytest.mark.parametrize("side", (1.0, -1.0))
def test_the_disturbance_within_its_bound_is_covered_and_past_it_outside(side, joint):
    """uncertainty.disturbance = 0.3 N·m about the model's 0.01: the constant's error and
    the sinusoid's amplitude each alone, either sign, at each joint."""
    model = OUTPUT_FEEDBACK.tau_d[joint - 1]
    bound = DECLARED.disturbance
    for key, within, past in ((f"tau_d[{joint}]", model + side * (bound - DELTA),
                               model + side * (bound + DELTA)),
                              (f"tau_d_amp[{joint}]", side * (bound - DELTA),
                               side * (bound + DELTA))):
        assert conclude(make_trace(), {key: within})["outside"] == [], key
        outside = conclude(make_trace(), {key: past})["outside"]
        assert len(outside) == 1 and f"on joint {joint} > the declared 0.3 N·m" in outside[0]
        assert f"plant {key} = {past:g} N·m" in outside[0], outside


@pytest.mark.parametrize("joint", LINKS)
def test_the_observers_disturbance_model_is_compared_at_every_joint(joint):
    """The filter's τ_d the plant's; the observer's off at one joint by just within or just
    past the declared 0.3 N·m."""
    right = OUTPUT_FEEDBACK._replace(tau_d=np.array([0.01, 0.01]))
    for error, named in ((0.3 - DELTA, False), (0.3 + DELTA, True), (-0.3 - DELTA, True)):
        observer = np.array([0.01, 0.01])
        observer[joint - 1] += error
        outside = conclude(make_trace(), {}, right, tau_d_model=observer)["outside"]
        assert (outside != []) is named, (error, outside)
        if named:
            assert outside[0].startswith(f"plant tau_d[{joint}] = 0.01 N·m (observer.tau_d "
                                         f"{observer[joint - 1]:g} N·m)")
            assert outside[0].endswith("assumes observer.tau_d")


@pytest.mark.parametrize(("payload", "named"), [
    (0.0, False), (1.0, False), (-DELTA, True), (1.0 + DELTA, True), (0.5, False)])
def test_the_payload_at_either_end_of_its_range(payload, named):
    g = conclude(make_trace(), {"m[2]": 2.3 + payload})
    assert (g["outside"] != []) is named, g["outside"]
    if named:
        assert g["outside"] == [f"payload {payload:.7g} kg outside [0, 1]"]


@pytest.mark.parametrize("joint", LINKS)
@pytest.mark.parametrize("family", ("l", "lc", "I"))
def test_every_link_parameter_not_declared_uncertain_is_compared_at_every_joint(family,
                                                                                joint):
    nominal = {"l": 1.0, "lc": 1.0, "I": 0.0}[family]
    for value, named in ((nominal + 0.5e-9, False), (nominal + EXACT, True),
                         (nominal - EXACT, True)):
        g = conclude(make_trace(), {f"{family}[{joint}]": value})
        assert (g["outside"] != []) is named, (value, g["outside"])
        if named:
            assert g["outside"] == [f"plant {family}[{joint}] = {value:.10g} (nominal "
                                    f"{nominal:g})"]


def test_the_first_links_mass_is_compared_the_last_ones_is_the_payload():
    for value, named in ((0.8 + 0.5e-9, False), (0.8 + EXACT, True), (0.8 - EXACT, True)):
        g = conclude(make_trace(), {"m[1]": value})
        assert (g["outside"] != []) is named, (value, g["outside"])
    g = conclude(make_trace(), {"m[1]": 0.9, "m[2]": 2.3 + 2.0, "l[2]": 1.1})
    assert g["outside"] == ["payload 2 kg outside [0, 1]", "plant m[1] = 0.9 (nominal 0.8)",
                            "plant l[2] = 1.1 (nominal 1)"]


@pytest.mark.parametrize("value", (9.8 + EXACT, 9.8 - EXACT))
def test_gravity_either_way(value):
    g = conclude(make_trace(), {"g": value})
    assert g["outside"] == [f"plant g = {value:.10g} m/s² (the nominal chain's 9.8 m/s²): "
                            "gravity is not declared uncertain"]
    assert conclude(make_trace(), {"g": 9.8 + 0.5e-9})["outside"] == []


@pytest.mark.parametrize("joint", (0, 1))
@pytest.mark.parametrize("side", (1.0, -1.0))
def test_the_noise_the_filter_reads_at_every_joint_either_sign(side, joint):
    """|q_meas − q| against uncertainty.noise_bound (1e-3 rad) at one step of one joint."""
    for error, named in ((1e-3 - DELTA, False), (1e-3 + DELTA, True)):
        trace = make_trace()
        trace["q_meas"][700, joint] += side * error
        outside = conclude(trace, {})["outside"]
        assert (outside != []) is named, (error, outside)
        if named:
            assert outside == [f"noise {error:.4g} rad > 0.001"]


@pytest.mark.parametrize("joint", (0, 1))
@pytest.mark.parametrize("side", (1.0, -1.0))
def test_the_initial_observer_error_at_every_joint_either_sign(side, joint):
    """|q̇(0) − x̂2(0)| against uncertainty.initial_velocity_error (0.5 rad/s); ε(0) made to
    hold it, so that only the start is judged."""
    for error, named in ((0.5 - DELTA, False), (0.5 + DELTA, True)):
        trace = make_trace()
        trace["qdot_hat"][0, joint] += side * error
        trace["qdot_hat_bound"][0] = 1.0
        outside = conclude(trace, {})["outside"]
        assert (outside != []) is named, (error, outside)
        if named:
            assert outside == [f"initial observer error {error:.7g} rad/s > 0.5"]


def test_the_coulomb_laws_smoothing_is_compared_where_only_the_plant_has_coulomb_friction():
    """A nominal model without Coulomb friction (f̂c = 0) that declares |fc − f̂c| ≤ 0.4 N·m:
    the plant's fc within it, but its fc_vel another than the model's: outside, named."""
    table = friction_table(2, [0.0, 0.0], [0.0, 0.0], 0.01, [0.0, 0.0], [0.4, 0.4])
    out = undeclared_differences({"fc[1]": 0.3, "fc_vel[1]": 0.05, "fc_vel[2]": 0.01}, None,
                                 Uncertainty(coulomb_friction=[0.4, 0.4]), np.zeros(2), 2, table)
    assert out == ["fc_vel[1] = 0.05 rad/s (the nominal model's 0.01 rad/s, "
                   "inertia_model.fc_vel): another Coulomb friction law"]


def test_a_parameter_the_rigid_chain_does_not_have_makes_it_another_model():
    _, differ = plant_payload({**DEFAULTS, "m[2]": 2.8, "k[1]": 100.0}, NOMINAL,
                              rigid_chain_parameters(2))
    assert differ == ["has parameters the nominal rigid chain does not (k[1]): it is another "
                      "model"]


def drive_trace(error) -> Trace:
    """A system's run: the torque commanded 1 N·m, the arm given 1 N·m + ``error``."""
    trace = Trace({"tau": Signal("n", "N·m", "tau"), "arm.tau": Signal("n", "N·m", "arm.tau")},
                  2, 100, 1e-3)
    trace.arrays["tau"][:] = 1.0
    trace.arrays["arm.tau"][:] = 1.0 + np.asarray(error)
    trace.rows_done = 101
    return trace


def drives(rotor=(0.0, 0.0)) -> dict:
    """A system of an arm and its drives (gear 100, rotor inertias ``rotor``, kg·m²)."""
    parameters = {f"{k}[{i}]": v for i in LINKS for k, v in
                  (("N", 100.0), ("kt", 0.1), ("i_max", 10.0), ("T", 0.001))}
    parameters.update({f"J[{i}]": rotor[i - 1] for i in LINKS})
    return {"arm": "arm", "arm_torque": "arm.tau",
            "components": {"arm": {"parameters": {}, "model_name": "arm"},
                           "drives": {"parameters": parameters, "model_name": "drives"}}}


@pytest.mark.parametrize("joint", LINKS)
def test_a_drives_torque_error_shares_the_disturbance_bound_with_the_plants_own(joint):
    """0.15 N·m between command and arm on one joint, 0.3 N·m declared: within it alone, but
    outside once the plant's own 0.2 N·m disturbance on that joint takes its share."""
    error = [0.15 if i == joint else 0.0 for i in LINKS]
    declared = Uncertainty(disturbance=0.3)
    assert system_differences(drive_trace(error), drives(), {}, declared, np.zeros(2)) == []
    out = system_differences(drive_trace(error), drives(), {f"tau_d_amp[{joint}]": 0.2},
                             declared, np.zeros(2))
    assert len(out) == 1 and f"on joint {joint}" in out[0]
    assert "more than the 0.1 N·m uncertainty.disturbance leaves" in out[0]


@pytest.mark.parametrize("joint", LINKS)
def test_a_rotor_inertia_is_named_at_every_joint(joint):
    rotor = tuple(1e-5 if i == joint else 0.0 for i in LINKS)
    out = system_differences(drive_trace([0.0, 0.0]), drives(rotor), {},
                             Uncertainty(disturbance=0.3), np.zeros(2))
    assert len(out) == 1 and out[0].startswith(f"drive 'drives': J[{joint}] = 1e-05 kg·m²")


# The URDF reader's held joints, at angles other than zero: the nominal model (the reader's
# chain, folded) against Pinocchio's model of the same URDF with those joints locked there.

HELD = [("ur5", {"wrist_1_joint": 0.7}), ("ur5", {"elbow_joint": -1.3}),
        ("panda", {"panda_joint4": -1.5, "panda_joint7": 0.9})]


@pytest.mark.parametrize(("arm", "held"), HELD)
def test_held_joints_at_nonzero_angles_fold_as_pinocchio_locks_them(arm, held):
    """M̂ and b̂ (with a 0.7 kg payload at the tip) at random states within 1e-10 of
    Pinocchio's crba and rnea for its reduced model; and a different angle gives a
    different arm (the angle is used, not dropped)."""
    pin = pytest.importorskip("pinocchio")
    from urdf_helpers import ARMS, configuration, pinocchio_model, random_states

    from cosim.dynamics.model import chain_model, model_bias, model_geometry, model_mass
    from plant_fmu.urdf import read_urdf

    chain = read_urdf(ARMS[arm], fixed=held)
    assert held.items() <= dict(chain.held).items()
    model = chain_model(chain)
    reference = pinocchio_model(ARMS[arm], chain, payload=0.7)
    data = reference.createData()
    rng = np.random.default_rng(52)
    q, qd, _ = random_states(chain, rng, 20)
    n = chain.n
    for x, v in zip(q, qd, strict=True):
        model_geometry(model, x)
        mass, bias = np.zeros((n, n)), np.zeros(n)
        model_mass(model, 1.0, 0.7, mass)
        model_bias(model, v, 1.0, 0.7, 1.0, bias)
        configured = configuration(reference, x)
        expected = pin.crba(reference, data, configured)
        expected = np.triu(expected) + np.triu(expected, 1).T
        np.testing.assert_allclose(mass, expected, rtol=0, atol=1e-10 * np.abs(expected).max())
        h = pin.rnea(reference, data, configured, v, np.zeros(n))
        np.testing.assert_allclose(bias, h, rtol=0, atol=1e-10 * (1 + np.abs(h).max()))
    other = read_urdf(ARMS[arm], fixed={name: value + 0.3 for name, value in held.items()})
    model_geometry(model, q[0])
    model_mass(model, 1.0, 0.7, mass)
    moved = chain_model(other)
    model_geometry(moved, q[0])
    shifted = np.zeros((n, n))
    model_mass(moved, 1.0, 0.7, shifted)
    assert np.abs(shifted - mass).max() > 1e-6
