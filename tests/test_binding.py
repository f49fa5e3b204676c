"""A kernel record bound from what its fields declare (cosim.blocks.binding): each declared
field takes its value from the one place it names (the block's parameter, per joint or one,
an input or output signal, the declared uncertainty, the master step, zeros of a shape),
every other field from reset, and each mistake is refused naming the record's field; a
parameter's per-joint form is declared once, in its type."""

from __future__ import annotations

from enum import auto
from typing import NamedTuple

import numpy as np
import pytest
from pydantic import Field

from cosim.blocks.base import Block, BlockContext, Ports
from cosim.blocks.binding import (
    master_step,
    parameter,
    published,
    reads,
    scratch,
    sources,
    uncertainty,
    writes,
)
from cosim.declared import Uncertainty
from cosim.records import RecordReference, Rows, kernel_record
from cosim.schema import JointList, PerJoint, PositiveFloat, Section, per_joint_keys
from cosim.signals import Trace


class ToyParams(Section):
    gain: PerJoint[PositiveFloat] = 2.0
    rate: PerJoint[PositiveFloat] | None = None  # per joint behind an Optional
    masses: JointList[PositiveFloat] | None = None
    lam: PerJoint[PositiveFloat] = Field(3.0, alias="lambda")
    scale: PositiveFloat = 0.5
    width: int = 4
    enabled: bool = True
    mode: str = "fast"


@kernel_record
class ToyArgs(NamedTuple):
    dt: master_step()
    gain: parameter()
    lam: parameter()
    scale: parameter()
    hidden_width: parameter("width")
    enabled: parameter()
    noise: uncertainty("noise_bound")
    position: reads("q")
    torque: writes("tau")
    buffer: scratch("width + 1, n")
    counts: scratch("2 * cells", int)
    offset: float  # no source: reset computes it


class Toy(Block):
    kind = "toy"
    Params = ToyParams
    per_joint = ("extra",)  # a class's own keys are kept beside the declared ones


def _bound(params: ToyParams | None = None, record=ToyArgs, published=None, **computed):
    context = BlockContext(links=3, dt=0.002, run="r", plant_outputs=frozenset(),
                           uncertainty=Uncertainty(noise_bound=1e-4))
    block = Toy(params or ToyParams(), context)
    block.publishes.update(published or {})
    trace = Trace({}, 3, 4, 0.002)
    q, tau = np.arange(12.0).reshape(4, 3), np.zeros((4, 3))
    ports = Ports(inputs={"q": q}, outputs={"tau": tau}, trace=trace)
    return block.bind(record, ports, **computed), q, tau


def test_each_declared_field_comes_from_the_place_it_names():
    args, q, tau = _bound(ToyParams(gain=[1.0, 2.0, 4.0]), sizes={"cells": 3}, offset=7.0)
    assert isinstance(args, RecordReference)
    assert args.dt == 0.002
    np.testing.assert_array_equal(args.gain, [1.0, 2.0, 4.0])  # per joint, as given
    np.testing.assert_array_equal(args.lam, [3.0, 3.0, 3.0])  # one for all, broadcast
    assert args.lam.flags.writeable and args.lam.dtype == float  # a copy of its own
    assert (args.scale, args.hidden_width, args.enabled) == (0.5, 4, True)
    assert type(args.hidden_width) is int and type(args.enabled) is bool
    assert args.noise == 1e-4
    assert args.position is q and args.torque is tau  # the trace's arrays, not copies
    assert args.buffer.shape == (5, 3) and not args.buffer.any()  # width + 1 = 5, n = 3
    assert args.counts.shape == (6,) and args.counts.dtype == np.int64
    assert args.offset == 7.0


def test_a_record_says_where_each_field_comes_from():
    declared = sources(ToyArgs)
    assert set(declared) == set(ToyArgs._fields) - {"offset"}
    assert (declared["hidden_width"].kind, declared["hidden_width"].name) == ("parameter",
                                                                              "width")
    assert (declared["torque"].kind, declared["torque"].name) == ("writes", "tau")
    assert declared["buffer"].shape == "width + 1, n"


def test_a_field_declared_and_given_too_is_refused_by_name():
    with pytest.raises(TypeError, match=r"ToyArgs: gain declared bound from parameter and "
                                        "given too"):
        _bound(sizes={"cells": 1}, offset=0.0, gain=np.ones(3))


def test_a_field_without_a_source_must_be_given():
    with pytest.raises(TypeError, match=r"ToyArgs: missing offset"):
        _bound(sizes={"cells": 1})


def test_a_signal_the_block_does_not_have_is_refused_by_name():
    @kernel_record
    class Reads(NamedTuple):
        velocity: reads("qdot")

    with pytest.raises(TypeError, match=r"Reads.velocity reads signal 'qdot', which toy does "
                                        r"not read \(its signals: q\)"):
        _bound(record=Reads)


def test_a_parameter_the_block_lacks_or_a_kernel_cannot_read_is_refused_by_name():
    class Missing(NamedTuple):
        gains: parameter()

    class Text(NamedTuple):
        mode: parameter()

    class Unset(NamedTuple):  # per joint, but None by default
        rate: parameter()

    with pytest.raises(TypeError, match="Missing.gains: toy has no parameter 'gains'"):
        _bound(record=Missing)
    with pytest.raises(TypeError, match="Unset.rate: parameter 'rate' may be unset"):
        _bound(record=Unset)
    with pytest.raises(TypeError, match="Text.mode: parameter 'mode' is str, which a kernel "
                                        "cannot read"):
        _bound(record=Text)


