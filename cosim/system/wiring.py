"""A system checked against its components' FMUs: every component an FMU with
Co-Simulation for this machine, every connector a variable of its FMU of the declared kind,
type and unit, every connection from an output (or the system's input) to an input (or the
system's output) of one unit, every input fed once, every parameter one its FMU can take.
The first problem is one :class:`FmuError` naming the component, connector or connection
and what would be valid. SI units, radians."""

from __future__ import annotations

import re
from dataclasses import dataclass

from fmpy.model_description import ModelDescription

from ..plant.errors import FmuError
from ..plant.mapping import (
    REAL_TYPES,
    check_co_simulation,
    check_parameters,
    declared_unit,
    read_description,
    unit_spelling,
)
from .structure import Component, Connection, Endpoint, System

# A component's name starts the names of its trace signals and recording entities.
COMPONENT_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}")
_TYPE = {"Real": "Real", "Float64": "Real", "Float32": "Real"}  # FMI 2 and 3 spell it apart


@dataclass(frozen=True)
class SystemPort:
    """One of the system's own connectors: an input the plant is given, or an output the
    plant reads, and its unit (the connected component variable's where the system declares
    none)."""

    name: str
    kind: str
    unit: str | None


@dataclass
class Wiring:
    """A checked system: its components' model descriptions (by name), its ports, and per
    input it feeds (a component's input, or the system's output) the output that feeds it
    (a component's, or the system's input) and whether through a delayed connection."""

    system: System
    descriptions: dict[str, ModelDescription]
    ports: list[SystemPort]
    sources: dict[Endpoint, Endpoint]
    delayed: set[Endpoint]
    arm: str  # the component that feeds most of the system's outputs (first at a tie)

    def variable(self, end: Endpoint):
        """The FMU variable behind a component's endpoint."""
        return _by_name(self.descriptions[end.element])[end.connector]

    def parameter(self, key: str) -> tuple[str, str]:
        """(component, variable) a ``plant.parameters`` key names: "COMPONENT.VARIABLE",
        or a variable of the arm (a key whose first part names no component), so that a
        pipeline's or a sweep's arm parameters (``q0[1]``, ``m[2]``) reach the arm of a
        system as they reach one FMU."""
        head, dot, rest = key.partition(".")
        if dot and self.system.component(head) is not None:
            return head, rest
        return self.arm, key

    def component_parameters(self, name: str, parameters: dict[str, float] | None
                             ) -> dict[str, float]:
        """Component ``name``'s parameter values: its own, ``parameters`` (plant.parameters)
        over them."""
        over = {variable: value for key, value in (parameters or {}).items()
                for component, variable in (self.parameter(key),) if component == name}
        return {**self.system.component(name).parameters, **over}


def _by_name(md: ModelDescription) -> dict:
    return {v.name: v for v in md.modelVariables}


def _named(component: Component) -> str:
    return f"component {component.name!r} ({component.source.name})"


def check_system(system: System, parameters: dict[str, float] | None = None) -> Wiring:
    """``system`` checked (module docstring), with ``parameters`` (plant.parameters: keys as
    :meth:`Wiring.parameter` reads them) over its components' own."""
    if not system.components:
        raise FmuError(f"{system.origin or 'the system'}: has no components")
    descriptions = {}
    for component in system.components:
        if not COMPONENT_NAME.fullmatch(component.name):
            raise FmuError(f"component {component.name!r}{_at(component.where)}: name it with "
                           "up to 64 letters, digits and '_', starting with a letter (it "
                           "names its trace signals and recording entities)")
        if not isinstance(component.step_multiple, int) or component.step_multiple < 1:
            raise FmuError(f"{_named(component)}: its step multiple {component.step_multiple!r}"
                           " must be a whole number ≥ 1 (its step, in master steps)")
        try:
            md = read_description(component.source)
            check_co_simulation(component.source, md)
        except FmuError as exc:
            raise FmuError(f"component {component.name!r}{_at(component.where)}: "
                           f"{exc}") from None
        descriptions[component.name] = md
        _check_declared(component, md, system)
        check_parameters(component.source, md, component.parameters,
                         f"{_named(component)}, its parameter values")
    ports = {c.name: c for c in system.own_connectors()}
    for port in ports.values():
        if port.kind not in ("input", "output"):
            raise FmuError(f"{system.origin}: the system's connector {port.name!r} is of kind "
                           f"{port.kind}; a plant's system has inputs and outputs only")
    sources: dict[Endpoint, Endpoint] = {}
    delayed: set[Endpoint] = set()
    units: dict[str, str | None] = {}
    for connection in system.connections:
        start_unit = _check_end(connection, connection.start, "start", system, descriptions,
                                ports)
        end_unit = _check_end(connection, connection.end, "end", system, descriptions, ports)
        _check_units(connection, start_unit, end_unit, system, descriptions)
        if connection.end in sources:
            raise FmuError(f"connection {connection}{_at(connection.where)}: {connection.end} "
                           f"is fed already (by {sources[connection.end]}); an input has one "
                           "source")
        sources[connection.end] = connection.start
        if connection.delayed:
            if connection.start.element is None or connection.end.element is None:
                raise FmuError(f"connection {connection}{_at(connection.where)}: only a "
                               "connection between components can be delayed")
            delayed.add(connection.end)
        for end, unit in ((connection.start, end_unit), (connection.end, start_unit)):
            if end.element is None and unit is not None:
                units.setdefault(end.connector, unit)
    for port in ports.values():
        end = Endpoint(None, port.name)
        if port.kind == "output" and end not in sources:
            raise FmuError(f"{system.origin}: the system's output {port.name!r} is fed by no "
                           "connection")
        if port.kind == "output" and sources[end].element is None:
            raise FmuError(f"{system.origin}: the system's output {port.name!r} is its input "
                           f"{sources[end].connector!r} passed through; feed it from a "
                           "component")
        if port.kind == "input" and not any(s == end for s in sources.values()):
            raise FmuError(f"{system.origin}: the system's input {port.name!r} feeds no "
                           "connection")
    feeding = [sources[Endpoint(None, p.name)].element for p in ports.values()
               if p.kind == "output"]
    arm = max(dict.fromkeys(feeding), key=feeding.count)
    wiring = Wiring(system, descriptions,
                    [SystemPort(p.name, p.kind, p.unit or units.get(p.name))
                     for p in ports.values()], sources, delayed, arm)
    for key, value in (parameters or {}).items():
        name, variable = wiring.parameter(key)
        check_parameters(system.component(name).source, descriptions[name], {variable: value},
                         "plant.parameters")
    return wiring


