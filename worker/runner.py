"""Running a job inside a Celery task: state transitions, progress, heartbeats, cancel, errors and chunks.

A task body receives a `JobContext` and returns either the job's result (a JSON-able dict: the job succeeds) or
a `Chunked` plan: the job goes on as one chunk task per frame range on any worker, and a merge task, sent with
them, that takes the chunks in frame order, each as soon as it can (`_chunks_in_order`, `InOrder`), and ends the
job or plans the next such phase (see `fringelab.core.jobs` for why the join is counted in the database). When
the next chunk in order is nobody's, the merge claims it and measures it in its turn, straight into its output
(no hand-over); while another process measures the next one, the merge measures a later chunk nobody has started
(handed over), else waits. A chunk task goes on from its chunk to the next one nobody has started, so the other
processes do not go back to the queue between chunks. So the pass in frame order overlaps the chunks instead of
following them, no process idles while there is work, one worker process runs a whole phase inside its merge, and
the merge never waits for a chunk that needs its own slot. A claim is an UPDATE on the chunk's row that only one
process can win; a chunk whose process is gone is taken over at once (`_process_gone`: on the same machine) or
once its heartbeat is stale. Everything a person must act on (ValueError, MeasurementError) becomes the job's
error text; anything else is an internal error whose traceback goes to the worker log. Acks-late work can run
twice: a job that already finished is not run again, and only one run can finish it
(`UPDATE ... WHERE finished_at IS NULL`).

What does not belong here: what a job computes (worker/jobs/) and how the API reports it.
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np
import psutil
import redis
from celery import Task, group
from pydantic import BaseModel, ValidationError
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
from fringelab.core.job_kinds import spec_of
from fringelab.core.jobs import FINAL_STATES, add_log, as_utc, heartbeat_interval_s
from fringelab.core.models import Job, JobChunk, utcnow
from fringelab.core.settings import Settings
from fringelab.core.text import public_text
from fringelab.formats.atomic import atomic_path
from fringelab.science import Cancelled, MeasurementError
from worker.runtime import job_dir, redis_of, sessions_of, settings_of

log = logging.getLogger(__name__)
PROGRESS_INTERVAL_S = 0.5
# A merge waiting for a chunk another process measures wakes when that chunk is done (`chunk_done_key`), or after
# MERGE_WAIT_S to look at the database anyway (a dead process's chunk, a cancel); MERGE_POLL_S while Redis is down.
MERGE_WAIT_S = 1
MERGE_POLL_S = 0.05


@dataclass(frozen=True)
class Chunked:
    """A job body's answer "split me": frame ranges `[first, stop)` to run in parallel, then a merge."""

    frame_ranges: list[tuple[int, int]]
    stage: str


Spec = TypeVar("Spec", bound=BaseModel)


