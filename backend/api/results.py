"""Results: calibrations (versioned per camera) with their reports and files, and topography results cut to
what the dashboard draws (frame list and time histories, a frame's grid within a display budget, profiles,
point histories).

Thin: files are read through `fringelab.formats` (`backend.result_files` for paths and reports); access follows the
experiment (of the calibration's camera, or of the job). Arrays come as JSON lists with null where there is no
data, or, for a grid, as raw float32.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal, get_type_hints

import numpy as np
from fastapi import APIRouter, Query, Request, Response
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field
from sqlalchemy import select

from backend.api.deps import CalibrationDep, CurrentUser, JobDep, SessionDep, StateDep, experiment_for
from backend.cache import AnswerCache, cached_json
from backend.result_files import (
    camera_report,
    listed,
    plain,
    projector_report,
    projector_table,
    result_path,
    topography,
    topography_file,
)
from backend.schemas.common import GridExtentOut
from backend.schemas.jobs import JOB_ERRORS, MAX_ID, RESULT_ERRORS, CalibrationOut, calibration_out
from fringelab.core.accounts import readable_experiments
from fringelab.core.app_state import AppState
from fringelab.core.calibration_pairs import consistent_pairs, warnings_of
from fringelab.core.errors import Gone, Invalid, NotFound
from fringelab.core.jobs import job_error
from fringelab.core.models import Calibration, Camera, Experiment, Job
from fringelab.formats.topography import (
    GRID_BUDGET_NODES,
    MISSING_REASONS,
    OutsideGrid,
    ResultUnavailable,
    TopographyResult,
)
from fringelab.science.coverage import MISSING_DESCRIPTIONS, MISSING_LABELS
from fringelab.science.verdict import VerdictCheck

router = APIRouter(tags=["results"])
MM = Annotated[float, Query(allow_inf_nan=False, description="mm, in the object frame")]
OptionalMM = Annotated[float | None, Query(allow_inf_nan=False, description="mm, in the object frame (required)")]
DeprecatedMM = Annotated[
    float | None, Query(allow_inf_nan=False, deprecated=True, description="old name: use the `_mm` parameter")
]


def _line_mm(named: tuple[float | None, ...], old: tuple[float | None, ...]) -> tuple[float, float, float, float]:
    """The line from x0_mm, y0_mm, x1_mm, y1_mm, or from the deprecated x0, y0, x1, y1 (not a mix)."""
    for values in (named, old):
        if all(v is not None for v in values):
            x0, y0, x1, y1 = (float(v) for v in values)  # type: ignore[arg-type]
            return x0, y0, x1, y1
    missing = [n for n, v in zip(("x0_mm", "y0_mm", "x1_mm", "y1_mm"), named, strict=True) if v is None]
    raise Invalid(f"the line needs x0_mm, y0_mm, x1_mm and y1_mm (missing: {', '.join(missing)})", code="invalid_line")


@router.get("/calibrations", response_model=list[CalibrationOut])
def list_calibrations(
    session: SessionDep,
    principal: CurrentUser,
    camera_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    kind: Literal["camera", "projector"] | None = None,
) -> list[CalibrationOut]:
    """Calibrations, newest version first (per camera and kind)."""
    query = (
        select(Calibration)
        .join(Camera, Camera.id == Calibration.camera_id)
        .where(Camera.experiment_id.in_(select(Experiment.id).where(readable_experiments(session, principal))))
    )
    if camera_id is not None:
        query = query.where(Calibration.camera_id == camera_id)
    if kind is not None:
        query = query.where(Calibration.kind == kind)
    rows = session.scalars(query.order_by(Calibration.camera_id, Calibration.kind, Calibration.version.desc()))
    return [calibration_out(row, session) for row in rows]


class CalibrationPairOut(BaseModel):
    camera_calibration: CalibrationOut
    projector_calibration: CalibrationOut
    bad: bool = Field(description="Either is bad: a topography job with this pair needs accept_bad_calibration.")


@router.get("/calibrations/pairs", response_model=list[CalibrationPairOut])
def list_calibration_pairs(
    session: SessionDep, principal: CurrentUser, camera_id: Annotated[int, Query(ge=1, le=MAX_ID)]
) -> list[CalibrationPairOut]:
    """The consistent pairs of a camera: each projector calibration with the camera calibration it was built on
    (the only pairs a topography job accepts), newest first."""
    camera = session.get(Camera, camera_id)
    if camera is None:
        return []  # a list, like /calibrations?camera_id=: what the caller may not see is simply not in it
    try:
        experiment_for(session, principal, camera.experiment_id)
    except NotFound:
        return []
    pairs = []
    for base, projector in consistent_pairs(session, camera_id):
        base_out, projector_out = calibration_out(base, session), calibration_out(projector, session)
        pairs.append(CalibrationPairOut(camera_calibration=base_out, projector_calibration=projector_out,
                                        bad=base_out.bad or projector_out.bad))  # fmt: skip
    return pairs


@router.get("/calibrations/{calibration_id}", response_model=CalibrationOut, responses=JOB_ERRORS)
def read_calibration(calibration: CalibrationDep, session: SessionDep) -> CalibrationOut:
    return calibration_out(calibration, session)


class CalibrationReport(BaseModel):
    calibration: CalibrationOut
    report: dict[str, Any]


@router.get("/calibrations/{calibration_id}/report", response_model=CalibrationReport, responses=RESULT_ERRORS)
def calibration_report(calibration: CalibrationDep, state: StateDep, session: SessionDep) -> CalibrationReport:
    """A camera calibration's report: parameters ± standard errors, per-frame RMS, residual vectors over the
    image, the residual map and the verdict (the fields of `camera.json`, units in every name)."""
    if calibration.kind != "camera":
        raise job_error(NotFound, "no_report", f"calibration {calibration.id} is a {calibration.kind} calibration")
    try:
        report = camera_report(state.settings.data_path, calibration.path)
    except ResultUnavailable as error:
        raise job_error(Gone, "result_missing", str(error)) from None
    return CalibrationReport(calibration=calibration_out(calibration, session), report=report)


# One check of a verdict: the fields of `fringelab.science.verdict.VerdictCheck`, read from it (a value that was
# not measured, NaN there, is null here). No docstring: it would become the schema's description.
class VerdictCheckOut(BaseModel):
    __annotations__ = {**get_type_hints(VerdictCheck), "value": float | None}
    value = Field(description="null: not measured")


class VerdictOut(BaseModel):
    level: str = Field(description="good, check or bad: the worst of the checks.")
    reasons: list[str]
    checks: list[VerdictCheckOut]


class ProjectorReport(BaseModel):
    calibration: CalibrationOut
    image_size_px: dict[str, int]
    verdict: VerdictOut
    limits: dict[str, dict[str, float]] = Field(description="Each rule's good and bad thresholds.")
    qa: dict[str, Any]
    cell_px: int = Field(description="Side of the square image cells of the maps, px.")
    cells_u: int
    cells_v: int
    sensitivity_px_per_mm: list[list[float | None]] = Field(
        description="(cells_v, cells_u) median |dt/dZ| of the table's entries in each cell; null: no entry."
    )
    z_resolution_mm: list[list[float | None]] = Field(
        description="(cells_v, cells_u) the Z step the measured edge noise amounts to: edge_noise_px / sensitivity."
    )
    coverage: list[list[float | None]] = Field(
        description="(cells_v, cells_u) share of the edges seen there on the flat plate that have a table entry."
    )
    z_mm: list[float | None] = Field(description="The calibration heights.")
    coverage_z: list[float | None] = Field(description="Share of the entries whose fitted Z range holds each height.")


@router.get("/calibrations/{calibration_id}/projector-report", response_model=ProjectorReport, responses=RESULT_ERRORS)
def projector_calibration_report(
    calibration: CalibrationDep,
    state: StateDep,
    session: SessionDep,
    cell_px: Annotated[int, Query(ge=4, le=256, description="Side of the maps' image cells, px.")] = 16,
) -> ProjectorReport:
    """A projector calibration's report, on a par with the camera's: the verdict with each rule's value,
    thresholds and meaning, and maps over the whole image of the sensitivity (px per mm of Z), the Z resolution
    it gives at the measured edge noise, and the table's coverage over the image and over Z."""
    if calibration.kind != "projector":
        raise job_error(NotFound, "no_report", f"calibration {calibration.id} is a {calibration.kind} calibration")
    try:
        report = projector_report(state.settings.data_path, calibration.path, cell_px=cell_px)
    except ResultUnavailable as error:
        raise job_error(Gone, "result_missing", str(error)) from None
    for name in ("sensitivity_px_per_mm", "z_resolution_mm", "coverage"):
        report[name] = listed(report[name])
    report["z_mm"] = listed(report["z_mm"])
    report["coverage_z"] = listed(report["coverage_z"])
    for check in report["verdict"]["checks"]:
        check["value"] = check["value"] if math.isfinite(check["value"]) else None
    return ProjectorReport(calibration=calibration_out(calibration, session), **report)


