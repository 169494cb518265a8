"""Jobs: the database row is the source of truth; Celery only carries the work out.

What belongs here: creating a job (row first, then its task by name), checking a spec against the database
before anything is queued (`fringelab.core.preparation`), cancel, retry, the job log, and reconciling the database
with the broker after a restart. Route handlers and Celery tasks are thin layers over these functions. The backend
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

import contextlib
import json
import logging
import uuid
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, date, datetime, timedelta
from typing import Any, overload

import redis
from celery import Celery
from kombu.exceptions import OperationalError
from pydantic import BaseModel
from sqlalchemy import select, update
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from fringelab import __version__
from fringelab.core.accounts import Principal, access_level, audit, can_access
from fringelab.core.errors import Conflict, Forbidden, NotFound, Unavailable
from fringelab.core.job_kinds import job_kind, kind_of, spec_of
from fringelab.core.models import (
    Experiment,
    Job,
    JobChunk,
    JobLog,
    utcnow,
)
from fringelab.core.preparation import Authorize, NotVisible, Prepared, job_error, nobody_checks, prepare_inputs
from fringelab.core.settings import Settings

CHUNK_TASK = "fringelab.job_chunk"
MERGE_TASK = "fringelab.job_merge"
DEMO_TASK = "fringelab.demo"  # makes a virtual experiment; its jobs are ordinary jobs
DEMO_ADVANCE_TASK = "fringelab.demo_advance"
PING_TASK = "fringelab.ping"

# How workers send the tasks that continue a job (chunks, merge): while Redis restarts they wait for it, up to
# about two minutes, rather than drop the job's next step. The API does not wait: it answers 503 at once.
WORKER_SEND_RETRY = {"max_retries": 60, "interval_start": 0.5, "interval_step": 0.5, "interval_max": 2.0}

ACTIVE_STATES = ("queued", "running")
FINAL_STATES = ("succeeded", "failed", "cancelled")

MAX_REQUEUES = 3  # a job lost more often than this is failed instead of re-queued again
log = logging.getLogger(__name__)


class QueueUnavailable(Exception):
    """The broker did not take the task; the job is marked failed with the reason."""


def chunk_task_id(job_id: str, phase: int, index: int) -> str:
    return f"{job_id}:{phase}:{index}"


def merge_task_id(job_id: str, phase: int) -> str:
    return f"{job_id}:merge:{phase}"


CHUNK_DONE_KEEP_S = 3600  # a list nobody pops (its merge died) is gone after this


def chunk_done_key(job_id: str, phase: int) -> str:
    """A Redis list each chunk task pushes its index to when it is done, so that the phase's merge, waiting for a
    chunk, wakes at once instead of polling the database. The database stays the truth: a push that is lost only
    delays the merge until its wait times out."""
    return f"fringelab:chunk-done:{job_id}:{phase}"


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


def job_task_ids(session: Session, job: Job) -> list[str]:
    """Every Celery task id this job may have in flight: its entry task, its chunks and its merge."""
    chunks = session.execute(select(JobChunk.phase, JobChunk.index).where(JobChunk.job_id == job.id)).all()
    merges = [merge_task_id(job.id, phase) for phase in range(job.phase + 1)]
    return [job.id, *(chunk_task_id(job.id, phase, index) for phase, index in chunks), *merges]


def _revoke(celery: Celery, task_ids: list[str], *, terminate: bool) -> str:
    try:
        celery.control.revoke(task_ids, terminate=terminate, signal="SIGTERM")
    except (OperationalError, redis.RedisError, OSError) as error:
        return f"; the queue could not be told ({error}), so waiting tasks are skipped when a worker takes them"
    return ""


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
        note = _revoke(celery, [job.id], terminate=False)
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
    note = _revoke(celery, job_task_ids(session, job), terminate=True)
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


def eta_seconds(job: Job, *, now: datetime | None = None) -> float | None:
    """Seconds left in the current stage at the rate it has run so far; None when there is no rate yet."""
    started = as_utc(job.stage_started_at)
    if job.state != "running" or started is None or not 0 < job.progress_done < job.progress_total:
        return None
    elapsed = ((now or utcnow()) - started).total_seconds()
    if elapsed <= 0:
        return None
    return elapsed / job.progress_done * (job.progress_total - job.progress_done)


# ------------------------------------------------------------------------------------------ reconciliation


@dataclass(frozen=True)
class Delivery:
    """A message delivered to a worker and not yet acknowledged: kombu's delivery tag and when it was handed out."""

    tag: str
    delivered_at: datetime


