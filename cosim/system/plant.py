"""A system of FMUs as the master sees a plant: the same interface as one FMU
(:class:`~cosim.plant.ports.Plant`: ``links``, ``mapped``, ``values``, ``tau``, ``start``,
``step``, ``info``, ``close``), so that blocks, the trace and the recording need no special
case; the system's own connectors are the plant's ports, mapped by ``plant.variables`` as
for one FMU.

A step from t_k to t_k + h (every value held over it, as cosim holds τ):

1. the plant's inputs (τ) and every value passes on through the components in dependency
   order (:mod:`.order`): a component's fed inputs are set, then its outputs that depend on
   them within the instant are read, so that a direct-feedthrough component adds no delay;
   a delayed connection carries the value its source had before this pass;
2. every component due at t_k steps over its own step (``step_multiple`` master steps);
3. the outputs of every component whose step ends at t_k + h are read (those of a
   component every output of which the next exchange gets before anything reads it, there
   instead: the same values, one FMI call fewer).

Every value lives in one flat array: the plant's ports and the trace's signals of the
components' inputs and outputs (``<component>.<variable>``, recorded under
``plant/<component>/``) are views into it and into its row per step, so a step copies
nothing beyond the FMI calls. The trace's row k holds what the components exchanged over
[t_k, t_k + h]. A component that fails names itself. SI units, radians.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

from ..plant.errors import FmuError
from ..plant.lifecycle import STATUS, open_instance
from ..plant.mapping import (
    map_variables,
    unit_differences,
    unit_spelling,
)
from ..plant.ports import OUTPUT_PORTS, output_buffers
from ..plant.unpack import remove
from ..signals import Trace
from .layout import (
    Call,
    Component,
    component_info,
    component_signals,
    folded_passes,
    lay_out,
    system_description,
)
from .order import schedule
from .structure import Endpoint, System
from .wiring import Wiring, check_system


class SystemPlant:
    """A system of FMU components run as the plant (module docstring). ``system`` (read from
    an SSP archive or a pipeline's ``[plant.system]``) is checked first, then its connectors
    mapped by ``mapping`` (``plant.variables``); ``parameters``: plant.parameters over the
    components' own ("COMPONENT.VARIABLE", or the arm's variable); ``folder``: an unpacked
    SSP this plant removes when it closes."""

    def __init__(self, system: System, mapping: dict[str, list[str] | None] | None = None,
                 parameters: dict[str, float] | None = None, folder: str | None = None):
        self.system, self.folder = system, folder
        self.path = Path(system.origin) if system.origin else Path(system.name)
        self.parameters = dict(parameters or {})
        self.wiring: Wiring = check_system(system, self.parameters)
        self.passes, self._read_after = folded_passes(system, self.wiring,
                                                      schedule(self.wiring))
        self.model_description = system_description(self.wiring)
        variables, problems = map_variables(self.model_description, mapping)
        if variables is None:
            raise FmuError(f"{self.path.name}: the system does not fit the plant interface: "
                           + "; ".join(problems))
        self.variables = variables
        inputs = [p.name for p in self.wiring.ports if p.kind == "input"]
        extra = [name for name in inputs if name not in variables.tau]
        if extra:
            raise FmuError(f"{self.path.name}: the system's input {extra[0]!r} is not one of "
                           f"the plant's torque inputs (plant.variables.tau: "
                           f"{', '.join(variables.tau)}); nothing would drive it")
        self.links = len(variables.q)
        self.mapped = frozenset(p.name for p in OUTPUT_PORTS if p.name in variables.mapped)
        self.fmi_version = tuple(sorted({int(md.fmiVersion[0])
                                         for md in self.wiring.descriptions.values()}))
        self._components, width = lay_out(system, self.wiring, self.passes, self.parameters,
                                          variables.tau, self.links)
        self._flat = np.zeros(width)
        self.tau = self._flat[:self.links]
        self.values, self._copied = self._ports()
        # trace key -> its signal, (first, count, shape) in the flat array, "input" | "output"
        self.signals, self._views, self._directions = component_signals(self._components,
                                                                        self.links)
        self._record: np.ndarray | None = None
        self._calls: list[Call] = []
        # what the exchange does with each: (its component's step multiple, its function and
        # arguments, the gather before it, the call); built once, read each step
        self._plan: list[tuple] = []
        # per component, what each step calls: (component, step multiple, doStep, its
        # instance, doStep's trailing arguments, the call that reads its outputs)
        self._steppers: list[tuple] = []
        self._delayed = self._delayed_copies()
        self._k = 0
        self.time = 0.0

    # What the system is, and where each value sits ----------------------------------------

    def _component(self, name: str) -> Component:
        return next(c for c in self._components if c.name == name)

    def _source_index(self, end: Endpoint) -> int:
        """Where the value that feeds ``end`` sits in the flat array."""
        source = self.wiring.sources[end]
        if source.element is None:
            return self.variables.tau.index(source.connector)
        return self._component(source.element).index(source.connector)

    def _ports(self) -> tuple[dict[str, np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
        """The plant's output ports: views into the flat array where their sources sit in
        order there, else arrays copied after each step (``copied``: (port, indices))."""
        values = output_buffers(self.links)
        copied = []
        for port in OUTPUT_PORTS:
            names = self.variables.names.get(port.name)
            if not names:
                continue
            index = np.array([self._source_index(Endpoint(None, n)) for n in names])
            if np.all(np.diff(index) == 1):
                values[port.name] = self._flat[index[0]:index[-1] + 1].reshape(
                    values[port.name].shape)
            else:
                copied.append((values[port.name].reshape(-1), index))
        return values, copied

    def _delayed_copies(self) -> tuple[np.ndarray, np.ndarray] | None:
        ends = sorted(self.wiring.delayed, key=str)
        if not ends:
            return None
        return (np.array([self._component(e.element).index(e.connector) for e in ends]),
                np.array([self._source_index(e) for e in ends]))

    # Life cycle ----------------------------------------------------------------------------

    def start(self, start_time: float = 0.0) -> None:
        """Instantiate every component (first call only, else reset), set its parameters,
        initialise; read every value and pass the inputs on once, so that what depends on
        them (a drive's inertia in the arm's M) holds at ``start_time``."""
        for c in self._components:
            refs = {v.name: v.valueReference for v in c.md.modelVariables}
            try:
                if c.fmi is None:
                    c.fmi = open_instance(c.path, c.md, "CoSimulation", c.name)
                    self._bind(c)
                else:
                    c.fmi.reset()
                c.fmi.initialize(start_time, {refs[n]: v for n, v in c.parameters.items()})
            except FmuError as exc:
                raise FmuError(f"component {c.name!r}: {exc}") from None
        if not self._calls:
            self._calls = self._pass_calls()
            self._plan = [(c.component.multiple, c.function, c.args, c.copy_from, c.copy_to, c)
                          for c in self._calls]
            self._steppers = [(c, c.multiple, c.functions[1], c.fmi.fmu.component, c.tail,
                               c.read_outputs if c.name in self._read_after else None)
                              for c in self._components]
        self.tau[:] = 0.0
        self.time, self._k = start_time, 0
        for c in self._components:
            self._call(c.read_outputs, start_time)
            self._call(c.read_inputs, start_time)
        self._exchange(0, start_time)
        self._copy_ports()

    def _bind(self, c: Component) -> None:
        """The component's per-step FMI functions, and its calls that read every output and
        every input into the flat array."""
        c.functions = c.fmi.raw_step_functions()
        c.refs = {v.name: v.valueReference for v in c.md.modelVariables}
        flags = c.flags.ctypes.data  # fmi3DoStep reports through four pointers
        c.tail = (1,) if c.version == 2 else (True, flags, flags + 8, flags + 16, flags + 24)
        c.read_outputs = self._on_flat(c, "get", c.outputs, c.at, "outputs")
        c.read_inputs = self._on_flat(c, "get", c.own, c.at + len(c.outputs), "inputs")

    def _on_flat(self, c: Component, action: str, names: list[str], first: int,
                 what: str, values: np.ndarray | None = None) -> Call:
        """An FMI call that sets or gets ``names`` of ``c`` from or into the flat array's
        slice at ``first`` (or ``values``, from its start)."""
        vrs = (ctypes.c_uint32 * len(names))(*(c.refs[n] for n in names))
        count = (len(names),) if c.version == 3 else ()
        function = c.functions[0 if action == "set" else 2]
        name = c.fmi.set_name if action == "set" else c.fmi.get_name
        array = self._flat if values is None else values
        return Call(c, f"{name} ({what})", function,
                     (c.fmi.fmu.component, vrs, len(names),
                      array.ctypes.data + 8 * int(first), *count))

    def _pass_calls(self) -> list[Call]:
        """The passes (:mod:`.order`) as calls on the flat array: on the slice their
        variables sit in, or (inputs whose sources are not adjacent) on a buffer gathered
        from them just before."""
        calls = []
        for step in self.passes:
            c = self._component(step.component)
            index = np.array([c.index(n) for n in step.variables])
            what = "inputs" if step.action == "set" else "outputs"
            if np.all(np.diff(index) == 1):
                calls.append(self._on_flat(c, step.action, list(step.variables), index[0],
                                           what))
                continue
            buffer = np.zeros(len(index))
            call = self._on_flat(c, step.action, list(step.variables), 0, what, buffer)
            call.copy_to, call.copy_from = buffer, index
            calls.append(call)
        return calls

    def _call(self, call: Call, t: float) -> None:
        status = call.function(*call.args)
        if status > 1:
            raise FmuError(self._failure(call.component, call.what, status, t))

    def _failure(self, c: Component, what: str, status: int, t: float) -> str:
        c.fmi.time = t
        return (f"component {c.name!r}: "
                + c.fmi.describe_failure(what, STATUS.get(status, f"status {status}")))

    def _exchange(self, k: int, t: float) -> None:
        """Step 1 of the module docstring at master step ``k``: the passes of the
        components due."""
        flat = self._flat
        if self._delayed is not None:
            flat[self._delayed[0]] = flat[self._delayed[1]]
        for multiple, function, args, copy_from, copy_to, call in self._plan:
            if k % multiple:
                continue
            if copy_from is not None:
                flat.take(copy_from, out=copy_to)
            status = function(*args)
            if status > 1:
                raise FmuError(self._failure(call.component, call.what, status, t))

    def _copy_ports(self) -> None:
        for values, index in self._copied:  # into the port, no temporary array per step
            self._flat.take(index, out=values)

    # Per step -------------------------------------------------------------------------------

    def step(self, t: float, h: float) -> None:
        """Apply ``tau`` (held) and advance from ``t`` to ``t + h`` seconds."""
        k = self._k
        self._exchange(k, t)
        if self._record is not None:
            self._record[k] = self._flat
        for c, multiple, do_step, handle, tail, _ in self._steppers:
            if k % multiple == 0:
                status = do_step(handle, t, multiple * h, *tail)
                if status > 1:
                    raise FmuError(self._failure(c, "DoStep", status, t))
        last = self._record is not None and k + 1 == len(self._record) - 1
        for c, multiple, _, _, _, read in self._steppers:
            if (k + 1) % multiple == 0 and (read is not None or last):
                read = read or c.read_outputs  # the last row's: every output as it ended
                status = read.function(*read.args)
                if status > 1:
                    raise FmuError(self._failure(c, read.what, status, t + h))
        if self._copied:
            self._copy_ports()
        self._k, self.time = k + 1, t + h
        if last:
            self._record[k + 1] = self._flat  # the last row: as read after the last step

    def bind_trace(self, trace: Trace) -> None:
        """Record into ``trace``: its arrays of this plant's :attr:`signals` become views
        into this plant's rows, which each step fills."""
        self._record = np.full((trace.steps + 1, len(self._flat)), np.nan)
        rows = len(self._record)
        for key, (first, count, form) in self._views.items():
            if key not in trace:
                continue
            if form == "1":
                trace.arrays[key] = self._record[:, first]
            else:
                view = self._record[:, first:first + count]
                trace.arrays[key] = view if form == "n" else view.reshape(
                    rows, self.links, self.links)
        self._record[0] = self._flat

    def info(self) -> dict:
        """What the recording and summary say of the plant (as :meth:`Fmu.info`): the
        system's name and file, the ports' names, the parameters of the arm (the component
        that feeds most of the system's outputs: the guarantee compares them with the nominal
        model), and
        under ``system``: that component's name, the trace key of its per-joint torque
        input (what it was given, beside the torque the plant was asked for), and per
        component its model, file, FMI version, step and every real parameter as used."""
        components = {c.name: component_info(c) for c in self._components}
        arm = self.wiring.arm
        torque = next((key for key, signal in self.signals.items()
                       if key.startswith(f"{arm}.") and signal.shape == "n"
                       and self._directions[key] == "input"
                       and unit_spelling(signal.unit) == "N.m"), None)
        versions = " and ".join(map(str, self.fmi_version))
        return {"model_name": f"{self.system.name} (a system of {len(components)} FMUs: "
                              f"{', '.join(components)})",
                "instantiation_token": "", "fmi_version": f"{versions} (its components')",
                "file": str(self.path), "generation_tool": "",
                "variables": {k: v for k, v in self.variables.names.items() if v},
                "parameters": components[arm]["parameters"],
                "unit_differences": unit_differences(self.model_description, self.variables),
                "system": {"arm": arm, "arm_torque": torque, "components": components}}

    def set_parameters(self, parameters: dict[str, float]) -> None:
        """Parameter values ("COMPONENT.VARIABLE") for the next :meth:`start`, checked."""
        check_system(self.system, parameters)
        self.parameters = dict(parameters)
        for c in self._components:
            c.parameters = self.wiring.component_parameters(c.name, parameters)

    def close(self) -> None:
        """Terminate and free every component; remove the unpacked SSP."""
        for c in self._components:
            if c.fmi is not None:
                fmi, c.fmi = c.fmi, None
                fmi.close()
        self._calls, self._plan, self._steppers = [], [], []
        if self.folder is not None:
            remove(self.folder)
            self.folder = None

    def __enter__(self) -> SystemPlant:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
