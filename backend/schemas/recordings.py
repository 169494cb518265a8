"""Recordings: an uploaded sequence of one camera, its frames' facts, sidecars, QA and state."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StringConstraints

from backend.schemas.common import PLAIN_NAME, UtcDatetime
from fringelab.core.app_state import AppState
from fringelab.core.models import Recording

RecordingKind = Literal["camera_calibration", "projector_calibration", "test", "coded"]
RecordingState = Literal["uploading", "ingesting", "ready", "invalid"]
SidecarName = Literal["z.csv", "frames.csv", "board.json"]
FileName = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=255), PLAIN_NAME]


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
    fps: float | None = Field(
        description="Frame rate: 1 / the median step of the per-frame times where they exist (time stamps, frame "
        "numbers with the record rate, frames.csv time_s), else the header's."
    )
    fps_header: float | None = Field(
        default=None, description="The rate the file's header states, where it differs from fps by more than 2 %."
    )
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

    model_config = ConfigDict(
        extra="forbid", json_schema_extra={"examples": [{"filename": "plate3-test.cine", "kind": "test"}]}
    )

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


def recording_out(recording: Recording) -> RecordingOut:
    """The API's view of a recording (call inside the session that loaded it)."""
    qa = recording.qa or {}
    return RecordingOut(
        id=recording.id,
        camera_id=recording.camera_id,
        experiment_id=recording.camera.experiment_id,
        kind=recording.kind,  # type: ignore[arg-type]
        state=recording.state,  # type: ignore[arg-type]
        filename=recording.filename,
        format=recording.format,
        size_bytes=recording.size_bytes,
        sha256=recording.sha256,
        frame_count=recording.frame_count,
        width_px=recording.width_px,
        height_px=recording.height_px,
        bit_depth=recording.bit_depth,
        fps=recording.fps,
        fps_header=qa.get("fps_header"),
        sidecars=dict(recording.sidecar or {}),
        warnings=list(qa.get("warnings", [])),
        notes=list(qa.get("notes", [])),
        error=recording.error,
        duplicate_of=recording.duplicate_of,
        ingest_job_id=recording.ingest_job_id,
        upload_id=recording.upload_id,
        created_at=recording.created_at,
    )


def recording_out_by_id(state: AppState, recording_id: int) -> RecordingOut:
    with state.sessions() as session:
        recording = session.get(Recording, recording_id)
        assert recording is not None  # the caller just registered or found it
        return recording_out(recording)
