"""The JSON job spec: one model per job kind, told apart by `kind`; the same for the browser, scripts and the worker.

Shapes and ranges are checked here (the API answers 422 naming the field); checks that need the database (is the
recording ready, does the calibration belong to its camera, is the frame range inside the recording) live in
`fringelab.core.preparation`. Which kinds there are, and what each names, is `fringelab.core.job_kinds`.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from fringelab.formats import ComparisonExport, ExportFormat

MAX_ID = 2**31 - 1  # ids and frame numbers are 32-bit integers in the database

# Frames per parallel chunk of a job that splits (selftest, topography); empty: the job's own choice.
ChunkFrames = Annotated[
    int | None,
    Field(
        ge=1,
        le=100_000,
        description="Frames per parallel chunk; empty: chunks that shrink towards the end, of at most "
        "FRINGELAB_CHUNK_FRAMES.",
    ),
]


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
    chunk_frames: ChunkFrames = None


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
    accept_bad_calibration: bool = Field(
        False,
        description='Use a calibration whose verdict is "bad" (or a projector calibration built on one) anyway: '
        "the user's explicit consent; the results carry the warning. Without it such a job is refused (422).",
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
        default_factory=FrameRange,  # type: ignore[arg-type]
        description="Frames to write; each is measured against the reference, frame 0 (flat plate).",
    )
    grid_step_mm: float = Field(2.0, ge=0.1, le=50, description="Spacing of the deflection grid, mm.")
    temporal_smoothing_frames: int = Field(0, ge=0, le=50, description="Half-width of the temporal filter; 0: off.")
    chunk_frames: ChunkFrames = None
    accept_bad_calibration: bool = Field(
        False,
        description='Use a calibration whose verdict is "bad" (or a projector calibration built on one) anyway: '
        "the user's explicit consent; the results carry the warning. Without it such a job is refused (422).",
    )
    reference_code_recording_id: int | None = Field(
        None,
        ge=1,
        le=MAX_ID,
        description="A ready recording of kind coded by the same camera: a Gray code recorded with the plate at rest "
        "before the test (its patterns.json beside the frames). It gives the reference frame's stripe order, "
        "checked against the projector table's (docs/procam.md §5); the projector table must come from a "
        "camera–projector calibration. Empty: the table's match alone.",
    )
    rim_circle_mm: tuple[float, float, float] | None = Field(
        None,
        description="X, Y, radius (mm, plate frame) of the clamp circle, when the clamp ring is not in view: the band "
        "inside it that the camera sees anchors every frame's stripe order. Empty: found from the ring.",
    )

    @model_validator(mode="after")
    def _circle(self) -> TopographySpec:
        if self.rim_circle_mm is not None:
            x, y, radius = self.rim_circle_mm
            if not (abs(x) <= 10_000 and abs(y) <= 10_000 and 0 < radius <= 10_000):
                raise ValueError(f"rim_circle_mm: expected X, Y within ±10 000 mm and 0 < radius ≤ 10 000, got "
                                 f"{list(self.rim_circle_mm)}")  # fmt: skip
        return self


class ExportSpec(_Spec):
    """Write a succeeded topography result, or a succeeded comparison with a simulation, in a format for other
    programs (a download when the job succeeds). Each kind of source has its formats."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"kind": "export", "job_id": "6f1c2b8e-2d4a-4f6e-9a51-3c7d0e9b2f10", "format": "grid-npz"}]
        },
    )

    kind: Literal["export"]
    job_id: str = Field(min_length=1, max_length=36, description="A succeeded topography or comparison job.")
    format: (
        Annotated[ExportFormat, Field(title="Topography export")]
        | Annotated[ComparisonExport, Field(title="Comparison export")]
    ) = Field(
        description="Of a topography: points-csv, grid-npz (numpy), mat (MATLAB), vtk (ParaView time series, zipped) "
        "or profile-csv (a section along `line`). Of a comparison: csv (per frame), hdf5 (the comparison file), mat, "
        "vtk or profile-csv (measured, simulated and σ along `line`, the points beyond 2σ marked)."
    )
    line: tuple[float, float, float, float] | None = Field(
        None, description="X0, Y0, X1, Y1 in mm, for profile-csv; empty: along X through the punch axis."
    )
    lines: list[tuple[float, float, float, float]] | None = Field(
        None,
        max_length=26,
        description="Several lines X0, Y0, X1, Y1 in mm for profile-csv (the viewer's section lines), labelled "
        "A, B, … in the file; instead of `line`.",
    )
    frames: FrameRange | None = Field(
        None, description="Only these frames of the result (recording frame numbers); empty: every frame."
    )

    @model_validator(mode="after")
    def _line_for_profiles(self) -> ExportSpec:
        if (self.line is not None or self.lines) and self.format != "profile-csv":
            raise ValueError("line and lines are only used by the profile-csv format")
        if self.line is not None and self.lines:
            raise ValueError("give line or lines, not both")
        return self


