"""Reading pipeline files: TOML, with ``extends = "other.toml"`` layering one file over
another, and paths in a file relative to that file."""

from __future__ import annotations

import tomllib
from pathlib import Path

from plant_fmu.named_file import not_a_file

from ..schema import PipelineError
from .overrides import merge_tables
from .sections import PLANT_SOURCES

MAX_EXTENDS = 32  # files in an `extends` chain: far more than any real layering needs


def read_toml(path: Path, chain: tuple[Path, ...] = (), read: list[Path] | None = None
              ) -> dict:
    """A pipeline file's tables, with ``extends = "other.toml"`` (relative to it) resolved:
    the other file's tables first, this file's merged over them key by key (runs by name).
    Paths in a file (``plant.fmu``, ``plant.ssp``, a system's FMUs, the URDFs, a reference's
    CSV, plugins) are relative to the file that declares them; a file that names a plant
    (``plant.fmu``, ``plant.builtin``, ``plant.urdf``, ``plant.ssp`` or ``plant.system``)
    replaces the one it extends. ``read``: each file read is appended to it, this one first."""
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
        why = not_a_file(path)
        raise PipelineError(f"{path}: no such pipeline file{where}" if why == "does not exist"
                            else f"{path}: {why.removesuffix(', not a file')}, not a pipeline "
                            f"file{where}")
    try:
        # utf-8-sig: a byte-order mark (Windows editors add one) is not part of the TOML
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except tomllib.TOMLDecodeError as exc:
        raise PipelineError(f"{path}: not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise PipelineError(f"{path}: not a UTF-8 text file ({exc.reason} at byte "
                            f"{exc.start})") from None
    except OSError as exc:
        raise PipelineError(f"{path}: cannot be read ({exc.strerror or exc}){where}") from None
    if read is not None:
        read.append(path)
    plugins = data.get("plugins")
    if isinstance(plugins, list):  # a .py file relative to this file; a module name as is
        data["plugins"] = [plugin_path(p, path.parent) if isinstance(p, str) else p
                           for p in plugins]
    for table in reference_tables(data):  # reference.csv: relative to this file
        table["csv"] = str(absolute(table["csv"], path.parent))
    for table in urdf_tables(data):  # safety.urdf, inertia_model.urdf: relative to this file
        table["urdf"] = urdf_relative_to(table["urdf"], path.parent)
    plant = data.get("plant")
    for table, key in plant_files(plant):
        table[key] = str(absolute(table[key], path.parent))
    if isinstance(plant, dict) and "urdf" in plant:
        plant["urdf"] = urdf_relative_to(plant["urdf"], path.parent)
    if "robot" in data:  # [robot] file: relative to this file, like plant.urdf
        data["robot"] = urdf_relative_to(data["robot"], path.parent)
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if not isinstance(parent, str) or not parent.strip():
        raise PipelineError(f"{path}: key 'extends' must be a file name (got {parent!r})")
    parent_path = path.parent / parent
    try:
        parent_resolved = parent_path.resolve(strict=False)
    except (OSError, RuntimeError):
        raise PipelineError(f"{path}: extends {parent!r}, a loop of symbolic links") from None
    if parent_resolved in chain or parent_resolved == resolved:
        raise PipelineError(f"{path}: 'extends' makes a cycle through {parent_path.name}")
    inherited = read_toml(parent_resolved, (*chain, resolved), read)
    merged = merge_tables(inherited, data)
    if isinstance(inherited.get("plugins"), list) and isinstance(plugins, list):
        # both files' plugins, the parent's first
        merged["plugins"] = list(dict.fromkeys([*inherited["plugins"], *data["plugins"]]))
    if isinstance(plant, dict) and isinstance(merged.get("plant"), dict):
        for key, others in PLANT_SOURCES.items():  # this file's plant, not the parent's too
            if key in plant:
                for other in others:
                    if other not in plant:
                        merged["plant"].pop(other, None)
    return merged


def plant_files(plant) -> list[tuple[dict, str]]:
    """The (table, key) pairs of a ``[plant]`` table that name a file relative to the
    pipeline file: ``plant.fmu``, ``plant.ssp``, and each ``plant.system`` component's
    ``fmu``."""
    if not isinstance(plant, dict):
        return []
    tables = [(plant, "fmu"), (plant, "ssp")]
    system = plant.get("system")
    components = system.get("components") if isinstance(system, dict) else None
    if isinstance(components, dict):
        tables += [(c, "fmu") for c in components.values() if isinstance(c, dict)]
    return [(table, key) for table, key in tables if isinstance(table.get(key), str)
            and table[key]]  # an empty name is the schema's to refuse, naming its key


def reference_tables(data: dict) -> list[dict]:
    """The ``[reference]`` tables of a pipeline's data (top level and runs) naming a CSV."""
    runs = data.get("runs")
    tables = [data.get("reference"),
              *(run.get("reference") for run in (runs.values() if isinstance(runs, dict)
                                                 else ()) if isinstance(run, dict))]
    return [t for t in tables if isinstance(t, dict) and isinstance(t.get("csv"), str)
            and t["csv"]]  # (an empty name is left for the schema to refuse)


def urdf_tables(data: dict) -> list[dict]:
    """The tables of a pipeline's data that name a URDF file under ``urdf`` besides the
    plant's: ``[safety]`` (its limits) and ``[inertia_model]`` (the nominal model), at the
    top level and in runs."""
    runs = data.get("runs")
    scopes = [data, *(run for run in (runs.values() if isinstance(runs, dict) else ())
                      if isinstance(run, dict))]
    tables = [scope.get(key) for scope in scopes for key in ("safety", "inertia_model")]
    return [t for t in tables if isinstance(t, dict) and isinstance(t.get("urdf"), str)
            and t["urdf"]]


def absolute(name: str, folder: Path) -> Path:
    """A path as given if absolute, else from ``folder`` (``~`` expanded)."""
    path = Path(name).expanduser()
    return path if path.is_absolute() else (folder / path).resolve()


def urdf_relative_to(urdf, folder: Path):
    """A URDF reference (a file, or a table with ``file``) with a relative path made absolute
    from ``folder``; a package:// or file:// address as is; anything else as is (the schema
    says what is wrong with it)."""
    file = urdf.get("file") if isinstance(urdf, dict) else urdf
    if not isinstance(file, str) or "://" in file or not file:
        return urdf
    path = Path(file).expanduser()
    file = str(path if path.is_absolute() else (folder / path).resolve())
    return {**urdf, "file": file} if isinstance(urdf, dict) else file


def plugin_path(name: str, folder: Path) -> str:
    """A plugin ``.py`` file's path made absolute from ``folder``; a module name as is."""
    if not name.endswith(".py"):
        return name
    path = Path(name).expanduser()
    return str(path if path.is_absolute() else (folder / path).resolve())


def key_origin(path: Path, key: str) -> Path | None:
    """The file of ``path``'s ``extends`` chain whose own tables set the dotted ``key``
    (``controller.kvv``, ``runs.a.controller.kv``), the nearest first; None if none does
    (it came from ``--set``, or the chain cannot be read)."""
    seen: set[Path] = set()
    while path not in seen and len(seen) < MAX_EXTENDS:
        seen.add(path)
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8-sig"))
        except (OSError, ValueError):
            return None
        node = data
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                break
            node = node[part]
        else:
            return path
        parent = data.get("extends")
        if not isinstance(parent, str):
            return None
        path = path.parent / parent
    return None
