"""`cosim params`: every pipeline key with its default, what values it takes and what it
means, generated from the schema the pipeline is validated with (so always current).

The meaning of a key is its comment in the section's source: the comment after the field
(a linter's ``# noqa`` directive left out), or the comment lines just above it, or its entry
in the section docstring's ``name``: list; for a field built from a table
(``plant.variables``, from the plant's ports), its description. Each names its unit after a
comma or in parentheses: SI, radians, "dimensionless", "mixed units" (the NN weights'), or
what the value is when it has none (a name, a flag, a path); tests/test_params.py holds
the list.
"""

from __future__ import annotations

import inspect
import io
import re
import tokenize
import types
import typing
from dataclasses import dataclass
from functools import cache
from typing import Any

from pydantic import BaseModel

from ..schema import Section

# What a meaning names as its unit, after a comma or in parentheses: an SI unit (angles in
# radians), or, for a value that has none, what it is (tests/test_params.py holds its own
# list, which every key's meaning is checked against).
UNITS = ("s", "1/s", "Hz", "rad", "rad²", "rad/s", "rad/s²", "rad/s³", "(rad/s)²", "m",
         "m/s²", "kg", "kg·m²", "N·m", "N·m/rad", "N·m·s/rad", "1/(N·m)", "√(N·m·rad/s)")
# What a value without an SI unit is, and what a table's unit column says of it then.
NOT_A_UNIT = {"dimensionless": "1", "mixed units": "mixed", "a name": None, "names": None,
              "a flag": None, "a path": None, "paths": None, "free text": None}
_NAMED_UNIT = re.compile(r"(?:, |\()(" + "|".join(
    re.escape(unit) for unit in sorted((*UNITS, *NOT_A_UNIT), key=len, reverse=True))
    + r")(?![\w/·])")


@dataclass(frozen=True)
class Param:
    key: str
    default: Any
    allowed: str
    meaning: str


@cache
def _comments(cls: type) -> dict[str, str]:
    """Field name → its comment in ``cls``'s source (trailing, else the lines above)."""
    try:
        source = inspect.getsource(cls)
    except (OSError, TypeError):
        return {}
    out: dict[str, str] = {}
    above: list[str] = []
    field = re.compile(r"\s+(\w+)\s*:")
    lines = source.splitlines()
    trailing: dict[int, str] = {}
    try:
        for tok in tokenize.generate_tokens(io.StringIO(source).readline):
            if tok.type == tokenize.COMMENT:
                trailing[tok.start[0]] = tok.string
    except (tokenize.TokenError, IndentationError):
        return {}
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if stripped.startswith("#"):
            above.append(stripped.lstrip("#").strip())
            continue
        match = field.match(line)
        if match and not stripped.startswith(("def ", "class ", "@", "return")):
            comment = trailing.get(number, "")
            text = re.sub(r"#\s*noqa\b.*", "", comment).lstrip("#").strip()
            out.setdefault(match.group(1), text or " ".join(above))
        above = []
    doc = inspect.getdoc(cls) or ""
    for name, text in re.findall(r"``(\w+)``: (.+?)(?=\n\s*-|\n\n|\Z)", doc, re.S):
        if not out.get(name):
            out[name] = " ".join(text.split())
    return out


def _meaning(model: type[BaseModel], name: str) -> str:
    for cls in model.__mro__:
        if name in getattr(cls, "__annotations__", {}):
            text = _comments(cls).get(name, "")
            if text:
                return text
    field = model.model_fields.get(name)  # a field built from a table (plant.variables)
    return (field.description or "") if field is not None else ""


def _constraint(item: Any) -> str:
    for attribute, symbol in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤")):
        value = getattr(item, attribute, None)
        if value is not None:
            return f"{symbol} {value:g}"
    if getattr(item, "min_length", None) is not None:
        return f"length ≥ {item.min_length}"
    if getattr(item, "max_length", None) is not None:
        return f"length ≤ {item.max_length}"
    return ""


