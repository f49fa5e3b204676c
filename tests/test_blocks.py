"""The block registry and the assembly: a new block in a few lines, wiring refused with its
message, and the two engines giving the same rows."""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import PAPER

from cosim.assemble import assemble_run
from cosim.blocks import BLOCKS, Block, register_block
from cosim.config import PipelineError, Section, load_pipeline
from cosim.engine import simulate
from cosim.runner import run
from cosim.schema import PositiveFloat
from cosim.signals import Signal

CHAIN = '["reference", "sensor", "inertia_model", "observer", "controller", "torque_limiter"]'


class TorqueLimiterParams(Section):
    limit: PositiveFloat = 100.0  # N·m, per joint


@register_block
class TorqueLimiter(Block):
    """The toy block: clips the torque it is given (a filter of ``tau``), in plain numpy."""

    kind = "torque_limiter"
    Params = TorqueLimiterParams

    def __init__(self, params, context):
        super().__init__(params, context)
        self.inputs = ("tau",)
        self.outputs = {"tau": Signal("n", "N·m", "limited torque", "torque_limiter/tau")}

    def reset(self, ports):
        self.before, self.after = ports.inputs["tau"], ports.outputs["tau"]

    def step(self, k):
        self.after[k] = np.clip(self.before[k], -self.params.limit, self.params.limit)
        return True


def test_two_instances_of_one_kind_in_one_chain():
    """"kind as name" adds a named instance with its own table over the kind's: two limiters
    in series, each keeping what it was given under its own name, recorded apart."""
    chain = CHAIN.replace('"torque_limiter"]', '"torque_limiter", "torque_limiter as outer"]')
    pipeline = load_pipeline(PAPER, ["simulation.duration=1", "torque_limiter.limit=300",
                                     f"runs.baseline.blocks={chain}",
                                     "runs.baseline.outer.limit=150"])
    results = run(pipeline, None, progress=False)
    trace = results["baseline"].trace
    assert np.abs(trace["tau_controller"]).max() > 300
    np.testing.assert_array_equal(trace["tau_torque_limiter"],
                                  np.clip(trace["tau_controller"], -300, 300))
    np.testing.assert_array_equal(trace["tau"], np.clip(trace["tau_torque_limiter"], -150, 150))
    plan = assemble_run(pipeline, "baseline", TwoLinkArm())
    assert [b.instance for b in plan.blocks][-2:] == ["torque_limiter", "outer"]
    entities = plan.entities()
    assert entities["torque_limiter/tau"][0] == "tau_torque_limiter"
    assert entities["outer/tau"][0] == "tau"
    assert plan.torque_before_filter() == ("tau_torque_limiter", "outer")


@pytest.mark.parametrize("overrides,message", [
    (['runs.baseline.blocks=["reference", "torque_limiter as controller"]'],
     "blocks: 'torque_limiter as controller': the name 'controller' is taken (by a block kind "
     "or another instance); name it otherwise"),
    ([f"runs.baseline.blocks={CHAIN[:-1]}, \"torque_limiter as outer\"]",
      "runs.baseline.outer.limit=-1"],
     "outer.limit: Input should be greater than 0 (got -1)"),
    (['runs.baseline.blocks=["reference", "torque_limiter as 2nd"]'],
     "blocks: 'torque_limiter as 2nd' is not a block (\"kind\", or \"kind as name\" for a "
     "named instance, both identifiers)"),
])
def test_named_instances_are_refused_with_the_key_at_fault(overrides, message):
    with pytest.raises(PipelineError) as info:
        load_pipeline(PAPER, overrides)
    assert str(info.value).endswith(message), str(info.value)


class TwoLinkArm:  # what assembly needs to know of a plant
    links, mapped = 2, frozenset({"q", "qdot", "M"})


def test_a_registered_block_runs_in_a_pipeline():
    assert BLOCKS["torque_limiter"] is TorqueLimiter
    pipeline = load_pipeline(PAPER, ["simulation.duration=2", "torque_limiter.limit=150",
                                     f"runs.baseline.blocks={CHAIN}"])
    results = run(pipeline, None, progress=False)
    limited, free = results["baseline"].trace, results["proposed"].trace
    # The controller's torque is kept under its producer's name; the plant got the clipped one.
    assert np.abs(limited["tau_controller"]).max() > 150
    assert np.abs(limited["tau"]).max() == 150.0
    np.testing.assert_array_equal(limited["tau"],
                                  np.clip(limited["tau_controller"], -150, 150))
    assert "tau_controller" not in free and np.abs(free["tau"]).max() > 150


def test_the_limiter_table_is_validated_like_any_other():
    with pytest.raises(PipelineError, match="key 'torque_limiter.limit': Input should be "
                                            "greater than 0"):
        load_pipeline(PAPER, ["torque_limiter.limit=-1"])
    with pytest.raises(PipelineError, match="'torque_limitr' is not a registered block"):
        load_pipeline(PAPER, ['runs.baseline.blocks=["reference", "torque_limitr"]'])


