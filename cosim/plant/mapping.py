"""Does an FMU fit cosim's plant interface? Open it safely and map our names onto its own.

The interface is the port table (:mod:`.ports`): per joint i of n, input ``tau`` (N·m),
output ``q`` (rad) and the optional outputs (``qdot``, the inertia matrix ``M`` n×n
row-major, the bias forces ``h``, the motor angles ``theta``), each a Real (FMI 2.0) or
Float64 (FMI 3.0) scalar variable. n is the number of ``q`` names: mapped in the pipeline,
else counted from outputs named ``q[1]``, ``q[2]``, … as the built-in plants have.

Every check here reports what is wrong in one message naming the file and the variable,
and what would be valid, so a user's FMU is refused before anything runs.
"""

from __future__ import annotations

import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import fmpy
from fmpy.model_description import ModelDescription, ValidationError

from .errors import FmuError
from .ports import PORT, PORTS
from .unpack import damaged_entry

REAL_TYPES = ("Real", "Float64")


@dataclass
class PlantVariables:
    """Our ports, in the FMU's own names: per port one name per joint (n×n row-major for
    an "nn" port), None for an optional port the FMU does not map. ``variables.q`` reads
    the port ``q``."""

    names: dict[str, list[str] | None]

    def __getattr__(self, port: str) -> list[str] | None:
        if port.startswith("_") or port not in PORT:
            raise AttributeError(port)
        return self.names.get(port)

    @property
    def links(self) -> int:
        return len(self.names["q"])

    @property
    def mapped(self) -> frozenset[str]:
        """The ports mapped."""
        return frozenset(name for name, names in self.names.items() if names)


def read_description(path: str | Path) -> ModelDescription:
    """The FMU's model description, or :class:`FmuError` saying why the file is not an FMU."""
    path = Path(path)
    if not path.exists():
        raise FmuError(f"{path}: no such FMU file")
    if path.is_dir():
        raise FmuError(f"{path}: is a folder; give the .fmu file (a zip archive)")
    if not zipfile.is_zipfile(path):
        raise FmuError(f"{path}: not an FMU: not a zip archive (is the file complete?)")
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
            if "modelDescription.xml" not in names:
                raise FmuError(f"{path}: not an FMU: the archive has no modelDescription.xml "
                               "at its top level")
            head = archive.open("modelDescription.xml").read(4096)
        # the CRC check reads every entry as a stream, abandoned at the size cap
        problem = damaged_entry(path)
        if problem:
            raise FmuError(f"{path}: {problem}")
        version = re.search(rb'fmiVersion\s*=\s*["\']([^"\']*)', head)
        if version and version.group(1).startswith(b"1."):
            raise FmuError(f"{path}: an FMI {version.group(1).decode()} FMU: FMI 1.0 is not "
                           "supported; export the model as FMI 2.0 or 3.0 Co-Simulation")
        return fmpy.read_model_description(str(path))
    except FmuError:
        raise
    except ValidationError as exc:
        raise FmuError(f"{path}: modelDescription.xml is not valid FMI: "
                       + "; ".join(exc.problems[:3])) from None
    except Exception as exc:  # zipfile and lxml errors: a damaged file, not a user's bug
        raise FmuError(f"{path}: cannot read modelDescription.xml: {exc}") from None


def check_co_simulation(path: str | Path, md: ModelDescription) -> None:
    """Co-Simulation interface present, with a binary for this machine."""
    path = Path(path)
    if md.coSimulation is None:
        kinds = "Model Exchange only" if md.modelExchange is not None else "no interface"
        raise FmuError(f"{path}: the FMU has no Co-Simulation interface ({kinds}); cosim "
                       "steps the plant as a Co-Simulation slave: export it with "
                       "Co-Simulation")
    check_binary(path, md, md.coSimulation.modelIdentifier, "Co-Simulation")


def check_binary(path: str | Path, md: ModelDescription, model_identifier: str,
                 interface: str) -> None:
    """The FMU carries ``model_identifier``'s shared library for this machine."""
    path = Path(path)
    platform = fmpy.platform if md.fmiVersion.startswith("2") else fmpy.platform_tuple
    binary = f"binaries/{platform}/{model_identifier}{fmpy.sharedLibraryExtension}"
    with zipfile.ZipFile(path) as archive:
        names = archive.namelist()
    if binary in names:
        return
    present = sorted({n.split("/")[1] for n in names
                      if n.startswith("binaries/") and n.count("/") >= 2 and n.split("/")[1]})
    has_sources = any(n.startswith("sources/") and n.endswith(".c") for n in names)
    hint = (f"; it carries C sources: `fmpy compile {path}` builds one" if has_sources
            else "; export it for this platform")
    raise FmuError(f"{path}: no {interface} binary for this platform ({binary} is missing; "
                   f"the FMU has binaries for: {', '.join(present) or 'none'}){hint}")