def _at(where: str) -> str:
    return f" ({where})" if where else ""


def _check_declared(component: Component, md: ModelDescription, system: System) -> None:
    """The connectors the system declares for ``component``: each a variable of its FMU of
    that kind, type and unit."""
    by_name = _by_name(md)
    for connector in (component.connectors or {}).values():
        where = f"{_named(component)}, connector {connector.name!r}{_at(connector.where)}"
        var = by_name.get(connector.name)
        if var is None:
            raise FmuError(f"{where}: {component.source.name} has no variable of that name "
                           f"({_listed(md, connector.kind)})")
        if connector.kind != var.causality:
            raise FmuError(f"{where}: declared {connector.kind}, but the FMU's variable is "
                           f"a {var.causality}")
        kind = _TYPE.get(var.type, var.type)
        if connector.type is not None and connector.type != kind:
            raise FmuError(f"{where}: declared {connector.type}, but the FMU's variable is "
                           f"{var.type}")
        own = declared_unit(var)
        if connector.unit and own and not _same_unit(connector.unit, system.units, own,
                                                     definitions(md, system)):
            raise FmuError(f"{where}: declared in {connector.unit}, but the FMU's variable is "
                           f"in {own}; cosim converts no units")


def _listed(md: ModelDescription, kind: str) -> str:
    names = [v.name for v in md.modelVariables if v.causality == kind]
    shown = ", ".join(names[:12]) + (f", … ({len(names)} in all)" if len(names) > 12 else "")
    return f"its {kind}s: {shown or 'none'}"


def _check_end(connection: Connection, end: Endpoint, side: str, system: System,
               descriptions: dict[str, ModelDescription], ports: dict) -> str | None:
    """One end of a connection exists and points the right way; its unit (None: none)."""
    at = f"connection {connection}{_at(connection.where)}"
    wanted = "output" if side == "start" else "input"
    if end.element is None:
        port = ports.get(end.connector)
        own = "input" if side == "start" else "output"
        if port is None:
            raise FmuError(f"{at}: the system has no connector {end.connector!r} (its own: "
                           f"{', '.join(ports) or 'none'}; a component's is "
                           "COMPONENT.CONNECTOR)")
        if port.kind != own:
            raise FmuError(f"{at}: the system's {port.kind} {end.connector!r} cannot be a "
                           f"connection's {side}; a connection's {side} is the system's {own} "
                           f"or a component's {wanted}")
        return port.unit
    component = system.component(end.element)
    if component is None:
        raise FmuError(f"{at}: the system has no component {end.element!r} (its components: "
                       f"{', '.join(c.name for c in system.components)})")
    md = descriptions[component.name]
    var = _by_name(md).get(end.connector)
    declared = component.connectors
    if var is None or (declared is not None and end.connector not in declared):
        where = (f"declares no connector {end.connector!r} for it"
                 if declared is not None and var is not None else
                 f"{component.source.name} has no variable {end.connector!r}")
        raise FmuError(f"{at}: component {component.name!r}: {where} ({_listed(md, wanted)})")
    if var.causality != wanted:
        raise FmuError(f"{at}: {end} is an {var.causality}, and a connection's {side} must be "
                       f"an {wanted}")
    if var.type not in REAL_TYPES:
        raise FmuError(f"{at}: {end} is {var.type}; cosim connects Real (Float64) variables")
    return declared_unit(var)


def _check_units(connection: Connection, start: str | None, end: str | None, system: System,
                 descriptions: dict[str, ModelDescription]) -> None:
    if start is None or end is None:
        return
    defined = [definitions(descriptions.get(end.element), system)
               for end in (connection.start, connection.end)]
    if not _same_unit(start, defined[0], end, defined[1]):
        raise FmuError(f"connection {connection}{_at(connection.where)}: {connection.start} is "
                       f"in {start}, {connection.end} in {end}; cosim converts no units "
                       "(connect variables of one unit)")


def definitions(md: ModelDescription | None, system: System) -> dict[str, tuple]:
    """Unit name -> (kg, m, s, A, K, mol, cd, rad exponents, factor, offset): an FMU's
    <UnitDefinitions>, or the system's <Units>."""
    if md is None:
        return system.units
    out = {}
    for unit in getattr(md, "unitDefinitions", None) or []:
        base = unit.baseUnit
        if base is not None:
            out[unit.name] = (base.kg, base.m, base.s, base.A, base.K, base.mol, base.cd,
                              base.rad, base.factor, base.offset)
    return out


def _same_unit(a: str, a_defined: dict[str, tuple], b: str, b_defined: dict[str, tuple]
               ) -> bool:
    """Whether units ``a`` and ``b`` are one: the same spelling, or the same definition
    (:func:`definitions`) where both sides define theirs."""
    if unit_spelling(a) == unit_spelling(b):
        return True
    return a in a_defined and b in b_defined and a_defined[a] == b_defined[b]
