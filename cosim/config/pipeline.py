"""Pipelines: TOML files naming the plant, the blocks with their parameters, and the runs.

The schema is assembled from the block registry: every registered block's ``Params`` is a
table (``[controller]``, ``[observer]``, …) at the top level and in each run, and each run
may name its chain of blocks (``blocks = [...]``, default :data:`DEFAULT_CHAIN`). Validated
with pydantic on load: an unknown key, a wrong type or an out-of-range value ends with one
:class:`PipelineError` naming the key and what is allowed. Each run's tables
(``[runs.NAME.controller]`` …) are merged over the pipeline's top-level tables.
SI units, radians.
"""

from __future__ import annotations

import copy
import re
import sys
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field, ValidationError, create_model, model_validator

from plant_fmu import DEFAULT_MODEL, MODELS

from ..blocks import BLOCKS, DEFAULT_CHAIN
from ..blocks.plugins import load_entry_points, load_plugins
from ..declared import Safety, Uncertainty
from ..plant.ports import PORTS
from ..schema import FiniteFloat, PipelineError, PositiveFloat, Section


class Simulation(Section):
    duration: PositiveFloat = 20.0  # s
    step: Annotated[float, Field(gt=0, le=0.1)] = 1e-3  # s, master rate
    # The built-in plant integrates each step in RK4 sub-steps of at most its rk4_step
    # parameter (1e-4 s: 10 a step). One FMU call cannot be interrupted, so the sub-steps a
    # step may take are capped: a tiny rk4_step would otherwise run for hours unstoppably.
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
    # The model: plant_fmu.models.MODELS (the elastic-joint arm's motors drive the links
    # through springs; its extra parameters are k, d, J per joint).
    model: Literal[tuple(MODELS)] = DEFAULT_MODEL  # the rigid arm, or with elastic joints
    links: Annotated[int, Field(ge=1, le=7)] = 2  # joints of the built-in arm
    fmi_version: Literal[2, 3] = 2  # the FMI version it is built for


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


class Plant(Section):
    builtin: BuiltinPlant | None = None
    fmu: str | None = None  # path relative to the pipeline file
    parameters: dict[str, FiniteFloat] = {}  # FMU parameter and start values, by FMU name
    variables: VariableMapping = VariableMapping()

    @model_validator(mode="after")
    def _one_source(self) -> Plant:
        if self.builtin is not None and self.fmu is not None:
            raise ValueError("give either plant.builtin or plant.fmu, not both")
        if self.builtin is None and self.fmu is None:
            self.builtin = BuiltinPlant()
        return self


def chain_entry(entry: str) -> tuple[str, str]:
    """(instance name, kind) of one ``blocks`` entry: ``"kind"``, or ``"kind as name"`` for
    a named instance (two of one kind in a chain). ValueError if malformed."""
    kind, _, name = (part.strip() for part in entry.partition(" as "))
    name = name or kind
    if not kind.isidentifier() or not name.isidentifier():
        raise ValueError(f"blocks: {entry!r} is not a block (\"kind\", or \"kind as name\" "
                         "for a named instance, both identifiers)")
    return name, kind


