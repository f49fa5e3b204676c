"""SSP 1.0 (System Structure and Parameterization, the FMI family's standard for systems of
FMUs) in and out: an ``.ssp`` archive's ``SystemStructure.ssd`` (components, connectors,
connections), its parameter values (``.ssv`` files or inline parameter sets) and its FMUs
under ``resources/``, read into a :class:`~.structure.System`, and a system written as one.

Every file is checked against the standard's own XML schemas (the copies FMPy ships), then
for what cosim can run: one flat system of FMU components (no nested systems, signal
dictionaries or parameter mappings), Real and Integer parameter values, connections without
unit conversions. What SSP 1.0 has no element for, cosim keeps in annotations of type
:data:`ANNOTATION` that other tools ignore: a component's step as a multiple of the
master's, and a connection that carries the previous step's value (a declared loop break).
A problem is one :class:`FmuError` naming the file, the element and its line.
"""

from __future__ import annotations

import functools
import math
import shutil
import zipfile
from pathlib import Path, PurePosixPath

from lxml import etree

from ..plant.errors import FmuError
from ..plant.unpack import extract, remove
from .structure import Component, Connection, Connector, Endpoint, System

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
COSIM = "https://github.com/cosim/ssp"  # cosim's annotations' elements
NS = {"ssd": SSD, "ssc": SSC, "ssv": SSV, "cosim": COSIM}
ANNOTATION = "org.cosim.ssp"  # the type of cosim's annotations
DESCRIPTION = "SystemStructure.ssd"
FMU_TYPE = "application/x-fmu-sharedlibrary"
TYPES = ("Real", "Integer", "Boolean", "String", "Enumeration", "Binary")
BASE_UNIT = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")  # a unit's SI base exponents


@functools.cache
def _schema(name: str) -> etree.XMLSchema:
    """One of the SSP 1.0 XML schemas FMPy ships (fmpy/ssp/schema)."""
    import fmpy.ssp

    return etree.XMLSchema(file=str(Path(fmpy.ssp.__file__).parent / "schema" / name))


def _parse(data: bytes, where: str, schema: str) -> etree._Element:
    """An SSP XML file's root, checked against its schema; :class:`FmuError` naming the
    file, the line and what is wrong."""
    try:
        root = etree.fromstring(data, etree.XMLParser(resolve_entities=False, no_network=True))
    except etree.XMLSyntaxError as exc:
        line, column = exc.position
        raise FmuError(f"{where}: not XML (line {line}, column {column}: {exc.msg})") from None
    validator = _schema(schema)
    if not validator.validate(root):
        error = validator.error_log[0]
        raise FmuError(f"{where}: not valid SSP 1.0 (line {error.line}: {error.message})")
    return root


def _line(element: etree._Element) -> str:
    return f"line {element.sourceline}"


# Reading ------------------------------------------------------------------------------------


def read_ssp(path: str | Path) -> tuple[System, str]:
    """The system of an ``.ssp`` archive, and the folder it was unpacked into (its FMUs are
    read from there; the caller removes it with :func:`cosim.plant.unpack.remove`)."""
    path = Path(path)
    if not path.is_file():
        raise FmuError(f"{path}: no such SSP file" if not path.exists()
                       else f"{path}: is a folder; give the .ssp archive")
    if not zipfile.is_zipfile(path):
        raise FmuError(f"{path}: not an SSP archive (not a zip file)")
    with zipfile.ZipFile(path) as archive:
        if DESCRIPTION not in archive.namelist():
            raise FmuError(f"{path}: not an SSP archive: it has no {DESCRIPTION} at its top "
                           "level")
    folder = extract(path)
    try:
        return _read_folder(path, Path(folder)), folder
    except BaseException:
        remove(folder)
        raise