class ProjectorTable(BaseModel):
    calibration: CalibrationOut
    axis: str
    period_px: float | None
    reference_z_mm: float | None
    n_edges: int
    n_lines: int
    line: int
    z_mm: list[float | None]
    curves: list[dict[str, Any]] = Field(description="[{edge, polarity, t_px: [...] per z_mm, null: not seen}]")
    qa: dict[str, Any]


@router.get("/calibrations/{calibration_id}/table", response_model=ProjectorTable, responses=RESULT_ERRORS)
def projector_table_curves(
    calibration: CalibrationDep,
    state: StateDep,
    session: SessionDep,
    line: Annotated[int | None, Query(ge=0, le=MAX_ID, description="Scan line; empty: the middle one.")] = None,
    edges: Annotated[
        list[Annotated[int, Field(ge=0, le=MAX_ID)]] | None, Query(description="Edge indices; empty: all.")
    ] = None,
) -> ProjectorTable:
    """The curves of a projector calibration's look-up table: the position of each stripe edge along one scan
    line against the plate's Z (docs/method.md §4), with the table's QA."""
    if calibration.kind != "projector":
        raise job_error(NotFound, "no_table", f"calibration {calibration.id} is a {calibration.kind} calibration")
    try:
        table = projector_table(state.settings.data_path, calibration.path, line=line, edges=edges)
    except OutsideGrid as error:
        raise job_error(Invalid, "outside_table", str(error)) from None
    except ResultUnavailable as error:
        raise job_error(Gone, "result_missing", str(error)) from None
    table["z_mm"] = listed(table["z_mm"])
    for curve in table["curves"]:
        curve["t_px"] = listed(curve["t_px"])
    return ProjectorTable(calibration=calibration_out(calibration, session), **table)


