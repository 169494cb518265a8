"""A chunked phase: its frame ranges stored as `JobChunk` rows, claimed by one process each (an UPDATE only one
can win; a chunk whose process is gone is taken over at once, `_process_gone`, on the same machine, or once its
heartbeat is stale), marked done, and taken by the phase's merge in frame order, each as soon as it can
(`chunks_in_order`, `InOrder`); how a job's frames are split (`planned_frame_ranges`). See `worker.runner` for
how the entry, chunk and merge tasks use them, and `fringelab.core.jobs` for why the join is counted in the database.
"""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import psutil
import redis
from celery import Task, group
from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, sessionmaker

from fringelab.core.broker import (
    CHUNK_DONE_KEEP_S,
    CHUNK_TASK,
    MERGE_TASK,
    WORKER_SEND_RETRY,
    chunk_done_key,
    chunk_task_id,
    merge_task_id,
)
from fringelab.core.jobs import add_log, as_utc, heartbeat_interval_s
from fringelab.core.models import Job, JobChunk, utcnow
from fringelab.core.settings import Settings
from fringelab.science import Cancelled
from worker.context import (
    WORKER_NAME,
    Chunked,
    JobContext,
    confirm_cancel,
    heartbeats,
    job_spec,
    phase_done,
)
from worker.runtime import redis_of

log = logging.getLogger(__name__)

# A merge waiting for a chunk another process measures wakes when that chunk is done (`chunk_done_key`), or after
# MERGE_WAIT_S to look at the database anyway (a dead process's chunk, a cancel); MERGE_POLL_S while Redis is down.
MERGE_WAIT_S = 1


MERGE_POLL_S = 0.05


ChunkBody = Callable[[JobContext[Any], int, int], None]


# A merge gets each chunk's turn (`InOrder`) in frame order, as soon as that chunk can be taken.
MergeBody = Callable[[JobContext[Any], Iterator["InOrder"]], "dict[str, Any] | Chunked"]


def phase_chunks(session: Session, job_id: str, phase: int) -> list[JobChunk]:
    query = select(JobChunk).where(JobChunk.job_id == job_id, JobChunk.phase == phase).order_by(JobChunk.index)
    return list(session.scalars(query))


def start_phase(task: Task, sessions: sessionmaker[Session], job_id: str, plan: Chunked, *, phase: int) -> None:
    """Store the phase's chunk rows and make it the job's phase (once: a second run keeps the first plan), then
    send a task per unfinished chunk."""
    if not plan.frame_ranges:
        raise ValueError("a chunked phase needs at least one frame range")
    with sessions() as session:
        if not phase_chunks(session, job_id, phase):
            session.add_all(
                JobChunk(job_id=job_id, phase=phase, index=i, first_frame=first, stop_frame=stop)
                for i, (first, stop) in enumerate(plan.frame_ranges)
            )
            job = session.get(Job, job_id)
            assert job is not None  # checked by the caller; the row is never deleted while its task runs
            job.phase, job.merge_queued_at = phase, None
            job.progress_done = 0
            job.progress_total = sum(stop - first for first, stop in plan.frame_ranges)
            job.stage, job.stage_started_at = plan.stage, utcnow()
            longest = max(stop - first for first, stop in plan.frame_ranges)
            add_log(session, job_id, f"{plan.stage}: {len(plan.frame_ranges)} chunk(s) of up to {longest} frames")
            try:
                session.commit()
            except IntegrityError:  # a second delivery of this task planned them a moment ago: keep those
                session.rollback()
    send_pending(task, sessions, job_id, phase)


def send_pending(task: Task, sessions: sessionmaker[Session], job_id: str, phase: int) -> None:
    """Send the phase's merge (once), then the tasks of its unfinished chunks (a Celery group over every worker)."""
    send_merge_once(task, sessions, job_id, phase)
    with sessions() as session:
        pending = [c.index for c in phase_chunks(session, job_id, phase) if c.state != "done"]
    if not pending:
        return
    signatures = [
        task.app.signature(CHUNK_TASK, args=[job_id, phase, index]).set(task_id=chunk_task_id(job_id, phase, index))
        for index in pending
    ]
    group(signatures).apply_async(retry=True, retry_policy=WORKER_SEND_RETRY)