def test_a_scratch_size_is_integers_and_names_only():
    class Sized(NamedTuple):
        block: scratch("n ** 2")

    class Unknown(NamedTuple):
        block: scratch("rows")

    with pytest.raises(TypeError, match=r"Sized.block: scratch size 'n \*\* 2' is not a sum"):
        _bound(record=Sized)
    with pytest.raises(TypeError, match=r"Unknown.block: scratch size 'rows'.* width, n"):
        _bound(record=Unknown)


class Layout(Rows):
    """Rows of a scratch array (a Rows class in the record's module: what its shape names)."""

    A = auto()
    B = auto()
    C = auto()  # the first of a few, as the filter's Vector.X


class Published(NamedTuple):
    limit: np.ndarray


@kernel_record
class Laid(NamedTuple):
    rows: scratch("Layout, n")
    tail: scratch("Layout.C + n")
    limit: published("assumes")


def test_named_rows_are_numbered_by_their_order_and_sized_by_their_class():
    """A Rows class numbers its members 0, 1, … as declared, whatever is added before them;
    a shape naming it takes its count, ``Class.MEMBER`` that member's row; a kernel indexes
    by member as by the integer."""
    from numba import njit

    assert [int(row) for row in Layout] == [0, 1, 2]

    class Longer(Rows):
        NEW = auto()  # a row added first moves the others on
        A = auto()
        B = auto()

    assert (Longer.A, Longer.B, len(Longer)) == (1, 2, 3)

    class Misnamed(NamedTuple):
        rows: scratch("Layout.D + n")

    with pytest.raises(TypeError, match=r"Misnamed.rows: scratch size 'Layout.D \+ n': Layout "
                                        r"has no row D \(its rows: A, B, C\)"):
        _bound(record=Misnamed)
    args, _, _ = _bound(record=Laid, published={"assumes": Published(np.full(3, 5.0))})
    assert args.rows.shape == (3, 3) and args.tail.shape == (2 + 3,)

    @njit
    def fill(rows):
        for i in range(rows.shape[1]):
            rows[Layout.B, i] = 1.0
            rows[Layout.C + 0, i] = 2.0
        return rows[Layout.A:Layout.C].sum()

    rows = np.zeros((len(Layout), 2))
    assert fill(rows) == 2.0
    np.testing.assert_array_equal(rows, [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])


def test_a_published_field_is_the_blocks_own_constant_and_a_missing_one_is_named():
    """``published`` binds the field of a constant the block resolved as it was made (the
    filter's torque limit, its default from the robot), the same array the blocks after it
    read; a constant the block does not publish is refused, named."""
    limit = np.array([1.0, 2.0, 3.0])
    args, _, _ = _bound(record=Laid, published={"assumes": Published(limit)})
    assert args.limit is limit
    with pytest.raises(TypeError, match=r"Laid.limit: toy publishes no 'assumes' \(it "
                                        r"publishes: nothing\)"):
        _bound(record=Laid)
    with pytest.raises(TypeError, match=r"Laid.limit: toy's 'assumes' has no field 'limit' "
                                        r"\(its fields: bound\)"):
        _bound(record=Laid, published={"assumes": NamedTuple("Other", [("bound", float)])(1.0)})


def test_a_signal_chosen_by_the_block_is_read_from_the_attribute_that_names_it():
    """``reads(chosen_by=...)``: the input the block chose as it was made (a controller's
    measured or true position), named by its attribute; an attribute naming a signal the
    block does not read is refused, named."""

    @kernel_record
    class Chosen(NamedTuple):
        position: reads(chosen_by="position")

    with pytest.raises(TypeError, match=r"Chosen.position reads the signal toy's attribute "
                                        r"'position' names, but it names none"):
        _bound(record=Chosen)
    with pytest.raises(TypeError, match=r"reads\('q', chosen_by='position'\): one or the other"):
        reads("q", chosen_by="position")
    Toy.position = "q"
    try:
        args, q, _ = _bound(record=Chosen)
        assert args.position is q
        Toy.position = "q_meas"
        with pytest.raises(TypeError, match=r"Chosen.position reads signal 'q_meas', which toy "
                                            r"does not read"):
            _bound(record=Chosen)
    finally:
        del Toy.position


def test_per_joint_is_read_from_the_parameters_types_at_any_depth():
    assert per_joint_keys(ToyParams) == ("gain", "rate", "masses", "lambda")
    assert Toy.per_joint == ("gain", "rate", "masses", "lambda", "extra")


def test_the_paper_blocks_per_joint_keys_are_those_they_listed_by_hand():
    """The keys each block listed in ``per_joint`` before its parameters' types declared
    them: the same keys, so the same lists are checked against the plant's joints."""
    import cosim.paper  # noqa: F401  (registers the blocks)
    from cosim.blocks import BLOCKS

    listed = {"pd_controller": ("kp", "kd"), "controller": ("kv", "lambda"),
              "observer": ("tau_d", "initial_velocity"),
              "inertia_model": ("m", "l", "lc", "I", "b", "fc"),
              "cbf_filter": ("tau_d", "torque_limit", "braking_torque", "startup_torque"),
              "sensor": (), "reference": ()}
    assert {kind: set(BLOCKS[kind].per_joint) for kind in listed} == \
        {kind: set(keys) for kind, keys in listed.items()}
