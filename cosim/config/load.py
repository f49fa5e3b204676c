"""Loading a pipeline: its file read, the ``--set`` overrides applied, its plugins imported
(they add block tables to the schema), then validated."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

from ..blocks.plugins import load_entry_points, load_plugins
from ..schema import PipelineError
from .files import absolute, key_origin, plugin_path, read_toml, urdf_relative_to
from .overrides import apply_override, shadowed
from .pipeline import Pipeline
from .validation import validate


def _print_warning(text: str) -> None:
    print(f"cosim: warning: {text}", file=sys.stderr)


def load_pipeline(path: str | Path | None, overrides: list[str] | None = None,
                  warn: Callable[[str], None] | None = _print_warning) -> Pipeline:
    """Read, override (``--set`` style) and validate a pipeline file; ``None``: the defaults
    (the paper's scenario) with the overrides. ``warn(text)`` is told of overrides that a
    run's own key shadows (None: say nothing)."""
    load_entry_points()  # installed packages' blocks (the paper's too), before any key is read
    if path is None:
        data: dict = {}
        source, base = "--set", Path.cwd()  # plant.fmu relative to where the user is
    else:
        path = Path(path)
        read: list[Path] = []
        data = read_toml(path, read=read)
        source, base = str(path), path.parent
    for assignment in overrides or []:
        data = apply_override(data, assignment)
        if assignment.split("=", 1)[0].strip().startswith("plant.urdf"):
            data["plant"]["urdf"] = urdf_relative_to(data["plant"]["urdf"], Path.cwd())
        if assignment.split("=", 1)[0].strip() == "plant.ssp" and \
                isinstance(data["plant"].get("ssp"), str):  # from where the user is, as urdf
            data["plant"]["ssp"] = str(absolute(data["plant"]["ssp"], Path.cwd()))
        if assignment.split("=", 1)[0].strip().startswith("robot"):
            data["robot"] = urdf_relative_to(data["robot"], Path.cwd())
        for warning in shadowed(data, assignment) if warn else ():
            warn(warning)
    plugins = data.get("plugins")
    if isinstance(plugins, list):  # before validating: they add block tables to the schema
        data["plugins"] = [plugin_path(p, Path.cwd()) if isinstance(p, str) else p
                           for p in plugins]  # from --set: relative to where the user is
        load_plugins(data["plugins"])
    try:
        pipeline = validate(data, source)
    except PipelineError as exc:
        raise _blamed_on_its_file(exc, path, source, overrides or []) from None
    if path is not None:
        pipeline._source_files = tuple(str(p.absolute()) for p in read)
    if pipeline.plant.fmu is not None:
        pipeline.plant.fmu = str(absolute(pipeline.plant.fmu, base))
    for component in (pipeline.plant.system.components.values()
                      if pipeline.plant.system is not None else ()):
        if component.fmu is not None:
            component.fmu = str(absolute(component.fmu, base))
    for table in [pipeline, *pipeline.runs.values()]:  # a CSV given by --set: from ``base``
        reference = getattr(table, "reference", None)
        if reference is not None and reference.csv is not None:
            reference.csv = str(absolute(reference.csv, base))
    return pipeline


def _sets_within(assignment: str, key: str, tables: set[str], message: str) -> bool:
    """Whether a ``--set`` assignment sets ``key`` (or a table holding it), or a key inside
    one of ``tables`` that ``message`` names."""
    assigned = assignment.split("=", 1)[0].strip()
    inside = any(assigned.startswith(f"{table}.") for table in tables)
    return f".{assigned}." in f".{key}." or (inside and assigned in message)


def _blamed_on_its_file(exc: PipelineError, path: Path | None, source: str,
                        overrides: list[str]) -> PipelineError:
    """A key's error named against where the key was set: the ``--set`` assignment that set
    it last, else the file of the ``extends`` chain that sets it (a typo in a base file is
    not the top file's)."""
    import re

    message = str(exc)
    found = re.match(rf"{re.escape(source)}: (?:unknown key|key) '([^']+)'", message)
    if path is None or not found:
        return exc
    key = found.group(1)
    # the key as the top-level tables name it too (a run's copy: runs.NAME.reference.…)
    tables = {key, re.sub(r"^runs\.[^.]+\.", "", key)}
    # the key, a table of it, or a run's copy of it; or a key inside the table at fault
    # that the message names (reference.waypoints.times set, reference.waypoints refused)
    blamed = [a for a in reversed(overrides) if _sets_within(a, key, tables, message)]
    if blamed:
        return PipelineError(f"--set {blamed[0].strip()}{message[len(source):]}")
    origin = key_origin(path, key)
    if origin is None or origin.resolve() == path.resolve():
        return exc
    return PipelineError(f"{origin} (extended by {source}){message[len(source):]}")
