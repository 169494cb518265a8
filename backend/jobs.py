"""Creating jobs: the database row first (the source of truth), then the Celery task by name.

The backend never imports task code; `TASK_NAMES` maps each job kind to the name its task is registered under.
"""

from __future__ import annotations

import uuid
from typing import Any

from celery import Celery
from kombu.exceptions import OperationalError
from sqlalchemy.orm import Session

from backend.models import Job, utcnow

TASK_NAMES = {
    "ingest": "fringelab.ingest",
    "camera_calibration": "fringelab.camera_calibration",
    "projector_calibration": "fringelab.projector_calibration",
    "topography": "fringelab.topography",
    "export": "fringelab.export",
}

ACTIVE_STATES = ("queued", "running")
FINAL_STATES = ("succeeded", "failed", "cancelled")


class QueueUnavailable(Exception):
    """The broker did not take the task; the job is marked failed with the reason."""


def submit_job(
    session: Session,
    celery: Celery,
    *,
    kind: str,
    spec: dict[str, Any],
    experiment_id: int | None = None,
    retry_of: Job | None = None,
) -> Job:
    """Store a queued job, commit, then send its task (task id = job id). Raises QueueUnavailable."""
    if kind not in TASK_NAMES:
        raise ValueError(f"unknown job kind {kind!r}; expected one of {sorted(TASK_NAMES)}")
    job = Job(
        id=str(uuid.uuid4()),
        kind=kind,
        spec=spec,
        experiment_id=experiment_id,
        state="queued",
        attempt=(retry_of.attempt + 1) if retry_of else 1,
        retry_of=retry_of.id if retry_of else None,
    )
    session.add(job)
    session.commit()
    try:
        celery.send_task(TASK_NAMES[kind], args=[job.id], task_id=job.id)
    except OperationalError as error:
        job.state = "failed"
        job.error = f"the job queue (Redis) is unreachable: {error}; try again when it is back"
        job.finished_at = utcnow()
        session.commit()
        raise QueueUnavailable(job.error) from None
    return job
