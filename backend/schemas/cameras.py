"""Cameras of an experiment: name, image size and pixel pitch (→ D_u, D_v of the camera model)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, StringConstraints

from backend.schemas.common import UtcDatetime

CameraName = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=100)]
Pixels = Annotated[int, Field(gt=0, le=100_000)]
PitchUm = Annotated[float, Field(gt=0, le=1000, description="Pixel pitch in micrometres.")]


class CameraCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: CameraName
    image_width_px: Pixels
    image_height_px: Pixels
    pixel_pitch_um: PitchUm


class CameraUpdate(BaseModel):
    """Fields to change; those left out keep their value."""

    model_config = ConfigDict(extra="forbid")

    name: CameraName | None = None
    image_width_px: Pixels | None = None
    image_height_px: Pixels | None = None
    pixel_pitch_um: PitchUm | None = None


class CameraOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    experiment_id: int
    name: str
    image_width_px: int
    image_height_px: int
    pixel_pitch_um: float
    created_at: UtcDatetime
