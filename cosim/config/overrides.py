"""``--set KEY.PATH=VALUE`` overrides of a pipeline's tables, VALUE in TOML syntax."""

from __future__ import annotations

import copy
import tomllib

from ..blocks import BLOCKS
from ..schema import PipelineError
from .sections import PLANT_SOURCES


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
        node[keys[-1]] = merge_tables(old, value)
    else:
        node[keys[-1]] = value
    if keys[:-1] == ["plant"] and keys[-1] in PLANT_SOURCES:  # swap the plant, not add one
        for other in PLANT_SOURCES[keys[-1]]:
            node.pop(other, None)
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


def merge_tables(base: dict, over: dict) -> dict:
    """``over`` merged over ``base`` key by key, tables within tables too (a new dict)."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_tables(out[key], value)
        else:
            out[key] = value
    return out
