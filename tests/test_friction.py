"""Joint friction in the nominal model (cosim/dynamics/model.py: model_friction and the
bound on its error, model_friction_spread): the law against its closed form and against
the plant FMU's own (the C model's M q̈ + h + friction = τ, read through Model Exchange), its
error bound against a dense sampling of the velocities and friction laws it must cover, the
URDF's <dynamics> carried into the blocks' model, and the guarantee with friction: the
observer's bound and the filter's hard sets hold on every step of near-boundary runs whose
plant friction lies within what is declared, which the classifier covers, and a friction
beyond it is named as outside."""

from __future__ import annotations

import numpy as np
import pytest
from fmu_helpers import FmuInstance
from test_observer_bound import NEAR_BOUNDARY, excess
from test_robust_safety import MC
from urdf_helpers import OWN_ROBOT

from cosim.blocks.base import BlockContext
from cosim.declared import Uncertainty
from cosim.dynamics.model import (
    chain_model,
    friction_table,
    model_bias,
    model_friction,
    model_friction_spread,
    model_geometry,
    own_scratch,
    planar_model,
)
from cosim.paper.inertia import InertiaModel, InertiaModelParams
from plant_fmu import build_urdf_fmu
from plant_fmu.urdf import read_urdf

DAMPING, COULOMB, SMOOTHING = np.array([2.0, 0.5]), np.array([3.0, 1.0]), np.array([0.01, 0.2])


def two_link(friction):
    return planar_model([0.8, 2.3], [1.0, 1.0], [1.0, 1.0], [0.0, 0.0], 9.8, friction)


def test_the_friction_law_is_its_closed_form_and_adds_nothing_without_friction():
    v = np.array([0.3, -2.0])
    out = np.array([1.0, 1.0])
    model_friction(two_link(friction_table(2, DAMPING, COULOMB, SMOOTHING)), v, out)
    np.testing.assert_allclose(out, 1.0 + DAMPING * v + COULOMB * np.tanh(v / SMOOTHING),
                               rtol=1e-15)
    none = np.array([1.5, -0.25])
    model_friction(two_link(None), np.array([np.inf, -np.inf]), none)
    assert none.tolist() == [1.5, -0.25]  # not NaN: a term without its coefficient is 0


def test_the_error_bound_covers_every_velocity_and_law_it_must_and_no_more():
    """For |q̇ − c| ≤ r and a true law whose b, fc lie within the declared bounds of the
    nominal's, |F_true(q̇) − F̂(c)| never exceeds the bound, and reaches it but for the
    declared Coulomb departure's unsaturated tanh: the bound is, at the end of the interval
    where it is largest, the nominal law's change plus the declared departures'."""
    declared = np.array([0.5, 0.2]), np.array([0.4, 0.1])
    model = two_link(friction_table(2, DAMPING, COULOMB, SMOOTHING, *declared))
    rng = np.random.default_rng(11)
    for _ in range(200):
        centre = rng.normal(0.0, 0.3, 2)
        radius = rng.uniform(0.0, 0.5, 2)
        bound = np.zeros(2)
        model_friction_spread(model, centre, radius, bound)
        nominal = DAMPING * centre + COULOMB * np.tanh(centre / SMOOTHING)
        worst = np.zeros(2)
        for velocity in np.linspace(centre - radius, centre + radius, 201):
            for b_sign in (-1, 1):
                for fc_sign in (-1, 1):
                    true = ((DAMPING + b_sign * declared[0]) * velocity
                            + (COULOMB + fc_sign * declared[1]) * np.tanh(velocity / SMOOTHING))
                    worst = np.maximum(worst, np.abs(true - nominal))
        assert np.all(worst <= bound + 1e-12), (centre, radius, worst, bound)
        # and no more than the Coulomb departure's |tanh| ≤ 1 gives away where tanh is not
        # yet saturated (the ends of the interval are sampled)
        ends = np.abs(np.stack([centre - radius, centre + radius]))
        slack = declared[1] * (1.0 - np.tanh(np.min(ends, axis=0) / SMOOTHING))
        assert np.all(worst >= bound - slack - 1e-9), (centre, radius, worst, bound, slack)


def test_the_plant_fmus_friction_is_the_nominal_models(fmu_cache):
    """Our own robot's URDF has <dynamics> on its lift (5 N·s/m, 2 N), turret and wrist: the
    blocks' model built from it (inertia_model.urdf, its b and fc unset)
    gives, at random states, the friction the plant FMU's C model applies: τ − M q̈ − h with
    τ = 0, from its Model Exchange derivatives and outputs."""
    chain = read_urdf(OWN_ROBOT)
    assert chain.damping.tolist() == [5.0, 0.1, 0.0, 0.02]
    assert chain.friction.tolist() == [2.0, 0.0, 0.0, 0.1]
    params = InertiaModelParams(source="nominal", urdf=str(OWN_ROBOT))
    model = own_scratch(InertiaModel(params, BlockContext(chain.n, 1e-3, "run",
                                                          frozenset({"q"}))).model)
    plant = FmuInstance(build_urdf_fmu(OWN_ROBOT, cache_dir=fmu_cache), "ModelExchange")
    rng = np.random.default_rng(5)
    try:
        for _ in range(10):
            q = rng.uniform(np.maximum(chain.lower, -3), np.minimum(chain.upper, 3))
            v = rng.normal(0.0, 0.2, chain.n)
            plant.set_states(np.concatenate([q, v]))
            acceleration = plant.derivatives()[chain.n:]
            mass = plant.get(plant.names("M")).reshape(chain.n, chain.n)
            bias = plant.get(plant.names("h"))
            applied = -(mass @ acceleration + bias)
            nominal = np.zeros(chain.n)
            model_friction(model, v, nominal)
            np.testing.assert_allclose(nominal, applied, atol=1e-9)
            # and the rigid-body part is the nominal model's too (friction apart from h)
            model_geometry(model, q)
            rigid = np.zeros(chain.n)
            model_bias(model, v, 1.0, 0.0, 1.0, rigid)
            np.testing.assert_allclose(rigid, bias, atol=1e-9)
    finally:
        plant.free()
    assert chain_model(chain).friction.tolist() == friction_table(chain.n).tolist()


