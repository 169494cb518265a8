"""Results of rigs with a digital projector (docs/procam.md): the scan view's data (a scan job's points, decimated,
its depth map and its decoding's QA) and a camera–projector calibration's report.

Thin: find the succeeded job's or calibration's file, read it (`fringelab.formats.scan`, numpy and h5py only; the
calibration's JSON), thin it to what a browser draws, answer. Not here: computing them (the worker) or exporting a
scan (`fringelab export`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from fastapi import APIRouter, Query
from pydantic import BaseModel, Field

from backend.api.deps import CalibrationDep, JobDep, SessionDep, StateDep
from backend.result_files import listed, read_json, succeeded_file
from backend.schemas.jobs import RESULT_ERRORS, CalibrationOut, calibration_out
from fringelab.core.errors import Gone, NotFound
from fringelab.core.jobs import job_error
from fringelab.formats.scan import read_scan
from fringelab.formats.topography import ResultUnavailable

router = APIRouter(tags=["results"])

MAX_POINTS = 40_000  # a 3-D scatter of this many points stays interactive in a browser
MAP_SIDE = 200  # the decoding's maps, sampled to at most this many pixels per side


class ScanPoints(BaseModel):
    x_mm: list[float | None]
    y_mm: list[float | None]
    z_mm: list[float | None]
    sigma_mm: list[float | None]
    source: list[int] = Field(description="0 stripe edge, 1 phase, 2 per-pixel code")
    n_total: int = Field(description="Points in the file; the lists hold an even sample of them, edges first.")


class ScanMap(BaseModel):
    step_px: int = Field(description="Camera pixels between samples along each axis.")
    width: int
    height: int
    values: list[list[float | None]] = Field(description="Rows of samples; null where there is nothing.")


class ScanView(BaseModel):
    job_id: str
    axis: str
    qa: dict[str, Any]
    points: ScanPoints
    depth_z_mm: ScanMap
    code: ScanMap = Field(description="The decoded code value (null: none).")
    shading_grey: ScanMap
    reason: ScanMap = Field(description="0 decoded, 1 a bit not clear, 2 shading too low, 3 beyond the projector.")


def _map(values: np.ndarray, *, invalid: np.ndarray | None = None, decimals: int = 3) -> ScanMap:
    step = max(1, int(np.ceil(max(values.shape) / MAP_SIDE)))
    sampled = values[::step, ::step].astype(np.float64)
    if invalid is not None:
        sampled = np.where(invalid[::step, ::step], np.nan, sampled)
    rows = [listed(row, decimals) for row in sampled]
    return ScanMap(step_px=step, width=int(values.shape[1]), height=int(values.shape[0]), values=rows)


def _sample(source: np.ndarray, max_points: int) -> np.ndarray:
    """Indices of at most max_points points: every stripe-edge point while they fit in half the budget (else an
    even sample of them), the rest an even sample of the others."""
    edges, others = np.flatnonzero(source == 0), np.flatnonzero(source != 0)
    if len(source) <= max_points:
        return np.arange(len(source))

    def even(indices: np.ndarray, n: int) -> np.ndarray:
        return indices[np.linspace(0, len(indices) - 1, n).astype(int)] if n > 0 and len(indices) else indices[:0]

    kept_edges = edges if len(edges) <= max_points // 2 else even(edges, max_points // 2)
    return np.concatenate([kept_edges, even(others, min(len(others), max_points - len(kept_edges)))])


@router.get("/jobs/{job_id}/scan", response_model=ScanView, responses=RESULT_ERRORS)
def scan_view(job: JobDep, state: StateDep, max_points: int = Query(MAX_POINTS, ge=100, le=200_000)) -> ScanView:
    """A succeeded scan job's points (an even sample, stripe-edge points first), depth map and decoding maps."""
    path = succeeded_file(job, state.settings.data_path, kind="scan", name="scan.h5")
    scan = read_scan(path)
    take = _sample(scan.source, max_points)
    points = scan.points_cam_mm[take]
    return ScanView(
        job_id=job.id, axis=scan.axis, qa=scan.qa,
        points=ScanPoints(x_mm=listed(points[:, 0], 3), y_mm=listed(points[:, 1], 3), z_mm=listed(points[:, 2], 3),
                          sigma_mm=listed(scan.sigma_mm[take], 4), source=scan.source[take].astype(int).tolist(),
                          n_total=len(scan.sigma_mm)),
        depth_z_mm=_map(scan.depth_z_mm),
        code=_map(scan.code, invalid=scan.code < 0, decimals=0),
        shading_grey=_map(scan.shading_grey, decimals=1),
        reason=_map(scan.reason, decimals=0),
    )  # fmt: skip


class ProcamReport(BaseModel):
    calibration: CalibrationOut
    report: dict[str, Any] = Field(
        description="The calibration's document (schema fringelab.procam-calibration): camera and projector "
        "models, stereo pose, RMS of the camera, the projector and the pair, each pose's RMS and residual vectors "
        "in both images, and the verdict."
    )


@router.get("/calibrations/{calibration_id}/procam-report", response_model=ProcamReport, responses=RESULT_ERRORS)
def procam_report(calibration: CalibrationDep, state: StateDep, session: SessionDep) -> ProcamReport:
    """A camera–projector calibration's report (the fields of its procam.json)."""
    if calibration.kind != "procam":
        raise job_error(NotFound, "no_report", f"calibration {calibration.id} is a {calibration.kind} calibration")
    try:
        document = read_json(state.settings.data_path, calibration.path)
    except ResultUnavailable as error:
        raise job_error(Gone, "result_missing", str(error)) from None
    if document.get("schema") != "fringelab.procam-calibration":
        raise job_error(Gone, "result_missing", f"{calibration.path} is not a camera–projector calibration")
    return ProcamReport(calibration=calibration_out(calibration, session), report=document)
