"""The JSON job spec (one model per job kind, told apart by `kind`) and what the jobs API answers.

The browser and scripts send the same spec to `POST /api/v1/jobs`. Shapes and ranges are checked here (FastAPI
answers 422 naming the field); checks that need the database (is the recording ready, does the calibration
belong to its camera, is the frame range inside the recording) live in `backend.jobs.prepare_job`.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

MAX_ID = 2**31 - 1  # ids and frame numbers are 32-bit integers in the database


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid")  # a misspelt parameter is a 422 naming it, not silently ignored


class FrameRange(_Spec):
    """Frames `first` to `last` (inclusive), numbered from 0 as in the recording."""

    first: int = Field(0, ge=0, le=MAX_ID, description="First frame (0-based).")
    last: int | None = Field(
        None, ge=0, le=MAX_ID, description="Last frame, inclusive; empty means the recording's last."
    )

    @model_validator(mode="after")
    def _ordered(self) -> FrameRange:
        if self.last is not None and self.last < self.first:
            raise ValueError(f"last ({self.last}) is before first ({self.first})")
        return self


class SelftestSpec(_Spec):
    """A diagnostic of the job system itself, in the two fan-outs a topography uses: workers compute synthetic
    frames (an FFT of a seeded random image each) into the shared data directory, a pass in frame order checks
    that each came back once and chains them, other workers compute them again and compare, and the result file
    is written. It measures frames/s and names the workers that took part (or that compute differently)."""

    model_config = ConfigDict(
        extra="forbid", json_schema_extra={"examples": [{"kind": "selftest", "frames": 200, "frame_size_px": 256}]}
    )

    kind: Literal["selftest"]
    frames: int = Field(200, ge=1, le=100_000, description="Synthetic frames to compute.")
    frame_size_px: int = Field(256, ge=16, le=4096, description="Side of each square frame; sets the work per frame.")
    chunk_frames: int | None = Field(
        None, ge=1, le=100_000, description="Frames per parallel chunk; empty means FRINGELAB_CHUNK_FRAMES."
    )


class BoardSpec(_Spec):
    """The chessboard, when the recording has no `board.json` (or to override it)."""

    cols: int = Field(ge=2, le=200, description="Inner corners along a row.")
    rows: int = Field(ge=2, le=200, description="Inner corners along a column.")
    square_mm: float = Field(gt=0, le=10_000, description="Side of a square, mm.")
    origin: tuple[int, int] | None = Field(
        None, description="Origin inner corner (i, j) along +X, +Y from the lower left; empty means the centre."
    )


class CameraCalibrationSpec(_Spec):
    """Calibrate a camera (Heikkilä model, docs/method.md §3) from a ready camera-calibration recording: a chessboard
    moved along Z (`zstack`, with z.csv) or free views of it (`poses`). Every frame is used; frames without the
    board are skipped and listed. D_u, D_v come from the camera's pixel pitch."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"kind": "camera_calibration", "recording_id": 1, "mode": "zstack", "scale_on": "u"}]
        },
    )

    kind: Literal["camera_calibration"]
    recording_id: int = Field(ge=1, le=MAX_ID, description="A ready recording of kind camera_calibration.")
    mode: Literal["zstack", "poses"] = Field("zstack", description="zstack (stage Z per frame) or poses (free).")
    board: BoardSpec | None = Field(None, description="Empty means the recording's board.json.")
    scale_on: Literal["u", "v"] = Field("u", description="Axis of the scale factor: u (Heikkilä) or v (the paper).")
    reject_outliers: bool = Field(False, description="Drop frames whose RMS exceeds 3 × the median (and 0.2 px).")
    detector: Literal["auto", "classic"] = Field("auto", description="Chessboard detector.")
    subpix_window_px: int | None = Field(None, ge=1, le=50, description="cornerSubPix half-window; empty: auto.")


