"""Where each value of a system of FMUs sits (:class:`~cosim.system.plant.SystemPlant`):
its components as they run, their outputs and inputs laid out in one flat array so that each
pass's are one slice, the passes folded where a component's outputs can be read in the
exchange, the system's connectors as one FMU's variables, and every component's values as
trace signals. SI units, radians."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from fmpy.model_description import ModelDescription, ModelVariable

from ..plant.lifecycle import FmiInstance
from ..plant.mapping import REAL_TYPES, declared_unit
from ..signals import Signal
from .order import Pass
from .structure import Endpoint, System
from .wiring import Wiring

ELEMENT = re.compile(r"^(.+)\[(\d+)(?:,(\d+))?\]$")  # "tau[2]", "M[1,2]"


@dataclass
class Component:
    """A component as it runs: its FMI instance, and where its outputs and inputs (every
    Real one, for the trace) sit in the flat array."""

    name: str
    path: Path
    md: ModelDescription
    multiple: int
    parameters: dict[str, float]
    outputs: list[str]
    inputs: list[str]
    # where each output and input sits in the flat array: its outputs from ``at`` on, then
    # its inputs of their own (``own``: those no connection feeds, or a delayed one feeds);
    # an input a connection feeds is its source's place (the values are one)
    at: int = 0
    own: list[str] = field(default_factory=list)
    where: dict[str, int] = field(default_factory=dict)
    fmi: FmiInstance | None = None
    # Bound when it is instantiated: its (set, doStep, get) functions, value references,
    # doStep's trailing arguments, and the calls that read all its outputs and inputs.
    functions: tuple = ()
    refs: dict[str, int] = field(default_factory=dict)
    flags: np.ndarray = field(default_factory=lambda: np.zeros(4))
    tail: tuple = ()
    read_outputs: Call | None = None
    read_inputs: Call | None = None

    @property
    def version(self) -> int:
        return int(self.md.fmiVersion[0])

    def index(self, variable: str) -> int:
        """Where ``variable`` (an output or input) sits in the flat array."""
        return self.where[variable]


@dataclass
class Call:
    """One pass's FMI call, and the gather before it: ``copy_to[:] = flat[copy_from]``."""

    component: Component
    what: str  # the call, for messages: "SetReal (inputs)", "GetReal (outputs)"
    function: object
    args: tuple
    copy_to: np.ndarray | None = None
    copy_from: np.ndarray | None = None


def folded_passes(system: System, wiring: Wiring, passes: list[Pass]
                  ) -> tuple[list[Pass], set[str]]:
    """The passes, and the components whose outputs are read after each step. A
    component stepped every master step whose outputs are got in the exchange anyway,
    whose every reader (none of them the system's outputs, none through a delayed
    connection) is set after that get, has all its outputs got there instead: the
    values are the same (what depends on no input is unchanged by setting them) and a
    step makes one FMI call fewer."""
    sources = wiring.sources
    read_after = set()
    out = list(passes)
    for component in system.components:
        name = component.name
        gets = [i for i, p in enumerate(passes) if (p.component, p.action) == (name, "get")]
        readers = [end for end, source in sources.items() if source.element == name]
        folds = component.step_multiple == 1 and len(gets) == 1 and all(
            end.element is not None and end not in wiring.delayed
            and any(i > gets[0] and p.action == "set" and p.component == end.element
                    and end.connector in p.variables for i, p in enumerate(passes))
            for end in readers)
        if not folds:
            read_after.add(name)
            continue
        md = wiring.descriptions[name]
        out[gets[0]] = Pass(name, "get", tuple(
            v.name for v in md.modelVariables if v.causality == "output"
            and v.type in REAL_TYPES and not v.dimensions))
    return out, read_after

def system_description(wiring: Wiring) -> ModelDescription:
    """A system's own connectors as one FMU's variables (the ports' checks read them)."""
    md = ModelDescription()
    md.fmiVersion, md.modelName = "2.0", wiring.system.name
    for vr, port in enumerate(wiring.ports):
        md.modelVariables.append(ModelVariable(name=port.name, valueReference=vr,
                                               type="Real", causality=port.kind,
                                               unit=port.unit))
    return md

