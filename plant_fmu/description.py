"""Generate modelDescription.xml (FMI 2.0 / 3.0), variables.h/.c and buildDescription.xml
from a model's one variable table (``plant_fmu.models.<model>``)."""

from __future__ import annotations

import hashlib
import math
from types import ModuleType
from xml.sax.saxutils import quoteattr

from . import c_literals as c
from .variables import computed, first_vr, states

# name -> (base-unit exponents, display unit or None). Radian is kept as a base unit so
# that tools can offer degrees.
UNITS: dict[str, tuple[dict[str, int], tuple[str, float] | None]] = {
    "s": ({"s": 1}, None),
    "kg": ({"kg": 1}, None),
    "m": ({"m": 1}, None),
    "kg.m2": ({"kg": 1, "m": 2}, None),
    "N.m.s/rad": ({"kg": 1, "m": 2, "s": -1, "rad": -1}, None),
    "N.m": ({"kg": 1, "m": 2, "s": -2}, None),
    "J": ({"kg": 1, "m": 2, "s": -2}, None),
    "rad": ({"rad": 1}, ("deg", 57.29577951308232)),
    "rad/s": ({"rad": 1, "s": -1}, ("deg/s", 57.29577951308232)),
    "rad/s2": ({"rad": 1, "s": -2}, ("deg/s2", 57.29577951308232)),
    "Hz": ({"s": -1}, None),
    "m/s2": ({"m": 1, "s": -2}, None),
    "N.m/rad": ({"kg": 1, "m": 2, "s": -2, "rad": -1}, None),
    # The drives' motors (plant_fmu/models/drives).
    "A": ({"A": 1}, None),
    "A/s": ({"A": 1, "s": -1}, None),
    "N.m/A": ({"kg": 1, "m": 2, "s": -2, "A": -1}, None),
    # A spatial chain's prismatic joints and their mixed entries of M.
    "m/s": ({"m": 1, "s": -1}, None),
    "N": ({"kg": 1, "m": 1, "s": -2}, None),
    "N.s/m": ({"kg": 1, "s": -1}, None),
    "kg.m": ({"kg": 1, "m": 1}, None),
}

_KIND = {"independent": "KIND_INDEPENDENT", "parameter": "KIND_PARAMETER",
         "input": "KIND_INPUT", "output": "KIND_OUTPUT", "local": "KIND_LOCAL"}
_CHECK = {None: "CHECK_NONE", "finite": "CHECK_FINITE", "positive": "CHECK_POSITIVE",
          "nonnegative": "CHECK_NONNEGATIVE", "limit": "CHECK_LIMIT"}


def _c_group(group: str) -> str:
    """The C macro stem of a variable group: its name, or for a derivative der(xdot) its
    FMI-independent name xddot (der(qdot) -> qddot), for any other der(x) der_x."""
    if group.startswith("der(") and group.endswith("dot)"):
        return group[4:-4] + "ddot"
    if group.startswith("der(") and group.endswith(")"):
        return "der_" + group[4:-1]
    return group


def instantiation_token(model: ModuleType, links: int, sources_digest: str) -> str:
    """A GUID-shaped token that changes whenever the table or the C sources change."""
    table = repr(model.variables(links)).encode()
    h = hashlib.sha256(table + sources_digest.encode()).hexdigest()
    return f"{{{h[:8]}-{h[8:12]}-{h[12:16]}-{h[16:20]}-{h[20:32]}}}"


def _fmt(x: float) -> str:
    """A number for the XML: round-trip exact; an infinite limit is xs:double's INF."""
    x = float(x)
    if math.isinf(x):
        return "INF" if x > 0 else "-INF"
    return repr(x)


def _range(v) -> str:
    """The min/max attributes of a variable with a declared range."""
    return "".join(f' {key}="{_fmt(value)}"' for key, value in (("min", v.min), ("max", v.max))
                   if value is not None)


def _dependencies(v, reference) -> str:
    """An output's ``dependencies`` attribute (the inputs and states it depends on directly,
    each by ``reference(name)``: FMI 2's 1-based index, FMI 3's value reference); none
    where the table does not declare them (then an importer assumes every input)."""
    if v.depends is None:
        return ""
    return f' dependencies="{" ".join(str(reference(name)) for name in v.depends)}"'


def _unit_definitions(fmi_version: int) -> str:
    lines = ["  <UnitDefinitions>"]
    for name, (exponents, display) in UNITS.items():
        base = " ".join(f'{k}="{v}"' for k, v in exponents.items())
        lines.append(f'    <Unit name="{name}">')
        lines.append(f"      <BaseUnit {base}/>")
        if display:
            lines.append(f'      <DisplayUnit name="{display[0]}" factor="{display[1]!r}"/>')
        lines.append("    </Unit>")
    lines.append("  </UnitDefinitions>")
    return "\n".join(lines)


