"""Camera against camera: two topography results of one test compared where both cameras measured the peak.

Thin: the rule is `fringelab.science.camera_against_camera`; the results are read through `fringelab.formats`.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from fastapi import APIRouter, Path
from pydantic import BaseModel, Field

from backend.api.deps import CurrentUser, JobDep, SessionDep, StateDep
from backend.result_files import listed, topography
from backend.schemas.jobs import RESULT_ERRORS
from fringelab.core.jobs import job_for
from fringelab.formats.topography import TopographyResult
from fringelab.science.camera_against_camera import PeakSeries, peaks_against

router = APIRouter(tags=["results"])


class LeftOutFrame(BaseModel):
    frame: int
    reason: str


class CameraAgainstCamera(BaseModel):
    job_id: str
    other_job_id: str
    aligned_by: str = Field(description="time (both results have frame times) or frame (by frame number).")
    frames: list[int] = Field(description="This result's frames (recording indices).")
    time_s: list[float | None]
    other_frame: list[int | None] = Field(description="Per frame: the other camera's frame nearest this instant.")
    peak_w_mm: list[float | None] = Field(description="This camera's peak where compared (null: not compared).")
    other_peak_w_mm: list[float | None] = Field(
        description="The other camera's peak at this instant (linear in time between its frames), where compared."
    )
    difference_w_mm: list[float | None] = Field(description="this − other, only where both measured the peak.")
    compared: list[bool]
    left_out: list[str | None] = Field(description="Per frame: why it is not compared (null: compared).")
    left_out_frames: list[LeftOutFrame] = Field(description="The frames left out, each with its reason.")
    n_compared: int
    rms_difference_mm: float | None = Field(description="RMS of the differences over the compared frames.")
    largest_difference_mm: float | None = Field(description="Largest |this − other| over the compared frames only.")


def _series(reader: TopographyResult) -> PeakSeries:
    return PeakSeries(frames=reader.frames, time_s=reader.column("frames/time_s"),
                      peak_w_mm=reader.column("peak/w_mm"), measured=reader.peak_measured())  # fmt: skip


@router.get(
    "/jobs/{job_id}/topography/against/{other_job_id}", response_model=CameraAgainstCamera, responses=RESULT_ERRORS
)
def camera_against_camera(
    job: JobDep,
    other_job_id: Annotated[str, Path(max_length=64, description="The other camera's topography job.")],
    session: SessionDep,
    principal: CurrentUser,
    state: StateDep,
) -> CameraAgainstCamera:
    """This camera's peak deflection against another camera's of the same test, frame by frame: compared only
    where both measured the peak (docs/method.md §8), every other frame left out with its reason; the RMS and
    the largest difference are over the compared frames only."""
    other_job = job_for(session, principal, other_job_id)
    with topography(job, state.settings.data_path) as mine, topography(other_job, state.settings.data_path) as other:
        ours = _series(mine)
        result = peaks_against(ours, _series(other))
    compared = result.compared
    reasons = [reason or None for reason in result.left_out]
    return CameraAgainstCamera(
        job_id=job.id,
        other_job_id=other_job.id,
        aligned_by=result.aligned_by,
        frames=ours.frames.astype(int).tolist(),
        time_s=listed(ours.time_s, 6),
        other_frame=[int(f) if f >= 0 else None for f in result.other_frame],
        peak_w_mm=listed(np.where(compared, ours.peak_w_mm, np.nan)),
        other_peak_w_mm=listed(result.other_peak_w_mm),
        difference_w_mm=listed(result.difference_w_mm),
        compared=compared.tolist(),
        left_out=reasons,
        left_out_frames=[LeftOutFrame(frame=int(f), reason=r) for f, r in zip(ours.frames, reasons, strict=True) if r],
        n_compared=int(np.count_nonzero(compared)),
        rms_difference_mm=_finite(result.rms_difference_mm),
        largest_difference_mm=_finite(result.largest_difference_mm),
    )


def _finite(value: float) -> float | None:
    return round(value, 4) if np.isfinite(value) else None
