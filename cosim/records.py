"""A kernel's argument record, passed to compiled code as one pointer.

numba passes a NamedTuple by value, flattened into one parameter per member of each of its
arrays (seven for a 2-d array): the filter's record of ~100 arrays gave each function that
takes it 770 parameters, and compiling them took minutes (docs/performance.md). A record
class marked with :func:`kernel_record` is handed to compiled code instead as one pointer to
a C struct that holds its fields as numba lays them out, built once when the block is reset
(:func:`~cosim.blocks.binding.kernel_args`). A kernel still reads ``args.field``; the read is a
load marked invariant (the struct never changes while a kernel runs), so the compiler hoists
it out of loops as it did the NamedTuple's members.

The record's arrays stay owned by the NamedTuple the struct was built from, which the
reference keeps alive; the struct's arrays carry no numba meminfo (their parent is the
NumPy array itself), so compiled code never counts references to them (the kernels are
compiled without reference counting anyway, :func:`~cosim.numba_compat.no_refcount_jit`).
Python reads the fields through the reference as from the NamedTuple.

A record's scratch arrays name their rows with :class:`Rows` (numbered by their order), which
compiled code reads as integer constants.

This module uses numba's extension API (a type, its data model, its attributes, its unboxing)
and its internal ``cgutils``; tests/test_records.py checks it against the numba
installed.
"""

from __future__ import annotations

import ctypes
import enum
import functools
from typing import Any, NamedTuple, TypeVar

from llvmlite import ir
from numba import typeof, types
from numba.core import cgutils
from numba.core.imputils import impl_ret_borrowed, lower_getattr_generic
from numba.core.typing.templates import AttributeTemplate, infer_getattr
from numba.extending import NativeValue, models, register_model, typeof_impl, unbox

Record = TypeVar("Record", bound=type)


class Rows(enum.IntEnum):
    """The named rows of a scratch array, numbered 0, 1, … in the order they are declared
    (each member ``= enum.auto()``). A kernel indexes by member, which compiled code reads as
    the integer constant; a scratch shape naming the class (``"Rollout, n"``) takes its
    count, and ``Vector.X + 2`` the member two rows on."""

    @staticmethod
    def _generate_next_value_(name: str, start: int, count: int, last_values: list) -> int:
        return count


def kernel_record(record: Record) -> Record:
    """Mark ``record`` (a NamedTuple class) as a kernel's argument record:
    :func:`~cosim.blocks.binding.kernel_args` hands it to compiled code as one pointer
    (:func:`reference`)."""
    record.__kernel_record__ = True
    return record


def is_kernel_record(record: type) -> bool:
    return getattr(record, "__kernel_record__", False)


class RecordType(types.Type):
    """numba's type of a record reference: the record's class (``instance_class``, as
    numba's NamedTuple types name it) and its fields' types. Equal by name (numba's default
    key: the class's module and qualified name, every field's type), not by the class
    object, which numba's cache pickles by value where it cannot by reference (a script's
    ``__main__``): a loaded index would never match again."""

    def __init__(self, record: type, fields: tuple[tuple[str, types.Type], ...]):
        self.instance_class = record
        self.fields = tuple(fields)
        self.names = tuple(name for name, _ in self.fields)
        self.field_types = dict(self.fields)
        listed = ", ".join(f"{name}: {kind}" for name, kind in self.fields)
        super().__init__(name=f"{record.__module__}.{record.__qualname__}Ref({listed})")


@register_model(RecordType)
class _RecordModel(models.PrimitiveModel):
    """A pointer to the struct of the fields' data representations, in order."""

    def __init__(self, dmm, fe_type: RecordType):
        struct = ir.LiteralStructType([dmm.lookup(kind).get_data_type()
                                       for _, kind in fe_type.fields])
        super().__init__(dmm, fe_type, struct.as_pointer())


@infer_getattr
class _RecordAttributes(AttributeTemplate):
    key = RecordType

    def generic_resolve(self, typ: RecordType, attr: str):
        return typ.field_types.get(attr)


@lower_getattr_generic(RecordType)
def _record_getattr(context, builder, typ: RecordType, value, attr: str):
    index = typ.names.index(attr)
    kind = typ.fields[index][1]
    data = builder.load(cgutils.gep_inbounds(builder, value, 0, index))
    data.set_metadata("invariant.load", builder.module.add_metadata([]))
    field = context.data_model_manager[kind].from_data(builder, data)
    return impl_ret_borrowed(context, builder, kind, field)


