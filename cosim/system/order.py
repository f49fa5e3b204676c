"""In what order a system's values pass on at each communication point, so that a component
whose output depends on its input within the instant (direct feedthrough) adds no step of
delay: computed once from the connections and each FMU's ModelStructure, by Kahn's algorithm
over the variables; an algebraic loop (a cycle of such dependencies) is refused, naming
every component and connector on it, unless one of its connections is declared delayed.

An FMU's ``<Outputs>`` (FMI 2: ``<Unknown dependencies>``, FMI 3: ``<Output
dependencies>``) say which inputs each output depends on; an output that declares none
depends on every input, as the standard says.
"""

from __future__ import annotations

from dataclasses import dataclass

from fmpy.model_description import ModelDescription

from ..plant.errors import FmuError
from .structure import Endpoint
from .wiring import Wiring


def feedthrough(md: ModelDescription) -> dict[str, frozenset[str]]:
    """Per output of ``md``, the inputs it depends on within an instant."""
    inputs = frozenset(v.name for v in md.modelVariables if v.causality == "input")
    out = {}
    declared = {unknown.variable.name: unknown for unknown in md.outputs}
    for v in md.modelVariables:
        if v.causality != "output":
            continue
        unknown = declared.get(v.name)
        if unknown is None or unknown.dependencies is None:
            out[v.name] = inputs
        else:
            out[v.name] = frozenset(d.name for d in unknown.dependencies if d.name in inputs)
    return out


@dataclass(frozen=True)
class Pass:
    """One call at a communication point: set a component's ``inputs`` (from their sources)
    or get its ``outputs`` (those that changed with the inputs just set)."""

    component: str
    action: str  # "set" | "get"
    variables: tuple[str, ...]


def schedule(wiring: Wiring) -> list[Pass]:
    """The passes at each communication point, in dependency order: every fed input of
    every component set once, after whatever feeds it; every output that depends on an
    input got once, after those inputs are set. :class:`FmuError` naming an algebraic loop."""
    through = {name: feedthrough(md) for name, md in wiring.descriptions.items()}
    # The graph's nodes: fed inputs, and outputs that depend on a fed input.
    fed = [end for end in wiring.sources if end.element is not None]
    after: dict[Endpoint, list[Endpoint]] = {}  # node -> nodes that wait for it
    waiting: dict[Endpoint, int] = {}
    nodes: list[Endpoint] = list(fed)
    for end in fed:
        for output, depends in through[end.element].items():
            if end.connector in depends:
                node = Endpoint(end.element, output)
                if node not in waiting:
                    nodes.append(node)
                    waiting[node] = 0
                after.setdefault(end, []).append(node)
                waiting[node] += 1
    for end in fed:
        waiting.setdefault(end, 0)
        source = wiring.sources[end]
        if end not in wiring.delayed and source in waiting:
            after.setdefault(source, []).append(end)
            waiting[end] += 1
    order = _kahn(nodes, after, waiting, wiring)
    grouped: list[tuple[str, str, list[str]]] = []
    for node in order:
        action = "set" if node in wiring.sources else "get"
        if grouped and grouped[-1][:2] == (node.element, action):
            grouped[-1][2].append(node.connector)
        else:
            grouped.append((node.element, action, [node.connector]))
    # within a pass, the FMU's own order (a family such as tau[1], tau[2] stays together)
    place = {name: {v.name: i for i, v in enumerate(md.modelVariables)}
             for name, md in wiring.descriptions.items()}
    return [Pass(element, action, tuple(sorted(names, key=place[element].get)))
            for element, action, names in grouped]


def _kahn(nodes: list[Endpoint], after: dict, waiting: dict, wiring: Wiring
          ) -> list[Endpoint]:
    """The nodes in an order where each comes after what it waits for: of those ready, one
    of the component and action just taken first (fewer calls), else the first declared."""
    rank = {name: i for i, name in enumerate(wiring.descriptions)}
    key = {node: (rank[node.element], node not in wiring.sources, i)
           for i, node in enumerate(nodes)}
    ready = sorted((n for n in nodes if waiting[n] == 0), key=key.get)
    count = dict(waiting)
    order: list[Endpoint] = []
    while ready:
        last = order[-1] if order else None
        pick = next((n for n in ready if last is not None and n.element == last.element
                     and (n in wiring.sources) == (last in wiring.sources)), ready[0])
        ready.remove(pick)
        order.append(pick)
        for node in after.get(pick, []):
            count[node] -= 1
            if count[node] == 0:
                ready.append(node)
                ready.sort(key=key.get)
    if len(order) < len(nodes):
        raise FmuError(_loop_message([n for n in nodes if count[n] > 0], after, wiring))
    return order


def _loop_message(stuck: list[Endpoint], after: dict, wiring: Wiring) -> str:
    """One cycle among the nodes left waiting, from input through output round to itself."""
    left = set(stuck)
    path, seen = [stuck[0]], {stuck[0]: 0}
    while True:
        successor = next(n for n in after.get(path[-1], []) if n in left)
        if successor in seen:
            cycle = path[seen[successor]:] + [successor]
            break
        seen[successor] = len(path)
        path.append(successor)
    components = list(dict.fromkeys(n.element for n in cycle))
    return (f"{wiring.system.origin or 'the system'}: an algebraic loop through "
            f"{', '.join(components)}: {' -> '.join(map(str, cycle))} (each output there "
            "depends on its component's input within the same instant, by the FMUs' "
            "ModelStructure); break it by declaring one of its connections delayed (a step's "
            "delay: plant.system.delayed, or cosim's annotation in the SSD)")
