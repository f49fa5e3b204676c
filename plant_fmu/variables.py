"""A model's one table of FMU variables, written as families (``m`` per link, ``M`` n×n, …)
and expanded to scalar variables for a link count. Everything else is generated from it
(``plant_fmu/description.py``): the FMI 2.0 and 3.0 ``modelDescription.xml`` and the C
header ``variables.h`` the model and the FMI glue index by value reference.

Names are the same in FMI 2.0 and 3.0 (scalar variables, 1-based indices): ``q[1]``,
``M[1,2]``, ``der(qdot[1])``. SI units, radians.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Variable:
    """One scalar FMU variable. ``vr`` is its value reference."""

    name: str
    vr: int
    causality: str  # parameter | input | output | local | independent
    variability: str  # fixed | continuous
    unit: str | None
    description: str
    start: float | None = None
    check: str | None = None  # positive | nonnegative | finite | limit (> 0 or inf)
    derivative_of: str | None = None  # name of the variable this is the derivative of
    group: str = ""  # base name: "m" for "m[1]"
    min: float | None = None  # declared range (modelDescription min/max), where there is one
    max: float | None = None
    # An output's direct dependencies (ModelStructure): the names of the inputs and states
    # its value at an instant depends on; None: not declared (an importer assumes all).
    depends: tuple[str, ...] | None = None


@dataclass(frozen=True)
class VariableFamily:
    """Variables sharing a base name: one scalar, one per link, or n×n (row-major)."""

    base: str
    shape: str  # "" | "n" | "nn"
    causality: str
    variability: str
    unit: str | None
    description: str
    start: Callable[[int], float] | None = None  # link index (0-based) -> start value
    check: str | None = None
    derivative_of: str | None = None
    # Where the unit differs by element (a chain of revolute and prismatic joints): the
    # element's index -> its unit, in place of ``unit``.
    unit_of: Callable[[tuple[int, ...]], str] | None = None
    # The same for the description (a joint's own name in it, say).
    description_of: Callable[[tuple[int, ...]], str] | None = None
    # link index -> (min, max) of the element; None or an infinite bound declares none.
    bounds: Callable[[int], tuple[float, float]] | None = None
    # An output's direct dependencies: the families (inputs, states) its value depends on at
    # the same instant, what a co-simulation master orders its components by (an output
    # that depends on no input adds no algebraic loop). A family's name: every element of
    # it; "name[i]": the same joint's element (of a per-joint output). None: undeclared,
    # read by importers as "depends on every input".
    depends: tuple[str, ...] | None = None


def per_link(first_links: tuple[float, ...], rest: float) -> Callable[[int], float]:
    """Start values: ``first_links`` for the first links, ``rest`` for the others."""
    return lambda i: first_links[i] if i < len(first_links) else rest


def constant(value: float) -> Callable[[int], float]:
    return lambda i: value


def element_name(base: str, index: tuple[int, ...]) -> str:
    if not index:
        return base
    inner = ",".join(str(k + 1) for k in index)
    if base.startswith("der("):  # der(qdot)[1] reads badly: der(qdot[1])
        return f"der({base[4:-1]}[{inner}])"
    return f"{base}[{inner}]"


def expand(families: Sequence[VariableFamily], links: int) -> list[Variable]:
    """Every scalar variable of the families for ``links`` links, ordered by value
    reference."""
    out: list[Variable] = []
    by_base = {family.base: family for family in families}
    for family in families:
        for index in _indices(family.shape, links):
            start = family.start(index[0] if index else 0) if family.start else None
            low, high = family.bounds(index[0]) if family.bounds else (None, None)
            derivative_of = (element_name(family.derivative_of, index)
                             if family.derivative_of else None)
            out.append(Variable(
                name=element_name(family.base, index), vr=len(out),
                causality=family.causality, variability=family.variability,
                unit=family.unit_of(index) if family.unit_of else family.unit,
                description=(family.description_of(index) if family.description_of
                             else family.description),
                start=start, check=family.check,
                derivative_of=derivative_of, group=family.base,
                min=_finite_or_none(low), max=_finite_or_none(high),
                depends=_dependencies(family, index, by_base, links),
            ))
    return out


def _dependencies(family: VariableFamily, index: tuple[int, ...],
                  families: dict[str, VariableFamily], links: int) -> tuple[str, ...] | None:
    """The element ``index`` of ``family``'s declared direct dependencies, as variable names
    (see :attr:`VariableFamily.depends`)."""
    if family.depends is None:
        return None
    names: list[str] = []
    for base in family.depends:
        if base.endswith("[i]"):
            names.append(element_name(base[:-3], index))
        else:
            names += [element_name(base, i) for i in _indices(families[base].shape, links)]
    return tuple(names)


def _indices(shape: str, links: int) -> list[tuple[int, ...]]:
    if shape == "":
        return [()]
    if shape == "n":
        return [(i,) for i in range(links)]
    return [(i, j) for i in range(links) for j in range(links)]


def _finite_or_none(bound: float | None) -> float | None:
    return bound if bound is not None and math.isfinite(bound) else None


def first_vr(table: list[Variable], group: str) -> int:
    """Value reference of the first element of a variable group."""
    return next(v.vr for v in table if v.group == group)


def states(table: list[Variable]) -> list[tuple[Variable, Variable]]:
    """(state, its derivative) pairs, in the order of the states' value references: the
    continuous-state vector of Model Exchange and of the glue's get/set states."""
    by_name = {v.name: v for v in table}
    pairs = [(by_name[v.derivative_of], v) for v in table if v.derivative_of]
    return sorted(pairs, key=lambda pair: pair[0].vr)


def computed(table: list[Variable]) -> set[int]:
    """Value references the model computes on demand (model_update_outputs): outputs and
    locals that are not states."""
    state_vrs = {state.vr for state, _ in states(table)}
    return {v.vr for v in table if v.causality in ("output", "local") and v.vr not in state_vrs}