def _read_folder(archive: Path, folder: Path) -> System:
    where = f"{archive.name}: {DESCRIPTION}"
    root = _parse((folder / DESCRIPTION).read_bytes(), where, "SystemStructureDescription.xsd")
    system = root.find("ssd:System", NS)
    nested = system.find("ssd:Elements/ssd:System", NS)
    unsupported = nested if nested is not None else system.find(
        "ssd:Elements/ssd:SignalDictionaryReference", NS)
    if unsupported is not None:
        raise FmuError(f"{where} ({_line(unsupported)}): <{etree.QName(unsupported).localname}> "
                       f"{unsupported.get('name')!r}: cosim runs one flat system of FMU "
                       "components (no nested systems or signal dictionaries)")
    units = _units(root)
    components = [_component(element, archive, folder, where, units)
                  for element in system.findall("ssd:Elements/ssd:Component", NS)]
    names = [c.name for c in components]
    twice = next((n for n in names if names.count(n) > 1), None)
    if twice:
        raise FmuError(f"{where}: two components are named {twice!r}; a component's name is "
                       "unique in its system")
    for name, values in _bindings(system, archive, folder, where).items():
        component, _, variable = name.partition(".")
        target = next((c for c in components if c.name == component), None)
        if target is None or not variable:
            raise FmuError(f"{where}: the system's parameter {name!r} names no component "
                           f"(its components: {', '.join(names)}); a system's parameter is "
                           "COMPONENT.VARIABLE")
        target.parameters[variable] = values
    connections = [_connection(element, where)
                   for element in system.findall("ssd:Connections/ssd:Connection", NS)]
    return System(system.get("name"), components, connections,
                  _connectors(system, where, units), str(archive), units)


def _units(root: etree._Element) -> dict[str, tuple]:
    """The SSD's unit definitions: name -> (kg, m, s, A, K, mol, cd, rad, factor, offset)."""
    out = {}
    for unit in root.findall("ssd:Units/ssc:Unit", NS):
        base = unit.find("ssc:BaseUnit", NS)
        out[unit.get("name")] = tuple(
            [int(base.get(k, 0)) for k in BASE_UNIT]
            + [float(base.get("factor", 1.0)), float(base.get("offset", 0.0))])
    return out


def _connectors(element: etree._Element, where: str, units: dict[str, tuple]
                ) -> list[Connector]:
    """An element's declared connectors; a unit each names must be one the SSD defines."""
    out = []
    for connector in element.findall("ssd:Connectors/ssd:Connector", NS):
        typed = next((child for child in connector
                      if etree.QName(child).namespace == SSC
                      and etree.QName(child).localname in TYPES), None)
        unit = typed.get("unit") if typed is not None else None
        if unit is not None and unit not in units:
            raise FmuError(f"{where} ({_line(typed)}): connector {connector.get('name')!r} "
                           f"has unit {unit!r}, which the SSD's <Units> does not define")
        out.append(Connector(connector.get("name"), connector.get("kind"),
                             etree.QName(typed).localname if typed is not None else None,
                             unit, f"{where} {_line(connector)}"))
    return out


def _component(element: etree._Element, archive: Path, folder: Path, where: str,
               units: dict[str, tuple]) -> Component:
    name = element.get("name")
    at = f"{where} ({_line(element)})"
    kind = element.get("type", FMU_TYPE)
    if kind != FMU_TYPE:
        raise FmuError(f"{at}: component {name!r} is of type {kind!r}; cosim runs FMU "
                       f"components ({FMU_TYPE})")
    source = element.get("source")
    relative = PurePosixPath(source)
    if "://" in source or relative.is_absolute() or ".." in relative.parts:
        raise FmuError(f"{at}: component {name!r}: its source {source!r} is not a file inside "
                       f"{archive.name} (give a relative path such as resources/{name}.fmu)")
    path = folder / relative
    if not path.is_file():
        raise FmuError(f"{at}: component {name!r}: its source {source} is not in "
                       f"{archive.name} (a missing resource)")
    connectors = {c.name: c for c in _connectors(element, where, units)}
    component = Component(name, path, connectors=connectors, where=at)
    component.parameters = {
        key: value for key, value in _bindings(element, archive, folder, where).items()}
    for annotation in element.findall(f"ssd:Annotations/ssc:Annotation[@type='{ANNOTATION}']",
                                      NS):
        stepping = annotation.find("cosim:Component", NS)
        if stepping is not None:
            component.step_multiple = _whole(stepping.get("stepMultiple", "1"), at, name)
    return component