@dataclass
class JobContext(Generic[Spec]):
    """What a job body runs with: its job's id, its spec (the kind's model, parsed from the stored JSON when the
    task loaded the job), the settings and database sessions of this process."""

    job_id: str
    spec: Spec
    settings: Settings
    sessions: sessionmaker[Session]
    chunk: tuple[int, int] | None = None  # (phase, index) of the chunk this context runs, if any
    # Hand-overs this context writes stay in this process (`array_records`): a merge's own later chunk, which only
    # that merge reads (a merge that runs again after its process died measures it again: `run_merge` hold_steals).
    hold: bool = False
    files: dict[str, str] = field(default_factory=dict)  # name -> media type, of the files this run published
    provenance: dict[str, Any] = field(default_factory=dict)  # added to the job's provenance when it succeeds
    _last_progress: float = field(default=0.0)
    _stage: str = field(default="")

    @property
    def directory(self) -> Path:
        """The job's own result directory under the data directory (one per job id, so no two jobs collide)."""
        return job_dir(self.settings, self.job_id)

    def progress(self, done: int, total: int, stage: str = "") -> None:
        """Record progress (throttled; a stage change and the last frame are always written) and raise
        Cancelled here if the job was cancelled."""
        now = time.monotonic()
        new_stage = bool(stage) and stage != self._stage
        if not new_stage and done < total and now - self._last_progress < PROGRESS_INTERVAL_S:
            return
        self._last_progress = now
        with self.sessions() as session:
            job = session.get(Job, self.job_id)
            if job is None or job.state != "running":
                raise Cancelled("the job was cancelled" if job is None or job.state == "cancelled" else job.state)
            moment = utcnow()
            if self.chunk is None:
                job.progress_done, job.progress_total = done, total
            else:
                phase, index = self.chunk
                session.execute(
                    update(JobChunk)
                    .where(JobChunk.job_id == self.job_id, JobChunk.phase == phase, JobChunk.index == index)
                    .values(done=done, heartbeat_at=moment)
                )
                session.flush()
                job.progress_done = _phase_done(session, self.job_id, phase)
            if new_stage and stage != job.stage:
                job.stage, job.stage_started_at = stage, moment
            job.heartbeat_at = moment
            session.commit()
        if stage:
            self._stage = stage

    def should_cancel(self) -> bool:
        with self.sessions() as session:
            job = session.get(Job, self.job_id)
            return job is None or job.state != "running"

    def log(self, message: str, *, level: str = "info") -> None:
        """A line for the job's log, which users read through the API."""
        with self.sessions() as session:
            add_log(session, self.job_id, message, level=level)
            session.commit()

    @contextmanager
    def output(
        self, name: str, *, media_type: str = "application/octet-stream", publish: bool = True
    ) -> Iterator[Path]:
        """Write a file atomically: yields a temporary path in the job directory; on success it is renamed to
        `name`, so readers and a second run of the task see the old complete file or the new one, never a part.
        Published files are listed on the job (size, SHA-256) when it succeeds."""
        with atomic_path(self.directory / name) as partial:
            yield partial
        if publish:
            self.files[name] = media_type


JobBody = Callable[[JobContext[Any]], "dict[str, Any] | Chunked"]
ChunkBody = Callable[[JobContext[Any], int, int], None]
# A merge gets each chunk's turn (`InOrder`) in frame order, as soon as that chunk can be taken.
MergeBody = Callable[[JobContext[Any], Iterator["InOrder"]], "dict[str, Any] | Chunked"]


def _spec(job: Job) -> BaseModel:
    """The job's spec model from its stored JSON (`fringelab.core.job_kinds.spec_of`); a spec that no longer
    reads (stored by another version of fringelab) is a ValueError whose text says what to do."""
    try:
        return spec_of(job.kind, job.spec)
    except ValidationError as error:
        raise ValueError(
            f"the spec of this {job.kind} job no longer reads ({error.error_count()} error(s): "
            f"{error.errors()[0]['msg']}); start a new job"
        ) from None


def _worker_name(task: Task) -> str:
    return f"{task.request.hostname or socket.gethostname()} (pid {os.getpid()})"


_WORKER_NAME = re.compile(r"^(?:[^@]*@)?(?P<host>.+) \(pid (?P<pid>\d+)\)$")  # a `_worker_name`: node@host (pid N)


