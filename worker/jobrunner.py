"""Running a job inside a Celery task: state transitions, progress, cancellation and errors, in one place.

A task body receives a `JobContext` and returns the job's result (a JSON-able dict). Everything a person must
act on (ValueError, MeasurementError) becomes the job's error text; anything else is an internal error whose
traceback goes to the worker log. Acks-late work can run twice: a job that already finished is not run again.
"""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from celery import Task
from sqlalchemy.orm import Session, sessionmaker

from backend.jobs import FINAL_STATES
from backend.models import Job, utcnow
from backend.settings import Settings
from worker.measurement import MeasurementError
from worker.runtime import sessions_of, settings_of

log = logging.getLogger(__name__)
PROGRESS_INTERVAL_S = 0.5


class JobCancelled(Exception):
    """Raised between frames when the user cancelled the job."""


@dataclass
class JobContext:
    job_id: str
    spec: dict[str, Any]
    settings: Settings
    sessions: sessionmaker[Session]
    _last_progress: float = field(default=0.0)

    def progress(self, done: int, total: int, stage: str = "") -> None:
        """Record progress (throttled; the last frame is always written) and stop here if cancelled."""
        now = time.monotonic()
        if done < total and now - self._last_progress < PROGRESS_INTERVAL_S:
            return
        self._last_progress = now
        with self.sessions() as session:
            job = session.get(Job, self.job_id)
            if job is None:
                raise JobCancelled("the job record was deleted")
            if job.state == "cancelled":
                raise JobCancelled("cancelled by the user")
            job.progress_done, job.progress_total = done, total
            if stage:
                job.stage = stage
            session.commit()

    def should_cancel(self) -> bool:
        with self.sessions() as session:
            job = session.get(Job, self.job_id)
            return job is None or job.state == "cancelled"


JobBody = Callable[[JobContext], dict[str, Any]]


def run_job(task: Task, job_id: str, body: JobBody) -> dict[str, Any]:
    sessions = sessions_of(task.app)
    with sessions() as session:
        job = session.get(Job, job_id)
        if job is None:
            log.warning("job %s has no record; nothing to do", job_id)
            return {}
        if job.state in FINAL_STATES:  # a redelivered task whose job already ended
            return dict(job.result)
        job.state = "running"
        job.started_at = job.started_at or utcnow()
        job.worker = f"{task.request.hostname or socket.gethostname()}"
        job.error = ""
        spec = dict(job.spec)
        session.commit()
    context = JobContext(job_id=job_id, spec=spec, settings=settings_of(task.app), sessions=sessions)
    try:
        result = body(context)
    except JobCancelled:
        _finish(sessions, job_id, state="cancelled")
        return {}
    except (ValueError, MeasurementError) as error:
        _finish(sessions, job_id, state="failed", error=str(error))
        return {}
    except Exception as error:
        log.exception("job %s failed", job_id)
        _finish(sessions, job_id, state="failed", error=f"internal error ({type(error).__name__}: {error})")
        return {}
    _finish(sessions, job_id, state="succeeded", result=result)
    return result


def _finish(
    sessions: sessionmaker[Session], job_id: str, *, state: str, error: str = "", result: dict[str, Any] | None = None
) -> None:
    with sessions() as session:
        job = session.get(Job, job_id)
        if job is None:
            return
        if job.state == "cancelled" and state != "cancelled":
            state, error = "cancelled", ""  # cancelled while finishing: the user's word wins
        job.state = state
        job.error = error
        if result is not None:
            job.result = result
            job.progress_done = max(job.progress_done, job.progress_total)
        job.finished_at = utcnow()
        session.commit()