def model_description(model: ModuleType, links: int, fmi_version: int, token: str) -> str:
    """The modelDescription.xml text of the ``links``-link ``model`` for FMI 2 or 3."""
    table = model.variables(links)
    by_name = {v.name: v for v in table}
    head = (f'modelName="{model.MODEL_IDENTIFIER}{links}" '
            f"description={quoteattr(model.describe(links))} "
            'generationTool="cosim plant_fmu"')
    experiment = '  <DefaultExperiment startTime="0" stopTime="20" stepSize="0.001"/>'
    logs = ("  <LogCategories>\n"
            '    <Category name="logStatusError" description="Errors"/>\n'
            '    <Category name="logStatusWarning" description="Warnings"/>\n'
            '    <Category name="logEvents" description="Mode changes and state handling"/>\n'
            "  </LogCategories>")
    outputs = [v for v in table if v.causality == "output"]
    pairs = states(table)  # the state vector's order: by the states' value references
    derivatives = [derivative for _, derivative in pairs]
    initial_unknowns = sorted({v.vr: v for v in outputs + [s for s, _ in pairs]
                               + derivatives}.values(),
                              key=lambda v: v.vr)
    if fmi_version == 2:
        return _fmi2(model.MODEL_IDENTIFIER, table, by_name, head, token, experiment, logs,
                     outputs, derivatives, initial_unknowns)
    if fmi_version == 3:
        return _fmi3(model.MODEL_IDENTIFIER, table, by_name, head, token, experiment, logs,
                     outputs, derivatives, initial_unknowns)
    raise ValueError(f"fmi_version must be 2 or 3, got {fmi_version}")


def _fmi2(identifier, table, by_name, head, token, experiment, logs, outputs, derivatives,
          initial_unknowns) -> str:
    caps = (f'modelIdentifier="{identifier}" canGetAndSetFMUstate="true" '
            'canSerializeFMUstate="true" providesDirectionalDerivative="true"')
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           f'<fmiModelDescription fmiVersion="2.0" {head} guid="{token}" '
           'variableNamingConvention="structured" numberOfEventIndicators="0">',
           f'  <ModelExchange {caps} completedIntegratorStepNotNeeded="true"/>',
           f'  <CoSimulation {caps} canHandleVariableCommunicationStepSize="true"/>',
           _unit_definitions(2), logs, experiment, "  <ModelVariables>"]
    for v in table:
        attrs = [f"name={quoteattr(v.name)}", f'valueReference="{v.vr}"',
                 f"description={quoteattr(v.description)}", f'causality="{v.causality}"',
                 f'variability="{v.variability}"']
        if v.causality in ("output", "local"):
            attrs.append('initial="calculated"')
        real = []
        if v.unit:
            real.append(f'unit="{v.unit}"')
        if v.start is not None:
            real.append(f'start="{_fmt(v.start)}"')
        if v.derivative_of:
            real.append(f'derivative="{by_name[v.derivative_of].vr + 1}"')
        if _range(v):
            real.append(_range(v).strip())
        out.append(f"    <ScalarVariable {' '.join(attrs)}>")
        out.append(f"      <Real {' '.join(real)}/>")
        out.append("    </ScalarVariable>")
    out.append("  </ModelVariables>")
    out.append("  <ModelStructure>")
    out.append("    <Outputs>")
    out += [f'      <Unknown index="{v.vr + 1}"'
            f'{_dependencies(v, lambda name: by_name[name].vr + 1)}/>' for v in outputs]
    out.append("    </Outputs>")
    out.append("    <Derivatives>")
    out += [f'      <Unknown index="{v.vr + 1}"/>' for v in derivatives]
    out.append("    </Derivatives>")
    out.append("    <InitialUnknowns>")
    out += [f'      <Unknown index="{v.vr + 1}"/>' for v in initial_unknowns]
    out.append("    </InitialUnknowns>")
    out.append("  </ModelStructure>")
    out.append("</fmiModelDescription>")
    return "\n".join(out) + "\n"


def _fmi3(identifier, table, by_name, head, token, experiment, logs, outputs, derivatives,
          initial_unknowns) -> str:
    caps = (f'modelIdentifier="{identifier}" canGetAndSetFMUState="true" '
            'canSerializeFMUState="true" providesDirectionalDerivatives="true"')
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           f'<fmiModelDescription fmiVersion="3.0" {head} instantiationToken="{token}" '
           'variableNamingConvention="flat">',
           f'  <ModelExchange {caps} needsCompletedIntegratorStep="false"/>',
           f'  <CoSimulation {caps} canHandleVariableCommunicationStepSize="true" '
           'hasEventMode="false"/>',
           _unit_definitions(3), logs, experiment, "  <ModelVariables>"]
    for v in table:
        attrs = [f"name={quoteattr(v.name)}", f'valueReference="{v.vr}"',
                 f"description={quoteattr(v.description)}", f'causality="{v.causality}"',
                 f'variability="{v.variability}"']
        if v.causality in ("output", "local"):
            attrs.append('initial="calculated"')
        if v.unit:
            attrs.append(f'unit="{v.unit}"')
        if v.start is not None:
            attrs.append(f'start="{_fmt(v.start)}"')
        if v.derivative_of:
            attrs.append(f'derivative="{by_name[v.derivative_of].vr}"')
        if _range(v):
            attrs.append(_range(v).strip())
        out.append(f"    <Float64 {' '.join(attrs)}/>")
    out.append("  </ModelVariables>")
    out.append("  <ModelStructure>")
    out += [f'    <Output valueReference="{v.vr}"'
            f'{_dependencies(v, lambda name: by_name[name].vr)}/>' for v in outputs]
    out += [f'    <ContinuousStateDerivative valueReference="{v.vr}"/>' for v in derivatives]
    out += [f'    <InitialUnknown valueReference="{v.vr}"/>' for v in initial_unknowns]
    out.append("  </ModelStructure>")
    out.append("</fmiModelDescription>")
    return "\n".join(out) + "\n"