@dataclass(frozen=True)
class BrokerTasks:
    """What the broker holds, by task id: `waiting` in a queue, `delivered` to a worker and unacknowledged."""

    waiting: set[str]
    delivered: dict[str, Delivery]


UNACKED, UNACKED_INDEX = "unacked", "unacked_index"  # kombu's Redis keys of delivered, unacknowledged messages


def broker_tasks(redis_url: str, queues: Iterable[str]) -> BrokerTasks:
    """Read kombu's Redis layout: one list per queue and priority (`name`, `name\x06\x16<p>`), the `unacked`
    hash (tag -> `[message, exchange, routing_key]`) and the `unacked_index` sorted set (tag -> delivery time)."""
    client = redis.Redis.from_url(redis_url, socket_timeout=10, socket_connect_timeout=5)
    try:
        waiting: list[bytes] = []
        for queue in queues:
            for key in (queue, *(f"{queue}\x06\x16{p}" for p in (3, 6, 9))):
                waiting.extend(client.lrange(key, 0, -1))  # type: ignore[arg-type]
        unacked = client.hgetall(UNACKED)
        index = dict(client.zrange(UNACKED_INDEX, 0, -1, withscores=True))  # type: ignore[arg-type]
    finally:
        client.close()

    def task_id(message: dict[str, Any]) -> str | None:
        return (message.get("headers") or {}).get("id")

    delivered = {}
    for tag, raw in unacked.items():
        found = task_id(json.loads(raw)[0])
        if found:
            moment = datetime.fromtimestamp(index.get(tag, 0.0), UTC)
            delivered[found] = Delivery(tag=tag.decode() if isinstance(tag, bytes) else tag, delivered_at=moment)
    return BrokerTasks(waiting={t for raw in waiting if (t := task_id(json.loads(raw)))}, delivered=delivered)


def forget_delivery(redis_url: str, delivery: Delivery) -> None:
    """Drop a delivery whose worker is gone, so that kombu does not hand it out again after the visibility timeout
    (the task is sent anew instead; were its worker alive after all, its acknowledgement finds nothing: harmless)."""
    client = redis.Redis.from_url(redis_url, socket_timeout=10, socket_connect_timeout=5)
    try:
        pipeline = client.pipeline()
        pipeline.hdel(UNACKED, delivery.tag)
        pipeline.zrem(UNACKED_INDEX, delivery.tag)
        pipeline.execute()
    finally:
        client.close()


def tasks_held_by_live_workers(celery: Celery, *, timeout_s: float) -> set[str]:
    """Ids of the tasks live workers report as running or reserved (a bounded broadcast; none answer: empty)."""
    inspector = celery.control.inspect(timeout=timeout_s)
    held: set[str] = set()
    for replies in (inspector.active(), inspector.reserved()):
        for requests in (replies or {}).values():
            held.update(request["id"] for request in requests)
    return held


@dataclass(frozen=True)
class TaskToSend:
    """A task an active job needs, with what the database knows of its run: `started` (a worker began it) and
    `last_sign_s` (when the run, or the job if it has not started, last showed life)."""

    name: str
    args: list[Any]
    task_id: str
    started: bool
    last_sign: datetime | None


def _latest(*moments: datetime | None) -> datetime | None:
    known = [as_utc(m) for m in moments if m is not None]
    return max(known) if known else None


