"""Reconciling the database with the broker: the database says which tasks each active job needs; what the
broker no longer holds (Redis restarted without its data, a worker died with the message) is sent again, or the
job fails with the reason after MAX_REQUEUES; a recording or simulation whose check job so ended is failed with
it (`fringelab.core.upload_checks.settle_checks`). The API runs it at start-up and then every
FRINGELAB_RECONCILE_INTERVAL_S (`reconcile_periodically`).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

import redis
from celery import Celery
from kombu.exceptions import OperationalError
from sqlalchemy import select, update
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from fringelab.core.broker import (
    CHUNK_TASK,
    MERGE_TASK,
    BrokerTasks,
    broker_tasks,
    chunk_task_id,
    forget_delivery,
    job_task_ids,
    merge_task_id,
    revoke,
    tasks_held_by_live_workers,
)
from fringelab.core.job_kinds import job_kind
from fringelab.core.jobs import ACTIVE_STATES, add_log, as_utc
from fringelab.core.models import Job, JobChunk, utcnow
from fringelab.core.settings import Settings
from fringelab.core.upload_checks import settle_checks

MAX_REQUEUES = 3  # a job lost more often than this is failed instead of re-queued again
log = logging.getLogger(__name__)


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
            revoke(celery, job_task_ids(session, job), terminate=True)
            job.finished_at = now
            add_log(session, job.id, "closed the cancelled job: its worker is gone")
            actions.append(f"{job.id}: closed after cancel")
    session.commit()
    actions += settle_checks(session)  # a check job that ended without a word leaves no upload busy
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


async def reconcile_periodically(sessions: sessionmaker[Session], celery: Celery, settings: Settings) -> None:
    """The API's sweep: `reconcile_quietly` every FRINGELAB_RECONCILE_INTERVAL_S, in a thread, until cancelled."""
    import anyio

    while True:
        await anyio.sleep(settings.reconcile_interval_s)
        await anyio.to_thread.run_sync(reconcile_quietly, sessions, celery, settings)
