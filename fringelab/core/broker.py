"""What fringelab says to the broker (Redis, through Celery and kombu) and reads from it.

What belongs here: the names of the tasks that are not a job kind's (a kind's task is named by its entry in
`fringelab.core.job_kinds`), the ids of a job's tasks, the key a chunk announces itself done under, how workers
retry a send, revoking tasks, and reading kombu's Redis layout (what waits in a queue, what a worker holds
unacknowledged). No job state changes here: that is `fringelab.core.jobs` (creating, cancelling, retrying) and
`fringelab.core.reconcile` (making the broker hold what the database says).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import redis
from celery import Celery
from kombu.exceptions import OperationalError
from sqlalchemy import select
from sqlalchemy.orm import Session

from fringelab.core.models import Job, JobChunk

CHUNK_TASK = "fringelab.job_chunk"
MERGE_TASK = "fringelab.job_merge"
DEMO_TASK = "fringelab.demo"  # makes an experiment from a virtual test; its jobs are ordinary jobs
DEMO_ADVANCE_TASK = "fringelab.demo_advance"
PING_TASK = "fringelab.ping"

# How workers send the tasks that continue a job (chunks, merge): while Redis restarts they wait for it, up to
# about two minutes, rather than drop the job's next step. The API does not wait: it answers 503 at once.
WORKER_SEND_RETRY = {"max_retries": 60, "interval_start": 0.5, "interval_step": 0.5, "interval_max": 2.0}


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


def job_task_ids(session: Session, job: Job) -> list[str]:
    """Every Celery task id this job may have in flight: its entry task, its chunks and its merge."""
    chunks = session.execute(select(JobChunk.phase, JobChunk.index).where(JobChunk.job_id == job.id)).all()
    merges = [merge_task_id(job.id, phase) for phase in range(job.phase + 1)]
    return [job.id, *(chunk_task_id(job.id, phase, index) for phase, index in chunks), *merges]


def revoke(celery: Celery, task_ids: list[str], *, terminate: bool) -> str:
    try:
        celery.control.revoke(task_ids, terminate=terminate, signal="SIGTERM")
    except (OperationalError, redis.RedisError, OSError) as error:
        return f"; the queue could not be told ({error}), so waiting tasks are skipped when a worker takes them"
    return ""


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