class Run(Section):
    """One run: its chain of blocks and their tables (merged over the top level's). An entry
    ``"kind as name"`` adds an instance of ``kind`` named ``name``, with its own table
    ``[runs.RUN.name]`` merged over the top-level ``[kind]`` (``instances`` holds them)."""

    blocks: list[str] = list(DEFAULT_CHAIN)
    instances: dict[str, dict] = {}  # named instances' tables, from [runs.RUN.NAME]

    @model_validator(mode="before")
    @classmethod
    def _gather_instances(cls, data: Any) -> Any:
        """Take each named instance's table out of the run's keys, into ``instances``."""
        if not isinstance(data, dict) or not isinstance(data.get("blocks"), list):
            return data
        instances = dict(data.get("instances") or {})
        data = dict(data)
        for entry in data["blocks"]:
            if not isinstance(entry, str):
                continue
            name, kind = chain_entry(entry)
            if name != kind and name in data:
                instances[name] = data.pop(name)
        return {**data, "instances": instances}

    @model_validator(mode="after")
    def _known_blocks(self) -> Run:
        names: set[str] = set()
        for entry in self.blocks:
            name, kind = chain_entry(entry)
            if kind not in BLOCKS:
                raise ValueError(f"blocks: {kind!r} is not a registered block (registered: "
                                 f"{', '.join(BLOCKS)})")
            if name != kind:
                if name in BLOCKS or name in names:
                    raise ValueError(f"blocks: {entry!r}: the name {name!r} is taken (by a "
                                     "block kind or another instance); name it otherwise")
                self._instance_params(name, kind)  # refused here, naming the key
            names.add(name)
        unknown = sorted(set(self.instances) - names)
        if unknown:
            raise ValueError(f"instances: {', '.join(unknown)} named by no \"kind as name\" "
                             "entry of blocks")
        return self

    def _instance_params(self, name: str, kind: str) -> Section:
        try:
            return BLOCKS[kind].Params.model_validate(self.instances.get(name, {}))
        except ValidationError as exc:
            error = exc.errors()[0]
            key = ".".join(str(p) for p in error["loc"])
            raise ValueError(f"{name}.{key}: {error['msg']} (got {error.get('input')!r})"
                             ) from None

    def chain(self) -> list[tuple[str, str]]:
        """(instance name, kind) of every block in order."""
        return [chain_entry(entry) for entry in self.blocks]

    def block_params(self, name: str) -> Section:
        """The table of the block named ``name`` (its kind, or a named instance's)."""
        kinds = dict(self.chain())
        if name in kinds and kinds[name] != name:
            return self._instance_params(name, kinds[name])
        return getattr(self, name)


class Pipeline(Section):
    """The fixed tables; the block tables are added from the registry by
    :func:`pipeline_model`."""

    name: str = "pipeline"  # names the run folder (runs/NAME) and the recording
    description: str = ""  # free text, kept in summary.json
    # Modules of the user's own blocks, imported before the pipeline is validated: a .py file
    # (relative to the pipeline file naming it) or an importable module name.
    plugins: list[str] = []
    simulation: Simulation = Simulation()
    plant: Plant = Plant()
    safety: Safety = Safety()
    uncertainty: Uncertainty = Uncertainty()
    # Then a table per registered block, and last ``runs: dict[str, Run]`` (added by
    # pipeline_model, so that a bad top-level key is reported before the runs inheriting it).

    @model_validator(mode="after")
    def _bounded_plant_work(self) -> Pipeline:
        internal = self.plant.parameters.get("rk4_step")
        if self.plant.builtin is not None and internal is not None and internal > 0:
            substeps = self.simulation.step / internal
            if substeps > self.simulation.max_plant_substeps:
                raise ValueError(
                    f"plant.parameters.rk4_step = {internal:g} s makes {substeps:,.0f} RK4 "
                    f"sub-steps per step of {self.simulation.step:g} s, more than "
                    f"simulation.max_plant_substeps = {self.simulation.max_plant_substeps}: "
                    f"use rk4_step ≥ {self.simulation.step / self.simulation.max_plant_substeps:g}"
                    " s, or raise max_plant_substeps if the run is meant to take that long")
        return self

    @model_validator(mode="before")
    @classmethod
    def _merge_runs(cls, data: Any) -> Any:
        """Each run inherits the top-level block tables, then overrides."""
        if not isinstance(data, dict):
            return data
        runs = data.get("runs")
        if runs is not None and not isinstance(runs, dict):
            raise ValueError(f"runs must be a table of runs ([runs.NAME] ...), got {runs!r}")
        if not runs:
            data = {**data, "runs": {"default": {}}}
            runs = data["runs"]
        for name in runs:
            check_name(name, "run name")
        if isinstance(data.get("name"), str):
            check_name(data["name"], "pipeline name")
        merged = {}
        for name, spec in runs.items():
            if not isinstance(spec, dict):
                merged[name] = spec
                continue
            run = dict(spec)
            for section in BLOCKS:
                base = data.get(section, {})
                if isinstance(base, dict) and isinstance(run.get(section, {}), dict):
                    run[section] = {**base, **run.get(section, {})}
            for entry in run.get("blocks") or []:  # a named instance: over its kind's table
                if isinstance(entry, str) and " as " in entry:
                    instance, kind = chain_entry(entry)
                    base = data.get(kind, {})
                    if isinstance(base, dict) and isinstance(run.get(instance, {}), dict):
                        run[instance] = {**base, **run.get(instance, {})}
            merged[name] = run
        return {**data, "runs": merged}


