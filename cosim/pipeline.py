"""Pipelines: TOML files naming the plant, the blocks with their parameters, and the runs.

Validated with pydantic on load: an unknown key, a wrong type or an out-of-range value ends
with one :class:`PipelineError` naming the key and what is allowed. Each run's sections
(``[runs.NAME.controller]`` …) are merged over the pipeline's top-level sections.
SI units, radians.
"""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
GainVector = PositiveFloat | list[PositiveFloat]


class PipelineError(ValueError):
    """A pipeline that cannot be run; the message names the key or file at fault."""


class Section(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)


class Simulation(Section):
    duration: PositiveFloat = 20.0  # s
    step: Annotated[float, Field(gt=0, le=0.1)] = 1e-3  # s, master rate


class BuiltinPlant(Section):
    links: Annotated[int, Field(ge=1, le=7)] = 2
    fmi_version: Literal[2, 3] = 2


class PlantVariables(Section):
    """Our interface in the FMU's names, one name per joint (M: n×n, row-major). Unset: our
    FMU's names (``tau[1]``, ``q[1]``, …; ``qdot``/``M`` only where the FMU has them);
    ``[]`` for ``qdot`` or ``M``: not mapped."""

    tau: list[str] | None = None  # inputs, N·m
    q: list[str] | None = None  # outputs, rad
    qdot: list[str] | None = None  # outputs, rad/s
    M: list[str] | None = None  # outputs, kg·m²


class Plant(Section):
    builtin: BuiltinPlant | None = None
    fmu: str | None = None  # path relative to the pipeline file
    parameters: dict[str, FiniteFloat] = {}  # FMU parameter and start values, by FMU name
    variables: PlantVariables = PlantVariables()

    @model_validator(mode="after")
    def _one_source(self) -> Plant:
        if self.builtin is not None and self.fmu is not None:
            raise ValueError("give either plant.builtin or plant.fmu, not both")
        if self.builtin is None and self.fmu is None:
            self.builtin = BuiltinPlant()
        return self


class Reference(Section):
    """q_d,i(t) = offset_i + Σ_j amplitude_ij sin(frequency_ij t + phase_ij)."""

    offset: list[FiniteFloat] = [0.0, 0.0]  # rad
    amplitude: list[list[FiniteFloat]] = [[20.0], [10.0]]  # rad
    frequency: list[list[NonNegativeFloat]] = [[0.5], [1.0]]  # rad/s
    phase: list[list[FiniteFloat]] | None = None  # rad, default 0
    safe_case: Literal["tracking", "midpoint"] = "midpoint"  # Remark 1 case i / ii

    @model_validator(mode="after")
    def _shapes(self) -> Reference:
        n = len(self.offset)
        for key in ("amplitude", "frequency", "phase"):
            value = getattr(self, key)
            if value is None:
                continue
            if len(value) != n:
                raise ValueError(f"reference.{key} has {len(value)} rows, offset has {n} joints")
            if any(len(row) != len(self.amplitude[i]) for i, row in enumerate(value)):
                raise ValueError(f"reference.{key} rows must match reference.amplitude's")
        return self


class Sensor(Section):
    noise_std: NonNegativeFloat = 0.0  # rad
    resolution: NonNegativeFloat = 0.0  # rad
    seed: int = 0


class Observer(Section):
    kp: PositiveFloat = 100.0
    kd: PositiveFloat = 100.0
    nu: PositiveFloat = 5e-4
    z_wo: NonNegativeFloat = 10.0
    eps_om: NonNegativeFloat = 1.0
    zeta_om: NonNegativeFloat = 1.0
    fo: PositiveFloat = 1.0
    kappa_o: NonNegativeFloat = 6.0
    law: Literal["paper", "error_driven"] = "error_driven"
    basis: Literal["lagged", "no_acceleration"] = "no_acceleration"
    substeps: Annotated[int, Field(ge=1, le=1000)] = 10
    tau_d: FiniteFloat | list[FiniteFloat] = 0.01  # N·m, the disturbance (7) assumes known
    initial_velocity: Literal["desired", "zero"] | list[FiniteFloat] = "desired"


