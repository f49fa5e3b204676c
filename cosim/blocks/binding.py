"""A kernel's argument record, bound by the framework from what its fields declare.

A block's kernel reads one record (a NamedTuple, usually marked
:func:`~cosim.records.kernel_record`). Each field of it may say where its value comes from,
in its annotation, so that the block's ``reset`` writes only what it computes:

    class PdArgs(NamedTuple):
        dt: master_step()                # the master step, s
        kp: parameter()                  # the block's parameter ``kp`` (per joint: (n,))
        q_d: reads()                     # the input signal ``q_d``, all rows
        tau: writes()                    # the output signal ``tau``, all rows
        acceleration: scratch("n")       # zeros (n,), the step's own
        rollout: scratch("Rollout, n")   # a row per member of the Rows class Rollout
        model: RigidBodyModel            # no source: ``reset`` computes it

    self.args = self.bind(PdArgs, ports, model=...)

A scratch array with named rows declares them as a :class:`~cosim.records.Rows` class beside
the record, one member a row, numbered by their order; its shape names the class for their
count, and a kernel indexes the array by member (``w.rollout[Rollout.DV]``): no row number
or count is written by hand.

A parameter is thus declared once, in the block's ``Params`` (name, type, default, units,
per joint or not), and named once more where the kernel reads it; nothing copies it by hand
on the way. Every field is bound from exactly one place: one with a source given by hand as
well, or one with neither, is refused, named, as the block is reset (a developer's
mistake, not a user's).
"""

from __future__ import annotations

import ast
import sys
import typing
from dataclasses import dataclass
from typing import Annotated, TypeVar

import numpy as np

from ..records import Rows, is_kernel_record, reference
from ..schema import per_joint_array

Record = TypeVar("Record", bound=tuple)


@dataclass(frozen=True)
class Source:
    """Where a field's value comes from (see the module's docstring)."""

    # "parameter", "reads", "writes", "uncertainty", "master_step", "scratch", "published"
    kind: str
    name: str | None = None  # the parameter, signal or declared key (default: the field's)
    constant: str = ""  # published: the block's own published constant the field is read from
    chosen_by: str = ""  # reads: the block's attribute that names the signal (set as it is made)
    shape: str = ""  # scratch: its shape, comma-separated sizes ("n", "hidden + 1", "2, n")
    dtype: type = float  # scratch: float, int (int64) or bool


def parameter(name: str | None = None) -> object:
    """The block's parameter ``name`` (default: the field's name; a key with an alias, as
    ``lambda``, by its attribute name). A per-joint parameter becomes an (n,) float array,
    one value for all joints broadcast; a bool, int or float stays one."""
    return Annotated[object, Source("parameter", name)]


def reads(signal: str | None = None, *, chosen_by: str = "") -> object:
    """The input signal ``signal`` (default: the field's name): its array of every row. Or,
    with ``chosen_by`` instead, the signal the block chose as it was made, named by that
    attribute of it (a controller's ``position``: ``self.position = "q_meas"`` where it
    reads the sensor)."""
    if signal is not None and chosen_by:
        raise TypeError(f"reads({signal!r}, chosen_by={chosen_by!r}): one or the other")
    return Annotated[np.ndarray, Source("reads", signal, chosen_by=chosen_by)]


def writes(signal: str | None = None) -> object:
    """The output signal ``signal`` (default: the field's name): its array of every row."""
    return Annotated[np.ndarray, Source("writes", signal)]


def uncertainty(key: str | None = None) -> object:
    """The pipeline's declared ``[uncertainty]`` key (default: the field's name)."""
    return Annotated[float, Source("uncertainty", key)]


def published(constant: str, name: str | None = None) -> object:
    """Field ``name`` (default: the field's) of the block's own published constant
    ``constant`` (a NamedTuple the block resolved as it was made, as a parameter's default
    taken from the robot): the value the blocks after it read, bound unchanged."""
    return Annotated[object, Source("published", name, constant=constant)]


def master_step() -> object:
    """The master step h, s."""
    return Annotated[float, Source("master_step")]


def scratch(shape: str, dtype: type = float) -> object:
    """Zeros of ``shape``: comma-separated sizes, each a sum or product of integers and
    names: ``n`` the joint count, the block's integer parameters, the sizes given to
    :func:`bind`, the integer constants of the record's module and its
    :class:`~cosim.records.Rows` classes, a class for its count and ``Class.MEMBER`` for a
    member's row (``"hidden + 1"``, ``"2, n, n"``, ``"Rollout, n"``,
    ``"GroupValue.OFFSETS + d"``)."""
    return Annotated[np.ndarray, Source("scratch", shape=shape, dtype=dtype)]


def kernel_args(record: type[Record], **fields: object) -> Record:
    """``record`` (a NamedTuple class: a kernel's arguments, a published model) built from
    its fields by name, every one given: built by position, two swapped fields of one type
    would run silently. A missing or an unknown field is refused, named, when the block is
    reset. A record marked :func:`~cosim.records.kernel_record` comes back as the
    one pointer compiled code takes (:func:`~cosim.records.reference`), its fields
    read as the record's."""
    missing = [name for name in record._fields if name not in fields]
    unknown = [name for name in fields if name not in record._fields]
    if missing or unknown:
        problems = [f"{label} {', '.join(names)}" for label, names in
                    (("missing", missing), ("unknown", unknown)) if names]
        raise TypeError(f"{record.__name__}: {'; '.join(problems)} (its fields: "
                        f"{', '.join(record._fields)})")
    built = record(**fields)
    if not is_kernel_record(record):
        return built
    return reference(built)