def claim_next(
    sessions: sessionmaker[Session],
    settings: Settings,
    job_id: str,
    phase: int,
    worker: str,
    *,
    wanted: int | None,
    takeable: Callable[[JobChunk], bool],
) -> tuple[JobContext, int, int] | None:
    """Claim chunk `wanted` if it can be taken, else the first of the phase that can: its context and frames
    [first, stop). None when none can, or the job no longer runs this phase."""
    with sessions() as session:
        job = session.get(Job, job_id)
        if job is None or job.state != "running" or job.phase != phase:
            confirm_cancel(sessions, job)
            return None
        chunks = phase_chunks(session, job_id, phase)
        for chunk in sorted(chunks, key=lambda c: c.index != wanted):  # `wanted` first, then in order
            if takeable(chunk) and _claim(session, chunk, worker):
                context = JobContext(
                    job_id=job_id, spec=job_spec(job), settings=settings, sessions=sessions, chunk=(phase, chunk.index)
                )
                return context, chunk.first_frame, chunk.stop_frame
    return None


def announce_done(task: Task, job_id: str, phase: int, index: int) -> None:
    """Wake the phase's merge if it waits for this chunk (best effort: it looks at the database anyway)."""
    try:
        client, key = redis_of(task.app), chunk_done_key(job_id, phase)
        pipe = client.pipeline()
        pipe.lpush(key, index)
        pipe.expire(key, CHUNK_DONE_KEEP_S)
        pipe.execute()
    except redis.RedisError as error:
        log.warning("chunk %s:%s:%s done, but its merge could not be told (%s); it finds out by itself", job_id,
                    phase, index, error)  # fmt: skip


def wait_for_a_chunk(task: Task, job_id: str, phase: int) -> None:
    """Until a chunk task announces a chunk done (`announce_done`), at most MERGE_WAIT_S."""
    try:
        redis_of(task.app).blpop([chunk_done_key(job_id, phase)], timeout=MERGE_WAIT_S)
    except redis.RedisError:
        time.sleep(MERGE_POLL_S)


def _process_gone(chunk: JobChunk) -> bool | None:
    """Whether the process running the chunk has ended, where that can be told: on this machine (the host of its
    worker's name, `worker_name`, is this one), True when its PID is gone (or a zombie), else False. None for a
    process elsewhere: its heartbeat decides (`chunk_takeable`). A PID taken again by another process reads as alive:
    the heartbeat decides then too."""
    match = WORKER_NAME.match(chunk.worker or "")
    if match is None or match["host"] != socket.gethostname():
        return None
    try:
        return psutil.Process(int(match["pid"])).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def chunk_takeable(chunk: JobChunk, settings: Settings, *, orphaned: Callable[[JobChunk], bool]) -> bool:
    """Whether a process may run this chunk now: nobody has started it, or its run died: its process is gone
    (`_process_gone`, on this machine), or, for a process elsewhere, the caller knows it died (`orphaned`), or it
    has sent no heartbeat for FRINGELAB_WORKER_LOST_AFTER_S."""
    if chunk.state == "pending":
        return True
    if chunk.state != "running":
        return False
    beat = as_utc(chunk.heartbeat_at)
    if beat is None or (utcnow() - beat).total_seconds() > settings.worker_lost_after_s:
        return True  # stale: no need to look for its process
    gone = _process_gone(chunk)
    return bool(gone) or (gone is None and orphaned(chunk))


def _claim(session: Session, chunk: JobChunk, worker: str) -> bool:
    """Mark the chunk running on `worker`, if nobody changed it since it was read (of two claims, one wins)."""
    moment = utcnow()
    claimed = session.execute(
        update(JobChunk)
        .where(JobChunk.job_id == chunk.job_id, JobChunk.phase == chunk.phase, JobChunk.index == chunk.index)
        .where(JobChunk.state == chunk.state, JobChunk.worker == chunk.worker)
        .values(state="running", worker=worker, started_at=moment, heartbeat_at=moment, done=0)
    ).rowcount  # type: ignore[attr-defined]
    session.commit()
    return bool(claimed)