@pytest.mark.parametrize("chain,message", [
    ('["reference", "inertia_model", "observer", "controller"]',
     "the observer block reads 'q_meas', which nothing before it produces "
     "(produced by: sensor)"),
    ('["reference", "sensor", "inertia_model", "observer"]',
     "the observer block reads 'tau' of the previous step, which no block produces "
     "(produced by: cbf_filter, controller, pd_controller, torque_limiter)"),
    ('["reference", "sensor", "inertia_model", "observer", "controller", "controller"]',
     "'tau' is produced twice, by the controller and the controller block; a block that "
     "changes a signal must also read it (a filter)"),
    ('["sensor", "reference", "inertia_model", "observer", "controller"]', None),
])
def test_wiring_errors_name_the_run_the_block_and_the_signal(chain, message):
    pipeline = load_pipeline(PAPER, [f"runs.proposed.blocks={chain}"])
    if message is None:  # order only matters where data flows
        assemble_run(pipeline, "proposed", TwoLinkArm())
        return
    with pytest.raises(PipelineError) as info:
        assemble_run(pipeline, "proposed", TwoLinkArm())
    assert str(info.value) == f"run 'proposed': {message}"


def test_a_plant_output_the_fmu_does_not_map_cannot_be_read():
    class NoVelocity(TwoLinkArm):
        mapped = frozenset({"q", "M"})

    pipeline = load_pipeline(PAPER, ["runs.baseline.controller.variant=\"baseline\""])
    with pytest.raises(PipelineError, match="full-state baseline reads the true joint velocity"):
        assemble_run(pipeline, "baseline", NoVelocity())


def test_the_fused_and_the_python_engine_give_the_same_rows_bit_for_bit(plant_fmu):
    from cosim.plant.fmu import Fmu

    pipeline = load_pipeline(PAPER, ["simulation.duration=1"])
    for fmi_version in (2, 3):
        with Fmu(plant_fmu(2, fmi_version)) as plant:
            traces = {}
            for engine in ("fused", "python"):
                plan = assemble_run(pipeline, "proposed", plant)
                traces[engine] = plan.new_trace(1000)
                simulate(plant, plan, traces[engine], engine=engine)
            fused, python = traces["fused"], traces["python"]
            assert fused.rows_done == python.rows_done == 1001
            for name in fused.arrays:
                np.testing.assert_array_equal(fused[name], python[name], err_msg=name)


class BadGainParams(Section):
    pass


@register_block
class BadGainPublisher(Block):
    """Publishes Theorem 1's gains as a plain number, not the NnGains it declares."""

    kind = "bad_gain_publisher"
    Params = BadGainParams
    PUBLISHES = {"nn_gains": tuple}

    def __init__(self, params, context):
        super().__init__(params, context)
        self.publishes = {"nn_gains": 5.0, "undeclared": 1}

    def reset(self, ports):
        pass


def test_a_published_constant_is_checked_against_its_declared_type():
    chain = ('["reference", "sensor", "inertia_model", "observer", "controller", '
             '"bad_gain_publisher"]')
    pipeline = load_pipeline(PAPER, [f"runs.proposed.blocks={chain}"])
    with pytest.raises(PipelineError, match=r"^run 'proposed': the bad_gain_publisher block "
                       r"publishes 'nn_gains' of type float, declared tuple$"):
        assemble_run(pipeline, "proposed", TwoLinkArm())
    BadGainPublisher.PUBLISHES = {"nn_gains": float}
    with pytest.raises(PipelineError, match=r"^run 'proposed': the bad_gain_publisher block "
                       r"publishes 'undeclared' not declared in its PUBLISHES$"):
        assemble_run(pipeline, "proposed", TwoLinkArm())


def test_kernel_arguments_are_built_by_name_and_refused_missing_or_unknown():
    """A block's kernel arguments (a NamedTuple) are built by field name, so that no two
    fields of one type can be swapped silently: a field left out, or one the record has
    not, is refused, named."""
    from cosim.blocks import kernel_args
    from cosim.paper.sensor import SensorArgs

    rows = np.zeros((2, 2))
    built = kernel_args(SensorArgs, q=rows, noise=rows, resolution=0.0, q_meas=rows)
    assert built.resolution == 0.0 and built.q_meas is rows
    with pytest.raises(TypeError, match=r"SensorArgs: missing resolution \(its fields"):
        kernel_args(SensorArgs, q=rows, noise=rows, q_meas=rows)
    with pytest.raises(TypeError, match="SensorArgs: unknown resolutoin"):
        kernel_args(SensorArgs, q=rows, noise=rows, resolutoin=0.0, resolution=0.0,
                    q_meas=rows)
    with pytest.raises(TypeError, match="missing resolution; unknown resolutoin"):
        kernel_args(SensorArgs, q=rows, noise=rows, resolutoin=0.0, q_meas=rows)
