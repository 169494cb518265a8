"""Recordings: an uploaded sequence of one camera, its frames' facts, sidecars, QA and state."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StringConstraints

from backend.schemas.common import UtcDatetime

RecordingKind = Literal["camera_calibration", "projector_calibration", "test"]
RecordingState = Literal["uploading", "ingesting", "ready", "invalid"]
SidecarName = Literal["z.csv", "frames.csv", "board.json"]
FileName = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=255)]


class QaWarningOut(BaseModel):
    code: str = Field(description="saturated, dark, low_contrast, board_not_found, no_board, missing_z, ...")
    message: str
    frames: list[int] = Field(default_factory=list, description="0-based indices of the frames concerned.")


class RecordingOut(BaseModel):
    """A recording. `warnings` and `notes` come from its ingest; `error` says why it is invalid."""

    model_config = ConfigDict(from_attributes=True)

    id: int
    camera_id: int
    experiment_id: int
    kind: RecordingKind
    state: RecordingState
    filename: str
    format: str = Field(description="zip, tiff, avi, mp4 or cine (empty until known).")
    size_bytes: int
    sha256: str
    frame_count: int
    width_px: int
    height_px: int
    bit_depth: int
    fps: float | None
    sidecars: dict[str, Any] = Field(description="Summary of each sidecar found: z.csv, frames.csv, board.json.")
    warnings: list[QaWarningOut]
    notes: list[str]
    error: str
    duplicate_of: int | None = Field(description="An earlier recording with identical bytes, stored once.")
    ingest_job_id: str | None
    upload_id: str | None
    created_at: UtcDatetime


class RecordingUpdate(BaseModel):
    """Fields to change. A new kind re-runs the ingest (its checks depend on the kind)."""

    model_config = ConfigDict(extra="forbid")

    filename: FileName | None = None
    kind: RecordingKind | None = None


class FrameQa(BaseModel):
    """Per-frame QA, each list of length frame_count (frame i at index i)."""

    mean_fraction: list[float] = Field(description="Mean grey level as a fraction of full scale.")
    saturation_pct: list[float] = Field(description="% of pixels clipped at the sensor's ceiling.")
    contrast: list[float] = Field(description="(p95 − p5) / (p95 + p5) of the grey levels.")
    board_found: list[bool | None] = Field(description="Chessboard found (camera calibration); null: not checked.")


class RecordingQa(BaseModel):
    recording_id: int
    state: RecordingState
    full_scale_dn: int = Field(description="Grey level of a saturated pixel (2^bit_depth − 1).")
    warnings: list[QaWarningOut]
    notes: list[str]
    error: str
    frames: FrameQa
