"""Where a pipeline's plant comes from: its file (``plant.fmu``, ``plant.ssp``, or the
``plant.urdf`` robot's or the built-in plant's FMU, built on demand and cached), or its
system of FMUs (``plant.system``, an SSP archive, or one FMU as a system of one), and the
plant opened and checked (:func:`open_plant`). Each problem is one :class:`PipelineError`
naming the key, the file and the variable, component or connection."""

from __future__ import annotations

from pathlib import Path

from plant_fmu import build_fmu
from plant_fmu.named_file import not_a_file

from .config import Pipeline, PipelineError
from .plant.fmu import Fmu, FmuError
from .plant.mapping import check_plant_fmu
from .plant.unpack import remove
from .system.export import single_fmu_system
from .system.plant import SystemPlant
from .system.ssp import read_ssp
from .system.structure import Component, System, parse_connection


def plant_path(pipeline: Pipeline) -> Path:
    """The plant's file: the pipeline's ``plant.fmu`` or ``plant.ssp``, or the built-in
    plant or the ``plant.urdf`` robot, built on demand and cached by its build options (a
    ``plant.system`` has none: :func:`plant_files`)."""
    if pipeline.plant.fmu is not None:
        return existing_file(pipeline.plant.fmu, "plant.fmu", "FMU")
    if pipeline.plant.ssp is not None:
        return existing_file(pipeline.plant.ssp, "plant.ssp", "SSP")
    if pipeline.plant.urdf is not None:
        return urdf_plant_path(pipeline.plant.urdf)
    b = pipeline.plant.builtin
    return build_fmu(links=b.links, fmi_version=b.fmi_version, model=b.model)


def existing_file(name: str, key: str, kind: str) -> Path:
    """``name``, a file the pipeline's ``key`` names (an ``kind`` archive), or a
    :class:`PipelineError` saying why it is not one."""
    path = Path(name)
    if path.is_dir():
        raise PipelineError(f"{key}: {path} is a folder, not an {kind} file (an unpacked "
                            f"{kind} cannot be used: give its .{kind.lower()} archive)")
    why = not_a_file(path)
    if why is not None:
        raise PipelineError(f"{key}: {path} {why.replace(', not a file', f', not an {kind} file')}")
    return path


def plant_files(pipeline: Pipeline) -> list[Path]:
    """The files the plant is made of, built on demand: its FMU, its SSP archive, or each
    FMU of its ``plant.system``."""
    if pipeline.plant.system is None:
        return [plant_path(pipeline)]
    return [component.source for component in table_system(pipeline.plant.system).components]


def table_system(table) -> System:
    """The system a pipeline's ``[plant.system]`` (a :class:`~cosim.config.sections.
    SystemTable`) writes: its built-in components built on demand (cached), its
    connections read."""
    components = []
    for name, spec in table.components.items():
        where = f"plant.system.components.{name}"
        if spec.fmu is not None:
            source = existing_file(spec.fmu, f"{where}.fmu", "FMU")
        else:
            b = spec.builtin
            source = build_fmu(links=b.links, fmi_version=b.fmi_version, model=b.model)
        components.append(Component(name, source, dict(spec.parameters), None,
                                    spec.step_multiple, where))
    names = set(table.components)
    delayed = [parse_connection(text, names, True, f"plant.system.delayed[{i}]")
               for i, text in enumerate(table.delayed, 1)]
    held = {(c.start, c.end) for c in delayed}
    connections = [parse_connection(text, names, False, f"plant.system.connections[{i}]")
                   for i, text in enumerate(table.connections, 1)]
    return System(table.name, components,
                  [c for c in connections if (c.start, c.end) not in held] + delayed,
                  origin="plant.system")


def urdf_plant_path(urdf) -> Path:
    """The FMU of ``plant.urdf`` (a :class:`~cosim.config.sections.UrdfPlant`), built on
    demand and cached by the URDF's chain; a URDF it refuses is a :class:`PipelineError`."""
    from plant_fmu import UrdfError, build_urdf_fmu
    from plant_fmu.urdf import resolve_uri

    try:
        return build_urdf_fmu(resolve_uri(urdf.file, Path.cwd()), base=urdf.base, tip=urdf.tip,
                              fixed=dict(urdf.fixed), fmi_version=urdf.fmi_version,
                              held_by="plant.urdf.fixed")
    except UrdfError as exc:
        raise PipelineError(f"plant.urdf: {exc}") from None


def open_plant(pipeline: Pipeline) -> Fmu | SystemPlant:
    """The pipeline's plant, checked: an FMU (its file, Co-Simulation binary,
    ``plant.variables`` and ``plant.parameters``) or a system of FMUs (every component,
    connector and connection too): :class:`PipelineError` naming the file and the
    variable, component or connection."""
    mapping, parameters = pipeline.plant.variables.model_dump(), dict(pipeline.plant.parameters)
    try:
        if pipeline.plant.system is None and pipeline.plant.ssp is None:
            return Fmu(plant_path(pipeline), mapping, parameters)
        system, folder = plant_system(pipeline)
        try:
            return SystemPlant(system, mapping, parameters, folder)
        except BaseException:
            if folder is not None:
                remove(folder)
            raise
    except FmuError as exc:
        raise PipelineError(str(exc)) from None


def plant_system(pipeline: Pipeline) -> tuple[System, str | None]:
    """The pipeline's plant as a system of FMUs, and the folder an SSP archive was unpacked
    into (the caller removes it; None for the others): ``plant.ssp``, ``plant.system``, or
    one FMU as a system of one component (:func:`~cosim.system.export.single_fmu_system`).
    :class:`FmuError` where the plant is not valid."""
    if pipeline.plant.ssp is not None:
        return read_ssp(plant_path(pipeline))
    if pipeline.plant.system is not None:
        return table_system(pipeline.plant.system), None
    path = plant_path(pipeline)
    _, variables = check_plant_fmu(path, pipeline.plant.variables.model_dump(),
                                   dict(pipeline.plant.parameters))
    return single_fmu_system(path, variables.names, dict(pipeline.plant.parameters)), None
