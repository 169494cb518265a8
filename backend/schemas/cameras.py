"""Cameras of an experiment: name, image size and pixel pitch (→ D_u, D_v of the camera model)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, StringConstraints, ValidationInfo, field_validator

from backend.schemas.common import PLAIN_NAME, UtcDatetime

CameraName = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=100), PLAIN_NAME]
Pixels = Annotated[int, Field(gt=0, le=100_000)]
PitchUm = Annotated[float, Field(gt=0, le=1000, description="Pixel pitch in micrometres.")]
PITCH_HELP = (
    "Data sheets give the pixel pitch (also 'pixel size' or 'cell size') in µm: one number for square pixels, or "
    "horizontal × vertical, which is u × v here. From the sensor size instead: pitch = sensor width (mm) × 1000 / "
    "image width (px), and the same with the heights for v. D_u = 1000 / pitch_u px/mm."
)


class CameraCreate(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"name": "left", "image_width_px": 1280, "image_height_px": 800, "pixel_pitch_um": 20.0}]
        },
    )

    name: CameraName
    image_width_px: Pixels
    image_height_px: Pixels
    pixel_pitch_um: PitchUm = Field(description=f"Pixel pitch along u (image rows, the width), µm. {PITCH_HELP}")
    pixel_pitch_v_um: PitchUm | None = Field(
        None, description="Pixel pitch along v (image columns, the height), µm; empty: square pixels (as along u)."
    )


class CameraUpdate(BaseModel):
    """Fields to change; those left out keep their value."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{"pixel_pitch_um": 28.0}]})

    name: CameraName | None = None
    image_width_px: Pixels | None = None
    image_height_px: Pixels | None = None
    pixel_pitch_um: PitchUm | None = None
    pixel_pitch_v_um: PitchUm | None = Field(None, description="Pitch along v, µm.")


class CameraOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    experiment_id: int
    name: str
    image_width_px: int
    image_height_px: int
    pixel_pitch_um: float = Field(description="Pixel pitch along u (image rows), µm.")
    pixel_pitch_v_um: float = Field(description="Pixel pitch along v (image columns), µm; as u for square pixels.")
    created_at: UtcDatetime

    @field_validator("pixel_pitch_v_um", mode="before")
    @classmethod
    def _square_unless_given(cls, value: float | None, info: ValidationInfo) -> float:
        return value if value is not None else info.data["pixel_pitch_um"]
