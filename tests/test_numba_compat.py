"""The numba API cosim uses beyond numba's documented one, all in cosim.numba_compat, still
works with the numba installed: a tiny function through each fenced use."""

from __future__ import annotations

import numpy as np
from numba import njit, types

from cosim.numba_compat import (
    cache_locator_base,
    compiled_entry_point,
    no_refcount_jit,
    prepend_cache_locator,
)


@no_refcount_jit()
def _total(values):
    total = 0.0
    for value in values:
        total += value
    return total


@njit
def _twice(x):
    return 2.0 * x


def test_a_function_compiles_without_reference_counting():
    assert _total(np.arange(4.0)) == 6.0
    assert not _total.targetoptions.get("_nrt", True)


def test_the_entry_point_of_one_signature_is_callable_directly():
    entry = compiled_entry_point(_twice, (types.float64,))
    assert entry(1.5) == 3.0


def test_a_cache_locator_can_be_put_first_once():
    from numba.core.caching import CacheImpl

    base = cache_locator_base()

    class ProbeLocator(base):
        @classmethod
        def from_function(cls, py_func, py_file):
            return None  # never chosen: numba asks the next locator

    before = list(CacheImpl._locator_classes)
    try:
        prepend_cache_locator(ProbeLocator)
        prepend_cache_locator(ProbeLocator)
        assert CacheImpl._locator_classes == [ProbeLocator, *before]
        assert {"get_cache_path", "get_source_stamp", "get_disambiguator",
                "ensure_cache_path"} <= set(dir(base))
    finally:
        CacheImpl._locator_classes[:] = before
