"""The one module that touches numba's private API: what cosim needs of numba beyond its
documented interface, in one small place, so that a numba release that changes it breaks
here, and tests/test_numba_compat.py says so at once. (pyproject.toml pins numba to the
releases this was tested with.)

- :func:`no_refcount_jit`: ``njit`` without reference counting (its underscored ``_nrt``
  option), for kernels that allocate nothing and pass many arrays around, compiled for
  its arguments' types, not the constants a caller passes (:func:`typed_by_kind`: numba's
  dispatcher's call template);
- :func:`cache_locator_base` and :func:`prepend_cache_locator`: numba's cache locator class
  and the list of locators it asks, for cosim's per-module cache folders
  (:mod:`cosim.jit_cache`);
- :func:`compiled_entry_point`: a dispatcher's compiled function for one signature, to call
  without numba's type dispatch.

numba is imported inside the functions: :mod:`cosim.jit_cache` imports this module, and the
warm-up recognises a warm cache without importing numba.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


def no_refcount_jit(**options: Any) -> Callable[[Callable], Any]:
    """``numba.njit(**options)`` compiled without numba's reference counting (NRT): the
    function may allocate nothing (the compiler refuses an allocation), and binding or
    passing arrays costs nothing. Called from compiled code, it is compiled for its
    arguments' types, never their literal values (:func:`typed_by_kind`)."""
    from numba import njit

    def compile(function: Callable) -> Any:
        return typed_by_kind(njit(_nrt=False, **options)(function))

    return compile


def typed_by_kind(dispatcher: Any) -> Any:
    """``dispatcher`` (a numba dispatcher), called from compiled code, compiled for its
    arguments' types rather than their literal values: numba compiles a callee once per
    distinct constant a caller passes (``f(x, False, 0)`` and ``f(x, True, p)`` are two
    compiles, both again where ``f(x, flag, p)`` is called), which multiplied the filter's
    compile. numba's call template of the compiled signatures accepts the literals."""
    from numba.core.types import unliteral

    resolve = dispatcher.get_call_template

    def get_call_template(args: tuple, kws: dict) -> Any:
        return resolve(tuple(unliteral(a) for a in args),
                       {key: unliteral(value) for key, value in kws.items()})

    dispatcher.get_call_template = get_call_template
    return dispatcher


def cache_locator_base() -> type:
    """numba's base class of cache locators (``numba.core.caching._CacheLocator``)."""
    from numba.core.caching import _CacheLocator

    return _CacheLocator


def prepend_cache_locator(locator: type) -> None:
    """Make ``locator`` the first numba asks where to cache a function (once: a locator of
    the same class name already there is kept)."""
    from numba.core.caching import CacheImpl

    if not any(getattr(c, "__name__", "") == locator.__name__
               for c in CacheImpl._locator_classes):
        CacheImpl._locator_classes.insert(0, locator)


def compiled_entry_point(dispatcher: Any, signature: tuple) -> Callable:
    """The compiled function of ``dispatcher`` (a numba dispatcher) for ``signature``,
    compiled or loaded from the cache first: called directly, it skips the type dispatch a
    call of the dispatcher does (which, for a NamedTuple of arrays, costs more than a small
    kernel)."""
    dispatcher.compile(signature)
    return dispatcher.overloads[signature].entry_point
