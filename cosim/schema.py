"""The building bricks of pipeline schemas: a strict section base class and the constrained
number types every block's parameters use. SI units, radians."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, Strict

# Strict: a number is a TOML integer or float, never true/false or a string ("0.1" in
# quotes, true taken as 1.0 would be a typo run silently).
PositiveFloat = Annotated[float, Strict(), Field(gt=0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Strict(), Field(ge=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Strict(), Field(allow_inf_nan=False)]
# A file's name: never empty (an empty path is the folder it is relative to, not a file)
FileName = Annotated[str, Field(min_length=1)]
Seed = Annotated[int, Field(ge=0)]  # numpy's generators take non-negative seeds only
GainVector = PositiveFloat | list[PositiveFloat]  # one value for every joint, or one each


class PipelineError(ValueError):
    """A pipeline that cannot be run; the message names the key or file at fault."""


class Section(BaseModel):
    """A pipeline table: unknown keys are refused, aliases (``lambda``) accepted."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

