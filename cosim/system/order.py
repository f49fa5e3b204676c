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
    every component set once, after whatever feeds it; an output that depends on a fed
    input within the instant got after those inputs are set, where the component has one
    that feeds another input (the others are read after the step). Component by component
    (a set, then a get) where the components can be ordered so, else variable by variable.
    :class:`FmuError` naming an algebraic loop."""
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
    passed_on: set[Endpoint] = set()  # outputs another input waits for within the instant
    for end in fed:
        waiting.setdefault(end, 0)
        source = wiring.sources[end]
        if end not in wiring.delayed and source in waiting:
            after.setdefault(source, []).append(end)
            waiting[end] += 1
            passed_on.add(source)
    order = _kahn(nodes, after, waiting, wiring)  # refuses a loop, named
    place = {name: {v.name: i for i, v in enumerate(md.modelVariables)}
             for name, md in wiring.descriptions.items()}
    # a component got from: all its outputs that changed (one call; the trace holds them)
    getting = {n.element for n in passed_on}
    wanted = [n for n in order if n in wiring.sources or n.element in getting]
    components = _component_order(wanted, after, wiring)
    if components is not None:
        wanted = [n for c in components for action in (True, False) for n in wanted
                  if n.element == c and (n in wiring.sources) == action]
    grouped: list[tuple[str, str, list[str]]] = []
    for node in wanted:
        action = "set" if node in wiring.sources else "get"
        if grouped and grouped[-1][:2] == (node.element, action):
            grouped[-1][2].append(node.connector)
        else:
            grouped.append((node.element, action, [node.connector]))
    # within a pass, the FMU's own order (a family such as tau[1], tau[2] stays together)
    return [Pass(element, action, tuple(sorted(names, key=place[element].get)))
            for element, action, names in grouped]


def _component_order(nodes: list[Endpoint], after: dict, wiring: Wiring) -> list[str] | None:
    """The components in an order where each one's inputs are all set after everything
    they wait for (so that one set and one get a component do), or None where none is
    (a component whose output feeds, through others, an input of its own that another of
    its outputs does not depend on: then the passes go variable by variable)."""
    names = list(dict.fromkeys(n.element for n in nodes))
    edges = {name: set() for name in names}
    for node in nodes:
        for successor in after.get(node, []):
            if successor.element != node.element:
                edges[node.element].add(successor.element)
    count = {name: 0 for name in names}
    for targets in edges.values():
        for target in targets:
            count[target] += 1
    ready = [name for name in names if count[name] == 0]
    order = []
    while ready:
        name = ready.pop(0)
        order.append(name)
        for target in sorted(edges[name], key=names.index):
            count[target] -= 1
            if count[target] == 0:
                ready.append(target)
    return order if len(order) == len(names) else None


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
    """One cycle among the nodes left waiting, from input through output round to itself
    (those only downstream of a cycle, which lead into none, set aside first)."""
    left = set(stuck)
    while dead := {n for n in left if not any(m in left for m in after.get(n, []))}:
        left -= dead
    start = next(n for n in stuck if n in left)
    path, seen = [start], {start: 0}
    while True:
        successor = next(n for n in after.get(path[-1], []) if n in left)
        if successor in seen:
            cycle = path[seen[successor]:]
            break
        seen[successor] = len(path)
        path.append(successor)
    # from the first declared component's input, round to it again
    rank = {name: i for i, name in enumerate(wiring.descriptions)}
    first = min(range(len(cycle)), key=lambda i: (rank[cycle[i].element],
                                                  cycle[i] not in wiring.sources))
    cycle = cycle[first:] + cycle[:first + 1]
    components = list(dict.fromkeys(n.element for n in cycle))
    return (f"{wiring.system.origin or 'the system'}: an algebraic loop through "
            f"{', '.join(components)}: {' -> '.join(map(str, cycle))} (each output there "
            "depends on its component's input within the same instant, by the FMUs' "
            "ModelStructure); break it by declaring one of its connections delayed (a step's "
            "delay: plant.system.delayed, or cosim's annotation in the SSD)")