def tasks_in_flight(session: Session, job: Job) -> list[TaskToSend]:
    """The tasks that must exist somewhere for this active job to progress, from what the database records."""
    chunks = list(
        session.scalars(
            select(JobChunk).where(JobChunk.job_id == job.id, JobChunk.phase == job.phase).order_by(JobChunk.index)
        )
    )
    job_sign = _latest(job.heartbeat_at, job.created_at)
    if job.state == "queued" or not chunks:
        running = job.state == "running"
        sign = as_utc(job.heartbeat_at) if running else as_utc(job.created_at)
        return [TaskToSend(job_kind(job.kind).task, [job.id], job.id, running, sign)]
    pending = [c for c in chunks if c.state != "done"]
    if pending:
        return [
            TaskToSend(
                CHUNK_TASK,
                [job.id, c.phase, c.index],
                chunk_task_id(job.id, c.phase, c.index),
                c.state == "running",
                as_utc(c.heartbeat_at) if c.state == "running" else job_sign,
            )
            for c in pending
        ]
    queued_at, beat = as_utc(job.merge_queued_at), as_utc(job.heartbeat_at)
    merging = queued_at is not None and beat is not None and beat >= queued_at  # run_merge beats as it starts
    return [TaskToSend(MERGE_TASK, [job.id, job.phase], merge_task_id(job.id, job.phase), merging, job_sign)]


def is_lost(
    task: TaskToSend, broker: BrokerTasks, *, now: datetime, lost_after_s: float, live: Callable[[], set[str]]
) -> bool:
    """Whether a task an active job needs exists nowhere any more. Waiting in a queue: not lost. Delivered but not
    started: lost only if no live worker (`live()`, asked only then) holds it after `lost_after_s` (its worker
    died with it reserved). Otherwise (started, or not in the broker): lost when its run, or the job, has shown
    no sign of life for `lost_after_s` (a run whose message Redis lost still finishes, and a message passing
    from the queue to a worker is briefly in neither place)."""
    limit = now - timedelta(seconds=lost_after_s)
    if task.task_id in broker.waiting:
        return False
    delivery = broker.delivered.get(task.task_id)
    if delivery is not None and not task.started:
        return delivery.delivered_at < limit and task.task_id not in live()
    return task.last_sign is None or task.last_sign < limit


def _recently_alive(session: Session, job: Job, now: datetime, lost_after_s: float) -> bool:
    beats = [as_utc(job.heartbeat_at)]
    beats += [as_utc(b) for b in session.scalars(select(JobChunk.heartbeat_at).where(JobChunk.job_id == job.id))]
    limit = now - timedelta(seconds=lost_after_s)
    return any(b is not None and b > limit for b in beats)


