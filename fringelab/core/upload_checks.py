"""The job that checks an upload before it can be used: a recording's ingest (`worker.jobs.ingest`) and a
simulation's check (`worker.jobs.simulation_check`). One rule for both, from queueing to settling:

- `submit_check` marks the upload busy (`ingesting`, `checking`) and queues its job; without a queue it fails
  the upload at once, saying so;
- `claim` (the job's first step) marks it busy again under this job's id: a job run again (acks-late
  redelivery, a retry) owns the upload it checks;
- `store` writes what the job found (its error text never shows a server path or an address);
- `settle_checks` (run by the reconciliation, `fringelab.core.reconcile`) fails every upload still busy whose job
  ended without a word (a worker lost too often, a cancel) or is gone, so that none stays busy for ever.

Not here: what a check reads or decides (the worker's job modules), how an upload is stored (`recordings`,
`simulations`).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta
from typing import Any

from celery import Celery
from sqlalchemy import select
from sqlalchemy.orm import Session

from fringelab.core.jobs import FINAL_STATES, QueueUnavailable, add_log, as_utc, submit_job
from fringelab.core.models import Job, Recording, Simulation, utcnow
from fringelab.core.specs import IngestSpec, SimulationCheckSpec
from fringelab.core.text import public_text
from fringelab.science import Cancelled


@dataclass(frozen=True)
class CheckedUpload:
    """An upload kind whose use waits for a check job: its table, the column naming the job, and its states."""

    model: type[Recording] | type[Simulation]
    noun: str
    job_column: str
    job_name: str  # how its error texts name the job ("the ingest", "its ingest job")
    busy: str
    failed: str
    spec: type[IngestSpec] | type[SimulationCheckSpec]

    def spec_for(self, upload_id: int) -> IngestSpec | SimulationCheckSpec:
        """The check job's spec: {"recording_id": N} or {"simulation_id": N}."""
        return self.spec.model_validate({f"{self.noun}_id": upload_id})


RECORDING_INGEST = CheckedUpload(
    Recording, "recording", "ingest_job_id", "ingest", "ingesting", "invalid", IngestSpec
)  # fmt: skip
SIMULATION_CHECK = CheckedUpload(
    Simulation, "simulation", "check_job_id", "check", "checking", "failed", SimulationCheckSpec
)  # fmt: skip
CHECKED_UPLOADS = (RECORDING_INGEST, SIMULATION_CHECK)

# A busy upload names its job a moment after it is marked busy: only older ones are orphans. (A recording checked
# again is older; were the reconciliation to run in that moment, its job's `claim` marks it busy again.)
UNQUEUED_GRACE_S = 300


def submit_check(session: Session, celery: Celery, kind: CheckedUpload, upload: Any, *, experiment_id: int) -> None:
    """Mark `upload` busy and queue its check job (the job's id stored on it); without a queue the upload is
    failed with the reason, and the caller answers with it."""
    upload.state, upload.error = kind.busy, ""
    setattr(upload, kind.job_column, None)  # never a former job's id: that one has ended, `settle_checks` would fail it
    session.commit()
    try:
        job = submit_job(session, celery, spec=kind.spec_for(upload.id), experiment_id=experiment_id)
    except QueueUnavailable as error:
        upload.state, upload.error = kind.failed, f"the {kind.job_name} could not be queued: {error}"
        session.commit()
        return
    setattr(upload, kind.job_column, job.id)
    session.commit()


def claim(session: Session, kind: CheckedUpload, upload_id: int, *, job_id: str) -> Any:
    """The upload a check job starts on, marked busy under `job_id` (the caller commits once it has read what it
    needs); Cancelled when it was deleted meanwhile (the job then ends quietly)."""
    upload: Any = session.get(kind.model, upload_id)
    if upload is None:
        raise Cancelled(f"{kind.noun} {upload_id} was deleted")
    upload.state, upload.error = kind.busy, ""
    setattr(upload, kind.job_column, job_id)
    return upload


def store(session: Session, kind: CheckedUpload, upload_id: int, /, **fields: Any) -> None:
    """Write what the check found on the upload and commit; Cancelled when it was deleted meanwhile."""
    upload = session.get(kind.model, upload_id)
    if upload is None:
        raise Cancelled(f"{kind.noun} {upload_id} was deleted")
    for name, value in fields.items():
        setattr(upload, name, public_text(value) if name == "error" else value)  # no server path shown
    session.commit()


def settle_checks(session: Session) -> list[str]:
    """Fail every upload still busy whose check job has ended (failed or cancelled without saying: its worker was
    lost too often, or it was cancelled), with the job's error, or is gone (deleted, or never named) for longer
    than UNQUEUED_GRACE_S; run by the reconciliation. Returns one line per upload failed."""
    settled = []
    orphaned_before = utcnow() - timedelta(seconds=UNQUEUED_GRACE_S)
    for kind in CHECKED_UPLOADS:
        busy: list[Any] = list(session.scalars(select(kind.model).where(kind.model.state == kind.busy)))
        for upload in busy:
            job_id = getattr(upload, kind.job_column)
            job = session.get(Job, job_id) if job_id else None
            if job is None:
                if as_utc(upload.created_at) > orphaned_before:
                    continue
                reason = f"its {kind.job_name} job is gone; upload it again"
            elif job.state in FINAL_STATES:
                reason = job.error or f"its {kind.job_name} job {job.id} ended {job.state} without a result"
                add_log(session, job.id, f"{kind.noun} {upload.id} marked {kind.failed}: its job ended {job.state}")
            else:
                continue
            upload.state, upload.error = kind.failed, f"the {kind.job_name} did not finish: {reason}"
            settled.append(f"{kind.noun} {upload.id}: {kind.failed} ({reason})")
    session.commit()
    return settled