class ProjectorCalibrationSpec(_Spec):
    """Build the projector look-up table (docs/method.md §4) from a ready projector-calibration recording: the flat
    plate moved along Z (with z.csv), filmed by the camera of `camera_calibration_id`."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"kind": "projector_calibration", "recording_id": 2, "camera_calibration_id": 1}]
        },
    )

    kind: Literal["projector_calibration"]
    recording_id: int = Field(ge=1, le=MAX_ID, description="A ready recording of kind projector_calibration.")
    camera_calibration_id: int = Field(
        ge=1, le=MAX_ID, description="A camera calibration of the same camera and image size."
    )
    axis: Literal["auto", "rows", "cols"] = Field(
        "auto", description="Scan along image rows (vertical stripes) or columns; auto detects it."
    )
    reference_z_mm: float = Field(0.0, ge=-1000, le=1000, description="Z of the test plate at rest.")
    poly_degree: int = Field(3, ge=1, le=5, description="Degree of Z(t) per edge and scan line.")


class TopographySpec(_Spec):
    """Deflection of every frame of a ready test recording, from a camera and a projector calibration. Edges are
    located in parallel chunks on every worker; identity, Z and X, Y follow in one pass in frame order, so the
    result does not depend on the chunking."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "kind": "topography",
                    "recording_id": 3,
                    "camera_calibration_id": 1,
                    "projector_calibration_id": 2,
                    "frames": {"first": 0, "last": 99},
                    "grid_step_mm": 2.0,
                }
            ]
        },
    )

    kind: Literal["topography"]
    recording_id: int = Field(ge=1, le=MAX_ID, description="A ready recording of kind test.")
    camera_calibration_id: int = Field(
        ge=1, le=MAX_ID, description="A camera calibration of the same camera and image size."
    )
    projector_calibration_id: int = Field(
        ge=1, le=MAX_ID, description="A projector calibration of the same camera and size."
    )
    frames: FrameRange = Field(
        default_factory=FrameRange, description="Frames to write; tracking always starts at frame 0 (flat plate)."
    )
    grid_step_mm: float = Field(2.0, ge=0.1, le=50, description="Spacing of the deflection grid, mm.")
    temporal_smoothing_frames: int = Field(0, ge=0, le=50, description="Half-width of the temporal filter; 0: off.")
    chunk_frames: int | None = Field(
        None, ge=1, le=100_000, description="Frames per parallel chunk; empty means FRINGELAB_CHUNK_FRAMES."
    )


class ExportSpec(_Spec):
    """Write a succeeded topography result in a format for other programs (a download when the job succeeds)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"kind": "export", "job_id": "6f1c2b8e-2d4a-4f6e-9a51-3c7d0e9b2f10", "format": "grid-npz"}]
        },
    )

    kind: Literal["export"]
    job_id: str = Field(min_length=1, max_length=36, description="A succeeded topography job.")
    format: Literal["points-csv", "grid-npz", "mat", "vtk", "profile-csv"] = Field(
        description="points-csv, grid-npz (numpy), mat (MATLAB), vtk (ParaView time series, zipped) or "
        "profile-csv (a section along `line`)."
    )
    line: tuple[float, float, float, float] | None = Field(
        None, description="X0, Y0, X1, Y1 in mm, for profile-csv; empty: along X through the punch axis."
    )

    @model_validator(mode="after")
    def _line_for_profiles(self) -> ExportSpec:
        if self.line is not None and self.format != "profile-csv":
            raise ValueError("line is only used by the profile-csv format")
        return self


JobSpec = Annotated[
    SelftestSpec | CameraCalibrationSpec | ProjectorCalibrationSpec | TopographySpec | ExportSpec,
    Field(discriminator="kind"),
]
JobState = Literal["queued", "running", "succeeded", "failed", "cancelled"]


class Progress(BaseModel):
    stage: str = Field(description="What the job is doing now, for people.")
    done: int
    total: int
    fraction: float | None = Field(description="done / total, or null before the total is known.")
    eta_s: float | None = Field(description="Seconds left in this stage at the rate so far; null when unknown.")


class JobFileOut(BaseModel):
    name: str
    size_bytes: int
    sha256: str
    media_type: str
    url: str


class ChunkOut(BaseModel):
    phase: int = Field(description="0, 1, ...: the fan-outs of the job, each joined by a pass in frame order.")
    index: int
    first_frame: int
    stop_frame: int = Field(description="Exclusive.")
    state: Literal["pending", "running", "done"]
    done: int
    worker: str
    started_at: datetime | None
    finished_at: datetime | None


class JobOut(BaseModel):
    id: str
    kind: str
    state: JobState
    stopping: bool = Field(description="Cancelled, and the worker has not stopped yet.")
    spec: dict[str, Any]
    experiment_id: int | None
    progress: Progress
    error: str = Field(description="Why it failed and what to do; empty unless failed.")
    worker: str
    files: list[JobFileOut]
    result: dict[str, Any]
    provenance: dict[str, Any]
    attempt: int
    retry_of: str | None
    retried_by: str | None
    chunks: list[ChunkOut]
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    duration_s: float | None


class JobList(BaseModel):
    items: list[JobOut]
    total: int


class LogLineOut(BaseModel):
    id: int
    at: datetime
    level: str
    message: str


class ErrorOut(BaseModel):
    detail: str = Field(description="What is wrong and what to do.")
    code: str = Field(description="A stable machine-readable code, e.g. recording_not_ready.")
    field: str | None = Field(None, description="The spec field at fault, dotted (e.g. frames.last).")


class CalibrationOut(BaseModel):
    id: int
    kind: Literal["camera", "projector"]
    camera_id: int
    recording_id: int | None
    job_id: str | None
    version: int = Field(description="1, 2, ... per camera and kind; topography jobs name the id they use.")
    image_width_px: int
    image_height_px: int
    sha256: str
    summary: dict[str, Any]
    created_at: datetime
    file_url: str
    report_url: str