def mark_done(sessions: sessionmaker[Session], job_id: str, phase: int, index: int, frames: int) -> None:
    with sessions() as session:
        session.execute(
            update(JobChunk)
            .where(JobChunk.job_id == job_id, JobChunk.phase == phase, JobChunk.index == index)
            .where(JobChunk.state != "done")
            .values(state="done", done=frames, finished_at=utcnow())
        )
        session.flush()
        job = session.get(Job, job_id)
        if job is not None:
            job.progress_done = phase_done(session, job_id, phase)
        session.commit()


def after_chunk(task: Task, sessions: sessionmaker[Session], job_id: str, phase: int) -> None:
    with sessions() as session:
        left = session.scalar(
            select(func.count()).where(JobChunk.job_id == job_id, JobChunk.phase == phase, JobChunk.state != "done")
        )
    if not left:
        send_merge_once(task, sessions, job_id, phase)


def send_merge_once(task: Task, sessions: sessionmaker[Session], job_id: str, phase: int) -> None:
    """Send the phase's merge task, once: whoever claims `merge_queued_at` sends it (the phase's start; a chunk
    that ends the phase, if that send failed)."""
    with sessions() as session:
        claimed = session.execute(
            update(Job)
            .where(Job.id == job_id, Job.state == "running", Job.phase == phase, Job.merge_queued_at.is_(None))
            .values(merge_queued_at=utcnow())
        ).rowcount  # type: ignore[attr-defined]
        session.commit()
    if not claimed:
        return
    try:
        task.app.send_task(
            MERGE_TASK,
            args=[job_id, phase],
            task_id=merge_task_id(job_id, phase),
            ignore_result=True,
            retry=True,
            retry_policy=WORKER_SEND_RETRY,
        )
    except Exception:  # give the claim back, so that a redelivered chunk or the reconciliation sends it
        with sessions() as session:
            session.execute(update(Job).where(Job.id == job_id, Job.phase == phase).values(merge_queued_at=None))
            session.commit()
        raise


@dataclass(frozen=True)
class InOrder:
    """A chunk's turn in a merge's pass in frame order: frames [first, stop). `measure_here` is the chunk's own
    context when nobody has measured it yet: the merge measures it itself, now, straight into its output (no
    hand-over; the progress and heartbeat are the chunk's); otherwise its hand-over is ready to read."""

    first: int
    stop: int
    measure_here: JobContext | None = None


def chunks_in_order(
    context: JobContext,
    phase: int,
    chunk_body: ChunkBody,
    *,
    worker: str,
    dead_merge: str | None,
    wait: Callable[[], None],
    hold_steals: bool,
) -> Iterator[InOrder]:
    """The phase's chunks in frame order, each as soon as it can be taken: done elsewhere (read its hand-over), or
    the next one is nobody's (claimed and measured by the merge in its turn). While another process measures the
    next one, this process measures a later chunk nobody runs (through `chunk_body`, handed over, `hold_steals`: kept
    in this process), else `wait`s
    (until a chunk task says it is done). `chunk_takeable` decides what nobody runs. Raises Cancelled when the job stops
    running."""
    job_id, settings, sessions = context.job_id, context.settings, context.sessions
    interval_s = heartbeat_interval_s(settings)

    def takeable(chunk: JobChunk) -> bool:
        return chunk_takeable(chunk, settings, orphaned=lambda c: c.worker == dead_merge)

    def chunk_context(index: int, *, hold: bool = False) -> JobContext:
        return JobContext(
            job_id=job_id, spec=context.spec, settings=settings, sessions=sessions, chunk=(phase, index), hold=hold
        )

    given = 0  # chunks handed to the merge so far
    while True:
        with sessions() as session:
            if session.scalar(select(Job.state).where(Job.id == job_id)) != "running":
                raise Cancelled("the job was cancelled")
            chunks = phase_chunks(session, job_id, phase)
            if given == len(chunks):
                return
            ready = []
            for chunk in chunks[given:]:
                if chunk.state != "done":
                    break
                ready.append(InOrder(chunk.first_frame, chunk.stop_frame))
            ahead = chunks[given + len(ready) :]
            here = next((c for c in ahead[:1] if takeable(c) and _claim(session, c, worker)), None)
            later = None
            if here is None and not ready:
                later = next((c for c in ahead[1:] if takeable(c) and _claim(session, c, worker)), None)
            here_range = None if here is None else (here.index, here.first_frame, here.stop_frame)
            later_range = None if later is None else (later.index, later.first_frame, later.stop_frame)
        yield from ready
        given += len(ready)
        if here_range is not None:
            index, first, stop = here_range
            with heartbeats(sessions, job_id, (phase, index), interval_s=interval_s):
                yield InOrder(first, stop, measure_here=chunk_context(index))
            mark_done(sessions, job_id, phase, index, stop - first)
            given += 1
        elif later_range is not None:
            index, first, stop = later_range
            with heartbeats(sessions, job_id, (phase, index), interval_s=interval_s):
                chunk_body(chunk_context(index, hold=hold_steals), first, stop)
            mark_done(sessions, job_id, phase, index, stop - first)
        elif not ready:
            wait()


