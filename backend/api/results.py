"""Results: calibrations (versioned per camera) with their reports and files; later topography results.

Thin: files are read through `backend.results`; access follows the experiment of the calibration's camera.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends
from fastapi.responses import FileResponse
from pydantic import BaseModel
from sqlalchemy import select

from backend.api.deps import CurrentUser, SessionDep, StateDep, experiment_for
from backend.api.jobs import ERRORS
from backend.auth import readable_experiments
from backend.errors import NotFound
from backend.jobs import JobError, as_utc
from backend.models import Calibration, Camera, Experiment
from backend.results import ResultUnavailable, camera_report, result_path
from backend.schemas.jobs import CalibrationOut

router = APIRouter(tags=["results"])


def calibration_out(row: Calibration) -> CalibrationOut:
    return CalibrationOut(
        id=row.id,
        kind=row.kind,  # type: ignore[arg-type]
        camera_id=row.camera_id,
        recording_id=row.recording_id,
        job_id=row.job_id,
        version=row.version,
        image_width_px=row.image_width_px,
        image_height_px=row.image_height_px,
        sha256=row.sha256,
        summary=row.summary,
        created_at=as_utc(row.created_at),  # type: ignore[arg-type]
        file_url=f"/api/v1/calibrations/{row.id}/file",
        report_url=f"/api/v1/calibrations/{row.id}/report",
    )


def readable_calibration(calibration_id: int, session: SessionDep, principal: CurrentUser) -> Calibration:
    missing = JobError(404, "calibration_not_found", f"there is no calibration {calibration_id}")
    row = session.get(Calibration, calibration_id)
    camera = session.get(Camera, row.camera_id) if row else None
    if row is None or camera is None:
        raise missing
    try:
        experiment_for(session, principal, camera.experiment_id)
    except NotFound:
        raise missing from None
    return row


CalibrationDep = Annotated[Calibration, Depends(readable_calibration)]


@router.get("/calibrations", response_model=list[CalibrationOut])
def list_calibrations(
    session: SessionDep, principal: CurrentUser, camera_id: int | None = None, kind: str | None = None
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
    return [calibration_out(row) for row in rows]


@router.get("/calibrations/{calibration_id}", response_model=CalibrationOut, responses=ERRORS)
def read_calibration(calibration: CalibrationDep) -> CalibrationOut:
    return calibration_out(calibration)


class CalibrationReport(BaseModel):
    calibration: CalibrationOut
    report: dict[str, Any]


@router.get("/calibrations/{calibration_id}/report", response_model=CalibrationReport, responses=ERRORS)
def calibration_report(calibration: CalibrationDep, state: StateDep) -> CalibrationReport:
    """A camera calibration's report: parameters ± standard errors, per-frame RMS, residual vectors over the
    image, the residual map and the verdict (the fields of `camera.json`, units in every name)."""
    if calibration.kind != "camera":
        raise JobError(404, "no_report", f"calibration {calibration.id} is a {calibration.kind} calibration")
    try:
        report = camera_report(state.settings.data_path, calibration.path)
    except ResultUnavailable as error:
        raise JobError(410, "result_missing", str(error)) from None
    return CalibrationReport(calibration=calibration_out(calibration), report=report)


@router.get("/calibrations/{calibration_id}/file", response_class=FileResponse, responses=ERRORS)
def calibration_file(calibration: CalibrationDep, state: StateDep) -> FileResponse:
    """The calibration file itself (camera.json), streamed."""
    try:
        path = result_path(state.settings.data_path, calibration.path)
    except ResultUnavailable as error:
        raise JobError(410, "result_missing", str(error)) from None
    return FileResponse(path, media_type="application/json", filename=f"calibration-{calibration.id}-{path.name}")
