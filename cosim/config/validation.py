"""Validating a pipeline's tables, with pydantic: an unknown key, a wrong type or an
out-of-range value ends with one :class:`PipelineError` naming the key and what is allowed."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ValidationError

from ..schema import PipelineError
from .pipeline import Pipeline, pipeline_model


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
        plugins = data.get("plugins") if isinstance(data.get("plugins"), list) else []
        return model.model_validate(data, context={"plugins": [
            p for p in plugins if isinstance(p, str)]})
    except ValidationError as exc:
        # The first problem only: runs inherit the top-level sections, so one bad key
        # would otherwise be reported once more for every run.
        raise PipelineError(f"{source}: {_format(_first(exc.errors()), model)}") from None


def _first(errors: list[dict]) -> dict:
    """The error to report: the first, or, where a list was given to a key that takes a
    number or a list (a union), what is wrong inside the list (not "should be a number")."""
    first = errors[0]
    if not isinstance(first.get("input"), list):
        return first
    inside = [e for e in errors if len(e["loc"]) > len(first["loc"])
              and e["loc"][:len(first["loc"]) - 1] == first["loc"][:-1]
              and str(e["loc"][len(first["loc"]) - 1]).startswith("list[")]
    return inside[0] if inside else first
