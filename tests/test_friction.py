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