@router.get(
    "/calibrations/{calibration_id}/file",
    response_class=FileResponse,
    responses={
        **RESULT_ERRORS,
        200: {
            "description": "camera.json (application/json) or projector.h5 (application/x-hdf5)",
            "content": {
                "application/json": {"schema": {"type": "object"}},
                "application/x-hdf5": {"schema": {"type": "string", "format": "binary"}},
            },
        },
    },
)
def calibration_file(calibration: CalibrationDep, state: StateDep) -> FileResponse:
    """The calibration file itself (camera.json or projector.h5), streamed."""
    try:
        path = result_path(state.settings.data_path, calibration.path)
    except ResultUnavailable as error:
        raise job_error(Gone, "result_missing", str(error)) from None
    media_type = "application/json" if path.suffix == ".json" else "application/x-hdf5"
    return FileResponse(path, media_type=media_type, filename=f"calibration-{calibration.id}-{path.name}")


# ---------------------------------------------------------------------------------------------- topography

# Rendered grids, overviews and profiles of results (immutable once their job succeeded), shared by the viewers.
ANSWERS = AnswerCache(max_bytes=16 * 2**20)


class TopographyOverview(BaseModel):
    job_id: str
    frames: list[int]
    time_s: list[float | None]
    punch_displacement_mm: list[float | None]
    force_kN: list[float | None]
    peak_w_mm: list[float | None]
    peak_x_mm: list[float | None]
    peak_y_mm: list[float | None]
    grid: dict[str, float | int]
    summary: dict[str, Any]
    measured_fraction: list[float | None] = Field(
        description="Per frame: measured area / area of the plate the reference frame sees (null: not recorded)."
    )
    missing_mm2: dict[str, list[float | None]] = Field(
        description="Per reason (hole, shadow, low_contrast, order_unresolved, order_conflict, out_of_range), the "
        "area not measured in each frame, mm²."
    )
    missing_reasons: dict[str, dict[str, str]] = Field(
        description="Per reason of `missing_mm2`: its `label` (a few words, for a legend) and `description`."
    )
    n_order_conflicts: list[float | None] = Field(description="Per frame: conflicts between the order's sources.")
    n_temporal_jumps: list[float | None] = Field(
        description="Per frame: points whose change of height from the frame before departs from their neighbouring "
        "edges' by more than 3/4 of a stripe step (a cross-check of the order; null: not checked)."
    )
    peak_measured: list[bool | None] = Field(
        description="Per frame: whether the peak was measured, i.e. the surface around the maximum on all sides "
        "over the punch radius (docs/method.md §8); false: `peak_w_mm` is null and `peak_w_lower_bound_mm` holds "
        "the largest measured w, a lower bound; null: unknown (a result written before the flag)."
    )
    peak_w_lower_bound_mm: list[float | None] = Field(
        description="Per frame: where the peak was not measured, the largest measured w (the peak is at least "
        "this); null elsewhere."
    )
    peak_reason: list[str | None] = Field(description="Per frame: why the peak is not measured (null: it is).")
    warnings: list[str] = Field(
        default_factory=list, description="What the result must be read with (a bad calibration used by consent)."
    )
    log_columns: list[str] = Field(
        default_factory=list,
        description="Which of time_s, punch_displacement_mm, force_kN the test log gives for any frame: plots and "
        "their titles show only these (empty: no frames.csv and no time stamps).",
    )
    notes: list[str] = Field(default_factory=list, description="What the frames lack, for people (no frames.csv).")