@unbox(RecordType)
def _unbox_record(typ: RecordType, obj, c):
    address = c.pyapi.object_getattr_string(obj, "_address")
    failed = cgutils.is_null(c.builder, address)  # not a reference: Python's error stands
    pointer = cgutils.alloca_once_value(c.builder, cgutils.voidptr_t(None))
    with c.builder.if_then(c.builder.not_(failed)):
        c.builder.store(c.pyapi.long_as_voidptr(address), pointer)
        c.pyapi.decref(address)
    value = c.builder.bitcast(c.builder.load(pointer), c.context.get_value_type(typ))
    return NativeValue(value, is_error=failed)


@functools.cache
def _ctype(kind: types.Type) -> Any:
    """The ctypes type laid out as numba's data representation of ``kind``."""
    if isinstance(kind, types.Array):  # numba's ArrayModel, member for member
        return type(f"Array{kind.ndim}", (ctypes.Structure,), {"_fields_": [
            ("meminfo", ctypes.c_void_p), ("parent", ctypes.c_void_p),
            ("nitems", ctypes.c_ssize_t), ("itemsize", ctypes.c_ssize_t),
            ("data", ctypes.c_void_p), ("shape", ctypes.c_ssize_t * kind.ndim),
            ("strides", ctypes.c_ssize_t * kind.ndim)]})
    if isinstance(kind, RecordType):
        return ctypes.c_void_p
    if isinstance(kind, types.BaseTuple):  # a NamedTuple field (a model): its members inline
        return type("Tuple", (ctypes.Structure,), {"_fields_": [
            (f"m{i}", _ctype(member)) for i, member in enumerate(kind.types)]})
    scalars = {types.float64: ctypes.c_double, types.int64: ctypes.c_int64,
               types.boolean: ctypes.c_uint8}
    if kind in scalars:
        return scalars[kind]
    raise TypeError(f"a kernel record cannot hold a field of numba type {kind}")


@functools.cache
def _struct(kind: RecordType) -> type:
    """The ctypes struct of a record's fields, laid out as :class:`_RecordModel` points to."""
    return type(kind.instance_class.__name__, (ctypes.Structure,),
                {"_fields_": [(name, _ctype(field)) for name, field in kind.fields]})


def _native(kind: types.Type, value: Any) -> Any:
    """``value`` as a ctypes value of :func:`_ctype` (kind)."""
    if isinstance(kind, types.Array):
        # parent: the array itself (kept alive by the reference), which numba hands back
        # should compiled code that counts references return the array to Python
        array = _ctype(kind)(parent=id(value), nitems=value.size, itemsize=value.itemsize,
                             data=value.ctypes.data)
        array.shape[:], array.strides[:] = value.shape, value.strides
        return array
    if isinstance(kind, RecordType):
        return value._address
    if isinstance(kind, types.BaseTuple):
        return _ctype(kind)(*(_native(m, v) for m, v in zip(kind.types, value, strict=True)))
    return bool(value) if kind == types.boolean else value  # numpy's bool is no int to ctypes


class RecordReference:
    """A record as compiled code takes it (one pointer, ``_address``), its fields read from
    Python as from the record itself (``record``)."""

    def __init__(self, record: NamedTuple):
        # a field that is a record itself (a model) is referenced too, once per reference
        values = tuple(reference(value) if is_kernel_record(type(value)) else value
                       for value in record)
        kinds = tuple((name, typeof(value)) for name, value in zip(record._fields, values,
                                                                    strict=True))
        for name, kind in kinds:
            try:
                _ctype(kind)
            except TypeError as exc:
                raise TypeError(f"{type(record).__name__}.{name}: {exc}") from None
        self.record = record
        self._values = values  # what the struct points into, kept alive with it
        self._numba_type = RecordType(type(record), kinds)
        native = (_native(kind, value) for (_, kind), value in zip(kinds, values, strict=True))
        self._struct = _struct(self._numba_type)(*native)
        self._address = ctypes.addressof(self._struct)

    def __getattr__(self, name: str) -> Any:
        try:
            record = self.__dict__["record"]
        except KeyError:  # not built yet (a copy being made): no fields to read
            raise AttributeError(name) from None
        return getattr(record, name)

    def __repr__(self) -> str:
        return f"reference to {self.record!r}"


@typeof_impl.register(RecordReference)
def _typeof_reference(value: RecordReference, context) -> RecordType:
    return value._numba_type


def reference(record: NamedTuple) -> RecordReference:
    """``record`` as one pointer for compiled code."""
    return RecordReference(record)