@contextmanager
def _heartbeat(
    sessions: sessionmaker[Session], job_id: str, chunk: tuple[int, int] | None, *, interval_s: float
) -> Iterator[None]:
    """Write `heartbeat_at` every `interval_s` while the body runs, so reconciliation can tell a long frame from
    a dead worker."""
    stop = threading.Event()

    def beat() -> None:
        while not stop.wait(interval_s):
            try:
                with sessions() as session:
                    moment = utcnow()
                    session.execute(update(Job).where(Job.id == job_id).values(heartbeat_at=moment))
                    if chunk is not None:
                        session.execute(
                            update(JobChunk)
                            .where(JobChunk.job_id == job_id, JobChunk.phase == chunk[0], JobChunk.index == chunk[1])
                            .values(heartbeat_at=moment)
                        )
                    session.commit()
            except Exception:  # a missed beat is harmless; the next one retries
                log.warning("heartbeat of job %s failed", job_id, exc_info=True)

    thread = threading.Thread(target=beat, name=f"heartbeat-{job_id}", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


def _run_guarded(context: JobContext, step: Callable[[], Any]) -> tuple[bool, Any]:
    """Run one step of a job; turn its errors into the job's end. (True, value) when it returned normally."""
    sessions, job_id = context.sessions, context.job_id
    try:
        with _heartbeat(sessions, job_id, context.chunk, interval_s=heartbeat_interval_s(context.settings)):
            return True, step()
    except Cancelled:
        finish(sessions, job_id, state="cancelled")
    except (ValueError, MeasurementError) as error:
        finish(sessions, job_id, state="failed", error=str(error))
    except Exception as error:
        log.exception("job %s failed", job_id)
        finish(
            sessions,
            job_id,
            state="failed",
            error=f"internal error ({type(error).__name__}: {error}); retry it, and report it if it fails again",
        )
    return False, None


def run_job(task: Task, job_id: str, body: JobBody) -> dict[str, Any]:
    """The entry task of a job (task id = job id): mark it running, run `body`, and end it or split it."""
    sessions = sessions_of(task.app)
    worker = _worker_name(task)
    with sessions() as session:
        job = session.get(Job, job_id)
        if job is None:
            log.warning("job %s has no record; nothing to do", job_id)
            return {}
        if job.state in FINAL_STATES:  # a redelivered task whose job already ended
            _confirm_cancel(sessions, job)
            return dict(job.result)
        again = job.state == "running"
        moment = utcnow()
        job.state = "running"
        job.started_at = job.started_at or moment
        job.stage_started_at = moment
        job.heartbeat_at = moment
        job.worker = worker
        job.error = ""
        try:
            spec, unread = _spec(job), ""
        except ValueError as error:
            spec, unread = None, str(error)
        add_log(session, job_id, f"{'restarted' if again else 'started'} on {worker}")
        session.commit()
    if spec is None:
        finish(sessions, job_id, state="failed", error=unread)
        return {}
    context = JobContext(job_id=job_id, spec=spec, settings=settings_of(task.app), sessions=sessions)
    ok, outcome = _run_guarded(context, lambda: body(context))
    if not ok:
        return {}
    if isinstance(outcome, Chunked):
        _start_phase(task, sessions, job_id, outcome, phase=0)
        return {}
    finish(sessions, job_id, state="succeeded", result=outcome, context=context)
    return dict(outcome)


def _phase_chunks(session: Session, job_id: str, phase: int) -> list[JobChunk]:
    query = select(JobChunk).where(JobChunk.job_id == job_id, JobChunk.phase == phase).order_by(JobChunk.index)
    return list(session.scalars(query))


def _start_phase(task: Task, sessions: sessionmaker[Session], job_id: str, plan: Chunked, *, phase: int) -> None:
    """Store the phase's chunk rows and make it the job's phase (once: a second run keeps the first plan), then
    send a task per unfinished chunk."""
    if not plan.frame_ranges:
        raise ValueError("a chunked phase needs at least one frame range")
    with sessions() as session:
        if not _phase_chunks(session, job_id, phase):
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
    _send_pending(task, sessions, job_id, phase)


def _send_pending(task: Task, sessions: sessionmaker[Session], job_id: str, phase: int) -> None:
    """Send the phase's merge (once), then the tasks of its unfinished chunks (a Celery group over every worker)."""
    _send_merge_once(task, sessions, job_id, phase)
    with sessions() as session:
        pending = [c.index for c in _phase_chunks(session, job_id, phase) if c.state != "done"]
    if not pending:
        return
    signatures = [
        task.app.signature(CHUNK_TASK, args=[job_id, phase, index]).set(task_id=chunk_task_id(job_id, phase, index))
        for index in pending
    ]
    group(signatures).apply_async(retry=True, retry_policy=WORKER_SEND_RETRY)


def run_chunk(task: Task, job_id: str, phase: int, index: int, body: ChunkBody) -> None:
    """This task's chunk, then every chunk of the phase that nobody has started, lowest first, until none is left:
    the process goes on without a round trip through the queue per chunk (the tasks of the chunks it took find them
    taken and end at once). A chunk whose process died is taken over (`_takeable`); a redelivered task (its earlier
    run died with its process) takes its own chunk over too, unless a live process on this machine runs it (one
    that took it over first)."""
    sessions, settings = sessions_of(task.app), settings_of(task.app)
    redelivered = bool((task.request.delivery_info or {}).get("redelivered"))
    worker = _worker_name(task)

    def takeable(chunk: JobChunk) -> bool:
        return _takeable(chunk, settings, orphaned=lambda c: redelivered and c.index == index)

    wanted: int | None = index
    while claimed := _claim_next(sessions, settings, job_id, phase, worker, wanted=wanted, takeable=takeable):
        context, first, stop = claimed
        ok, _ = _run_guarded(context, partial(body, context, first, stop))
        if not ok:
            return
        assert context.chunk is not None
        _mark_done(sessions, job_id, phase, context.chunk[1], stop - first)
        _announce_done(task, job_id, phase, context.chunk[1])
        wanted = None
    _after_chunk(task, sessions, job_id, phase)


def _claim_next(
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
            _confirm_cancel(sessions, job)
            return None
        chunks = _phase_chunks(session, job_id, phase)
        for chunk in sorted(chunks, key=lambda c: c.index != wanted):  # `wanted` first, then in order
            if takeable(chunk) and _claim(session, chunk, worker):
                context = JobContext(
                    job_id=job_id, spec=_spec(job), settings=settings, sessions=sessions, chunk=(phase, chunk.index)
                )
                return context, chunk.first_frame, chunk.stop_frame
    return None


def _announce_done(task: Task, job_id: str, phase: int, index: int) -> None:
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


def _wait_for_a_chunk(task: Task, job_id: str, phase: int) -> None:
    """Until a chunk task announces a chunk done (`_announce_done`), at most MERGE_WAIT_S."""
    try:
        redis_of(task.app).blpop([chunk_done_key(job_id, phase)], timeout=MERGE_WAIT_S)
    except redis.RedisError:
        time.sleep(MERGE_POLL_S)


def _process_gone(chunk: JobChunk) -> bool | None:
    """Whether the process running the chunk has ended, where that can be told: on this machine (the host of its
    worker's name, `_worker_name`, is this one), True when its PID is gone (or a zombie), else False. None for a
    process elsewhere: its heartbeat decides (`_takeable`). A PID taken again by another process reads as alive:
    the heartbeat decides then too."""
    match = _WORKER_NAME.match(chunk.worker or "")
    if match is None or match["host"] != socket.gethostname():
        return None
    try:
        return psutil.Process(int(match["pid"])).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def _takeable(chunk: JobChunk, settings: Settings, *, orphaned: Callable[[JobChunk], bool]) -> bool:
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


def _mark_done(sessions: sessionmaker[Session], job_id: str, phase: int, index: int, frames: int) -> None:
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
            job.progress_done = _phase_done(session, job_id, phase)
        session.commit()


def _phase_done(session: Session, job_id: str, phase: int) -> int:
    done = select(func.sum(JobChunk.done)).where(JobChunk.job_id == job_id, JobChunk.phase == phase)
    return int(session.scalar(done) or 0)


def _after_chunk(task: Task, sessions: sessionmaker[Session], job_id: str, phase: int) -> None:
    with sessions() as session:
        left = session.scalar(
            select(func.count()).where(JobChunk.job_id == job_id, JobChunk.phase == phase, JobChunk.state != "done")
        )
    if not left:
        _send_merge_once(task, sessions, job_id, phase)


def _send_merge_once(task: Task, sessions: sessionmaker[Session], job_id: str, phase: int) -> None:
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


def run_merge(
    task: Task, job_id: str, phase: int, body: MergeBody, chunk_body: ChunkBody, *, hold_steals: bool = False
) -> dict[str, Any]:
    """The in-order pass of a phase over its chunks' turns (`_chunks_in_order`: measured here when nobody has
    started them, `chunk_body` for a later chunk measured while waiting), which ends the job (a result) or starts
    the next phase (a `Chunked` plan). hold_steals: the later chunks this merge measures stay in its process (no
    file, no fsync, no reading back from disk); only for a body that measures a done chunk again when its hand-over
    is gone (a merge that runs again after its process died)."""
    sessions = sessions_of(task.app)
    redelivered = bool((task.request.delivery_info or {}).get("redelivered"))
    with sessions() as session:
        job = session.get(Job, job_id)
        if job is None or job.state != "running":
            _confirm_cancel(sessions, job)
            return dict(job.result) if job else {}
        if job.phase != phase:  # redelivered after it started the next phase: make sure that one is under way
            session.close()
            if job.phase == phase + 1:
                _send_pending(task, sessions, job_id, phase + 1)
            return {}
        # A redelivered merge's earlier run died with its process, and with it the chunks that run was computing.
        dead_merge = job.worker if redelivered else None
        spec = _spec(job)
        if dead_merge is not None:
            add_log(
                session, job_id, f"the pass in frame order starts again on {_worker_name(task)} ({dead_merge} was lost)"
            )
        job.worker = _worker_name(task)
        job.heartbeat_at = utcnow()  # after merge_queued_at: tells reconciliation that the merge has started
        session.commit()
    context = JobContext(job_id=job_id, spec=spec, settings=settings_of(task.app), sessions=sessions)
    turns = _chunks_in_order(context, phase, chunk_body, worker=_worker_name(task), dead_merge=dead_merge,
                             wait=lambda: _wait_for_a_chunk(task, job_id, phase), hold_steals=hold_steals)  # fmt: skip
    try:
        ok, outcome = _run_guarded(context, lambda: body(context, turns))
    finally:
        _drop_held(job_id)
    if not ok:
        return {}
    if isinstance(outcome, Chunked):
        _start_phase(task, sessions, job_id, outcome, phase=phase + 1)
        return {}
    finish(sessions, job_id, state="succeeded", result=outcome, context=context)
    _remove_chunk_files(context.directory)  # after the job's end: a merge that runs again needs them until then
    return dict(outcome)


@dataclass(frozen=True)
class InOrder:
    """A chunk's turn in a merge's pass in frame order: frames [first, stop). `measure_here` is the chunk's own
    context when nobody has measured it yet: the merge measures it itself, now, straight into its output (no
    hand-over; the progress and heartbeat are the chunk's); otherwise its hand-over is ready to read."""

    first: int
    stop: int
    measure_here: JobContext | None = None


def _chunks_in_order(
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
    (until a chunk task says it is done). `_takeable` decides what nobody runs. Raises Cancelled when the job stops
    running."""
    job_id, settings, sessions = context.job_id, context.settings, context.sessions
    interval_s = heartbeat_interval_s(settings)

    def takeable(chunk: JobChunk) -> bool:
        return _takeable(chunk, settings, orphaned=lambda c: c.worker == dead_merge)

    def chunk_context(index: int, *, hold: bool = False) -> JobContext:
        return JobContext(
            job_id=job_id, spec=context.spec, settings=settings, sessions=sessions, chunk=(phase, index), hold=hold
        )

    given = 0  # chunks handed to the merge so far
    while True:
        with sessions() as session:
            if session.scalar(select(Job.state).where(Job.id == job_id)) != "running":
                raise Cancelled("the job was cancelled")
            chunks = _phase_chunks(session, job_id, phase)
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
            with _heartbeat(sessions, job_id, (phase, index), interval_s=interval_s):
                yield InOrder(first, stop, measure_here=chunk_context(index))
            _mark_done(sessions, job_id, phase, index, stop - first)
            given += 1
        elif later_range is not None:
            index, first, stop = later_range
            with _heartbeat(sessions, job_id, (phase, index), interval_s=interval_s):
                chunk_body(chunk_context(index, hold=hold_steals), first, stop)
            _mark_done(sessions, job_id, phase, index, stop - first)
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


def _confirm_cancel(sessions: sessionmaker[Session], job: Job | None) -> None:
    """A task of a cancelled job that has not stopped yet reached a worker: it stops here, so say so."""
    if job is not None and job.state == "cancelled" and job.finished_at is None:
        finish(sessions, job.id, state="cancelled")


def _file_entry(context: JobContext, name: str, media_type: str) -> dict[str, Any]:
    path = context.directory / name
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    relative = path.relative_to(context.settings.data_path)
    return {
        "name": name,
        "path": str(relative),
        "size_bytes": path.stat().st_size,
        "sha256": digest.hexdigest(),
        "media_type": media_type,
    }


def finish(
    sessions: sessionmaker[Session],
    job_id: str,
    *,
    state: str,
    error: str = "",
    result: dict[str, Any] | None = None,
    context: JobContext | None = None,
) -> bool:
    """End the job, once. A cancel that came first wins over success or failure. True if this call ended it."""
    error = public_text(error)  # no server path or memory address in what a user reads
    files = [_file_entry(context, n, t) for n, t in sorted(context.files.items())] if context else []
    with sessions() as session:
        moment = utcnow()
        values: dict[str, Any] = {"state": state, "error": error, "finished_at": moment, "heartbeat_at": moment}
        if result is not None:
            values["result"] = result
            values["files"] = files
        if state != "cancelled":
            won = session.execute(
                update(Job).where(Job.id == job_id, Job.state == "running", Job.finished_at.is_(None)).values(**values)
            ).rowcount  # type: ignore[attr-defined]
        else:
            won = 0
        if not won:  # cancelled meanwhile (or now): only confirm that the worker stopped
            state, error = "cancelled", ""
            won = session.execute(
                update(Job)
                .where(Job.id == job_id, Job.state.in_(("running", "cancelled")), Job.finished_at.is_(None))
                .values(state="cancelled", error="", finished_at=moment)
            ).rowcount  # type: ignore[attr-defined]
        if won:
            if state == "succeeded":
                job = session.get(Job, job_id)
                if job is not None:
                    job.progress_done = job.progress_total
                    if context is not None and context.provenance:
                        job.provenance = {**job.provenance, **context.provenance}
                add_log(session, job_id, "succeeded" + (f": {', '.join(f['name'] for f in files)}" if files else ""))
            elif state == "failed":
                add_log(session, job_id, f"failed: {error}", level="error")
            else:
                add_log(session, job_id, "stopped after the cancel")
        session.commit()
    return bool(won)


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


def this_worker() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _remove_chunk_files(directory: Path) -> None:
    chunk_dir = directory / "chunks"
    if chunk_dir.is_dir():
        for path in chunk_dir.iterdir():
            path.unlink(missing_ok=True)
        chunk_dir.rmdir()


def save_arrays(context: JobContext, name: str, **arrays: Any) -> None:
    """Arrays a task hands over (to `load_arrays`), in one file written atomically (one `array_records` record)."""
    with array_records(context, name) as write:
        write(**arrays)


def load_arrays(context: JobContext, name: str) -> dict[str, np.ndarray]:
    return next(read_array_records(context, name))


def _npy_writer(handle: Any) -> Callable[..., None]:
    """`write(**arrays)`: one record, its names, then each array as a .npy record (no ZIP: read back at the speed
    of the disk cache, no checksum per read)."""
    from numpy.lib import format as npy

    def write(**arrays: Any) -> None:
        npy.write_array(handle, np.array(list(arrays), dtype=str), allow_pickle=False)
        for value in arrays.values():
            npy.write_array(handle, np.asarray(value), allow_pickle=False)

    return write


def _npy_records(handle: Any) -> Iterator[dict[str, np.ndarray]]:
    """The records `_npy_writer` wrote to `handle`, from its start."""
    from numpy.lib import format as npy

    size = handle.seek(0, os.SEEK_END)
    handle.seek(0)
    while handle.tell() < size:
        names = npy.read_array(handle, allow_pickle=False)
        yield {str(key): npy.read_array(handle, allow_pickle=False) for key in names}


# Hand-overs kept in this process (`JobContext.hold`), by (job id, name); a merge drops its job's when it ends.
HELD_HAND_OVER_BYTES = 256 << 20


class _Kept:
    """A hand-over kept in this process: its records as written (arrays, not encoded and decoded again) while
    they fit in HELD_HAND_OVER_BYTES, the rest in an anonymous temporary file."""

    def __init__(self) -> None:
        self.records: list[dict[str, np.ndarray]] = []
        self.nbytes = 0
        self.spill: Any = None

    def write(self, **arrays: Any) -> None:
        # contiguous: a column of a larger array is copied, not kept as a view holding the whole
        record = {name: np.array(value, order="C", copy=None) for name, value in arrays.items()}
        size = sum(value.nbytes for value in record.values())
        if self.spill is None and self.nbytes + size <= HELD_HAND_OVER_BYTES:
            self.records.append(record)
            self.nbytes += size
            return
        if self.spill is None:
            import tempfile

            self.spill = tempfile.TemporaryFile()  # noqa: SIM115 (closed by `close`)
        _npy_writer(self.spill)(**record)

    def read(self) -> Iterator[dict[str, np.ndarray]]:
        while self.records:  # each record given up as it is read
            yield self.records.pop(0)
        if self.spill is not None:
            yield from _npy_records(self.spill)

    def close(self) -> None:
        self.records.clear()
        if self.spill is not None:
            self.spill.close()


_held: dict[tuple[str, str], _Kept] = {}


@contextmanager
def array_records(context: JobContext, name: str) -> Iterator[Callable[..., None]]:
    """A hand-over file written record by record (`write(**arrays)`, e.g. one per frame, so that what a chunk holds
    does not grow with its frames, `_npy_writer`), committed when the block completes. With `context.hold` it
    stays in this process instead (`_Kept`: no file, no fsync), for this process to read."""
    if context.hold:
        kept = _Kept()
        try:
            yield kept.write
        except BaseException:
            kept.close()
            raise
        _held[(context.job_id, name)] = kept
        return
    with context.output(name, publish=False) as path, path.open("wb") as handle:
        yield _npy_writer(handle)


def read_array_records(context: JobContext, name: str) -> Iterator[dict[str, np.ndarray]]:
    """The records of a hand-over (`array_records`), one at a time: kept in this process (given up as read), or
    its file."""
    kept = _held.pop((context.job_id, name), None)
    if kept is not None:
        try:
            yield from kept.read()
        finally:
            kept.close()
        return
    path = context.directory / name
    if not path.is_file():
        raise RuntimeError(f"the intermediate file {name} is missing")
    with path.open("rb") as handle:
        yield from _npy_records(handle)


def has_hand_over(context: JobContext, name: str) -> bool:
    """Whether a hand-over `name` of the context's job can be read here (kept in this process, or its file)."""
    return (context.job_id, name) in _held or (context.directory / name).is_file()


def _drop_held(job_id: str) -> None:
    for key in [key for key in _held if key[0] == job_id]:
        _held.pop(key).close()


def finite_or_none(value: Any) -> Any:
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, list):
        return [finite_or_none(v) for v in value]
    return value