def test_a_declared_friction_range_must_have_one_entry_per_joint():
    from cosim.assemble import assemble
    from cosim.config import PipelineError, load_pipeline

    pipeline = load_pipeline("pipelines/paper_two_link.toml",
                             ["uncertainty.viscous_friction=[0.1, 0.2, 0.3]"], warn=None)
    with pytest.raises(PipelineError, match=r"^uncertainty.viscous_friction has 3 entries; "
                       r"the plant \(.*\) has 2 joints$"):
        assemble(pipeline)
    assert Uncertainty().viscous_friction == 0.0 and Uncertainty().coulomb_friction == 0.0


FRICTION_PLANT = ['plant.parameters."b[1]"=2.4', 'plant.parameters."b[2]"=1.0',
                  'plant.parameters."fc[1]"=3.3', 'plant.parameters."fc[2]"=0.8']
FRICTION_MODEL = ["inertia_model.b=[2.0, 1.0]", "inertia_model.fc=[3.0, 1.0]"]
DECLARED = ["uncertainty.viscous_friction=[0.5, 0.1]",
            "uncertainty.coulomb_friction=[0.4, 0.3]"]


@pytest.fixture(scope="module")
def with_friction():
    """proposed_cbf from the near-boundary start (tests/test_observer_bound.py), its plant's
    friction within what is declared of the nominal model's, run through cosim's own
    runner: the pipeline and the run's result."""
    from cosim.config import load_pipeline
    from cosim.runner import run

    pipeline = load_pipeline(MC, ["simulation.duration=1.0", *NEAR_BOUNDARY,
                                  'plant.parameters."m[2]"=2.9',
                                  "uncertainty.initial_velocity_error=0.5",
                                  *FRICTION_PLANT, *FRICTION_MODEL, *DECLARED], warn=None)
    pipeline.runs = {"proposed_cbf": pipeline.runs["proposed_cbf"]}
    result = run(pipeline, None, progress=False, record=False, figures=False)
    return pipeline, result["proposed_cbf"]


def test_the_observer_bound_holds_with_friction_within_what_is_declared(with_friction):
    """On every step, both joints: |q̇ − x̂2| ≤ ε(t) with the plant's friction departing from
    the nominal model's by up to what is declared; the filter braking hard and keeping its
    hard sets."""
    pipeline, result = with_friction
    trace = result.trace
    worst = excess(trace)
    assert np.all(np.isfinite(trace["qdot_hat_bound"]))
    assert worst.max() <= 0.0, (worst.max(), np.unravel_index(worst.argmax(), worst.shape))
    assert np.any(trace["cbf_position_active"] + trace["cbf_velocity_active"] > 0)
    bound = pipeline.safety.position_bound
    assert np.max(np.abs(trace["q"] - trace["q_s"])) <= bound


def test_the_classifier_covers_friction_within_the_declared_bounds_and_names_it_beyond():
    """The run with its friction inside what is declared is covered; 0.2 N·m·s/rad more on
    joint 1 than declared, or another smoothing velocity, is named as outside."""
    from cosim.paper.within_bounds import undeclared_differences

    params = {"b[1]": 2.4, "b[2]": 1.0, "fc[1]": 3.3, "fc[2]": 0.8, "fc_vel[1]": 0.01,
              "fc_vel[2]": 0.01}
    declared = Uncertainty(viscous_friction=[0.5, 0.1], coulomb_friction=[0.4, 0.3])
    table = friction_table(2, [2.0, 1.0], [3.0, 1.0], 0.01, [0.5, 0.1], [0.4, 0.3])
    assert undeclared_differences(params, None, declared, np.zeros(2), 2, table) == []
    beyond = {**params, "b[1]": 2.7, "fc_vel[2]": 0.02}
    assert undeclared_differences(beyond, None, declared, np.zeros(2), 2, table) == [
        "b[1] = 2.7 N·m·s/rad (nominal 2 ± 0.5): viscous friction beyond "
        "uncertainty.viscous_friction",
        "fc_vel[2] = 0.02 rad/s (the nominal model's 0.01 rad/s, inertia_model.fc_vel): "
        "another Coulomb friction law"]
    # the planar arm's one smoothing velocity, named once
    planar = {**params, "fc_vel": 0.05}
    del planar["fc_vel[1]"], planar["fc_vel[2]"]
    assert undeclared_differences(planar, None, declared, np.zeros(2), 2, table) == [
        "fc_vel = 0.05 rad/s (the nominal model's 0.01 rad/s, inertia_model.fc_vel): another "
        "Coulomb friction law"]
    # without a declared bound, any friction the nominal model does not have is named
    assert undeclared_differences({"b[1]": 0.1}, None, Uncertainty(), np.zeros(2), 2) == [
        "b[1] = 0.1 N·m·s/rad (nominal 0): viscous friction is not declared uncertain "
        "(uncertainty.viscous_friction)"]


def test_a_run_with_friction_within_its_bounds_is_covered(with_friction):
    _, result = with_friction
    guarantee = result.metrics["guarantee"]
    assert guarantee["outside"] == [] and guarantee["covered"] and not guarantee["broken"]
    assert guarantee["hard_kept"] and guarantee["observer_bound_exceeded_steps"] == 0