def allowed(annotation: Any, metadata: list | tuple = ()) -> str:
    """What values an annotation takes, in words: ``number > 0``, ``one of "a", "b"``."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    constraints = []
    for item in metadata:
        constraints.extend(_constraint(m) for m in getattr(item, "metadata", [item]))
    limits = ", ".join(c for c in constraints if c)
    if origin is typing.Annotated:
        return allowed(args[0], args[1:])
    if origin is typing.Literal:
        return "one of " + ", ".join(f'"{a}"' if isinstance(a, str) else str(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        parts = [allowed(a) for a in args if a is not type(None)]
        text = " or ".join(parts)
        return f"{text} or unset" if type(None) in args else text
    if origin is list:
        inner = allowed(args[0]) if args else "values"
        return f"list of {inner}" + (f" ({limits})" if limits else "")
    if origin is dict:
        return "table of " + allowed(args[1]) if len(args) == 2 else "table"
    names = {float: "number", int: "integer", str: "text", bool: "true or false"}
    base = names.get(annotation, getattr(annotation, "__name__", str(annotation)))
    return f"{base} {limits}".strip()


def _section(annotation: Any) -> type[BaseModel] | None:
    """The section class of a field that is a table (or an optional one)."""
    candidates = typing.get_args(annotation) or (annotation,)
    for item in candidates:
        if isinstance(item, type) and issubclass(item, BaseModel):
            return item
    return None


def parameters(model: type[BaseModel], values: BaseModel | None = None,
               prefix: str = "") -> list[Param]:
    """Every key under ``model``: tables are walked into, ``runs`` summarised (a run's
    tables are the top level's, overridden). ``values``: a validated instance whose values
    replace the defaults."""
    out = []
    for name, field in model.model_fields.items():
        key = f"{prefix}{field.alias or name}"
        value = getattr(values, name) if values is not None else None
        if name == "runs":
            out.append(Param(f"{key}.NAME", None, "table per run: blocks = [...] and any "
                             "block table, merged over the top level's",
                             "the runs to compare, each under its own name (default: one run, "
                             "'default'), names"))
            continue
        table = _section(field.annotation)
        if table is not None and typing.get_origin(field.annotation) is dict:
            # tables by name (a system's components): each name's keys, at their defaults
            out.extend(parameters(table, None, f"{key}.NAME."))
            continue
        default = field.get_default(call_default_factory=True)
        if table is not None and issubclass(table, Section) and (default is not None
                                                                 or value is not None):
            out.extend(parameters(table, value if values is not None else default,
                                  f"{key}."))
            continue
        if table is not None:  # an optional table, unset: its keys, at their defaults
            out.append(Param(key, None, f"a table ({', '.join(table.model_fields)}) or unset",
                             _meaning(model, name)))
            continue
        shown = value if values is not None else default
        out.append(Param(key, shown, allowed(field.annotation, field.metadata),
                         _meaning(model, name)))
    return out


def unit_named(meaning: str) -> str | None:
    """The unit a key's meaning names (its first; a later one is an aside: "1/s. A model
    error D (rad/s²) ..."): an SI unit, "1" for a dimensionless number, "mixed" for the NN
    weights'; None for a name, a flag or a path, or where the meaning names none (a
    plugin's key without one)."""
    named = _NAMED_UNIT.search(meaning)
    return NOT_A_UNIT.get(named[1], named[1]) if named else None


def key_units(pipeline: BaseModel, keys: list[str]) -> dict[str, str]:
    """The unit of each of ``keys`` (pipeline keys, a run's as ``runs.NAME.key``) that
    names one, from its meaning in ``pipeline``'s schema."""
    meanings = {p.key: p.meaning for p in parameters(type(pipeline), pipeline)}
    out = {}
    for key in keys:
        parts = key.split(".")
        plain = ".".join(parts[2:]) if parts[0] == "runs" and len(parts) > 2 else key
        unit = unit_named(meanings.get(plain, ""))
        if unit is not None:
            out[key] = unit
    return out


def _defaults() -> tuple[type[BaseModel], dict[str, Any]]:
    from .pipeline import pipeline_model

    model, _ = pipeline_model()
    return model, {p.key: p.default for p in parameters(model, model())}


def describe(pipeline: BaseModel | None = None, grep: str = "") -> str:
    """The keys as text, one per line: ``key = value  [allowed]  # meaning``; with a
    pipeline, its values, and ``*`` where they differ from the defaults. ``grep``: only the
    lines containing it (case-insensitive)."""
    model, defaults = _defaults()
    shown = parameters(model, pipeline if pipeline is not None else model())
    width = min(48, max(len(f"{p.key} = {p.default!r}") for p in shown) + 2)
    lines = []
    for p in shown:
        mark = "*" if pipeline is not None and p.key in defaults and \
            defaults[p.key] != p.default else " "
        value = "" if p.key.endswith(".NAME") else f" = {_toml(p.default)}"
        head = f"{mark} {p.key}{value}"
        line = f"{head.ljust(width)}  [{p.allowed}]" + (f"  # {p.meaning}" if p.meaning
                                                        else "")
        if grep.lower() in line.lower():
            lines.append(line)
    return "\n".join(lines)


def changed(pipeline: BaseModel) -> list[str]:
    """``key = value (default: …)`` for every top-level key the pipeline sets to other than
    its default, and each run's chain and the block keys it overrides."""
    model, defaults = _defaults()
    out = [f"{p.key} = {_toml(p.default)} (default {_toml(defaults[p.key])})"
           for p in parameters(model, pipeline)
           if p.key in defaults and defaults[p.key] != p.default]
    top = {p.key: p.default for p in parameters(model, pipeline)}
    for name, run in getattr(pipeline, "runs", {}).items():
        for p in parameters(type(run), run):
            if p.key == "blocks" or top.get(p.key, p.default) != p.default:
                out.append(f"runs.{name}.{p.key} = {_toml(p.default)}")
    return out


def _toml(value: Any) -> str:
    if value is None:
        return "(unset)"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, BaseModel):
        return "{…}"
    return repr(value)
