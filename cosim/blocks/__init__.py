"""The blocks' interface and registry.

A block is a small class (:class:`Block`) that declares its parameters (a pydantic section,
which is also its pipeline table), the signals it reads and writes, and steps one row at a
time. ``register_block`` makes it available to pipelines under its ``kind``: a new
controller or filter is one new file plus that decorator, with no change to the master.
The paper's blocks (:mod:`cosim.paper`) register the same way, from the package's
``cosim.blocks`` entry point, and set the chain a pipeline that names none steps.
"""

from ..jit_cache import use_versioned_cache

# Before any kernel is defined (a block module defines its kernels on import, after
# importing this package): numba caches each kernel under a folder keyed by every kernel
# source, so an edited callee in another file never leaves stale machine code.
use_versioned_cache()

from .base import (  # noqa: E402
    BLOCKS,
    Block,
    BlockContext,
    Ports,
    default_chain,
    kernel_args,
    register_block,
    set_default_chain,
)

__all__ = ["BLOCKS", "Block", "BlockContext", "Ports", "default_chain", "kernel_args",
           "register_block", "set_default_chain"]