@router.get("/jobs/{job_id}/topography", response_model=TopographyOverview, responses=RESULT_ERRORS)
def topography_overview(job: JobDep, state: StateDep, request: Request) -> TopographyOverview:
    """The frames of a topography result with the test log and the peak deflection of each (for the frame
    slider and the plots of peak deflection against time, punch displacement and force), the grid's extent and
    the result's summary."""

    def render() -> bytes:
        return _overview(job, state).model_dump_json().encode()

    path = topography_file(job, state.settings.data_path)
    return cached_json(ANSWERS, request.headers, path, ("overview",), render)  # type: ignore[return-value]


def _overview(job: Job, state: AppState) -> TopographyOverview:
    with topography(job, state.settings.data_path, frames=state.frames) as reader:
        coverage = reader.coverage()
        peaks, verdicts = reader.column("peak/w_mm"), reader.peak_measurements()
        not_measured = np.array([v is not None and not v.measured for v in verdicts], bool)
        return TopographyOverview(
            job_id=job.id,
            frames=reader.frames.astype(int).tolist(),
            time_s=listed(reader.column("frames/time_s"), 6),
            punch_displacement_mm=listed(reader.column("frames/punch_displacement_mm")),
            force_kN=listed(reader.column("frames/force_kN")),
            peak_w_mm=listed(np.where(not_measured, np.nan, peaks)),
            peak_x_mm=listed(reader.column("peak/x_mm")),
            peak_y_mm=listed(reader.column("peak/y_mm")),
            grid=GridExtentOut.of(reader.grid).model_dump(),
            summary={key: plain(value) for key, value in reader.summary().items()},
            measured_fraction=listed(coverage["measured_fraction"]),
            missing_mm2={name: listed(coverage[f"missing_{name}_mm2"], 1) for name in MISSING_REASONS},
            missing_reasons={
                name: {"label": MISSING_LABELS[name], "description": MISSING_DESCRIPTIONS[name]}
                for name in MISSING_REASONS
            },
            n_order_conflicts=listed(coverage["n_order_conflicts"], 0),
            n_temporal_jumps=listed(coverage["n_temporal_jumps"], 0),
            peak_measured=[None if v is None else v.measured for v in verdicts],
            peak_w_lower_bound_mm=listed(np.where(not_measured, peaks, np.nan)),
            peak_reason=[v.reason if v is not None and not v.measured else None for v in verdicts],
            warnings=warnings_of(job.provenance),
            **_log_of(reader),
        )