def _whole(text: str, at: str, name: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise FmuError(f"{at}: component {name!r}: stepMultiple = {text!r} in its {ANNOTATION} "
                       "annotation must be a whole number ≥ 1 (its step, in master steps)")
    return value


def _bindings(element: etree._Element, archive: Path, folder: Path, where: str
              ) -> dict[str, float]:
    """The parameter values an element's ParameterBindings give (later bindings win), by
    name (with each binding's prefix)."""
    values: dict[str, float] = {}
    for binding in element.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS):
        at = f"{where} ({_line(binding)})"
        if binding.find("ssd:ParameterMapping", NS) is not None:
            raise FmuError(f"{at}: a ParameterMapping: cosim reads parameter values by the "
                           "variables' own names; give them so, without a mapping")
        kind = binding.get("type", "application/x-ssp-parameter-set")
        if kind != "application/x-ssp-parameter-set":
            raise FmuError(f"{at}: a parameter binding of type {kind!r}; cosim reads SSP "
                           "parameter sets (.ssv)")
        if binding.get("sourceBase", "SSD") != "SSD":
            raise FmuError(f"{at}: sourceBase = {binding.get('sourceBase')!r}: cosim reads "
                           "parameter sets from the SSP archive (sourceBase=\"SSD\")")
        source = binding.get("source")
        if source is not None:
            relative = PurePosixPath(source)
            path = folder / relative
            if "://" in source or relative.is_absolute() or ".." in relative.parts \
                    or not path.is_file():
                raise FmuError(f"{at}: the parameter set {source} is not in {archive.name} "
                               "(a missing resource)")
            file = f"{archive.name}: {source}"
            sets = [_parse(path.read_bytes(), file, "SystemStructureParameterValues.xsd")]
        else:
            file = where
            sets = binding.findall("ssd:ParameterValues/ssv:ParameterSet", NS)
        prefix = binding.get("prefix", "")
        for parameter_set in sets:
            for parameter in parameter_set.findall("ssv:Parameters/ssv:Parameter", NS):
                values[prefix + parameter.get("name")] = _value(parameter, file)
    return values


def _value(parameter: etree._Element, where: str) -> float:
    name = parameter.get("name")
    typed = next((child for child in parameter if etree.QName(child).namespace == SSV), None)
    kind = etree.QName(typed).localname if typed is not None else "none"
    if kind not in ("Real", "Integer"):
        raise FmuError(f"{where} ({_line(parameter)}): parameter {name!r} is of type {kind}; "
                       "cosim sets Real (and Integer) parameters")
    text = typed.get("value")
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = math.nan
    if math.isnan(value):  # INF is a value (a limit that is none)
        raise FmuError(f"{where} ({_line(parameter)}): parameter {name!r} = {text!r} is not "
                       "a number")
    return value


def _connection(element: etree._Element, where: str) -> Connection:
    at = f"{where} ({_line(element)})"
    start = Endpoint(element.get("startElement"), element.get("startConnector"))
    end = Endpoint(element.get("endElement"), element.get("endConnector"))
    transform = next((child for child in element
                      if etree.QName(child).localname.endswith("Transformation")), None)
    if transform is not None:
        raise FmuError(f"{at}: connection {start} -> {end} has a "
                       f"{etree.QName(transform).localname}: cosim converts no values; connect "
                       "connectors of one unit")
    delayed = any(mark.get("delayed") == "true" for mark in element.findall(
        f"ssd:Annotations/ssc:Annotation[@type='{ANNOTATION}']/cosim:Connection", NS))
    return Connection(start, end, delayed, at)


# Writing ------------------------------------------------------------------------------------