def reconcile(
    session: Session,
    celery: Celery,
    *,
    redis_url: str,
    queues: Iterable[str],
    lost_after_s: float,
    inspect_timeout_s: float = 1.0,
) -> list[str]:
    """Make the broker hold every task the database says an active job needs (at API start-up and then every
    FRINGELAB_RECONCILE_INTERVAL_S).

    Lost tasks (`is_lost`: Redis restarted without its append-only file, a whole worker died with the message)
    are sent again (every task is idempotent), or the job fails with the reason after MAX_REQUEUES. A cancelled
    job whose worker never confirmed is closed. Returns one line per action, also written to each job's log.
    """
    broker = broker_tasks(redis_url, queues)  # read the broker BEFORE the database: a task acked in between
    now = utcnow()  # has already written its final state, so it is not mistaken for a lost one
    actions: list[str] = []
    asked: list[set[str]] = []

    def live() -> set[str]:
        if not asked:
            asked.append(tasks_held_by_live_workers(celery, timeout_s=inspect_timeout_s))
        return asked[0]

    for job in session.scalars(select(Job).where(Job.state.in_(ACTIVE_STATES)).order_by(Job.created_at)).all():
        session.refresh(job)
        wanted = tasks_in_flight(session, job)
        lost = [t for t in wanted if is_lost(t, broker, now=now, lost_after_s=lost_after_s, live=live)]
        if not lost:
            continue
        if job.requeues >= MAX_REQUEUES:
            message = (
                f"the job queue lost this job {job.requeues + 1} times (a worker may be crashing on it, e.g. out "
                "of memory; see the worker log); retry it, with fewer frames per chunk if memory is short"
            )
            done = session.execute(
                update(Job)
                .where(Job.id == job.id, Job.state.in_(ACTIVE_STATES))
                .values(state="failed", error=message, finished_at=now)
            ).rowcount  # type: ignore[attr-defined]
            if done:
                add_log(session, job.id, message, level="error")
                actions.append(f"{job.id}: failed ({message})")
            session.commit()
            continue
        job.requeues += 1
        message = (
            f"the job queue no longer held this {job.state} job (Redis restarted without its data, or its worker "
            f"vanished); re-queued {len(lost)} task(s) (re-queue {job.requeues} of {MAX_REQUEUES})"
        )
        add_log(session, job.id, message, level="warning")
        session.commit()
        for task in lost:
            if task.task_id in broker.delivered:
                forget_delivery(redis_url, broker.delivered[task.task_id])
            celery.send_task(task.name, args=task.args, task_id=task.task_id, ignore_result=True)
        actions.append(f"{job.id}: {message}")
    stuck = select(Job).where(Job.state == "cancelled", Job.finished_at.is_(None))
    for job in session.scalars(stuck).all():
        if not _recently_alive(session, job, now, lost_after_s):
            _revoke(celery, job_task_ids(session, job), terminate=True)
            job.finished_at = now
            add_log(session, job.id, "closed the cancelled job: its worker is gone")
            actions.append(f"{job.id}: closed after cancel")
    session.commit()
    return actions


RECONCILE_LOCK = "fringelab:reconcile-lock"
RECONCILE_LOCK_S = 120  # longer than a reconciliation takes; a process that died holding it frees it by then


def reconcile_quietly(sessions: sessionmaker[Session], celery: Celery, settings: Settings) -> list[str]:
    """`reconcile` as the API runs it: a broker or database that is down is logged, not fatal (the health
    endpoint reports it, and the next round reconciles). One API process at a time (a lock in Redis): two
    processes reading the broker at once could both find a task lost and send it twice."""
    from fringelab.core.queue import QUEUE

    try:
        connection = redis.Redis.from_url(settings.redis_url, socket_timeout=5, socket_connect_timeout=5)
        lock = connection.lock(RECONCILE_LOCK, timeout=RECONCILE_LOCK_S, blocking=False)
        if not lock.acquire():
            connection.close()
            return []  # another API process is reconciling right now
        try:
            with sessions() as session:
                actions = reconcile(
                    session,
                    celery,
                    redis_url=settings.redis_url,
                    queues=[QUEUE],
                    lost_after_s=settings.worker_lost_after_s,
                    inspect_timeout_s=settings.health_worker_timeout_s,
                )
        finally:
            with contextlib.suppress(redis.RedisError):
                lock.release()
            connection.close()
    except (SQLAlchemyError, redis.RedisError, OperationalError, OSError) as error:
        log.warning("jobs not reconciled with the queue: %s", error)
        return []
    for action in actions:
        log.warning("reconciled job %s", action)
    return actions


def heartbeat_interval_s(settings: Settings) -> float:
    """How often a running task reports: often enough that `worker_lost_after_s` means a dead worker."""
    return min(10.0, settings.worker_lost_after_s / 6)


async def reconcile_periodically(sessions: sessionmaker[Session], celery: Celery, settings: Settings) -> None:
    """The API's sweep: `reconcile_quietly` every FRINGELAB_RECONCILE_INTERVAL_S, in a thread, until cancelled."""
    import anyio

    while True:
        await anyio.sleep(settings.reconcile_interval_s)
        await anyio.to_thread.run_sync(reconcile_quietly, sessions, celery, settings)


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