def _log_of(reader: TopographyResult) -> dict[str, list[str]]:
    """The test log's columns that have any value, and a note for what is missing (nothing silent)."""
    columns = [name for name in ("time_s", "punch_displacement_mm", "force_kN")
               if np.any(np.isfinite(reader.column(f"frames/{name}")))]  # fmt: skip
    notes = []
    missing = [label for name, label in (("punch_displacement_mm", "punch displacement"), ("force_kN", "force"))
               if name not in columns]  # fmt: skip
    if missing:
        why = (
            "its frames.csv has no such column"
            if reader.time_source == "frames.csv"
            else "the recording has no frames.csv with those columns"
        )
        notes.append(f"no {' or '.join(missing)} for any frame: {why}")
    if "time_s" not in columns:
        notes.append("no time for any frame: plots are against the frame number")
    return {"log_columns": columns, "notes": notes}


class GridOut(BaseModel):
    frame: int
    step: int = Field(description="Grid nodes per returned node along each axis (1: full resolution).")
    x_mm: list[float]
    y_mm: list[float]
    w_mm: list[list[float | None]] = Field(description="Deflection [iy][ix], mm; null where there is no data.")


@router.get(
    "/jobs/{job_id}/topography/grid",
    response_model=GridOut,
    responses={
        **RESULT_ERRORS,
        200: {
            "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}},
            "description": "JSON, or float32",
        },
    },
)
def topography_grid(
    job: JobDep,
    state: StateDep,
    request: Request,
    frame: Annotated[int, Query(ge=0, le=MAX_ID, description="Recording frame index.")],
    budget: Annotated[int, Query(ge=8, le=2000, description="Largest number of nodes per side.")] = GRID_BUDGET_NODES,
    x_min: Annotated[float | None, Query(allow_inf_nan=False)] = None,
    x_max: Annotated[float | None, Query(allow_inf_nan=False)] = None,
    y_min: Annotated[float | None, Query(allow_inf_nan=False)] = None,
    y_max: Annotated[float | None, Query(allow_inf_nan=False)] = None,
    format: Literal["json", "f32"] = "json",
) -> Any:
    """The deflection w of one frame on the grid, block-averaged to at most `budget` nodes per side; give all of
    x_min, x_max, y_min, y_max (mm) for a zoom window, at full resolution when it fits the budget. format=f32
    answers the float32 array itself (row-major [iy][ix], little-endian, NaN where no data), its shape and
    coordinates in the headers X-Grid-Shape (ny,nx), X-Grid-X-mm and X-Grid-Y-mm (first,step)."""
    bounds = (x_min, x_max, y_min, y_max)
    if any(b is None for b in bounds) and not all(b is None for b in bounds):
        raise job_error(Invalid, "incomplete_window", "give all of x_min, x_max, y_min, y_max, or none", field="x_min")
    window = None if x_min is None else tuple(float(b) for b in bounds)  # type: ignore[arg-type]
    if format == "json":

        def render() -> bytes:
            with topography(job, state.settings.data_path, frames=state.frames) as reader:
                cut = reader.grid_cut(frame, budget=budget, window_mm=window)  # type: ignore[arg-type]
            grid = GridOut(frame=cut.frame, step=cut.step, x_mm=listed(cut.x_mm), y_mm=listed(cut.y_mm),
                           w_mm=listed(cut.w_mm))  # fmt: skip
            return grid.model_dump_json().encode()

        key = ("grid", frame, budget, window)
        path = topography_file(job, state.settings.data_path)
        return cached_json(ANSWERS, request.headers, path, key, render)
    with topography(job, state.settings.data_path, frames=state.frames) as reader:
        cut = reader.grid_cut(frame, budget=budget, window_mm=window)  # type: ignore[arg-type]
    if format == "f32":

        def first_step(axis: np.ndarray) -> str:
            return f"{axis[0]:.6g},{(axis[1] - axis[0]) if axis.size > 1 else 0:.6g}"

        return Response(
            content=np.ascontiguousarray(cut.w_mm, dtype="<f4").tobytes(),
            media_type="application/octet-stream",
            headers={
                "X-Grid-Shape": f"{cut.w_mm.shape[0]},{cut.w_mm.shape[1]}",
                "X-Grid-X-mm": first_step(cut.x_mm),
                "X-Grid-Y-mm": first_step(cut.y_mm),
                "X-Grid-Step": str(cut.step),
            },  # fmt: skip
        )
    return GridOut(frame=cut.frame, step=cut.step, x_mm=listed(cut.x_mm), y_mm=listed(cut.y_mm), w_mm=listed(cut.w_mm))


