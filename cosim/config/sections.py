"""The pipeline's fixed tables: ``[simulation]`` and ``[plant]`` (a built-in arm or an FMU,
its parameters and the mapping of its ports), and the names a pipeline and its runs may
take. SI units, radians."""

from __future__ import annotations

import re
from typing import Annotated, Literal

from pydantic import Field, create_model, model_validator

from plant_fmu import ARMS, DEFAULT_MODEL, MODELS

from ..plant.ports import PORTS
from ..schema import FileName, FiniteFloat, PositiveFloat, Section


class Simulation(Section):
    duration: PositiveFloat = 20.0  # simulated time of each run, s
    # master step, the controller's sample time and the plant's communication step, s
    step: Annotated[float, Field(gt=0, le=0.1)] = 1e-3
    # cap on the built-in plant's RK4 sub-steps per master step (simulation.step /
    # plant.parameters.rk4_step): one FMU call cannot be interrupted, so a tiny rk4_step
    # would otherwise run for hours unstoppably, dimensionless (a count)
    max_plant_substeps: Annotated[int, Field(ge=1)] = 1000

    @model_validator(mode="after")
    def _whole_steps(self) -> Simulation:
        steps = self.duration / self.step
        if steps < 1.0 - 1e-9:
            raise ValueError(f"simulation.step = {self.step:g} s is longer than "
                             f"simulation.duration = {self.duration:g} s: the run would have "
                             "no step")
        if abs(steps - round(steps)) > 1e-6 * max(1.0, steps):
            below, above = int(steps) * self.step, (int(steps) + 1) * self.step
            raise ValueError(f"simulation.duration = {self.duration:g} s is not a whole number "
                             f"of steps of {self.step:g} s ({steps:.6g}); use {below:g} or "
                             f"{above:g} s")
        return self

    @property
    def steps(self) -> int:
        return int(round(self.duration / self.step))


# A run's or pipeline's name becomes a file and folder name and a recording entity path.
SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def check_name(name: str, what: str) -> str:
    if not SAFE_NAME.fullmatch(name) or ".." in name:
        raise ValueError(f"{what} {name!r}: use up to 64 letters, digits, '_', '-' and '.', "
                         "starting with a letter or digit (it names files and recording "
                         "entities)")
    return name


class BuiltinPlant(Section):
    # the built-in plant model (a name): "planar_arm", the rigid arm, or "elastic_joints",
    # the arm whose motors drive the links through springs (extra parameters k, d, J per
    # joint)
    model: Literal[ARMS] = DEFAULT_MODEL
    links: Annotated[int, Field(ge=1, le=7)] = 2  # number of joints, dimensionless (a count)
    fmi_version: Literal[2, 3] = 2  # the FMI version it is built for, 2 or 3 (a name)


class UrdfPlant(Section):
    """A robot's URDF, built into a spatial-chain FMU at run time (cached, as ``cosim
    build-fmu --urdf``). ``plant.urdf = "robot.urdf"`` is short for ``[plant.urdf] file =
    "robot.urdf"``."""

    # the URDF: a path relative to the pipeline file, or package://PKG/... (e.g.
    # package://example-robot-data/robots/panda_description/urdf/panda.urdf), a path
    file: FileName
    base: str | None = None  # the link the chain is fixed to (default: the root link), a name
    # the chain's last link, where the payload sits (default: from the base, the one way on
    # to a moving joint, stopping where it forks), a name
    tip: str | None = None
    # joints held at a value and folded into their parent body, rad (m for a prismatic joint)
    fixed: dict[str, FiniteFloat] = {}
    fmi_version: Literal[2, 3] = 2  # the FMI version it is built for, 2 or 3 (a name)

    @model_validator(mode="before")
    @classmethod
    def _file_alone(cls, data):
        return {"file": data} if isinstance(data, str) else data


class Robot(Section):
    """The robot a pipeline is about, named once: its URDF, chain and held joints. Where the
    pipeline does not set them itself, it is the plant (``plant.urdf``), the nominal model
    of the blocks (``inertia_model.urdf``, ``base``, ``tip``, ``fixed``) and the source of
    the safe sets (``safety.limits = "urdf"`` and ``safety.urdf``, ``urdf_base``,
    ``urdf_tip``, ``urdf_fixed``). ``robot = "arm.urdf"`` is short for ``[robot] file =
    "arm.urdf"``."""

    # the robot's URDF: a path relative to the pipeline file, or package://PKG/..., a path
    file: FileName
    base: str | None = None  # the link the chain is fixed to (default: the root link), a name
    # the chain's last link, where the payload sits (default: from the base, the one way on
    # to a moving joint, stopping where it forks), a name
    tip: str | None = None
    # joints held at a value and folded into their parent body, rad (m for a prismatic joint)
    fixed: dict[str, FiniteFloat] = {}

    @model_validator(mode="before")
    @classmethod
    def _file_alone(cls, data):
        return {"file": data} if isinstance(data, str) else data