def handed_over(turns: Iterator[InOrder], chunk_body: ChunkBody) -> list[tuple[int, int]]:
    """For a merge that reads every chunk's hand-over: the chunks the merge measures itself are measured through
    `chunk_body` (handed over like the others); their frame ranges in order."""
    ranges = []
    for turn in turns:
        if turn.measure_here is not None:
            chunk_body(turn.measure_here, turn.first, turn.stop)
        ranges.append((turn.first, turn.stop))
    return ranges


def frame_ranges(count: int, chunk_frames: int) -> list[tuple[int, int]]:
    """Split positions `0..count-1` into consecutive `[first, stop)` ranges of at most `chunk_frames`."""
    if count < 1 or chunk_frames < 1:
        raise ValueError(f"need at least one frame and one frame per chunk, got {count} and {chunk_frames}")
    return [(first, min(first + chunk_frames, count)) for first in range(0, count, chunk_frames)]


# A job that names no chunk size is split by guided self-scheduling (Polychronopoulos & Kuck, IEEE Trans. Comput.
# 1987): each chunk takes 1/GUIDED_PARTS of the frames still left, at most FRINGELAB_CHUNK_FRAMES and at least
# MIN_CHUNK_FRAMES. The chunks shrink towards the end, so the worker processes run out of work at nearly the same
# time and the merge's pass in frame order has only a short chunk left to write after the last one is measured;
# each chunk costs a task, its inputs, its hand-over and the merge's turn (~10-20 ms), so they are not made smaller
# than that: at 160 frames of 512 x 480, chunks of at least 5 frames (18 chunks) gave 73 frames/s with 2 worker
# processes, at least 10 (13 chunks) 87, 8 chunks of 20 81 (bench/bench_jobs.py, medians of 3 rounds).
GUIDED_PARTS = 8


MIN_CHUNK_FRAMES = 10


def guided_frame_ranges(count: int, *, most: int, least: int = MIN_CHUNK_FRAMES) -> list[tuple[int, int]]:
    """Split positions `0..count-1` into consecutive ranges, each of 1/GUIDED_PARTS of those left, clipped to
    [least, most] frames (the last one may be shorter)."""
    if count < 1 or most < 1:
        raise ValueError(f"need at least one frame and one frame per chunk, got {count} and {most}")
    ranges, first = [], 0
    while first < count:
        size = min(most, max(least, -(-(count - first) // GUIDED_PARTS)))
        ranges.append((first, min(first + size, count)))
        first += size
    return ranges


def planned_frame_ranges(count: int, chunk_frames: int | None, settings: Settings) -> list[tuple[int, int]]:
    """The chunks of a job of `count` frames: of the job's own `chunk_frames` when it names one, else guided
    (`guided_frame_ranges`, at most FRINGELAB_CHUNK_FRAMES)."""
    if chunk_frames:
        return frame_ranges(count, chunk_frames)
    return guided_frame_ranges(count, most=int(settings.chunk_frames))