_MODELS: dict[tuple, tuple[type[Pipeline], type[Run]]] = {}


def pipeline_model() -> tuple[type[Pipeline], type[Run]]:
    """The Pipeline and Run models for the blocks registered now (built once per registry
    state): every block's ``Params`` as a table, with its defaults."""
    load_entry_points()  # installed packages' blocks, before the first model is built
    key = tuple((kind, cls) for kind, cls in BLOCKS.items())
    if key not in _MODELS:
        tables = {kind: (cls.Params, cls.Params()) for kind, cls in BLOCKS.items()}
        run = create_model("Run", __base__=Run, **tables)
        pipeline = create_model("Pipeline", __base__=Pipeline, **tables,
                                runs=(dict[str, run], {}))
        _MODELS[key] = pipeline, run
    return _MODELS[key]


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
    if error["type"] == "value_error" and (not loc or loc == ["simulation"]):
        return msg  # a check across keys: the message names them
    return f"key '{key}': {msg}{shown}"


def _allowed_keys(root: type[BaseModel], loc: tuple) -> list[str]:
    """The field names at ``loc`` in the schema (dict keys like run names are skipped)."""
    current: Any = root
    for part in loc:
        if not (isinstance(current, type) and issubclass(current, BaseModel)):
            return []
        field = current.model_fields.get(str(part))
        if field is None:  # a run name inside `runs`
            current = pipeline_model()[1] if issubclass(current, Pipeline) else None
            continue
        annotation = field.annotation
        current = next((a for a in getattr(annotation, "__args__", (annotation,))
                        if isinstance(a, type) and issubclass(a, BaseModel)), None)
        if current is None and str(part) == "runs":
            current = root
    if isinstance(current, type) and issubclass(current, BaseModel):
        return [f.alias or name for name, f in current.model_fields.items()]
    return []


def validate(data: dict, source: str = "pipeline") -> Pipeline:
    model = pipeline_model()[0]
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        # The first problem only: runs inherit the top-level sections, so one bad key
        # would otherwise be reported once more for every run.
        raise PipelineError(f"{source}: {_format(exc.errors()[0], model)}") from None


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
    old = node.get(keys[-1])
    if isinstance(value, dict) and isinstance(old, dict):  # a table merges key by key
        node[keys[-1]] = _merge(old, value)
    else:
        node[keys[-1]] = value
    if keys[:-1] == ["plant"] and keys[-1] in PLANT_SOURCES:  # swap the plant, not add one
        node.pop(PLANT_SOURCES[keys[-1]], None)
    return out


def shadowed(data: dict, assignment: str) -> list[str]:
    """The runs whose own table sets the key a top-level ``--set`` names, so that the
    override does not reach them: one warning each, naming the run."""
    path = assignment.split("=", 1)[0].strip()
    keys = _key_path(path)
    if len(keys) < 2 or keys[0] not in BLOCKS or not isinstance(data.get("runs"), dict):
        return []
    out = []
    for name, run in data["runs"].items():
        node = run
        for key in keys:
            if not isinstance(node, dict) or key not in node:
                break
            node = node[key]
        else:
            out.append(f"--set {path} does not reach run '{name}', whose own "
                       f"{'.'.join(keys)} = {node!r} wins; set runs.{name}.{path} to change it")
    return out


MAX_EXTENDS = 32  # files in an `extends` chain: far more than any real layering needs


