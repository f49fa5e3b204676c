"""The files a pipeline names, and their content: the pipeline file and those it extends, the
plugins it imports, the plant's FMU or URDF (and the URDF's meshes), the nominal model's and
the safe sets' URDFs, and each run's reference CSV.

A pipeline names them by path, and a path says nothing of what the file held when a run or
a sweep read it: a reference CSV edited between a sweep and its ``--resume`` would mix two
experiments in one table under the same keys. So each is hashed (SHA-256): a run folder's
summary.json keeps the digests in its provenance (``files``), a sweep's sweep.json among
what makes it that sweep, and ``--resume`` refuses one whose file changed, by its key and
path. Each must be a regular file (:func:`plant_fmu.named_file.sha256`: read without ever
blocking on a pipe or a device).
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

from plant_fmu.named_file import NotAFile, not_a_file, sha256

from ..schema import PipelineError
from .pipeline import Pipeline


def named_files(pipeline: Pipeline) -> dict[str, str]:
    """{absolute path: the key that names it} for every file ``pipeline`` names (the first
    key naming a path: the top level's before a run's)."""
    from plant_fmu.urdf import resolve_uri

    named: dict[str, str] = {}

    def add(path: Path | str, key: str) -> None:
        named.setdefault(str(Path(path).absolute()), key)

    for index, path in enumerate(pipeline.source_files):
        add(path, "the pipeline file" if index == 0 else "extends")
    for plugin in pipeline.plugins:
        origin = plugin if plugin.endswith(".py") else _module_file(plugin)
        if origin is not None:
            add(origin, "plugins")
    if pipeline.plant.fmu is not None:
        add(pipeline.plant.fmu, "plant.fmu")
    if pipeline.plant.urdf is not None:
        urdf = resolve_uri(pipeline.plant.urdf.file, Path.cwd())
        add(urdf, "plant.urdf")
        if not_a_file(urdf) is None:  # else file_digests says what it is
            stat = urdf.stat()
            for mesh in _meshes(str(urdf), stat.st_mtime_ns, stat.st_size):
                add(mesh, "a <mesh> of plant.urdf")
    scopes = [("", pipeline), *((f"runs.{name}.", run) for name, run in pipeline.runs.items())]
    for prefix, scope in scopes:
        for table, key in (("reference", "csv"), ("inertia_model", "urdf"), ("safety", "urdf")):
            value = getattr(getattr(scope, table, None), key, None)
            if isinstance(value, str):
                path = resolve_uri(value, Path.cwd()) if key == "urdf" else Path(value)
                add(path, f"{prefix}{table}.{key}")
    return named


@functools.lru_cache(maxsize=16)
def _meshes(urdf: str, mtime_ns: int, size: int) -> tuple[str, ...]:
    """The meshes the URDF names, read once per version of the file (a sweep's points
    mostly share one)."""
    from plant_fmu.urdf import UrdfError, mesh_files

    try:
        return tuple(map(str, mesh_files(Path(urdf))))
    except UrdfError as exc:  # read already, so only if it changed since
        raise PipelineError(f"plant.urdf: {exc}") from None


def _module_file(name: str) -> str | None:
    """The file an importable plugin module is read from (None: not a file)."""
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    origin = spec.origin if spec is not None else None
    return origin if origin and Path(origin).is_file() else None


def file_digests(named: dict[str, str]) -> list[dict]:
    """Each named file's key, path, SHA-256 and size in bytes, by path: a
    :class:`PipelineError` naming the key if one is not a regular file (any more)."""
    out = []
    for path, key in sorted(named.items()):
        try:
            digest, size = sha256(path)
        except NotAFile as exc:
            raise PipelineError(f"{key}: {exc}") from None
        out.append({"key": key, "path": path, "sha256": digest, "bytes": size})
    return out


def changed_files(before: list[dict], now: list[dict]) -> list[str]:
    """The files of ``before`` whose content ``now`` differs, each as ``key path
    (sha256 old… → new…)``; files named in only one of them are left to the keys that name
    them to tell."""
    current = {entry["path"]: entry for entry in now}
    out = []
    for entry in before:
        later = current.get(entry.get("path"))
        if later is not None and later["sha256"] != entry.get("sha256"):
            out.append(f"{later['key']} {later['path']} (its content changed: sha256 "
                       f"{str(entry.get('sha256'))[:12]}… then, {later['sha256'][:12]}… "
                       "now)")
    return out
