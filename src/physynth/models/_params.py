"""The base of every model's parameter class: frozen, strict about unknown fields, finite numbers.

Each model module owns the pydantic class of its own parameters (``PathParams`` in
:mod:`physynth.models.path`, ...); :mod:`physynth.scenario` composes them into a scenario.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
Probability = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
Vec3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]


class ParamsModel(BaseModel):
    """Frozen, validated parameters; unknown fields are an error (a typo never passes silently)."""

    model_config = ConfigDict(frozen=True, extra="forbid", strict=False)