def _read_toml(path: Path, chain: tuple[Path, ...] = ()) -> dict:
    """A pipeline file's tables, with ``extends = "other.toml"`` (relative to it) resolved:
    the other file's tables first, this file's merged over them key by key (runs by name).
    Paths in a file (``plant.fmu``) are relative to the file that declares them; a file that
    names a plant (``plant.fmu`` or ``plant.builtin``) replaces the one it extends."""
    where = f" (extended by {chain[-1]})" if chain else ""
    if len(chain) >= MAX_EXTENDS:
        raise PipelineError(f"{path}: the 'extends' chain is more than {MAX_EXTENDS} files "
                            f"deep (from {chain[0]}); flatten it")
    try:
        resolved = path.resolve(strict=False)
        exists = path.is_file()
    except (OSError, RuntimeError):  # a symbolic link loop
        raise PipelineError(f"{path}: cannot be read: a loop of symbolic links{where}") \
            from None
    if not exists:
        if path.is_dir():
            raise PipelineError(f"{path}: is a folder, not a pipeline file{where}")
        raise PipelineError(f"{path}: no such pipeline file{where}")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise PipelineError(f"{path}: not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise PipelineError(f"{path}: not a UTF-8 text file ({exc.reason} at byte "
                            f"{exc.start})") from None
    plugins = data.get("plugins")
    if isinstance(plugins, list):  # a .py file relative to this file; a module name as is
        data["plugins"] = [_relative_to(p, path.parent) if isinstance(p, str) else p
                           for p in plugins]
    plant = data.get("plant")
    if isinstance(plant, dict) and isinstance(plant.get("fmu"), str):
        fmu = Path(plant["fmu"]).expanduser()
        plant["fmu"] = str(fmu if fmu.is_absolute() else (path.parent / fmu).resolve())
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if not isinstance(parent, str):
        raise PipelineError(f"{path}: key 'extends' must be a file name (got {parent!r})")
    parent_path = path.parent / parent
    try:
        parent_resolved = parent_path.resolve(strict=False)
    except (OSError, RuntimeError):
        raise PipelineError(f"{path}: extends {parent!r}, a loop of symbolic links") from None
    if parent_resolved in chain or parent_resolved == resolved:
        raise PipelineError(f"{path}: 'extends' makes a cycle through {parent_path.name}")
    inherited = _read_toml(parent_resolved, (*chain, resolved))
    merged = _merge(inherited, data)
    if isinstance(inherited.get("plugins"), list) and isinstance(plugins, list):
        # both files' plugins, the parent's first
        merged["plugins"] = list(dict.fromkeys([*inherited["plugins"], *data["plugins"]]))
    if isinstance(plant, dict) and isinstance(merged.get("plant"), dict):
        for key, other in PLANT_SOURCES.items():  # this file's plant, not the parent's too
            if key in plant and other not in plant:
                merged["plant"].pop(other, None)
    return merged


def _relative_to(name: str, folder: Path) -> str:
    """A plugin ``.py`` file's path made absolute from ``folder``; a module name as is."""
    if not name.endswith(".py"):
        return name
    path = Path(name).expanduser()
    return str(path if path.is_absolute() else (folder / path).resolve())


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def _print_warning(text: str) -> None:
    print(f"cosim: warning: {text}", file=sys.stderr)


def load_pipeline(path: str | Path | None, overrides: list[str] | None = None,
                  warn=_print_warning) -> Pipeline:
    """Read, override (``--set`` style) and validate a pipeline file; ``None``: the defaults
    (the paper's scenario) with the overrides. ``warn(text)`` is told of overrides that a
    run's own key shadows (None: say nothing)."""
    if path is None:
        data: dict = {}
        source, base = "--set", Path.cwd()  # plant.fmu relative to where the user is
    else:
        path = Path(path)
        data = _read_toml(path)
        source, base = str(path), path.parent
    for assignment in overrides or []:
        data = apply_override(data, assignment)
        for warning in shadowed(data, assignment) if warn else ():
            warn(warning)
    plugins = data.get("plugins")
    if isinstance(plugins, list):  # before validating: they add block tables to the schema
        data["plugins"] = [_relative_to(p, Path.cwd()) if isinstance(p, str) else p
                           for p in plugins]  # from --set: relative to where the user is
        load_plugins(data["plugins"])
    pipeline = validate(data, source)
    if pipeline.plant.fmu is not None:
        fmu = Path(pipeline.plant.fmu).expanduser()
        pipeline.plant.fmu = str(fmu if fmu.is_absolute() else (base / fmu).resolve())
    return pipeline
