"""What the jobs API answers. The job spec it takes is `fringelab.core.specs`.

The browser and scripts send the same spec to `POST /api/v1/jobs`. Shapes and ranges are checked here (FastAPI
answers 422 naming the field); checks that need the database (is the recording ready, does the calibration
belong to its camera, is the frame range inside the recording) live in `fringelab.core.preparation`.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, Field
from sqlalchemy.orm import Session

from fringelab.core.calibration_pairs import standing
from fringelab.core.job_kinds import JobSpec  # noqa: F401  (re-exported for the routes)
from fringelab.core.jobs import as_utc
from fringelab.core.models import Calibration
from fringelab.core.specs import MAX_ID, JobState  # noqa: F401  (re-exported for the routes)


class Progress(BaseModel):
    stage: str = Field(description="What the job is doing now, for people.")
    done: int
    total: int
    fraction: float | None = Field(description="done / total, or null before the total is known.")
    eta_s: float | None = Field(description="Seconds left in this stage at the rate so far; null when unknown.")


RELATIVE_URL = (
    "Root-relative URL (`/api/v1/...`, no scheme, host or proxy sub-path): append it to the base URL you call the "
    "API at, e.g. `http://lab:8000` + url, or `https://lab.example/fringelab` + url behind a proxy at a sub-path "
    "(`fringelab.client.Client` does this)."
)


class JobFileOut(BaseModel):
    name: str
    size_bytes: int
    sha256: str
    media_type: str
    url: str = Field(description=RELATIVE_URL)


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
    experiment_name: str | None = Field(None, description="The experiment's name (null: no experiment).")
    camera_name: str | None = Field(
        None, description="The camera whose recording the job reads, itself or through the job it reads (null: none)."
    )
    progress: Progress
    error: str = Field(description="Why it failed and what to do; empty unless failed.")
    worker: str
    files: list[JobFileOut]
    result: dict[str, Any]
    provenance: dict[str, Any]
    warnings: list[str] = Field(
        default_factory=list,
        description="What the results must be read with: each calibration used whose verdict is bad (the user "
        "consented with accept_bad_calibration).",
    )
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


class JobSpecSchemasOut(BaseModel):
    """The JSON Schema of the job specs POST /api/v1/jobs takes, for building forms (the dashboard's)."""

    schemas: dict[str, dict[str, Any]] = Field(
        description="every startable kind's spec model and the models they use, by name (a spec model's `kind` "
        "says its kind; references read `#/schemas/NAME`): the same models as the OpenAPI document's, without the "
        "rest of it"
    )


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
    kind: Literal["camera", "projector", "procam"]
    camera_id: int
    recording_id: int | None
    job_id: str | None
    version: int = Field(description="1, 2, ... per camera and kind; topography jobs name the id they use.")
    image_width_px: int
    image_height_px: int
    sha256: str
    summary: dict[str, Any]
    created_at: datetime
    file_url: str = Field(description=RELATIVE_URL)
    report_url: str = Field(description=RELATIVE_URL + " (camera: /report, projector: /projector-report)")
    label: str = Field("", description="How to name it: kind, id, camera and date.")
    verdict: str | None = Field(None, description="good, acceptable or bad (null: none stored).")
    bad: bool = Field(
        False, description="Its verdict is bad, or it is a projector calibration built on a bad camera calibration."
    )
    bad_reason: str | None = Field(None, description="Why it is bad (null: it is not).")
    camera_calibration_id: int | None = Field(
        None, description="A projector calibration: the camera calibration it was built on (null: unknown)."
    )


# The error answers every job route declares, and those of routes that read a job's result files (OpenAPI
# `responses=`; shared by the routes of jobs, results, comparisons, scans and camera against camera).
JOB_ERRORS: dict[int | str, dict[str, Any]] = {
    status: {"model": ErrorOut, "description": description}
    for status, description in (
        (404, "No such job."),
        (409, "Not possible in the job's state, or its inputs are not ready."),
        (422, "The spec is invalid; `field` names the part at fault."),
        (503, "The job queue (Redis) is unreachable."),
    )
}
RESULT_ERRORS: dict[int | str, dict[str, Any]] = {
    **JOB_ERRORS,
    410: {"model": ErrorOut, "description": "The result file is no longer on disk (or unreadable); retry the job."},
}


def calibration_out(row: Calibration, session: Session) -> CalibrationOut:
    state = standing(session, row)
    report = "projector-report" if row.kind == "projector" else "report"
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
        created_at=as_utc(row.created_at),
        file_url=f"/api/v1/calibrations/{row.id}/file",
        report_url=f"/api/v1/calibrations/{row.id}/{report}",
        label=state.label,
        verdict=state.verdict,
        bad=state.bad,
        bad_reason=state.bad_reason,
        camera_calibration_id=state.camera_calibration_id,
    )
