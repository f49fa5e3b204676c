"""The plant as the master sees it: an FMU (FMI 2.0 or 3.0 Co-Simulation) behind FMPy.

Extracted and instantiated once, value references resolved once, and the per-step calls
go straight to the FMI functions with preallocated ctypes buffers that alias numpy arrays,
so a step allocates nothing.
"""

from __future__ import annotations

import ctypes
import shutil
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from fmpy.fmi1 import FMICallException
from fmpy.model_description import ModelDescription

from ..engine.fused import FusedIo, function_pointer
from .mapping import FmuError, PlantVariables, extract, open_plant

_STATUS = {2: "status Discard", 3: "status Error", 4: "status Fatal", 5: "status Pending"}


@dataclass
class Fmu:
    """One Co-Simulation instance of a plant FMU.

    After :meth:`start`, ``q``, ``qdot`` and ``M`` (numpy arrays) hold the latest outputs and
    :meth:`step` applies ``tau`` (held over the step) and advances by ``h`` seconds.
    ``mapping`` is ``plant.variables``: our interface key -> the FMU's names (unset keys:
    the built-in plant's names). The file, the mapping and the parameters are checked by
    :func:`cosim.plant.mapping.open_plant` first; ``variables`` then holds the mapping as used.
    """

    path: Path
    mapping: dict[str, list[str] | None] | None = None
    parameters: dict[str, float] = field(default_factory=dict)
    # The FMU's latest log messages (logging is on, so the reason for a failure is here).
    messages: deque[str] = field(default_factory=lambda: deque(maxlen=100))

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        md, variables = open_plant(self.path, self.mapping, self.parameters)
        self.model_description: ModelDescription = md
        self.variables: PlantVariables = variables
        self.fmi_version = int(md.fmiVersion[0])
        self._set_name, self._get_name = (("SetReal", "GetReal") if self.fmi_version == 2
                                          else ("SetFloat64", "GetFloat64"))
        self.by_name = {v.name: v for v in md.modelVariables}
        self.links = len(self.variables.q)
        self.has_qdot = bool(self.variables.qdot)
        self.has_M = bool(self.variables.M)
        self.q = np.zeros(self.links)
        self.qdot = np.full(self.links, np.nan)
        self.M = np.full((self.links, self.links), np.nan)
        self.tau = np.zeros(self.links)
        outputs = self.variables.q + (self.variables.qdot or []) + (self.variables.M or [])
        self._outputs = np.zeros(len(outputs))
        self._vr_tau = self._refs(self.variables.tau)
        self._vr_out = self._refs(outputs)
        self._flag_buffer = np.zeros(4)  # fmi3DoStep's three flags and last time
        self._unzip: str | None = None
        self._instance = None
        self.time = 0.0

    def _refs(self, names: list[str]):
        """Value references of names :func:`open_plant` has checked."""
        refs = [self.by_name[n].valueReference for n in names]
        return (ctypes.c_uint32 * len(refs))(*refs)

    # Life cycle ---------------------------------------------------------------------------

    def start(self, start_time: float = 0.0) -> None:
        """Instantiate (first call only, else reset), set parameters, initialise."""
        md = self.model_description
        if self._instance is None:
            self._unzip = extract(str(self.path))
            common = dict(guid=md.guid, unzipDirectory=self._unzip, instanceName="plant",
                          modelIdentifier=md.coSimulation.modelIdentifier)
            if self.fmi_version == 2:
                from fmpy.fmi2 import FMU2Slave

                instance = FMU2Slave(**common)
                self._call("Instantiate", instance.instantiate, callbacks=self._fmi2_callbacks(),
                           loggingOn=True)
            else:
                from fmpy.fmi3 import FMU3Slave

                instance = FMU3Slave(**common)
                self._call("Instantiate", instance.instantiate, logMessage=self._log3,
                           loggingOn=True)
            self._instance = instance
            self._bind_raw_functions()
        else:
            self._call("Reset", self._instance.reset)
        inst = self._instance
        if self.fmi_version == 2:
            self._call("SetupExperiment", inst.setupExperiment, startTime=start_time)
        self._call("EnterInitializationMode", inst.enterInitializationMode,
                   **({"startTime": start_time} if self.fmi_version == 3 else {}))
        if self.parameters:
            names = list(self.parameters)
            values = [float(self.parameters[n]) for n in names]
            setter = inst.setReal if self.fmi_version == 2 else inst.setFloat64
            self._call(f"{self._set_name} (plant.parameters)", setter, list(self._refs(names)),
                       values)
        self._call("ExitInitializationMode", inst.exitInitializationMode)
        self.time = start_time
        self._read_outputs()

    def _fmi2_callbacks(self):
        from fmpy.fmi2 import (
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
        )
        from fmpy.logging import addLoggerProxy

        libc = ctypes.CDLL(None)
        libc.calloc.restype = ctypes.c_void_p
        libc.free.argtypes = [ctypes.c_void_p]
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(self._log2)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(libc.calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(libc.free)
        addLoggerProxy(ctypes.byref(callbacks))
        self._callbacks = callbacks  # keep alive as long as the instance
        return callbacks

    def _log2(self, env, name, status, category, message) -> None:
        self._log(message)

    def _log3(self, env, status, category, message) -> None:
        self._log(message)

    def _log(self, message: bytes) -> None:
        # One line each: a message is quoted inside our one-line errors.
        self.messages.append(" ".join(message.decode(errors="replace").split()))

    def _call(self, what: str, function, *args, **kwargs):
        try:
            return function(*args, **kwargs)
        except FMICallException as exc:
            raise FmuError(self._describe_failure(what, exc)) from None
        except Exception as exc:  # FMPy raises a bare Exception when instantiate gives NULL
            if what != "Instantiate":
                raise
            raise FmuError(self._describe_failure(what, f"{exc}: the FMU returned no "
                                                  "instance")) from None

    def _describe_failure(self, what: str, detail) -> str:
        """``what``: the FMI function without its fmi2/fmi3 prefix, e.g. "DoStep"."""
        log = f": {self.messages[-1]}" if self.messages else ""
        return (f"{self.path.name}: fmi{self.fmi_version}{what} failed at t = {self.time:.6g} s "
                f"({detail}){log}")

    def _bind_raw_functions(self) -> None:
        """The per-step FMI functions, called with preallocated buffers."""
        inst = self._instance
        dll = inst.dll
        self._component = inst.component
        self._tau_buffer = self.tau.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        self._out_buffer = self._outputs.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        if self.fmi_version == 2:
            self._set = dll.fmi2SetReal
            self._get = dll.fmi2GetReal
            self._do_step = dll.fmi2DoStep
            self._set.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t,
                                  ctypes.c_void_p]
            self._get.argtypes = self._set.argtypes
            self._do_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                      ctypes.c_int]
        else:
            self._set = dll.fmi3SetFloat64
            self._get = dll.fmi3GetFloat64
            self._do_step = dll.fmi3DoStep
            self._set.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t,
                                  ctypes.c_void_p, ctypes.c_size_t]
            self._get.argtypes = self._set.argtypes
            self._do_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                      ctypes.c_bool] + [ctypes.c_void_p] * 4
            self._flags = (ctypes.c_bool * 3)()
            self._last_time = ctypes.c_double()
            self._flag_ptrs = [ctypes.byref(self._flags, i) for i in range(3)]
            self._flag_ptrs.append(ctypes.byref(self._last_time))
        for f in (self._set, self._get, self._do_step):
            f.restype = ctypes.c_int
        n_tau, n_out = len(self._vr_tau), len(self._vr_out)
        if self.fmi_version == 2:
            self._set_args = (self._component, self._vr_tau, n_tau, self._tau_buffer)
            self._get_args = (self._component, self._vr_out, n_out, self._out_buffer)
        else:
            self._set_args = (self._component, self._vr_tau, n_tau, self._tau_buffer, n_tau)
            self._get_args = (self._component, self._vr_out, n_out, self._out_buffer, n_out)

    def describe(self) -> dict:
        """What the recording's properties say of the plant: model name, instantiation token
        (FMI 2 GUID), FMI version, file, our interface in its names (``plant.variables`` as
        used), and every real parameter's value as used (after
        :meth:`start`, so pipeline overrides show; else the start values)."""
        md = self.model_description
        names = [v.name for v in md.modelVariables
                 if v.causality == "parameter" and v.type in ("Real", "Float64")]
        if self._instance is not None and names:
            getter = self._instance.getReal if self.fmi_version == 2 else self._instance.getFloat64
            values = [float(x) for x in getter(list(self._refs(names)))]
        else:
            values = [float(self.by_name[n].start or "nan") for n in names]
        return {"model_name": md.modelName, "instantiation_token": md.guid,
                "fmi_version": md.fmiVersion, "file": str(self.path),
                "generation_tool": md.generationTool or "",
                "variables": {k: v for k, v in vars(self.variables).items() if v},
                "parameters": dict(zip(names, values, strict=True))}

    # Per step -------------------------------------------------------------------------------

    def fused_io(self) -> FusedIo:
        """The per-step FMI functions and handles for the fused loop (after :meth:`start`)."""
        version = self.fmi_version
        functions = tuple(function_pointer(f, version, role) for f, role in
                          ((self._set, "set"), (self._do_step, "step"), (self._get, "get")))
        component = ctypes.cast(self._component, ctypes.c_void_p).value
        handles = (component, np.array(self._vr_tau, dtype=np.uint32),
                   np.array(self._vr_out, dtype=np.uint32), self._outputs,
                   self.links if self.has_qdot else 0,
                   self.links ** 2 if self.has_M else 0, self._flag_buffer)
        return FusedIo(version, functions, handles)

    def describe_failure(self, call: int, status: int, t: float) -> str:
        """The message for a failed per-step call of the fused loop: ``call`` 0, 1, 2 for
        set (tau), doStep, get (outputs), at ``t`` seconds."""
        self.time = t
        what = (self._set_name + " (tau)", "DoStep", self._get_name + " (outputs)")[call]
        return self._describe_failure(what, _STATUS.get(status, f"status {status}"))

    def step(self, t: float, h: float) -> None:
        """Apply ``tau`` (zero-order hold) and advance from ``t`` to ``t + h`` seconds."""
        self.time = t
        if self._set(*self._set_args) > 1:
            raise FmuError(self._describe_failure(self._set_name + " (tau)", "status error"))
        if self.fmi_version == 2:
            status = self._do_step(self._component, self.time, h, 1)
        else:
            status = self._do_step(self._component, self.time, h, True, *self._flag_ptrs)
        if status > 1:
            detail = _STATUS.get(status, f"status {status}")
            raise FmuError(self._describe_failure("DoStep", detail))
        self.time = t + h
        self._read_outputs()

    def _read_outputs(self) -> None:
        if self._get(*self._get_args) > 1:
            raise FmuError(self._describe_failure(self._get_name + " (outputs)", "status error"))
        n = self.links
        self.q[:] = self._outputs[:n]
        k = n
        if self.has_qdot:
            self.qdot[:] = self._outputs[k:k + n]
            k += n
        if self.has_M:
            self.M[:] = self._outputs[k:k + n * n].reshape(n, n)

    def close(self) -> None:
        """Terminate and free the instance, unload its library, delete the extracted files."""
        if self._instance is not None:
            instance, self._instance = self._instance, None
            try:
                instance.terminate()
            except FMICallException:
                pass
            getattr(instance, f"fmi{self.fmi_version}FreeInstance")(instance.component)
            _release_pythonfmu(instance.dll)
            instance.freeLibrary()
        if self._unzip:
            shutil.rmtree(self._unzip, ignore_errors=True)
            self._unzip = None

    def __enter__(self) -> Fmu:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _release_pythonfmu(dll) -> None:
    """PythonFMU (0.7.0) FMUs keep their interpreter guard in a static ``shared_ptr`` that
    the library's unload hook resets after C++ has already destroyed it: a use after free at
    process exit (or unload) that corrupts the heap, so that the process aborts with
    "corrupted double-linked list" after all its work is done, about one exit in two.
    Resetting it ourselves, through the hook it exports, while the library is loaded and
    the pointer alive, leaves both later resets nothing to do."""
    release = getattr(dll, "finalizePythonInterpreter", None)
    if release is not None:
        release.restype = None
        release()
