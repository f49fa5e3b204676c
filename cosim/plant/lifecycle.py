"""One FMI life cycle, per FMI version behind one interface (as FMPy's ``FMU2Slave`` /
``FMU3Slave``): instantiate with logging on, initialise with parameter values, reset,
terminate and free, and the raw per-step functions. Used by the co-simulation adapter
(:mod:`.fmu`), linearisation (Model Exchange) and the tests' helpers.

Every failing call raises :class:`~.mapping.FmuError` naming the FMU, the FMI call, the time
and the FMU's last log message.
"""

from __future__ import annotations

import ctypes
from collections import deque
from pathlib import Path
from typing import ClassVar

from fmpy.fmi1 import FMICallException
from fmpy.model_description import ModelDescription

from .mapping import FmuError
from .unpack import extract, remove

STATUS = {2: "status Discard", 3: "status Error", 4: "status Fatal", 5: "status Pending"}
INTERFACES = ("CoSimulation", "ModelExchange")


class FmiInstance:
    """One instance of an FMU through FMPy. Use :func:`open_instance`, which picks the
    version's class. ``messages`` keeps the FMU's last 100 log messages, one line each."""

    version: ClassVar[int]
    set_name: ClassVar[str]  # "SetReal" / "SetFloat64"
    get_name: ClassVar[str]

    def __init__(self, path: str | Path, md: ModelDescription, interface: str = "CoSimulation",
                 name: str = "plant"):
        if interface not in INTERFACES:
            raise ValueError(f"interface {interface!r}: one of {INTERFACES}")
        self.path, self.md, self.interface = Path(path), md, interface
        self.messages: deque[str] = deque(maxlen=100)
        self.time = 0.0
        kind = md.coSimulation if interface == "CoSimulation" else md.modelExchange
        self._unzip: str | None = extract(self.path)
        try:
            try:
                self.fmu = self._fmpy_class()(guid=md.guid, unzipDirectory=self._unzip,
                                              instanceName=name,
                                              modelIdentifier=kind.modelIdentifier)
            except Exception as exc:  # FMPy's bare Exception when dlopen fails
                detail = str(exc).rsplit(": ", 1)[-1]
                raise FmuError(f"{self.path}: its binary cannot be loaded on this machine "
                               f"({detail}); rebuild or re-export the FMU") from None
            self.call("Instantiate", self._instantiate)
        except FmuError:
            remove(self._unzip)
            raise

    # What differs between versions ---------------------------------------------------------

    def _fmpy_class(self):
        raise NotImplementedError

    def _instantiate(self) -> None:
        raise NotImplementedError

    def _enter_initialization(self, start_time: float) -> None:
        raise NotImplementedError

    def set_reals(self, refs: list[int], values: list[float]) -> None:
        raise NotImplementedError

    def get_reals(self, refs: list[int]) -> list[float]:
        raise NotImplementedError

    def _settle_events(self) -> None:
        """Model Exchange: event iteration at the start, before continuous time."""
        raise NotImplementedError

    def raw_step_functions(self) -> tuple:
        """The C functions (set, doStep, get) of the library, for per-step calls."""
        raise NotImplementedError

    # The life cycle --------------------------------------------------------------------------

    def initialize(self, start_time: float = 0.0, parameters: dict[int, float] | None = None
                   ) -> None:
        """Enter initialisation at ``start_time``, set ``parameters`` (value reference ->
        value), exit; Model Exchange then enters continuous time."""
        self.time = start_time
        self.call("EnterInitializationMode", self._enter_initialization, start_time)
        if parameters:
            self.call(f"{self.set_name} (plant.parameters)", self.set_reals, list(parameters),
                      [float(v) for v in parameters.values()])
        self.call("ExitInitializationMode", self.fmu.exitInitializationMode)
        if self.interface == "ModelExchange":
            self.call("UpdateDiscreteStates", self._settle_events)
            self.call("EnterContinuousTimeMode", self.fmu.enterContinuousTimeMode)

    def reset(self) -> None:
        self.call("Reset", self.fmu.reset)

    def close(self) -> None:
        """Terminate and free the instance, unload its library, delete the extracted files."""
        if self.fmu is not None:
            fmu, self.fmu = self.fmu, None
            try:
                fmu.terminate()
            except FMICallException:
                pass
            getattr(fmu, f"fmi{self.version}FreeInstance")(fmu.component)
            _release_pythonfmu(fmu.dll)
            fmu.freeLibrary()
        if self._unzip:
            remove(self._unzip)
            self._unzip = None

    def call(self, what: str, function, *args, **kwargs):
        """``function(*args)``, an FMI call; a failure raises :class:`FmuError` saying
        ``fmi<version><what>`` failed."""
        try:
            return function(*args, **kwargs)
        except FMICallException as exc:  # its text would name the function again
            status = getattr(exc, "status", None)
            raise FmuError(self.describe_failure(what, STATUS.get(status, exc))) from None
        except Exception as exc:  # FMPy raises a bare Exception when instantiate gives NULL
            if what != "Instantiate":
                raise
            raise FmuError(self.describe_failure(what, f"{exc}: the FMU returned no "
                                                 "instance")) from None

    def describe_failure(self, what: str, detail) -> str:
        """``what``: the FMI function without its fmi2/fmi3 prefix, e.g. "DoStep"."""
        log = f": {self.messages[-1]}" if self.messages else ""
        return (f"{self.path.name}: fmi{self.version}{what} failed at t = {self.time:.6g} s "
                f"({detail}){log}")

    def _log(self, message: bytes) -> None:
        # One line each: a message is quoted inside our one-line errors.
        self.messages.append(" ".join(message.decode(errors="replace").split()))