class Controller(Section):
    variant: Literal["baseline", "proposed"] = "proposed"
    kv: GainVector = 20.0
    lam: GainVector = Field(5.0, alias="lambda")
    f: PositiveFloat = 10.0
    g: PositiveFloat = 12.0
    kappa: PositiveFloat = 0.1
    kz: NonNegativeFloat = 5.0
    z_b: NonNegativeFloat = 10.0
    z_wc: NonNegativeFloat = 10.0
    c0: NonNegativeFloat = 150.0
    c1: NonNegativeFloat = 0.1
    delta: PositiveFloat = 1.0
    psi_b: NonNegativeFloat = 20.0
    hidden: Annotated[int, Field(ge=1, le=200)] = 10


class InertiaModel(Section):
    """Where the observer's M(q) (Assumption 3) comes from: ``fmu`` (its mapped M outputs),
    ``nominal`` (this planar chain, evaluated at the measured position) or ``auto`` (the FMU's
    when mapped, else nominal). Per link; unset: the paper's arm (m = 0.8, 2.3 kg, l = lc =
    1 m, I = 0), further links 1 kg, 1 m, like the built-in plant's defaults."""

    source: Literal["auto", "fmu", "nominal"] = "auto"
    m: list[PositiveFloat] | None = None  # kg
    l: list[PositiveFloat] | None = None  # m, joint i to joint i+1  # noqa: E741
    lc: list[FiniteFloat] | None = None  # m, joint i to the link's centre of mass
    I: list[NonNegativeFloat] | None = None  # kg·m², about the centre of mass  # noqa: E741


class Safety(Section):
    position_bound: PositiveFloat = 20.0
    velocity_bound: PositiveFloat = 13.5
    error_bound: PositiveFloat = 1.0
    error_rate_bound: PositiveFloat = 5.0
    observer_error_bound: PositiveFloat = 1.0
    z_wo_tilde: PositiveFloat = 20.0
    z_wc_tilde: PositiveFloat = 50.0
    z_vc_tilde: PositiveFloat = 50.0


class Run(Section):
    sensor: Sensor = Sensor()
    observer: Observer = Observer()
    controller: Controller = Controller()
    inertia_model: InertiaModel = InertiaModel()


RUN_SECTIONS = ("sensor", "observer", "controller", "inertia_model")


class Pipeline(Section):
    name: str = "pipeline"
    description: str = ""
    simulation: Simulation = Simulation()
    plant: Plant = Plant()
    reference: Reference = Reference()
    safety: Safety = Safety()
    sensor: Sensor = Sensor()
    observer: Observer = Observer()
    controller: Controller = Controller()
    inertia_model: InertiaModel = InertiaModel()
    runs: dict[str, Run] = {}

    @model_validator(mode="before")
    @classmethod
    def _merge_runs(cls, data: Any) -> Any:
        """Each run inherits the top-level sensor/observer/controller, then overrides."""
        if not isinstance(data, dict):
            return data
        runs = data.get("runs")
        if not isinstance(runs, dict) or not runs:
            data = {**data, "runs": {"default": {}}}
            runs = data["runs"]
        merged = {}
        for name, spec in runs.items():
            if not isinstance(spec, dict):
                merged[name] = spec
                continue
            run = dict(spec)
            for section in RUN_SECTIONS:
                base = data.get(section, {})
                if isinstance(base, dict) and isinstance(run.get(section, {}), dict):
                    run[section] = {**base, **run.get(section, {})}
            merged[name] = run
        return {**data, "runs": merged}


def _format(error: dict, root: type[BaseModel]) -> str:
    # Drop pydantic's union-member tags ("constrained-float", "list[...]") from the path.
    loc = [str(p) for p in error["loc"]
           if not str(p).startswith(("function-", "literal[", "list[", "constrained-"))]
    key = ".".join(loc) or "(pipeline)"
    if error["type"] == "extra_forbidden":
        allowed = _allowed_keys(root, error["loc"][:-1])
        hint = f"; allowed keys here: {', '.join(allowed)}" if allowed else ""
        return f"unknown key '{key}'{hint}"
    msg = error["msg"]
    if error["type"] == "value_error":
        msg = msg.removeprefix("Value error, ")
    got = error.get("input")
    shown = "" if isinstance(got, dict) else f" (got {got!r})"
    return f"key '{key}': {msg}{shown}"