def map_variables(md: ModelDescription, requested: dict[str, list[str] | None] | None = None
                  ) -> tuple[PlantVariables | None, list[str]]:
    """Our interface mapped onto ``md``'s variables: (mapping, []) when it fits, else
    (None, every problem found). ``requested`` holds ``plant.variables``: per key a list of
    names, None for the default names, ``[]`` for an optional key left unmapped."""
    requested = requested or {}
    by_name = {v.name: v for v in md.modelVariables}
    q = requested.get("q")
    if q is None:
        q = []
        while f"q[{len(q) + 1}]" in by_name:
            q.append(f"q[{len(q) + 1}]")
        if not q:
            return None, [f"no outputs named q[1], q[2], …: map the joint angles with "
                          f"plant.variables.q = [...] (its Real outputs: "
                          f"{_list(real_names(md, 'output'))})"]
    if not q:
        return None, ["plant.variables.q is empty: the plant needs at least one joint"]
    n = len(q)
    mapping: dict[str, list[str] | None] = {"q": q}
    problems = []
    for port in PORTS:
        if port.name == "q":
            continue
        names = requested.get(port.name)
        if names is None:
            names = port.default_names(n)
            if not all(name in by_name for name in names):
                if port.required:  # our names, which the user did not give: say so
                    missing = [name for name in names if name not in by_name]
                    problems.append(
                        f"the FMU has no {port.direction} named {', '.join(missing[:3])}"
                        f"{', …' * (len(missing) > 3)}: map the {port.role} with "
                        f"plant.variables.{port.name} = [...] (its Real {port.direction}s: "
                        f"{_list(real_names(md, port.direction))})")
                    continue
                names = None  # optional, and the FMU does not have our names: not mapped
        mapping[port.name] = names or None
        if port.required and not names:
            problems.append(f"plant.variables.{port.name} is empty: the plant needs one "
                            f"{port.role[:-1]} {port.direction} per joint")
    wrong: set[str] = set()  # names refused on their own: not also reported as repeated
    for key, names in mapping.items():
        if names is None:
            continue
        expected = PORT[key].width(n)
        if len(names) != expected:
            what = f"{n}×{n} = {expected}" if PORT[key].shape == "nn" else f"{n}"
            problems.append(f"plant.variables.{key} has {len(names)} name"
                            f"{'s' * (len(names) != 1)}, the plant has "
                            f"{n} joint{'s' * (n != 1)} (from plant.variables.q), so it "
                            f"needs {what}")
            continue
        found = [(name, p) for name in names if (p := _check(md, by_name, key, name))]
        problems += [p for _, p in found]
        wrong.update(name for name, _ in found)
    problems += _mapped_twice(mapping, wrong)
    if problems:
        return None, problems
    return PlantVariables(mapping), []


def _mapped_twice(mapping: dict[str, list[str] | None], wrong: set[str]) -> list[str]:
    """Each FMU variable feeds one entry of one port: a name given twice (``q =
    ["shoulder", "shoulder"]``, or as both q and qdot) would read one signal as two; M's
    entries alone may share one. Names in ``wrong`` are already refused."""
    first: dict[str, tuple[str, int]] = {}
    problems = []
    for key, names in mapping.items():
        for i, name in enumerate(names or []):
            if name in wrong:
                continue
            if name not in first or (key == "M" and first[name][0] == "M"):
                # (M is symmetric: one variable may give M[i,j] and M[j,i])
                first[name] = (key, i)
                continue
            other, j = first[name]
            problems.append(f"plant.variables.{key}[{i + 1}] names {name!r}, which "
                            f"plant.variables.{other}[{j + 1}] already names: each FMU "
                            "variable may feed one entry of one port")
    return problems


def declared_unit(var) -> str | None:
    """The unit a model variable declares, on itself or through its declared type."""
    return (getattr(var, "unit", None)
            or getattr(getattr(var, "declaredType", None), "unit", None))


# A prismatic joint's units for each rotational one (cosim converts no units: a mapped
# variable must be in the port's unit, or in its prismatic counterpart, which is reported)
PRISMATIC = {"rad": "m", "rad/s": "m/s", "N.m": "N"}
# Each of those in SI base units, (kg, m, s) exponents: FMI's <BaseUnit> says what a unit
# is, whatever its spelling (an angle's rad exponent is left out: tools differ on it)
BASE_UNITS = {"rad": (0, 0, 0), "m": (0, 1, 0), "rad/s": (0, 0, -1), "m/s": (0, 1, -1),
              "N.m": (1, 2, -2), "N": (1, 1, -2)}
# Spellings of other quantities, or other scales, refused when the FMU does not define them
OTHER_UNITS = frozenset({"J", "W", "kg", "kg.m2", "kg.m^2", "deg", "deg/s", "rpm", "mm",
                         "mm/s", "s", "A", "V", "K", "Pa", "rad/s2", "m/s2", "N.mm", "kN.m"})


