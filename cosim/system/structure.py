"""A system of FMUs as cosim holds it, whatever it was read from (an SSP archive or a
pipeline's ``[plant.system]`` table): its components, its own connectors (the plant's
ports) and the connections between them. SI units, radians."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from ..plant.errors import FmuError


@dataclass(frozen=True)
class Endpoint:
    """One end of a connection: a connector of a component (``element``), or of the system
    itself (``element`` None)."""

    element: str | None
    connector: str

    def __str__(self) -> str:
        return self.connector if self.element is None else f"{self.element}.{self.connector}"


@dataclass(frozen=True)
class Connection:
    """``start`` feeds ``end``. ``delayed``: it carries the value ``start`` had before this
    step's values were passed on (a one-step delay, declared where it breaks an algebraic
    loop). ``where``: the element or key it was read from, for messages."""

    start: Endpoint
    end: Endpoint
    delayed: bool = False
    where: str = ""

    def __str__(self) -> str:
        return f"{self.start} -> {self.end}"


@dataclass(frozen=True)
class Connector:
    """A connector a system or a component declares: its kind (``input``, ``output``, …),
    its type (``Real``, ``Integer``, … ; None: not declared) and unit (None: none)."""

    name: str
    kind: str
    type: str | None = None
    unit: str | None = None
    where: str = ""


@dataclass
class Component:
    """An FMU in the system: its name, its file, the values its parameters are given (by
    its variables' names, each in that variable's unit), the connectors the system declares
    for it (None: every variable of its FMU is one), and its step: ``step_multiple`` times
    the master's."""

    name: str
    source: Path
    parameters: dict[str, float] = field(default_factory=dict)
    connectors: dict[str, Connector] | None = None
    step_multiple: int = 1
    where: str = ""


@dataclass
class System:
    """A system: components, its own connectors (None: inferred from the connections, an
    unqualified name at a connection's start being an input and at its end an output),
    connections and unit definitions. ``origin``: the file it was read from, for
    messages."""

    name: str
    components: list[Component]
    connections: list[Connection]
    connectors: list[Connector] | None = None
    origin: str = ""
    # the units its connectors name, each defined by its SI base: (kg, m, s, A, K, mol, cd,
    # rad exponents, factor, offset); those an SSD's <Units> give
    units: dict[str, tuple] = field(default_factory=dict)

    def component(self, name: str) -> Component | None:
        return next((c for c in self.components if c.name == name), None)

    def own_connectors(self) -> list[Connector]:
        """The system's connectors, declared or inferred from its connections."""
        if self.connectors is not None:
            return self.connectors
        out: dict[str, Connector] = {}
        for connection in self.connections:
            for end, kind in ((connection.start, "input"), (connection.end, "output")):
                if end.element is None:
                    out.setdefault(end.connector, Connector(end.connector, kind,
                                                            where=connection.where))
        return list(out.values())


# "drives.tau[1] -> arm.tau[1]": a component's connector is COMPONENT.NAME, the system's its
# NAME alone. A component's name holds no dot; a variable's name may (FMI's structured
# names), so the first dot splits.
_ARROW = re.compile(r"^\s*(\S+)\s*->\s*(\S+)\s*$")


def parse_connection(text: str, components: set[str], delayed: bool, where: str
                     ) -> Connection:
    """A connection written ``"START -> END"``; :class:`FmuError` naming ``where`` if it is
    not one."""
    match = _ARROW.match(text)
    if not match:
        raise FmuError(f"{where} = {text!r}: write a connection as \"START -> END\", each "
                       "COMPONENT.CONNECTOR or a connector of the system's own (e.g. "
                       "\"drives.tau[1] -> arm.tau[1]\")")
    return Connection(_endpoint(match.group(1), components),
                      _endpoint(match.group(2), components), delayed, f"{where} {text!r}")


def _endpoint(text: str, components: set[str]) -> Endpoint:
    head, dot, rest = text.partition(".")
    if dot and head in components:
        return Endpoint(head, rest)
    return Endpoint(None, text)
