"""A plant as an SSP 1.0 archive another SSP tool opens (``cosim export-ssp``): a system's
components, connections and parameter values as they run in cosim, every connector declared
with its kind, type and unit, every unit defined by its SI base units. One FMU is written
as a system of one component, ``arm``, whose ports are the system's. SI units, radians."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ..plant.errors import FmuError
from ..plant.mapping import declared_unit
from .ssp import write_ssp
from .structure import Component, Connection, Connector, Endpoint, System
from .wiring import check_system, definitions


def single_fmu_system(path: Path, names: dict[str, list[str] | None],
                      parameters: dict[str, float]) -> System:
    """One FMU as a system of one component, ``arm``: the system's connectors are the
    plant's ports in the FMU's own names (``names``: ``plant.variables`` as used), each
    connected to its variable."""
    connections = []
    for port, variables in names.items():
        for name in variables or []:
            end = Endpoint("arm", name)
            connections.append(Connection(Endpoint(None, name), end) if port == "tau"
                               else Connection(end, Endpoint(None, name)))
    return System(Path(path).stem, [Component("arm", Path(path), dict(parameters))],
                  connections, origin=str(path))


def export_ssp(system: System, path: str | Path, parameters: dict[str, float] | None = None,
               duration: float | None = None) -> Path:
    """Write ``system`` (checked first) to ``path`` with ``parameters`` (plant.parameters,
    read as a system reads them) over its components' own, and ``duration`` (s) as its
    default experiment."""
    wiring = check_system(system, parameters)
    used: dict[str, set[str]] = {}
    for connection in system.connections:
        for end in (connection.start, connection.end):
            if end.element is not None:
                used.setdefault(end.element, set()).add(end.connector)
    units: dict[str, tuple] = {}
    components = []
    for component in system.components:
        md = wiring.descriptions[component.name]
        defined = definitions(md, system)
        connectors = {}
        for var in md.modelVariables:
            if var.name not in used.get(component.name, ()):
                continue
            unit = declared_unit(var)
            connectors[var.name] = Connector(var.name, var.causality, "Real", unit)
            if unit is not None:
                units[unit] = _defined(unit, defined, component.name)
        components.append(replace(component, connectors=connectors,
                                  parameters=wiring.component_parameters(component.name,
                                                                         parameters)))
    ports = [Connector(p.name, p.kind, "Real", p.unit) for p in wiring.ports]
    return write_ssp(replace(system, components=components, connectors=ports), path, units,
                     duration)


def _defined(unit: str, defined: dict[str, tuple], component: str) -> tuple:
    """A unit's definition for the SSD's <Units>, from the FMU that uses it."""
    if unit not in defined:
        raise FmuError(f"component {component!r}: its FMU uses the unit {unit!r} without "
                       "defining it (<UnitDefinitions>), which an SSD must (<Units>)")
    return defined[unit]