def _allowed_keys(model: type[BaseModel], loc: tuple) -> list[str]:
    """The field names at ``loc`` in the schema (dict keys like run names are skipped)."""
    current: Any = model
    for part in loc:
        if not (isinstance(current, type) and issubclass(current, BaseModel)):
            return []
        field = current.model_fields.get(str(part))
        if field is None:  # a run name inside `runs`
            current = Run if current is Pipeline else None
            continue
        annotation = field.annotation
        current = next((a for a in getattr(annotation, "__args__", (annotation,))
                        if isinstance(a, type) and issubclass(a, BaseModel)), None)
        if current is None and str(part) == "runs":
            current = Pipeline
    if isinstance(current, type) and issubclass(current, BaseModel):
        return [f.alias or name for name, f in current.model_fields.items()]
    return []


def validate(data: dict, source: str = "pipeline") -> Pipeline:
    try:
        return Pipeline.model_validate(data)
    except ValidationError as exc:
        # The first problem only: runs inherit the top-level sections, so one bad key
        # would otherwise be reported once more for every run.
        raise PipelineError(f"{source}: {_format(exc.errors()[0], Pipeline)}") from None


# plant.fmu and plant.builtin are alternatives: setting one with --set drops the other.
PLANT_SOURCES = {"fmu": "builtin", "builtin": "fmu"}


def _key_path(path: str) -> list[str]:
    """A dotted key as TOML reads it (quoted parts may hold dots or brackets:
    plant.parameters."m[2]"), else split at the dots (plant.parameters.m[2])."""
    try:
        node = tomllib.loads(f"{path} = 0")
    except tomllib.TOMLDecodeError:
        return [k.strip() for k in path.split(".")]
    keys = []
    while isinstance(node, dict):
        (key, node), = node.items()
        keys.append(key)
    return keys


def apply_override(data: dict, assignment: str) -> dict:
    """``key.path=VALUE`` with VALUE in TOML syntax (strings quoted: plant.fmu="x.fmu")."""
    if "=" not in assignment:
        raise PipelineError(f"--set {assignment!r}: expected KEY.PATH=VALUE, e.g. controller.kv=25")
    path, raw = assignment.split("=", 1)
    keys = _key_path(path.strip())
    if not all(keys):
        raise PipelineError(f"--set {assignment!r}: empty key in {path!r}")
    try:
        value = tomllib.loads(f"value = {raw.strip()}")["value"]
    except tomllib.TOMLDecodeError:
        raise PipelineError(f"--set {assignment!r}: {raw.strip()!r} is not a TOML value "
                            '(quote strings: plant.fmu="arm.fmu")') from None
    out = copy.deepcopy(data)
    node = out
    for key in keys[:-1]:
        child = node.setdefault(key, {})
        if not isinstance(child, dict):
            raise PipelineError(f"--set {assignment!r}: '{key}' is a value, not a table")
        node = child
    node[keys[-1]] = value
    if keys[:-1] == ["plant"] and keys[-1] in PLANT_SOURCES:  # swap the plant, not add one
        node.pop(PLANT_SOURCES[keys[-1]], None)
    return out


def load_pipeline(path: str | Path | None, overrides: list[str] | None = None) -> Pipeline:
    """Read, override (``--set`` style) and validate a pipeline file; ``None``: the defaults
    (the paper's scenario) with the overrides."""
    if path is None:
        data: dict = {}
        source, base = "--set", Path.cwd()  # plant.fmu relative to where the user is
    else:
        path = Path(path)
        if not path.is_file():
            raise PipelineError(f"{path}: no such pipeline file")
        try:
            data = tomllib.loads(path.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise PipelineError(f"{path}: not valid TOML: {exc}") from None
        source, base = str(path), path.parent
    for assignment in overrides or []:
        data = apply_override(data, assignment)
    pipeline = validate(data, source)
    if pipeline.plant.fmu is not None:
        fmu = Path(pipeline.plant.fmu).expanduser()
        pipeline.plant.fmu = str(fmu if fmu.is_absolute() else (base / fmu).resolve())
    return pipeline