def robot_defaults(data: dict) -> dict:
    """A pipeline's raw tables with what ``[robot]`` names filled in where the pipeline
    leaves it unset (:class:`Robot`); the tables as they are without a robot, or with one
    that is not a table or a path (the schema refuses it)."""
    robot = data.get("robot")
    if isinstance(robot, str):
        robot = {"file": robot}
    if not isinstance(robot, dict) or not isinstance(robot.get("file"), str):
        return data
    data = dict(data)
    chain = {key: robot[key] for key in ("file", "base", "tip", "fixed") if key in robot}
    plant = data.get("plant")
    if plant is None or isinstance(plant, dict):
        plant = dict(plant or {})
        if not any(key in plant for key in PLANT_SOURCES):
            plant["urdf"] = chain
        data["plant"] = plant
    model = data.get("inertia_model")
    if model is None or isinstance(model, dict):
        model = dict(model or {})
        if "urdf" not in model:
            model.update({"urdf": chain["file"], **{key: chain[key] for key in
                                                     ("base", "tip", "fixed") if key in chain}})
        data["inertia_model"] = model
    safety = data.get("safety")
    if safety is None or isinstance(safety, dict):
        safety = dict(safety or {})
        safety.setdefault("limits", "urdf")
        if safety["limits"] == "urdf" and "urdf" not in safety:
            safety.update({"urdf": chain["file"], **{f"urdf_{key}": chain[key] for key in
                                                      ("base", "tip", "fixed") if key in chain}})
        data["safety"] = safety
    return data


class _VariableMapping(Section):
    """The plant's ports in the FMU's names, one name per joint (n×n row-major for M), a
    key per port of cosim.plant.ports.PORTS. Unset: the built-in plants' names (``tau[1]``,
    ``q[1]``, …; an optional output only where the FMU has them); ``[]`` for an optional
    output: not mapped."""


VariableMapping = create_model(
    "VariableMapping", __base__=_VariableMapping,
    **{port.name: (list[str] | None, Field(None, description=(
        f"{port.direction}s, {port.signal.unit}: {port.role}"
        + ("" if port.required else " (optional)")))) for port in PORTS})


class BuiltinComponent(Section):
    # the built-in model (a name): "planar_arm" or "elastic_joints", an arm, or "drives",
    # the joints' motors behind their gears (build-fmu --model)
    model: Literal[tuple(MODELS)]
    # its number of links, or of joints for the drives, dimensionless (a count)
    links: Annotated[int, Field(ge=1, le=7)] = 2
    fmi_version: Literal[2, 3] = 2  # the FMI version it is built for, 2 or 3 (a name)


class SystemComponent(Section):
    """One FMU of a system: a file (``fmu``) or a built-in model (``builtin``)."""

    fmu: str | None = None  # the component's FMU file, relative to the pipeline file, a path
    # a built-in model built into its FMU at run time (a table: model, links, fmi_version),
    # names
    builtin: BuiltinComponent | None = None
    # its parameter and start values by its own variables' names, each in that variable's
    # unit, mixed units
    parameters: dict[str, FiniteFloat] = {}
    # its communication step as a whole number of master steps (simulation.step), which it
    # holds its inputs over, dimensionless (a count)
    step_multiple: Annotated[int, Field(ge=1)] = 1

    @model_validator(mode="after")
    def _one_source(self) -> SystemComponent:
        if (self.fmu is None) == (self.builtin is None):
            raise ValueError("a system's component is a file (fmu = \"...\") or a built-in "
                             "model (builtin = { model = \"...\", links = N }): give one")
        return self


class SystemTable(Section):
    """A system of FMUs written in the pipeline (docs/systems.md): the same as an SSP
    archive's. Its own connectors are the names in ``connections`` without a component:
    inputs where a connection starts, outputs where one ends; the plant's ports are mapped
    onto them by ``plant.variables`` (by default ``tau[i]`` in, ``q[i]``, ``qdot[i]``,
    ``M[i,j]`` out)."""

    name: str = "system"  # the system's name, in the summary and an exported SSP, a name
    # its components by name (letters, digits, '_'), each a table: fmu or builtin,
    # parameters, step_multiple, names
    components: dict[str, SystemComponent]
    # "START -> END", each COMPONENT.CONNECTOR or a connector of the system's own
    # ("drives.tau[1] -> arm.tau[1]", "tau[1] -> drives.tau_cmd[1]"), names
    connections: list[str] = []
    # connections, written the same way, that carry the value their start had before the
    # step's values passed on (a step's delay, declared where it breaks an algebraic loop),
    # names
    delayed: list[str] = []


class Plant(Section):
    builtin: BuiltinPlant | None = None
    fmu: FileName | None = None  # the plant FMU's file, relative to the pipeline file, a path
    # a robot's URDF built into the plant FMU at run time: its file, relative to the pipeline
    # file or package://..., a path (or a table: file, base, tip, fixed, fmi_version)
    urdf: UrdfPlant | None = None
    # a system of FMUs as an SSP 1.0 archive (SystemStructure.ssd, its .ssv parameter sets,
    # its FMUs under resources/): its file, relative to the pipeline file, a path
    ssp: str | None = None
    # a system of FMUs written here (a table: name, components, connections, delayed;
    # docs/systems.md), names
    system: SystemTable | None = None
    # FMU parameter and start values by the FMU's variable name (a system's: by
    # COMPONENT.VARIABLE, or by the name alone for its arm's), each in that variable's own
    # unit (cosim inspect lists them), mixed units
    parameters: dict[str, FiniteFloat] = {}
    variables: VariableMapping = VariableMapping()

    @model_validator(mode="after")
    def _one_source(self) -> Plant:
        given = [key for key in PLANT_SOURCES if getattr(self, key) is not None]
        if len(given) > 1:
            raise ValueError(f"give one of plant.builtin, plant.fmu or plant.urdf, not "
                             f"{' and '.join('plant.' + key for key in given)}; or in their "
                             "place a system of FMUs, plant.ssp or plant.system")
        if not given:
            self.builtin = BuiltinPlant()
        return self


# plant.builtin, plant.fmu, plant.urdf, plant.ssp and plant.system are alternatives: a file
# or --set naming one drops the others.
_SOURCES = ("builtin", "fmu", "urdf", "ssp", "system")
PLANT_SOURCES = {key: tuple(other for other in _SOURCES if other != key) for key in _SOURCES}