class ComparisonSpec(_Spec):
    """Compare a succeeded topography with a simulation of the same experiment (docs: README, "Comparison with a
    simulation"): the model is mapped into the plate frame, each frame paired with a (blended) state, and the
    difference map, σ_w, profiles and curves written to comparison.h5. Empty mapping options are detected; the
    result says what was detected. `format` also writes one export of the comparison as a download."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "kind": "comparison",
                    "job_id": "6f1c2b8e-2d4a-4f6e-9a51-3c7d0e9b2f10",
                    "simulation_id": 1,
                    "align": "displacement",
                }  # fmt: skip
            ]
        },
    )

    kind: Literal["comparison"]
    job_id: str = Field(min_length=1, max_length=36, description="A succeeded topography job.")
    simulation_id: int = Field(ge=1, le=MAX_ID, description="A simulation of the same experiment.")
    align: Literal["displacement", "time", "peak"] = Field(
        "displacement", description="Pair frames with states by punch displacement, by time, or by peak deflection."
    )
    units: Literal["mm", "m"] | None = Field(None, description="The model's length unit; empty: detect.")
    symmetry: Literal["none", "half-x", "half-y", "quarter"] | None = Field(
        None, description="The model's symmetry; empty: detect."
    )
    normal_axis: Literal["x", "y", "z"] | None = Field(None, description="Model axis out of the plate; empty: detect.")
    w_sign: Literal[1, -1] | None = Field(None, description="Sign that makes deflection toward the cameras positive.")
    origin_xy_mm: tuple[float, float] | None = Field(
        None, description="Where the model's origin lies in the plate frame, mm; empty: on the punch axis."
    )
    rotation_deg: float = Field(0.0, ge=-360, le=360, description="Model rotation about Z, degrees.")
    surface: Literal["toward-cameras", "away", "mid"] = Field(
        "toward-cameras", description="The model surface the cameras see."
    )
    shell_thickness_mm: float | None = Field(None, gt=0, le=1000, description="Overrides the file's.")
    punch_node: int | None = Field(None, ge=1, le=MAX_ID, description="Node whose travel is the punch displacement.")
    contact_interface: int | None = Field(None, ge=1, le=MAX_ID, description="rcforc interface of the punch force.")
    time_unit_s: float | None = Field(None, gt=0, le=1e6, description="Seconds per model time unit.")
    time_offset_s: float = Field(0.0, ge=-1e6, le=1e6, description="Added to the model's times before aligning.")
    format: ComparisonExport | None = Field(None, description="Also write this export as a download.")


class IngestSpec(_Spec):
    """Check an uploaded recording (its format, frames and sidecars) and make its previews. Started by the upload
    itself, not through POST /api/v1/jobs; stored as it always was, without a `kind`."""

    recording_id: int = Field(ge=1, le=MAX_ID, description="The recording to check.")


class SimulationCheckSpec(_Spec):
    """Read an uploaded simulation in a worker, within a memory and a time limit, and store what it holds (its
    state becomes ready or failed). Started by the upload itself, not through POST /api/v1/jobs."""

    simulation_id: int = Field(ge=1, le=MAX_ID, description="The simulation to check.")


JobState = Literal["queued", "running", "succeeded", "failed", "cancelled"]


class ProcamCalibrationSpec(_Spec):
    """Calibrate a camera and a digital projector (docs/procam.md §1) from ready recordings of kind `coded`, one
    per chessboard pose, each with an all-white and an all-black frame and Gray codes along projector columns and
    rows, described by patterns-columns.json and patterns-rows.json beside its frames."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"kind": "procam_calibration", "recording_ids": [4, 5, 6, 7, 8, 9],
                          "board": {"cols": 9, "rows": 7, "square_mm": 8.0}}]
        },
    )  # fmt: skip

    kind: Literal["procam_calibration"]
    recording_ids: list[int] = Field(
        min_length=3, max_length=200, description="Ready recordings of kind coded, one per chessboard pose."
    )
    board: BoardSpec = Field(description="The chessboard.")


class ScanSpec(_Spec):
    """3-D points of a ready Gray-code recording (kind `coded`, with its patterns.json) from a camera–projector
    calibration (docs/procam.md §3): points in the camera frame, mm, with σ, a depth map and the decoding's QA."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"kind": "scan", "recording_id": 10, "procam_calibration_id": 3}]},
    )

    kind: Literal["scan"]
    recording_id: int = Field(ge=1, le=MAX_ID, description="A ready recording of kind coded.")
    procam_calibration_id: int = Field(
        ge=1, le=MAX_ID, description="A camera–projector calibration of the same camera and image size."
    )
    projector_scale_x: float = Field(1.0, gt=0, le=16, description="Patterns' projector columns → calibration's.")
    projector_scale_y: float = Field(
        1.0, gt=0, le=16, description="Patterns' projector rows → calibration's (0.5: a diamond-pixel DLP)."
    )
    projector_offset_x_px: float = Field(
        0.0, ge=-100_000, le=100_000, description="Then added to the columns, in the calibration's pixels."
    )
    projector_offset_y_px: float = Field(
        0.0, ge=-100_000, le=100_000, description="Then added to the rows, in the calibration's pixels."
    )
    code_points: bool = Field(True, description="Add a point per decoded pixel without an edge (a band wide).")