def variables_header(model: ModuleType, links: int, token: str) -> str:
    """variables.h: the value-reference layout the model and the FMI glue index by, and
    the continuous states (plant_fmu/fmi/model.h)."""
    table = model.variables(links)
    groups = dict.fromkeys(v.group for v in table)
    pairs = states(table)
    lines = ["/* Generated by plant_fmu/description.py from the model's variable table. */",
             "#ifndef VARIABLES_H", "#define VARIABLES_H", "",
             f"#define N_LINKS {links}",
             f"#define N_VARIABLES {len(table)}",
             f"#define N_STATES {len(pairs)}",
             f"#define MODEL_IDENTIFIER_STRING {c.string_literal(model.MODEL_IDENTIFIER)}",
             f"#define INSTANTIATION_TOKEN {c.string_literal(token)}", "",
             "/* Value reference of the first element of each group (row-major for M). */"]
    stems: dict[str, str] = {}
    for g in groups:
        stem = _c_group(g)
        if stem in stems:  # two macros of one name: the later would silently win in C
            raise ValueError(f"{model.MODEL_IDENTIFIER}: the variable families {stems[stem]!r} "
                             f"and {g!r} both make the C name VR_{stem}; rename one")
        if not stem.isidentifier():
            raise ValueError(f"{model.MODEL_IDENTIFIER}: the variable family {g!r} makes "
                             f"VR_{stem}, not a C identifier; rename it")
        stems[stem] = g
        lines.append(f"#define VR_{stem} {first_vr(table, g)}")
    lines += ["",
              "typedef enum { KIND_INDEPENDENT, KIND_PARAMETER, KIND_INPUT, KIND_OUTPUT,"
              " KIND_LOCAL } VariableKind;",
              "typedef enum { CHECK_NONE, CHECK_FINITE, CHECK_POSITIVE, CHECK_NONNEGATIVE,"
              " CHECK_LIMIT } ValueCheck;",
              "typedef struct {", "    const char *name;", "    const char *unit;",
              "    VariableKind kind;", "    ValueCheck check;", "    double start;",
              "    int computed; /* by model_update_outputs, on demand */",
              "} VariableInfo;", "",
              "extern const VariableInfo VARIABLES[N_VARIABLES];",
              "/* The continuous states and their derivatives, in the state vector's order. */",
              "extern const unsigned STATE_VRS[N_STATES];",
              "extern const unsigned DERIVATIVE_VRS[N_STATES];", "", "#endif", ""]
    return "\n".join(lines)


def variables_source(model: ModuleType, links: int) -> str:
    """variables.c: name, unit, kind, check, start value and whether it is computed, of
    every value reference; the states and their derivatives."""
    table = model.variables(links)
    on_demand = computed(table)
    lines = ["/* Generated by plant_fmu/description.py from the model's variable table. */",
             "#include <math.h>", '#include "variables.h"', "",
             "const VariableInfo VARIABLES[N_VARIABLES] = {"]
    for v in table:
        start = c.number(v.start) if v.start is not None else "0.0"
        lines.append(f"    {{{c.string_literal(v.name)}, {c.string_literal(v.unit or '')}, "
                     f"{_KIND[v.causality]}, {_CHECK[v.check]}, {start}, "
                     f"{int(v.vr in on_demand)}}},")
    pairs = states(table)
    lines += ["};", "",
              "const unsigned STATE_VRS[N_STATES] = {"
              + ", ".join(str(s.vr) for s, _ in pairs) + "};",
              "const unsigned DERIVATIVE_VRS[N_STATES] = {"
              + ", ".join(str(d.vr) for _, d in pairs) + "};", ""]
    return "\n".join(lines)


def build_description(model: ModuleType, fmi_version: int, sources: list[str]) -> str:
    """sources/buildDescription.xml, read by ``fmpy compile`` to rebuild the binary."""
    files = "\n".join(f'      <SourceFile name="{s}"/>' for s in sources)
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n'
            f'<fmiBuildDescription fmiVersion="{fmi_version}.0">\n'
            f'  <BuildConfiguration modelIdentifier="{model.MODEL_IDENTIFIER}">\n'
            f'    <SourceFileSet language="C99">\n{files}\n    </SourceFileSet>\n'
            f"  </BuildConfiguration>\n</fmiBuildDescription>\n")