def write_ssp(system: System, path: str | Path, units: dict[str, tuple] | None = None,
              duration: float | None = None) -> Path:
    """``system`` as an SSP 1.0 archive at ``path``: its FMUs copied under ``resources/``,
    each component's parameter values as ``resources/<component>.ssv``, every connector
    with its kind, type and unit (``units``: each unit's definition, (kg, m, s, A, K, mol,
    cd, rad exponents, factor, offset), as an SSD's <Units> give it), ``duration`` (s) as
    the default experiment's stop time."""
    from plant_fmu.build import write_atomically

    path = Path(path)
    root = etree.Element(f"{{{SSD}}}SystemStructureDescription", nsmap={
        "ssd": SSD, "ssc": SSC, "ssv": SSV}, version="1.0", name=system.name,
        generationTool="cosim")
    element = etree.SubElement(root, f"{{{SSD}}}System", name=system.name)
    _write_connectors(element, system.own_connectors())
    elements = etree.SubElement(element, f"{{{SSD}}}Elements")
    files: dict[str, bytes | Path] = {}
    for component in system.components:
        source = f"resources/{component.name}.fmu"
        files[source] = component.source
        child = etree.SubElement(elements, f"{{{SSD}}}Component", name=component.name,
                                 type=FMU_TYPE, source=source)
        _write_connectors(child, list((component.connectors or {}).values()))
        if component.parameters:
            ssv = f"resources/{component.name}.ssv"
            files[ssv] = _parameter_set(component)
            bindings = etree.SubElement(child, f"{{{SSD}}}ParameterBindings")
            etree.SubElement(bindings, f"{{{SSD}}}ParameterBinding", source=ssv)
        if component.step_multiple != 1:
            annotation = _annotation(child)
            etree.SubElement(annotation, f"{{{COSIM}}}Component", nsmap={"cosim": COSIM},
                             stepMultiple=str(component.step_multiple))
    connections = etree.SubElement(element, f"{{{SSD}}}Connections")
    for connection in system.connections:
        ends = {"startElement": connection.start.element,
                "startConnector": connection.start.connector,
                "endElement": connection.end.element, "endConnector": connection.end.connector}
        child = etree.SubElement(connections, f"{{{SSD}}}Connection",
                                 **{k: v for k, v in ends.items() if v is not None})
        if connection.delayed:
            etree.SubElement(_annotation(child), f"{{{COSIM}}}Connection",
                             nsmap={"cosim": COSIM}, delayed="true")
    if units:
        defined = etree.SubElement(root, f"{{{SSD}}}Units")
        for name, base in units.items():
            unit = etree.SubElement(defined, f"{{{SSC}}}Unit", name=name)
            attributes = {key: str(e) for key, e in zip(BASE_UNIT, base[:8], strict=True) if e}
            attributes.update({key: repr(float(v)) for key, v, default in
                               (("factor", base[8], 1.0), ("offset", base[9], 0.0))
                               if v != default})
            etree.SubElement(unit, f"{{{SSC}}}BaseUnit", **attributes)
    if duration is not None:
        etree.SubElement(root, f"{{{SSD}}}DefaultExperiment", startTime="0",
                         stopTime=repr(float(duration)))
    text = etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)
    _parse(text, f"{path.name}: {DESCRIPTION} (as written)", "SystemStructureDescription.xsd")

    def pack(tmp: Path) -> None:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(DESCRIPTION, text)
            for name, content in files.items():
                if isinstance(content, Path):
                    with content.open("rb") as src, archive.open(name, "w") as dst:
                        shutil.copyfileobj(src, dst)
                else:
                    archive.writestr(name, content)

    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(path, pack)
    return path


def _annotation(parent: etree._Element) -> etree._Element:
    annotations = etree.SubElement(parent, f"{{{SSD}}}Annotations")
    return etree.SubElement(annotations, f"{{{SSC}}}Annotation", type=ANNOTATION)


def _write_connectors(parent: etree._Element, connectors: list[Connector]) -> None:
    if not connectors:
        return
    element = etree.SubElement(parent, f"{{{SSD}}}Connectors")
    for connector in connectors:
        child = etree.SubElement(element, f"{{{SSD}}}Connector", name=connector.name,
                                 kind=connector.kind)
        if connector.type is not None:
            typed = etree.SubElement(child, f"{{{SSC}}}{connector.type}")
            if connector.unit and connector.type == "Real":
                typed.set("unit", connector.unit)


def _parameter_set(component: Component) -> bytes:
    root = etree.Element(f"{{{SSV}}}ParameterSet", nsmap={"ssv": SSV, "ssc": SSC},
                         version="1.0", name=component.name)
    parameters = etree.SubElement(root, f"{{{SSV}}}Parameters")
    for name, value in component.parameters.items():
        parameter = etree.SubElement(parameters, f"{{{SSV}}}Parameter", name=name)
        etree.SubElement(parameter, f"{{{SSV}}}Real", value=_number(value))
    text = etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)
    _parse(text, f"{component.name}.ssv (as written)", "SystemStructureParameterValues.xsd")
    return text


def _number(value: float) -> str:
    """A value for xs:double, round-trip exact (INF for an infinite limit)."""
    value = float(value)
    if math.isinf(value):
        return "INF" if value > 0 else "-INF"
    return repr(value)
