"""The blocks the master steps between plant steps, and their registry.

A block is a small class (:class:`Block`) that declares its parameters (a pydantic section,
which is also its pipeline table), the signals it reads and writes, and steps one row at a
time. ``register_block`` makes it available to pipelines under its ``kind``: a new
controller or filter is one new file plus that decorator, with no change to the master.
"""

from ..jit_cache import use_versioned_cache

# Before any kernel is defined (the block modules below define theirs on import): numba
# caches each kernel under a folder keyed by every kernel source, so an edited callee in
# another file never leaves stale machine code.
use_versioned_cache()

# The built-in blocks register themselves on import.
from . import (  # noqa: E402, F401, I001
    cbf_filter, controller, inertia, observer, pd_controller, reference, sensor)
from .base import (  # noqa: E402
    BLOCKS, Block, BlockContext, Ports, kernel_args, register_block)

# The chain a run steps when its pipeline names none: the order data flows in.
DEFAULT_CHAIN = ("reference", "sensor", "inertia_model", "observer", "controller")

__all__ = ["BLOCKS", "DEFAULT_CHAIN", "Block", "BlockContext", "Ports", "kernel_args",
           "register_block"]
