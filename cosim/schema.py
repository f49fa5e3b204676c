"""The building bricks of pipeline schemas: a strict section base class and the constrained
number types every block's parameters use. SI units, radians."""

from __future__ import annotations

import typing
from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, Strict

# Strict: a number is a TOML integer or float, never true/false or a string ("0.1" in
# quotes, true taken as 1.0 would be a typo run silently).
PositiveFloat = Annotated[float, Strict(), Field(gt=0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Strict(), Field(ge=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Strict(), Field(allow_inf_nan=False)]
# A file's name: never empty (an empty path is the folder it is relative to, not a file)
FileName = Annotated[str, Field(min_length=1)]
Seed = Annotated[int, Field(ge=0)]  # numpy's generators take non-negative seeds only


class PerJoint:
    """A parameter given per joint: ``PerJoint[PositiveFloat]`` takes one value for every
    joint or a list of one each (its length checked against the plant's joints, the key
    named), and a kernel record's :func:`~cosim.blocks.binding.parameter` reads it as an
    (n,) array. ``PerJoint.marker`` inside an ``Annotated`` marks a type of another form
    (a name or a list, say)."""

    marker = "per joint"

    def __class_getitem__(cls, item: object) -> object:
        return Annotated[item | list[item], cls.marker]


class JointList:
    """A parameter given as a list of one value per joint (no one value for all):
    ``JointList[PositiveFloat]``, its length checked as :class:`PerJoint`'s."""

    def __class_getitem__(cls, item: object) -> object:
        return Annotated[list[item], PerJoint.marker]


GainVector = PerJoint[PositiveFloat]  # one value for every joint, or one each


class PipelineError(ValueError):
    """A pipeline that cannot be run; the message names the key or file at fault."""


class Section(BaseModel):
    """A pipeline table: unknown keys are refused, aliases (``lambda``) accepted."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)


def per_joint_array(value: object, n: int) -> np.ndarray:
    """A :class:`PerJoint` value (one for all joints, or a list of one each) as an (n,) float
    array of its own."""
    return np.broadcast_to(np.asarray(value, float), (n,)).copy()


def per_joint_keys(section: type[BaseModel]) -> tuple[str, ...]:
    """The keys (aliases where given) of ``section``'s fields declared :class:`PerJoint`."""

    def marked(annotation: object) -> bool:
        if PerJoint.marker in getattr(annotation, "__metadata__", ()):
            return True
        return any(marked(argument) for argument in typing.get_args(annotation))

    return tuple(field.alias or name for name, field in section.model_fields.items()
                 if PerJoint.marker in field.metadata or marked(field.annotation))