def _unit_fits(md: ModelDescription, declared: str, allowed: list[str]) -> bool | None:
    """Whether a variable declared in ``declared`` carries one of the ``allowed`` units:
    by the FMU's own definition of it where it gives one (its SI base units, with no scale
    or offset), else by its spelling; None where neither tells (a spelling cosim does not
    know: accepted, and warned of by :func:`unit_differences`)."""
    if unit_spelling(declared) in map(unit_spelling, allowed):
        return True
    defined = next((u for u in getattr(md, "unitDefinitions", None) or []
                    if u.name == declared and u.baseUnit is not None), None)
    if defined is not None:
        base = defined.baseUnit
        other = (base.A, base.K, base.mol, base.cd) != (0, 0, 0, 0)
        return (not other and base.factor == 1.0 and base.offset == 0.0
                and (base.kg, base.m, base.s) in {BASE_UNITS[unit_spelling(u)] for u in allowed})
    return False if unit_spelling(declared) in OTHER_UNITS else None


def unit_differences(md: ModelDescription, variables: PlantVariables) -> str | None:
    """Where the FMU declares a mapped per-joint variable in another unit than the port's
    (a prismatic joint's q in m, its force in N): one text naming each, else None. cosim's
    signals, checks and exports carry the port's unit for every joint."""
    by_name = {v.name: v for v in md.modelVariables}
    found, expected = [], {}
    for port in PORTS:
        for name in (variables.names.get(port.name) or []) if port.shape == "n" else []:
            var = by_name.get(name)
            declared = declared_unit(var)
            if declared and unit_spelling(declared) != unit_spelling(port.signal.unit):
                found.append(f"{name} in {declared}")
                expected[port.name] = port.signal.unit
    if not found:
        return None
    return (f"the FMU declares {', '.join(found)}, where cosim's interface has "
            f"{', '.join(f'{p} in {u}' for p, u in expected.items())}: cosim's signals, "
            "checks, tables and exports label those values with the interface's units "
            "(per-joint units, a prismatic joint's, are not carried through)")


def unit_spelling(text: str) -> str:
    """A unit's spelling compared: FMI's "N.m" is cosim's "N·m", and Simulink's "N*m"."""
    spelled = text.replace("·", ".").replace("*", ".").replace(" ", "").replace("/sec", "/s")
    return "N.m" if spelled == "Nm" else spelled


def _check(md: ModelDescription, by_name: dict, key: str, name: str) -> str | None:
    causality, what = PORT[key].direction, PORT[key].role
    var = by_name.get(name)
    where = f"plant.variables.{key} ({what})"
    if var is None:
        return (f"{where} names {name!r}, which is not a variable of the FMU (its Real "
                f"{causality}s: {_list(real_names(md, causality))})")
    if var.type not in REAL_TYPES:
        return f"{where} names {name!r}, which is {var.type}; it must be Real (Float64)"
    if var.dimensions:
        return f"{where} names {name!r}, which is an array; map its scalar elements"
    if var.causality != causality:
        return (f"{where} names {name!r}, whose causality is {var.causality}; it must be "
                f"an {causality}")
    declared, unit = declared_unit(var), PORT[key].signal.unit
    spelled = unit_spelling(unit)
    allowed = [unit] + ([PRISMATIC[spelled]] if spelled in PRISMATIC else [])
    # per joint ports only: M's entries mix units on a chain with a prismatic joint
    if PORT[key].shape == "n" and declared and _unit_fits(md, declared, allowed) is False:
        return (f"{where} names {name!r}, declared in {declared}; the port takes "
                f"{' or '.join(allowed)} (a prismatic joint's), and cosim converts no units")
    return None


def check_parameters(path: str | Path, md: ModelDescription, parameters: dict[str, float],
                     where: str = "plant.parameters") -> None:
    """``plant.parameters`` (or what ``where`` names): each name a Real variable whose value
    may be set before the FMU initialises (a parameter, an input, or a start value)."""
    by_name = {v.name: v for v in md.modelVariables}
    for name in parameters:
        var = by_name.get(name)
        if var is None:
            raise FmuError(f"{where}: {name!r} is not a variable of {Path(path).name} "
                           f"(its parameters: {_list(real_names(md, 'parameter'))})")
        settable = (var.causality in ("parameter", "input")
                    or (var.initial in ("exact", "approx") and var.variability != "constant"))
        if var.type not in REAL_TYPES or not settable:
            raise FmuError(f"{where}: {name!r} in {Path(path).name} is a "
                           f"{var.variability} {var.type} {var.causality}; only Real "
                           "parameters, inputs and start values can be set")


def check_plant_fmu(path: str | Path, requested: dict[str, list[str] | None] | None = None,
               parameters: dict[str, float] | None = None
               ) -> tuple[ModelDescription, PlantVariables]:
    """Every check a plant FMU must pass before it runs, in the order a user would fix
    them; raises :class:`FmuError` naming the file and all the interface's problems."""
    md = read_description(path)
    check_co_simulation(path, md)
    variables, problems = map_variables(md, requested)
    if variables is None:
        raise FmuError(f"{path}: does not fit the plant interface: " + "; ".join(problems))
    check_parameters(path, md, parameters or {})
    return md, variables


def real_names(md: ModelDescription, causality: str) -> list[str]:
    """Names of the Real (Float64) variables of one causality, in the FMU's order."""
    return [v.name for v in md.modelVariables
            if v.causality == causality and v.type in REAL_TYPES]


def _list(names: list[str], limit: int = 12) -> str:
    if not names:
        return "none"
    more = f", … ({len(names)} in all)" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more