class Fmi2Instance(FmiInstance):
    version, set_name, get_name = 2, "SetReal", "GetReal"

    def _fmpy_class(self):
        from fmpy.fmi2 import FMU2Model, FMU2Slave

        return FMU2Slave if self.interface == "CoSimulation" else FMU2Model

    def _instantiate(self) -> None:
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
        callbacks.logger = fmi2CallbackLoggerTYPE(
            lambda env, name, status, category, message: self._log(message))
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(libc.calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(libc.free)
        addLoggerProxy(ctypes.byref(callbacks))
        self._callbacks = callbacks  # keep alive as long as the instance
        self.fmu.instantiate(callbacks=callbacks, loggingOn=True)

    def _enter_initialization(self, start_time: float) -> None:
        self.fmu.setupExperiment(startTime=start_time)
        self.fmu.enterInitializationMode()

    def set_reals(self, refs: list[int], values: list[float]) -> None:
        self.fmu.setReal(refs, values)

    def get_reals(self, refs: list[int]) -> list[float]:
        return self.fmu.getReal(refs)

    def _settle_events(self) -> None:
        while self.fmu.newDiscreteStates()[0]:
            pass

    def raw_step_functions(self) -> tuple:
        dll = self.fmu.dll
        functions = dll.fmi2SetReal, dll.fmi2DoStep, dll.fmi2GetReal
        pointers = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p]
        functions[0].argtypes = functions[2].argtypes = pointers
        functions[1].argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                 ctypes.c_int]
        for f in functions:
            f.restype = ctypes.c_int
        return functions


class Fmi3Instance(FmiInstance):
    version, set_name, get_name = 3, "SetFloat64", "GetFloat64"

    def _fmpy_class(self):
        from fmpy.fmi3 import FMU3Model, FMU3Slave

        return FMU3Slave if self.interface == "CoSimulation" else FMU3Model

    def _instantiate(self) -> None:
        self.fmu.instantiate(logMessage=lambda env, status, category, message:
                             self._log(message), loggingOn=True)

    def _enter_initialization(self, start_time: float) -> None:
        self.fmu.enterInitializationMode(startTime=start_time)

    def set_reals(self, refs: list[int], values: list[float]) -> None:
        self.fmu.setFloat64(refs, values)

    def get_reals(self, refs: list[int]) -> list[float]:
        return self.fmu.getFloat64(refs)

    def _settle_events(self) -> None:
        while self.fmu.updateDiscreteStates()[0]:
            pass

    def raw_step_functions(self) -> tuple:
        dll = self.fmu.dll
        functions = dll.fmi3SetFloat64, dll.fmi3DoStep, dll.fmi3GetFloat64
        arrays = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p,
                  ctypes.c_size_t]
        functions[0].argtypes = functions[2].argtypes = arrays
        functions[1].argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                 ctypes.c_bool] + [ctypes.c_void_p] * 4
        for f in functions:
            f.restype = ctypes.c_int
        return functions


def open_instance(path: str | Path, md: ModelDescription, interface: str = "CoSimulation",
                  name: str = "plant") -> FmiInstance:
    """An instantiated FMU of ``md``'s FMI version (not yet initialised)."""
    cls = Fmi2Instance if md.fmiVersion.startswith("2") else Fmi3Instance
    return cls(path, md, interface, name)


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
