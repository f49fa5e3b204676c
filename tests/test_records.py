"""A kernel record handed to compiled code as one pointer (cosim.records): a kernel reads
every kind of field the blocks' records hold as Python holds it, writes into its arrays
land in Python's, a record inside a record is read through it, the type survives pickling
(the warm-up's jobs, numba's cache index) and a cached kernel taking it loads in a fresh
process."""

from __future__ import annotations

import pickle
import subprocess
import sys
import textwrap
from typing import NamedTuple

import numpy as np
import pytest
from numba import njit, typeof

from cosim.blocks.base import kernel_args
from cosim.numba_compat import compiled_entry_point, no_refcount_jit
from cosim.records import RecordReference, RecordType, kernel_record, reference


@kernel_record
class Inner(NamedTuple):
    weights: np.ndarray
    gain: float


class Plain(NamedTuple):  # not marked: held inline, as numba lays out a tuple
    offsets: np.ndarray
    count: int


@kernel_record
class Outer(NamedTuple):
    vector: np.ndarray
    matrix: np.ndarray
    cube: np.ndarray
    column: np.ndarray  # a strided view: numba's layout "A"
    counts: np.ndarray
    mask: np.ndarray
    scale: float
    steps: int
    enabled: bool
    inner: Inner
    plain: Plain
    out: np.ndarray


@no_refcount_jit()
def _read(a):
    """Every field, summed into ``a.out`` (which Python reads back)."""
    a.out[0] = a.vector.sum() + a.matrix[1, 2] + a.cube[1, 0, 1] + a.column.sum()
    a.out[1] = a.counts.sum() + a.mask.sum() + a.scale + a.steps + (1.0 if a.enabled else 0.0)
    a.out[2] = a.inner.weights[2] * a.inner.gain
    a.out[3] = a.plain.offsets[1] + a.plain.count
    a.out[4] = a.matrix.shape[0] * 10 + a.matrix.shape[1] + a.column.strides[0]
    return True


def _outer() -> Outer:
    table = np.arange(12.0).reshape(3, 4)
    return Outer(vector=np.arange(3.0), matrix=table, cube=np.arange(8.0).reshape(2, 2, 2),
                 column=table[:, 1], counts=np.array([2, 5], np.int64),
                 mask=np.array([True, False, True]), scale=0.25, steps=7, enabled=np.bool_(True),
                 inner=Inner(weights=np.array([1.0, 2.0, 3.0]), gain=-2.0),
                 plain=Plain(offsets=np.array([0.5, 1.5]), count=4), out=np.zeros(5))


def test_a_kernel_reads_every_kind_of_field_as_python_holds_it():
    record = _outer()
    assert _read(reference(record))
    expected = [3.0 + 6.0 + 5.0 + (1.0 + 5.0 + 9.0), 7 + 2 + 0.25 + 7 + 1.0, 3.0 * -2.0,
                1.5 + 4, 34 + 32]
    np.testing.assert_array_equal(record.out, expected)


def test_python_reads_the_fields_through_the_reference():
    record = _outer()
    ref = reference(record)
    assert ref.matrix is record.matrix and ref.scale == 0.25 and ref.inner is record.inner
    assert ref._fields == Outer._fields


def test_kernel_args_references_a_marked_record_and_builds_an_unmarked_one_as_it_is():
    inner = kernel_args(Inner, weights=np.ones(2), gain=1.0)
    assert isinstance(inner, RecordReference) and isinstance(inner.record, Inner)
    assert isinstance(kernel_args(Plain, offsets=np.ones(2), count=1), Plain)


def test_the_type_names_its_record_and_pickles_equal():
    kind = typeof(reference(_outer()))
    assert isinstance(kind, RecordType) and kind.instance_class is Outer
    assert isinstance(kind.field_types["inner"], RecordType)
    assert pickle.loads(pickle.dumps(kind)) == kind


def test_a_field_numba_cannot_lay_out_is_refused_naming_it():
    @kernel_record
    class Odd(NamedTuple):
        label: str

    with pytest.raises(TypeError, match=r"Odd\.label"):
        reference(Odd(label="x"))


def test_a_cached_kernel_taking_a_reference_loads_in_a_fresh_process(tmp_path):
    module = tmp_path / "record_kernel.py"
    module.write_text(textwrap.dedent('''\
        from typing import NamedTuple
        import numpy as np
        from numba import njit
        from cosim.records import kernel_record, reference

        @kernel_record
        class Args(NamedTuple):
            values: np.ndarray
            scale: float

        @njit(cache=True, _nrt=False)
        def kernel(a):
            return a.values.sum() * a.scale

        if __name__ == "__main__":
            result = kernel(reference(Args(values=np.arange(4.0), scale=0.5)))
            print(result, kernel.stats.cache_hits.get(kernel.signatures[0], 0))
        '''))
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PATH": "/usr/bin:/bin"}
    runs = [subprocess.run([sys.executable, str(module)], capture_output=True, text=True,
                           env=env, cwd=tmp_path, timeout=120) for _ in range(2)]
    for run in runs:
        assert run.returncode == 0, run.stderr
    assert runs[0].stdout.split() == ["3.0", "0"]  # compiled, saved
    assert runs[1].stdout.split() == ["3.0", "1"]  # loaded from the cache


@njit
def _whole(a):
    return a.vector


def test_a_kernel_that_counts_references_hands_back_the_array_itself():
    record = _outer()
    assert _whole(reference(record)) is record.vector


def test_a_kernel_given_what_is_no_reference_raises_and_does_not_crash():
    kind = typeof(reference(_outer()))
    entry = compiled_entry_point(_read, (kind,))
    with pytest.raises(AttributeError, match="_address"):
        entry(_outer())
