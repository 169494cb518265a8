"""What the measurement jobs load and record: a recording's file and camera, a calibration's file, a
calibration's row."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError

from fringelab.core.models import Calibration, Camera, Recording
from worker.context import JobContext


def recording_input(context: JobContext[Any]) -> tuple[Recording, Camera, Path]:
    """The recording the spec's `recording_id` names (every kind that reads one names it so), its camera and file."""
    recording_id = context.spec.recording_id
    with context.sessions() as session:
        recording = session.get(Recording, recording_id)
        if recording is None:
            raise ValueError(f"recording {recording_id} was deleted; upload it again")
        camera = recording.camera
        session.expunge_all()
    return recording, camera, context.settings.data_path / recording.path


def recording_file(context: JobContext[Any], recording_id: int) -> Path:
    """The file of a recording a spec names besides its `recording_id` (a topography's Gray code at rest)."""
    with context.sessions() as session:
        recording = session.get(Recording, recording_id)
        if recording is None:
            raise ValueError(f"recording {recording_id} was deleted; upload it again")
        path = recording.path
    return context.settings.data_path / path


def record_calibration(
    context: JobContext,
    *,
    kind: str,
    camera_id: int,
    recording_id: int,
    name: str,
    image_size_wh_px: tuple[int, int],
    summary: dict[str, Any],
) -> Calibration:
    """The versioned Calibration row of this job's file `name` (one per job: a second run finds the first).
    Versions count per camera and kind; two jobs finishing at once retry on the unique version."""
    path = context.directory / name
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    for _attempt in range(5):
        with context.sessions() as session:
            existing = session.scalar(select(Calibration).where(Calibration.job_id == context.job_id))
            if existing is not None:
                return existing
            latest = session.scalar(
                select(func.max(Calibration.version)).where(
                    Calibration.camera_id == camera_id, Calibration.kind == kind
                )
            )
            row = Calibration(
                kind=kind,
                camera_id=camera_id,
                recording_id=recording_id,
                job_id=context.job_id,
                version=(latest or 0) + 1,
                path=str(path.relative_to(context.settings.data_path)),
                summary=summary,
                image_width_px=image_size_wh_px[0],
                image_height_px=image_size_wh_px[1],
                sha256=digest,
            )
            session.add(row)
            try:
                session.commit()
            except IntegrityError:  # another job took this version a moment ago
                session.rollback()
                continue
            return row
    raise RuntimeError(f"could not number the {kind} calibration of camera {camera_id}; retry the job")


def calibration_file(context: JobContext, calibration_id: int) -> Path:
    with context.sessions() as session:
        row = session.get(Calibration, calibration_id)
        if row is None:
            raise ValueError(f"calibration {calibration_id} was deleted; choose another one and start a new job")
        path = context.settings.data_path / row.path
    if not path.is_file():
        raise ValueError(f"the file of calibration {calibration_id} is gone ({row.path}); run that calibration again")
    return path