class ProfileOut(BaseModel):
    s_mm: list[float]
    x_mm: list[float]
    y_mm: list[float]
    profiles: list[dict[str, Any]] = Field(
        description="[{frame, w_mm: [...], sigma_w_mm: [...] | null}] in the order asked; sigma_w_mm is σ of w "
        "(mm, null where unknown; null for the whole profile in a result written before σ was stored)."
    )


@router.get("/jobs/{job_id}/topography/profile", response_model=ProfileOut, responses=RESULT_ERRORS)
def topography_profile(
    job: JobDep,
    state: StateDep,
    request: Request,
    frames: Annotated[
        list[Annotated[int, Field(ge=0, le=MAX_ID)]],
        Query(min_length=1, max_length=50, description="Recording frame indices."),
    ],
    n_points: Annotated[int, Query(ge=2, le=5000)] = 200,
    x0_mm: OptionalMM = None,
    y0_mm: OptionalMM = None,
    x1_mm: OptionalMM = None,
    y1_mm: OptionalMM = None,
    x0: DeprecatedMM = None,
    y0: DeprecatedMM = None,
    x1: DeprecatedMM = None,
    y1: DeprecatedMM = None,
) -> ProfileOut:
    """Deflection profiles w(s) along the segment (x0_mm, y0_mm) → (x1_mm, y1_mm), for the frames asked.

    Points and lines take the same style everywhere: `x_mm, y_mm` for a point (history), `x0_mm, y0_mm, x1_mm,
    y1_mm` for a line. The old names `x0, y0, x1, y1` still work and are deprecated."""
    line = _line_mm((x0_mm, y0_mm, x1_mm, y1_mm), (x0, y0, x1, y1))

    def render() -> bytes:
        with topography(job, state.settings.data_path, frames=state.frames) as reader:
            cut = reader.profile(frames, line, n_points=n_points)
        return (
            ProfileOut(
                s_mm=listed(cut["s_mm"]),
                x_mm=listed(cut["x_mm"]),
                y_mm=listed(cut["y_mm"]),
                profiles=[
                    {
                        "frame": p["frame"],
                        "w_mm": listed(p["w_mm"]),
                        "sigma_w_mm": None if p["sigma_w_mm"] is None else listed(p["sigma_w_mm"]),
                    }
                    for p in cut["profiles"]
                ],  # fmt: skip
            )
            .model_dump_json()
            .encode()
        )

    key = ("profile", tuple(frames), *line, n_points)
    path = topography_file(job, state.settings.data_path)
    return cached_json(ANSWERS, request.headers, path, key, render)  # type: ignore[return-value]


class HistoryOut(BaseModel):
    x_mm: float
    y_mm: float
    frames: list[int]
    time_s: list[float | None]
    w_mm: list[float | None]
    sigma_w_mm: list[float | None] | None = Field(
        None, description="σ of w per frame (mm; null where unknown; null in a result written before σ was stored)."
    )


@router.get("/jobs/{job_id}/topography/history", response_model=HistoryOut, responses=RESULT_ERRORS)
def topography_history(job: JobDep, state: StateDep, x_mm: MM, y_mm: MM) -> HistoryOut:
    """The deflection w(t) at one point of the plate over every frame of the result."""
    with topography(job, state.settings.data_path, frames=state.frames) as reader:
        return HistoryOut(
            x_mm=x_mm,
            y_mm=y_mm,
            frames=reader.frames.astype(int).tolist(),
            time_s=listed(reader.column("frames/time_s"), 6),
            w_mm=listed(reader.history(x_mm, y_mm)),
            sigma_w_mm=None if (sigma := reader.sigma_history(x_mm, y_mm)) is None else listed(sigma),
        )
