"""The plant's FMI step functions as compiled code calls them: ctypes function pointers of
fixed prototypes, every handle and array an integer address (the fused loop,
:mod:`cosim.engine.fused`, takes them as arguments; their addresses differ between
processes, so they cannot be compiled in)."""

from __future__ import annotations

import ctypes
from typing import NamedTuple

_INT, _SIZE, _DOUBLE, _BOOL = ctypes.c_int, ctypes.c_size_t, ctypes.c_double, ctypes.c_bool
# FMI functions as the loop calls them: handles and arrays as addresses (size_t).
PROTOTYPES = {
    2: {"set": ctypes.CFUNCTYPE(_INT, _SIZE, _SIZE, _SIZE, _SIZE),  # fmi2SetReal
        "get": ctypes.CFUNCTYPE(_INT, _SIZE, _SIZE, _SIZE, _SIZE),  # fmi2GetReal
        "step": ctypes.CFUNCTYPE(_INT, _SIZE, _DOUBLE, _DOUBLE, _INT)},  # fmi2DoStep
    3: {"set": ctypes.CFUNCTYPE(_INT, _SIZE, _SIZE, _SIZE, _SIZE, _SIZE),  # fmi3SetFloat64
        "get": ctypes.CFUNCTYPE(_INT, _SIZE, _SIZE, _SIZE, _SIZE, _SIZE),  # fmi3GetFloat64
        "step": ctypes.CFUNCTYPE(_INT, _SIZE, _DOUBLE, _DOUBLE, _BOOL,  # fmi3DoStep
                                 _SIZE, _SIZE, _SIZE, _SIZE)},
}


class FmiFunctions(NamedTuple):
    """The per-step FMI functions, ctypes function pointers of PROTOTYPES."""

    set: object  # fmi2SetReal / fmi3SetFloat64
    step: object  # fmi2DoStep / fmi3DoStep
    get: object  # fmi2GetReal / fmi3GetFloat64


class FmiHandles(NamedTuple):
    """What the per-step functions take."""

    instance: int  # the FMU instance's address
    vr_tau: object  # value references of the torque inputs (uint32)
    vr_out: object  # value references of the outputs read each step (uint32)
    outputs: object  # their buffer (float64)
    starts: object  # where each output port starts in outputs (-1: not mapped; int64)
    flags: object  # fmi3DoStep's output flags


class FusedIo(NamedTuple):
    """What the fused loop needs of a plant: its FMI version, the three per-step functions
    (set, doStep, get) and the handles they take (instance, value references, buffers),
    each record built by field name."""

    fmi_version: int
    functions: FmiFunctions
    handles: FmiHandles


def function_pointer(function, fmi_version: int, role: str):
    """``function`` (a ctypes function of the FMU's library) as PROTOTYPES[...][role]."""
    address = ctypes.cast(function, ctypes.c_void_p).value
    return PROTOTYPES[fmi_version][role](address)
