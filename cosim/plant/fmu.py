"""The plant as the master sees it: an FMU (FMI 2.0 or 3.0 Co-Simulation) behind FMPy.

Extracted and instantiated once (then reset), value references resolved once, and the
per-step calls go straight to the FMI functions with preallocated ctypes buffers that alias
numpy arrays, so a step allocates nothing. What differs between FMI versions lives in
:mod:`.lifecycle`.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from fmpy.model_description import ModelDescription

from .lifecycle import STATUS, FmiInstance, open_instance
from .mapping import FmuError, PlantVariables, check_parameters, check_plant_fmu, unit_differences
from .native import FmiFunctions, FmiHandles, FusedIo, function_pointer
from .ports import OUTPUT_PORTS, output_buffers


@dataclass
class Fmu:
    """One Co-Simulation instance of a plant FMU.

    After :meth:`start`, ``values[port]`` (numpy arrays, :mod:`.ports`) hold the latest
    outputs (NaN for a port not in ``mapped``) and :meth:`step` applies ``tau`` (held over
    the step) and advances by ``h`` seconds. ``mapping`` is ``plant.variables``: a port ->
    the FMU's names (unset keys: the built-in plants' names). The file, the mapping and the
    parameters are checked by :func:`cosim.plant.mapping.check_plant_fmu` first; ``variables``
    then holds the mapping as used.
    """

    path: Path
    mapping: dict[str, list[str] | None] | None = None
    parameters: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        md, variables = check_plant_fmu(self.path, self.mapping, self.parameters)
        self.model_description: ModelDescription = md
        self.variables: PlantVariables = variables
        self.fmi_version = int(md.fmiVersion[0])
        self.by_name = {v.name: v for v in md.modelVariables}
        self.links = len(self.variables.q)
        self.mapped = frozenset(p.name for p in OUTPUT_PORTS if p.name in self.variables.mapped)
        self.values = output_buffers(self.links)
        self.tau = np.zeros(self.links)
        # The mapped outputs, port after port, in one buffer the FMU writes per step.
        outputs, self._layout = [], []
        for port in OUTPUT_PORTS:
            names = self.variables.names.get(port.name) or []
            self._layout.append(len(outputs) if names else -1)
            outputs += names
        self._outputs = np.zeros(len(outputs))
        self._vr_tau = self._refs(self.variables.tau)
        self._vr_out = self._refs(outputs)
        self._parameters = {self.by_name[n].valueReference: float(v)
                            for n, v in self.parameters.items()}
        self._flags = np.zeros(4)  # fmi3DoStep's three flags and its last successful time
        self._fmi: FmiInstance | None = None
        self.time = 0.0

    def set_parameters(self, parameters: dict[str, float]) -> None:
        """Parameter and start values for the next :meth:`start` (checked like the
        constructor's)."""
        check_parameters(self.path, self.model_description, parameters)
        self.parameters = dict(parameters)
        self._parameters = {self.by_name[n].valueReference: float(v)
                            for n, v in parameters.items()}

    def _refs(self, names: list[str]):
        """Value references of names :func:`check_plant_fmu` has checked."""
        refs = [self.by_name[n].valueReference for n in names]
        return (ctypes.c_uint32 * len(refs))(*refs)

    # Life cycle ---------------------------------------------------------------------------

    def start(self, start_time: float = 0.0) -> None:
        """Instantiate (first call only, else reset), set parameters, initialise."""
        if self._fmi is None:
            self._fmi = open_instance(self.path, self.model_description)
            self._bind_raw_functions()
        else:
            self._fmi.reset()
        self._fmi.initialize(start_time, self._parameters)
        self.time = start_time
        self._read_outputs()

    def _bind_raw_functions(self) -> None:
        """The per-step FMI functions, called with preallocated buffers."""
        self._set, self._do_step, self._get = self._fmi.raw_step_functions()
        component = self._fmi.fmu.component
        tau = self.tau.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        out = self._outputs.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        n_tau, n_out = len(self._vr_tau), len(self._vr_out)
        # FMI 3 repeats the value count (arrays); its doStep reports through four pointers.
        extra = ((n_tau,), (n_out,)) if self.fmi_version == 3 else ((), ())
        self._set_args = (component, self._vr_tau, n_tau, tau, *extra[0])
        self._get_args = (component, self._vr_out, n_out, out, *extra[1])
        flags = self._flags.ctypes.data
        self._step_tail = ((1,) if self.fmi_version == 2 else
                           (True, flags, flags + 8, flags + 16, flags + 24))
        self._component = component

    def info(self) -> dict:
        """What the recording's properties say of the plant: model name, instantiation token
        (FMI 2 GUID), FMI version, file, our interface in its names (``plant.variables`` as
        used), and every real parameter's value as used (after :meth:`start`, so pipeline
        overrides show; else the start values)."""
        md = self.model_description
        names = [v.name for v in md.modelVariables
                 if v.causality == "parameter" and v.type in ("Real", "Float64")]
        if self._fmi is not None and names:
            values = [float(x) for x in self._fmi.get_reals(list(self._refs(names)))]
        else:
            values = [float(self.by_name[n].start or "nan") for n in names]
        return {"model_name": md.modelName, "instantiation_token": md.guid,
                "fmi_version": md.fmiVersion, "file": str(self.path),
                "generation_tool": md.generationTool or "",
                "variables": {k: v for k, v in self.variables.names.items() if v},
                "parameters": dict(zip(names, values, strict=True)),
                "unit_differences": unit_differences(md, self.variables)}

    # Per step -------------------------------------------------------------------------------

    def step(self, t: float, h: float) -> None:
        """Apply ``tau`` (zero-order hold) and advance from ``t`` to ``t + h`` seconds."""
        self.time = t
        status = self._set(*self._set_args)
        if status > 1:
            raise FmuError(self.describe_failure(0, status, t))
        status = self._do_step(self._component, t, h, *self._step_tail)
        if status > 1:
            raise FmuError(self.describe_failure(1, status, t))
        self.time = t + h
        self._read_outputs()

    def _read_outputs(self) -> None:
        status = self._get(*self._get_args)
        if status > 1:
            raise FmuError(self.describe_failure(2, status, self.time))
        for port, offset in zip(OUTPUT_PORTS, self._layout, strict=True):
            if offset >= 0:
                values = self.values[port.name]
                values.reshape(-1)[:] = self._outputs[offset:offset + values.size]

    def fused_io(self) -> FusedIo:
        """The per-step FMI functions and handles for the fused loop (after :meth:`start`)."""
        version = self.fmi_version
        functions = FmiFunctions(set=function_pointer(self._set, version, "set"),
                                 step=function_pointer(self._do_step, version, "step"),
                                 get=function_pointer(self._get, version, "get"))
        handles = FmiHandles(instance=ctypes.cast(self._component, ctypes.c_void_p).value,
                             vr_tau=np.array(self._vr_tau, dtype=np.uint32),
                             vr_out=np.array(self._vr_out, dtype=np.uint32),
                             outputs=self._outputs,
                             starts=np.array(self._layout, dtype=np.int64), flags=self._flags)
        return FusedIo(fmi_version=version, functions=functions, handles=handles)

    def describe_failure(self, call: int, status: int, t: float) -> str:
        """The message for a failed per-step call: ``call`` 0, 1, 2 for set (tau), doStep,
        get (outputs), at ``t`` seconds."""
        self._fmi.time = self.time = t
        fmi = self._fmi
        what = (fmi.set_name + " (tau)", "DoStep", fmi.get_name + " (outputs)")[call]
        return fmi.describe_failure(what, STATUS.get(status, f"status {status}"))

    def close(self) -> None:
        """Terminate and free the instance, unload its library, delete the extracted files."""
        if self._fmi is not None:
            fmi, self._fmi = self._fmi, None
            fmi.close()

    def __enter__(self) -> Fmu:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
