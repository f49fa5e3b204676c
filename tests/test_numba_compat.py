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


@no_refcount_jit()
def _offset(x, flag, step):
    return x + (1.0 if flag else 0.0) + step


@no_refcount_jit()
def _offsets(x, step):
    return _offset(x, False, 0) + _offset(x, True, step) + _offset(x, x > 0.0, step)


def test_a_callee_is_compiled_once_for_its_types_whatever_constants_its_callers_pass():
    assert _offsets(1.0, 3) == 1.0 + 5.0 + 5.0
    assert [tuple(map(str, s)) for s in _offset.signatures] == [("float64", "bool", "int64")]


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


def _save_entries(folder: str, who: int, count: int, start, serialised: bool) -> None:
    """In a process of its own: ``count`` cache entries of one function, keys and data
    (who, i), saved through numba's own cache file as the compiler saves them, with
    cosim's lock (``serialised``) or by numba's own save alone."""
    from numba.core.caching import IndexDataCacheFile

    from cosim import jit_cache

    jit_cache.use_versioned_cache()  # as every cosim process (the suite's already has)
    save = IndexDataCacheFile.save if serialised else IndexDataCacheFile.save.__wrapped__
    cache = IndexDataCacheFile(folder, "probe-1.py311", "stamp")
    start.wait()
    for i in range(count):
        save(cache, (who, i), (who, i))


def _saved_by_two_at_once(folder, serialised: bool, count: int = 60) -> list:
    import multiprocessing

    from numba.core.caching import IndexDataCacheFile

    folder.mkdir()
    context = multiprocessing.get_context("fork")
    start = context.Barrier(2)
    workers = [context.Process(target=_save_entries, args=(str(folder), who, count, start,
                                                           serialised)) for who in range(2)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join(60)
        assert worker.exitcode == 0
    cache = IndexDataCacheFile(str(folder), "probe-1.py311", "stamp")
    return [cache.load((who, i)) for who in range(2) for i in range(count)]


def test_two_processes_saving_signatures_of_one_function_keep_each_its_own(tmp_path):
    """numba's cache saves are serialised across processes (cosim.jit_cache): two
    processes saving entries of one function at once (the warm-up's workers compiling its
    planar and its spatial signature) keep every entry, each pointing at its own data.
    Without the lock, the same run loses entries or crosses them."""
    expected = [(who, i) for who in range(2) for i in range(60)]
    assert _saved_by_two_at_once(tmp_path / "locked", True) == expected
    unlocked = [_saved_by_two_at_once(tmp_path / f"unlocked{t}", False) for t in range(5)]
    assert any(found != expected for found in unlocked)  # the race the lock closes