def lay_out(system: System, wiring: Wiring, passes: list[Pass], parameters: dict[str, float],
            tau: list[str], links: int) -> tuple[list[Component], int]:
    """Each component's outputs, ordered so that each pass's are adjacent (one FMI call
    on a slice of the flat array), then its inputs of its own; an input a connection
    feeds (not delayed) takes its source's place. Returns the components and the flat
    array's length."""
    by_pass: dict[str, list[str]] = {}
    for step in passes:
        by_pass.setdefault(f"{step.component}/{step.action}", []).extend(step.variables)
    out, at = [], links
    for component in system.components:
        md = wiring.descriptions[component.name]
        real = [v for v in md.modelVariables if v.type in REAL_TYPES and not v.dimensions]
        outputs = _ordered(by_pass.get(f"{component.name}/get", []),
                           [v.name for v in real if v.causality == "output"])
        inputs = _ordered(by_pass.get(f"{component.name}/set", []),
                          [v.name for v in real if v.causality == "input"])
        own = [n for n in inputs if Endpoint(component.name, n) not in wiring.sources
               or Endpoint(component.name, n) in wiring.delayed]
        given = wiring.component_parameters(component.name, parameters)
        c = Component(component.name, component.source, md, component.step_multiple,
                       given, outputs, inputs, at, own)
        c.where = {name: at + i for i, name in enumerate(outputs + own)}
        out.append(c)
        at += len(outputs) + len(own)
    by_name = {c.name: c for c in out}
    for c in out:
        for name in c.inputs:
            if name not in c.where:
                source = wiring.sources[Endpoint(c.name, name)]
                c.where[name] = (tau.index(source.connector)
                                 if source.element is None
                                 else by_name[source.element].where[source.connector])
    return out, at

def component_signals(components: list[Component], links: int
                      ) -> tuple[dict[str, Signal], dict[str, tuple], dict[str, str]]:
    """Every component's Real outputs and inputs as trace signals, ``<component>.<name>``
    (a family ``name[1]``..``name[n]`` of n = joints elements as one per-joint signal,
    ``name[i,j]`` n×n as one, each where it is adjacent in the flat array; any other
    variable alone), recorded under ``plant/<component>/``."""
    n = links
    signals: dict[str, Signal] = {}
    views: dict[str, tuple] = {}  # trace key -> (first, count, shape) in the flat array
    directions: dict[str, str] = {}  # trace key -> "input" | "output"
    for c in components:
        names = c.outputs + c.inputs
        families: dict[str, list[str]] = {}
        for name in names:
            match = ELEMENT.match(name)
            families.setdefault(match.group(1) if match else name, []).append(name)
        by_name = {v.name: v for v in c.md.modelVariables}
        for base, members in families.items():
            index = [c.index(m) for m in members]
            shape = ("n" if members == [f"{base}[{i}]" for i in range(1, n + 1)] else
                     "nn" if members == [f"{base}[{i},{j}]" for i in range(1, n + 1)
                                         for j in range(1, n + 1)] else None)
            adjacent = all(b == a + 1 for a, b in zip(index, index[1:], strict=False))
            groups = ([(base, members, shape)] if shape and adjacent
                      else [(m, [m], "1") for m in members])
            for name, elements, form in groups:
                var = by_name[elements[0]]
                direction = "input" if elements[0] in c.inputs else "output"
                key = f"{c.name}.{name}"
                signals[key] = Signal(
                    form, declared_unit(var) or "1",
                    f"{var.description or name} (component {c.name}'s {direction})",
                    f"plant/{c.name}/{_entity_part(name)}", name)
                views[key] = (c.index(elements[0]), len(elements), form)
                directions[key] = direction
    return signals, views, directions


def _ordered(first: list[str], every: list[str]) -> list[str]:
    """``first`` (a component's variables in pass order), then the rest of ``every``."""
    chosen = [name for name in first if name in every]
    return chosen + [name for name in every if name not in chosen]


def _entity_part(name: str) -> str:
    """A variable's name as a recording entity's path part: letters, digits, '_', '-' and
    '.' kept, anything else '_'."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name)


def component_info(c: Component) -> dict:
    names = [v.name for v in c.md.modelVariables
             if v.causality == "parameter" and v.type in REAL_TYPES and not v.dimensions]
    refs = {v.name: v.valueReference for v in c.md.modelVariables}
    if c.fmi is not None and names:
        values = [float(x) for x in c.fmi.get_reals([refs[n] for n in names])]
    else:
        by_name = {v.name: v for v in c.md.modelVariables}
        values = [float(by_name[n].start or "nan") for n in names]
    return {"model_name": c.md.modelName, "file": str(c.path),
            "fmi_version": c.md.fmiVersion, "generation_tool": c.md.generationTool or "",
            "step_multiple": c.multiple, "parameters": dict(zip(names, values, strict=True))}