_SOURCES: dict[type, dict[str, Source]] = {}


def sources(record: type) -> dict[str, Source]:
    """The declared source of each of ``record``'s fields that has one."""
    if record not in _SOURCES:
        hints = typing.get_type_hints(record, include_extras=True)
        _SOURCES[record] = {
            name: meta for name in record._fields
            for meta in getattr(hints.get(name), "__metadata__", ()) if isinstance(meta, Source)}
    return _SOURCES[record]


def bind(record: type[Record], block, ports, sizes: dict[str, int] | None = None,
         **computed: object) -> Record:
    """``record`` built by :func:`kernel_args` from its fields' declared sources (``block``'s
    parameters, context and ports: a :class:`~cosim.blocks.base.Block` and its
    :class:`~cosim.blocks.base.Ports`) and from ``computed``, the fields without one."""
    declared = sources(record)
    twice = sorted(set(declared) & set(computed))
    if twice:
        raise TypeError(f"{record.__name__}: {', '.join(twice)} declared bound from "
                        f"{', '.join(declared[name].kind for name in twice)} and given too")
    constants = {name: value for name, value in vars(sys.modules[record.__module__]).items()
                 if type(value) is int
                 or isinstance(value, type) and issubclass(value, Rows) and value is not Rows}
    integers = {name: value for name, value in block.params if type(value) is int}
    names = {**constants, **integers, "n": block.context.links, **(sizes or {})}
    values = {name: _value(record, name, source, block, ports, names)
              for name, source in declared.items()}
    return kernel_args(record, **values, **computed)


def _value(record: type, field: str, source: Source, block, ports,
           sizes: dict[str, int | type[Rows]]):
    key = source.name or field
    where = f"{record.__name__}.{field}"
    if source.kind == "parameter":
        return _parameter(block, key, where)
    if source.chosen_by:
        key = getattr(block, source.chosen_by, None)
        if not isinstance(key, str):
            raise TypeError(f"{where} reads the signal {block.kind}'s attribute "
                            f"{source.chosen_by!r} names, but it names none (set it to a "
                            "signal's name as the block is made)")
    if source.kind in ("reads", "writes"):
        signals = ports.inputs if source.kind == "reads" else ports.outputs
        if key not in signals:
            raise TypeError(f"{where} {source.kind} signal {key!r}, which {block.kind} does not "
                            f"{'read' if source.kind == 'reads' else 'write'} (its signals: "
                            f"{', '.join(signals)})")
        return signals[key]
    if source.kind == "uncertainty":
        return getattr(block.context.uncertainty, key)
    if source.kind == "master_step":
        return block.context.dt
    if source.kind == "published":
        if source.constant not in block.publishes:
            raise TypeError(f"{where}: {block.kind} publishes no {source.constant!r} (it "
                            f"publishes: {', '.join(block.publishes) or 'nothing'})")
        constant = block.publishes[source.constant]
        if key not in getattr(constant, "_fields", ()):
            raise TypeError(f"{where}: {block.kind}'s {source.constant!r} has no field {key!r} "
                            f"(its fields: {', '.join(getattr(constant, '_fields', ()))})")
        return getattr(constant, key)
    shape = tuple(_size(term, sizes, where) for term in source.shape.split(","))
    return np.zeros(shape, np.int64 if source.dtype is int else source.dtype)


def _parameter(block, key: str, where: str):
    fields = type(block.params).model_fields
    if key not in fields:
        raise TypeError(f"{where}: {block.kind} has no parameter {key!r}")
    value = getattr(block.params, key)
    if value is None:
        raise TypeError(f"{where}: parameter {key!r} may be unset (None), which a kernel "
                        "cannot read; compute the field in reset")
    if (fields[key].alias or key) in block.per_joint:
        return per_joint_array(value, block.context.links)
    if isinstance(value, (bool, int, float)):
        return value
    raise TypeError(f"{where}: parameter {key!r} is {type(value).__name__}, which a kernel "
                    "cannot read; compute the field in reset")


_OPERATORS = {ast.Add: int.__add__, ast.Sub: int.__sub__, ast.Mult: int.__mul__}


def _size(term: str, sizes: dict[str, int | type[Rows]], where: str) -> int:
    """One size of a scratch's shape: integers and names joined by +, − and ×; a
    :class:`~cosim.records.Rows` class its count, ``Class.MEMBER`` that member's row."""

    def evaluate(node: ast.AST) -> int:
        if isinstance(node, ast.Constant) and type(node.value) is int:
            return node.value
        if isinstance(node, ast.Name) and node.id in sizes:
            size = sizes[node.id]
            return len(size) if isinstance(size, type) else int(size)
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            rows = sizes.get(node.value.id)
            if isinstance(rows, type):
                if node.attr not in rows.__members__:
                    raise TypeError(f"{where}: scratch size {term.strip()!r}: {rows.__name__} "
                                    f"has no row {node.attr} (its rows: "
                                    f"{', '.join(rows.__members__)})")
                return int(rows[node.attr])
        if isinstance(node, ast.BinOp) and type(node.op) in _OPERATORS:
            return _OPERATORS[type(node.op)](evaluate(node.left), evaluate(node.right))
        raise TypeError(f"{where}: scratch size {term.strip()!r} is not a sum or product of "
                        f"integers and {', '.join(sizes)}")

    return evaluate(ast.parse(term.strip(), mode="eval").body)
