"""Jobs: the database row is the source of truth; Celery only carries the work out.

What belongs here: creating a job (row first, then its task by name), checking a spec against the database
before anything is queued (`fringelab.core.preparation`), cancel, retry, progress and the job log. What is said to
the broker and read from it is `fringelab.core.broker`; reconciling the database with the broker after a restart,
`fringelab.core.reconcile`. Route handlers and Celery tasks are thin layers over these functions. The backend
never imports task code: each job kind's entry in `fringelab.core.job_kinds` names its task.

State machine (the `state` column):

    queued ──> running ──> succeeded | failed
      │           │
      └───────────┴──────> cancelled     (a running job is `stopping` until its worker notices or is terminated)

`finished_at` is set exactly once, by whoever ends the job (an atomic `UPDATE ... WHERE finished_at IS NULL`), so
a task that runs twice (acks-late redelivery) cannot finish a job twice.

Chunked jobs (topography, selftest) run in phases. The entry task (id = job id) plans the first phase: frame
ranges stored as `JobChunk` rows, one chunk task per row (id `<job>:<phase>:<index>`, a Celery group over every
worker), and before them the phase's merge task (id `<job>:merge:<phase>`; sent once: `merge_queued_at`), which
runs in frame order over each chunk as soon as its row is done, measures the chunks nobody has started (the next
one in order straight into its output), and either ends the job or plans the next phase. A chunk runs where its
row is claimed (`pending -> running`, one claim wins); a chunk task that finds its row claimed by a live run
leaves it, and goes on to the next row nobody has claimed. The join is counted in the database, not in a Celery
chord: a chord's counter in Redis counts task deliveries, so an acks-late redelivery would count a chunk twice and
fire the merge early; a row that goes `-> done` once cannot.
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from datetime import UTC, date, datetime
from typing import Any, overload

from celery import Celery
from kombu.exceptions import OperationalError
from pydantic import BaseModel
from sqlalchemy import Row, select, update
from sqlalchemy.orm import Session

from fringelab import __version__
from fringelab.core.accounts import Principal, access_level, audit, can_access
from fringelab.core.broker import DEMO_TASK, job_task_ids, revoke
from fringelab.core.errors import Conflict, Forbidden, NotFound, TooLarge, Unavailable
from fringelab.core.job_kinds import kind_of, spec_of
from fringelab.core.models import (
    Experiment,
    Job,
    JobLog,
    utcnow,
)
from fringelab.core.preparation import Authorize, NotVisible, Prepared, job_error, nobody_checks, prepare_inputs
from fringelab.core.quota import check_result_quota
from fringelab.core.settings import Settings
from fringelab.core.storage import InsufficientStorage, check_room

ACTIVE_STATES = ("queued", "running")
FINAL_STATES = ("succeeded", "failed", "cancelled")


class QueueUnavailable(Exception):
    """The broker did not take the task; the job is marked failed with the reason."""


@overload
def as_utc(moment: datetime) -> datetime: ...
@overload
def as_utc(moment: None) -> None: ...
@overload
def as_utc(moment: datetime | None) -> datetime | None: ...
def as_utc(moment: datetime | None) -> datetime | None:
    """SQLite gives naive datetimes back; every time fringelab stores is UTC."""
    if moment is None or moment.tzinfo is not None:
        return moment
    return moment.replace(tzinfo=UTC)


def add_log(session: Session, job_id: str, message: str, *, level: str = "info") -> None:
    """Append a line to the job's log (committed with the caller's transaction)."""
    session.add(JobLog(job_id=job_id, message=message, level=level))


# ---------------------------------------------------------------------------------------------------- creating


def submit_job(
    session: Session,
    celery: Celery,
    *,
    spec: BaseModel,
    experiment_id: int | None = None,
    retry_of: Job | None = None,
    provenance: dict[str, Any] | None = None,
) -> Job:
    """Store a queued job of the spec's kind, commit, then send its task (task id = job id). Raises
    QueueUnavailable."""
    entry = kind_of(spec)
    kind, stored = entry.kind, spec.model_dump(mode="json")
    job = Job(
        id=str(uuid.uuid4()),
        kind=kind,
        spec=stored,
        experiment_id=experiment_id,
        state="queued",
        attempt=(retry_of.attempt + 1) if retry_of else 1,
        retry_of=retry_of.id if retry_of else None,
        provenance={"code_version": __version__, "spec": stored, **(provenance or {})},
    )
    session.add(job)
    add_log(
        session, job.id, f"queued ({kind}, attempt {job.attempt})" + (f", retry of {retry_of.id}" if retry_of else "")
    )
    session.commit()
    try:
        celery.send_task(entry.task, args=[job.id], task_id=job.id, ignore_result=True)
    except OperationalError as error:
        job.state = "failed"
        job.error = f"the job queue (Redis) is unreachable: {error}; try again when it is back"
        job.finished_at = utcnow()
        add_log(session, job.id, job.error, level="error")
        session.commit()
        raise QueueUnavailable(job.error) from None
    return job


def prepare_job(session: Session, spec: BaseModel, *, authorize: Authorize = nobody_checks) -> Prepared:
    """Check a (shape-valid) spec's inputs against the database (`fringelab.core.preparation`, the inputs its
    kind names in `fringelab.core.job_kinds`); raise a `job_error` naming the field, or say what it uses."""
    return prepare_inputs(session, spec, kind_of(spec).inputs, authorize=authorize)


def create_job(
    session: Session,
    celery: Celery,
    spec: BaseModel,
    *,
    authorize: Authorize = nobody_checks,
) -> Job:
    """Check the spec (and the caller's right to start it), refuse a duplicate of a job still queued or running,
    then store and queue the job."""
    prepared = prepare_job(session, spec, authorize=authorize)
    kind, stored = kind_of(spec).kind, spec.model_dump(mode="json")
    for active in session.scalars(select(Job).where(Job.kind == kind, Job.state.in_(ACTIVE_STATES))):
        if active.spec == stored:  # the stored JSON compared whole: the same spec is the same job
            error = job_error(
                Conflict,
                "duplicate_job",
                f"job {active.id} with the same spec is already {active.state}; watch it instead, or cancel it first",
            )
            error.job_id = active.id
            raise error
    # The results' expected size is reserved against the experiment's owner until the job ends (then its files').
    check_result_quota(session, celery.fringelab_settings, experiment_id=prepared.experiment_id, kind=kind,
                       stored=stored)  # fmt: skip
    return submit_job(
        session,
        celery,
        spec=spec,
        experiment_id=prepared.experiment_id,
        provenance={"inputs": prepared.inputs, "calibrations": prepared.calibrations},
    )


def get_job(session: Session, job_id: str) -> Job:
    job = session.get(Job, job_id)
    if job is None:
        raise job_error(NotFound, "job_not_found", f"there is no job {job_id}")
    return job


def _allowed(session: Session, principal: Principal, experiment_id: int | None, *, write: bool) -> bool:
    if experiment_id is None:
        return principal.is_admin
    experiment = session.get(Experiment, experiment_id)
    return experiment is not None and can_access(session, principal, experiment, write=write)


def job_for(session: Session, principal: Principal, job_id: str, *, write: bool = False) -> Job:
    """The job if `principal` may see it (or change it); otherwise NotFound, as if it did not exist."""
    job = get_job(session, job_id)
    if not _allowed(session, principal, job.experiment_id, write=False):
        raise job_error(NotFound, "job_not_found", f"there is no job {job_id}")
    if write and not _allowed(session, principal, job.experiment_id, write=True):
        raise job_error(
            Forbidden,
            "read_only",
            f"read-only access: you may read job {job_id} but not change it; ask the experiment's owner",
        )
    return job


def start_job_as(session: Session, celery: Celery, principal: Principal, spec: BaseModel) -> Job:
    """Start a job for `principal` (committed, audited): they need write access to the experiment its inputs
    belong to, or to be an admin for a job outside any experiment (selftest). Inputs in experiments they cannot
    see are answered as inputs that do not exist."""

    def may_start(experiment_id: int | None) -> None:
        if experiment_id is None:
            if not principal.is_admin:
                raise job_error(Forbidden, "forbidden", "jobs outside any experiment (selftest) need an admin account")
            return
        experiment = session.get(Experiment, experiment_id)
        level = access_level(session, principal, experiment) if experiment is not None else None
        if level is None:
            raise NotVisible  # the spec's ids are answered as if they did not exist
        if level == "read":
            raise job_error(
                Forbidden,
                "read_only",
                f"read-only access: experiment {experiment_id} is shared with your group for reading; "
                "ask its owner for write access to start jobs",
            )

    try:
        job = create_job(session, celery, spec, authorize=may_start)
    except QueueUnavailable as error:
        raise job_error(Unavailable, "queue_unavailable", str(error)) from None
    audit(session, principal, "start", "job", job.id, kind=job.kind)
    session.commit()
    return job


# ------------------------------------------------------------------------------------------- cancel and retry


def cancel_job(session: Session, celery: Celery, job_id: str) -> Job:
    """Cancel a queued or running job: the state changes now; a queued task is revoked, a running one stops at
    its next frame (cooperative; every pool). `terminate_unstopped` ends one that does not (prefork)."""
    job = get_job(session, job_id)
    if job.state == "cancelled":
        raise job_error(Conflict, "already_cancelled", f"job {job.id} was already cancelled; retry it to run it again")
    if job.state in FINAL_STATES:
        raise job_error(Conflict, "job_finished", f"job {job.id} already {job.state}; there is nothing to cancel")
    was_running = job.state == "running"
    result = session.execute(
        update(Job)
        .where(Job.id == job.id, Job.state.in_(ACTIVE_STATES))
        .values(state="cancelled", finished_at=None if was_running else utcnow(), error="")
    )
    if result.rowcount == 0:  # type: ignore[attr-defined]  # it ended between our read and our write
        session.rollback()
        session.refresh(job)
        raise job_error(Conflict, "job_finished", f"job {job.id} already {job.state}; there is nothing to cancel")
    if was_running:
        # Its waiting tasks are not revoked: the first one a worker takes confirms the stop (a job with every
        # task revoked would have nobody left to say that it stopped), and the rest return at once.
        add_log(session, job.id, "cancel requested: the worker stops after its current frame")
    else:
        note = revoke(celery, [job.id], terminate=False)
        add_log(session, job.id, "cancelled before it started" + note)
    session.commit()
    session.refresh(job)
    return job


def terminate_unstopped(session: Session, celery: Celery, job_id: str, *, grace_s: float) -> bool:
    """Hard-cancel a cancelled job whose worker has not stopped: terminate the process running it (prefork pools;
    other pools ignore it and rely on the cooperative check). True when it did."""
    job = session.get(Job, job_id)
    if job is None or job.state != "cancelled" or job.finished_at is not None:
        return False
    note = revoke(celery, job_task_ids(session, job), terminate=True)
    done = session.execute(
        update(Job).where(Job.id == job.id, Job.finished_at.is_(None)).values(finished_at=utcnow())
    ).rowcount  # type: ignore[attr-defined]
    if done:
        add_log(
            session,
            job.id,
            f"no worker confirmed the stop within {grace_s:g} s; a process still running it was terminated{note}",
        )
    session.commit()
    return bool(done)


def retry_job(session: Session, celery: Celery, job_id: str) -> Job:
    """A new attempt of a failed or cancelled job, with the same spec checked again, linked to the old one."""
    job = get_job(session, job_id)
    if job.state in ACTIVE_STATES:
        raise job_error(
            Conflict, "job_active", f"job {job.id} is still {job.state}; cancel it first, or wait for it to end"
        )
    if job.state == "succeeded":
        raise job_error(Conflict, "job_succeeded", f"job {job.id} succeeded; submit a new job to run it again")
    newer = session.scalars(select(Job).where(Job.retry_of == job.id, Job.state.in_(ACTIVE_STATES))).first()
    if newer is not None:
        raise job_error(Conflict, "already_retried", f"job {job.id} is already being retried as job {newer.id}")
    spec = spec_of(job.kind, job.spec)
    prepared = prepare_job(session, spec)
    return submit_job(
        session,
        celery,
        spec=spec,
        experiment_id=prepared.experiment_id if prepared.experiment_id is not None else job.experiment_id,
        retry_of=job,
        provenance={"inputs": prepared.inputs, "calibrations": prepared.calibrations},
    )


# ------------------------------------------------------------------------------------------------ progress


def eta_seconds(job: Job | Row[Any], *, now: datetime | None = None) -> float | None:
    """Seconds left in the current stage at the rate it has run so far; None when there is no rate yet."""
    started = as_utc(job.stage_started_at)
    if job.state != "running" or started is None or not 0 < job.progress_done < job.progress_total:
        return None
    elapsed = ((now or utcnow()) - started).total_seconds()
    if elapsed <= 0:
        return None
    return elapsed / job.progress_done * (job.progress_total - job.progress_done)


def heartbeat_interval_s(settings: Settings) -> float:
    """How often a running task reports: often enough that `worker_lost_after_s` means a dead worker."""
    return min(10.0, settings.worker_lost_after_s / 6)


def start_demo(
    session: Session,
    celery: Celery,
    principal: Principal,
    cameras: Sequence[str],
    test_frames: int,
    scenario: str = "quasi-static",
) -> int:
    """Store a new demo experiment of `principal` (committed, audited) and send the task that simulates its
    cameras' recordings and starts their jobs; returns the experiment's id. Unavailable without the queue.

    scenario: the virtual test (`fringelab.science.virtual_test.SCENARIOS`: the paper's quasi-static test, or a hard
    one: fast motion with springback at perforation, petals and cracks, a highlight, the punch's shadow)."""
    settings: Settings = celery.fringelab_settings
    try:  # below the disk's reserve a demo cannot be made: said now, not as an empty experiment
        check_room(settings.data_path, 0, reserve_bytes=settings.min_free_disk_bytes)
    except InsufficientStorage as error:
        raise TooLarge(f"the demo cannot be made: {error}", code="insufficient_storage") from None
    today = date.today().isoformat()
    kind = "virtual punch test" if scenario == "quasi-static" else f"virtual punch test, {scenario}"
    experiment = Experiment(
        name=f"Demo: {kind} ({today})",
        plate="virtual plate, clamped (simulated)",
        punch="hemispherical (simulated)",
        test_date=today,
        notes="Made by the dashboard's Load demo experiment button: the recordings of "
        f"{', '.join(cameras)} are simulated (fringelab virtual-test --scenario {scenario}), then checked, calibrated "
        "and measured by the workers like uploaded ones.",
        owner_id=principal.user_id,
    )
    session.add(experiment)
    session.flush()
    audit(session, principal, "create", "experiment", experiment.id, demo=True, scenario=scenario)
    session.commit()
    try:
        celery.send_task(DEMO_TASK, args=[experiment.id, cameras, test_frames, scenario])
    except OperationalError as error:
        raise Unavailable(f"the job queue (Redis) is unreachable: {error}; try again when it is back") from None
    return experiment.id
