"""Running a job inside a Celery task: state transitions, progress, heartbeats, cancel, errors and chunks.

A task body receives a `JobContext` and returns either the job's result (a JSON-able dict: the job succeeds) or
a `Chunked` plan (the job goes on as one chunk task per frame range on any worker, then a merge task; see
`backend.jobs` for why the join is counted in the database). Everything a person must act on (ValueError,
MeasurementError) becomes the job's error text; anything else is an internal error whose traceback goes to the
worker log. Acks-late work can run twice: a job that already finished is not run again, and only one run can
finish it (`UPDATE ... WHERE finished_at IS NULL`).

What does not belong here: what a job computes (worker/pipelines.py) and how the API reports it.
"""

from __future__ import annotations

import hashlib
import logging
import os
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from celery import Task, group
from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, sessionmaker

from backend.jobs import (
    CHUNK_TASK,
    FINAL_STATES,
    MERGE_TASK,
    WORKER_SEND_RETRY,
    add_log,
    chunk_task_id,
    heartbeat_interval_s,
    merge_task_id,
)
from backend.models import Job, JobChunk, utcnow
from backend.settings import Settings
from worker.measurement import MeasurementError
from worker.runtime import job_dir, sessions_of, settings_of

log = logging.getLogger(__name__)
PROGRESS_INTERVAL_S = 0.5


class JobCancelled(Exception):
    """Raised between frames when the job is no longer running (cancelled by the user, or failed elsewhere)."""


@dataclass(frozen=True)
class Chunked:
    """A job body's answer "split me": frame ranges `[first, stop)` to run in parallel, then a merge."""

    frame_ranges: list[tuple[int, int]]
    stage: str


@dataclass
class JobContext:
    job_id: str
    spec: dict[str, Any]
    settings: Settings
    sessions: sessionmaker[Session]
    chunk_index: int | None = None
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
        JobCancelled here if the job was cancelled."""
        now = time.monotonic()
        new_stage = bool(stage) and stage != self._stage
        if not new_stage and done < total and now - self._last_progress < PROGRESS_INTERVAL_S:
            return
        self._last_progress = now
        with self.sessions() as session:
            job = session.get(Job, self.job_id)
            if job is None or job.state != "running":
                raise JobCancelled("the job was cancelled" if job is None or job.state == "cancelled" else job.state)
            moment = utcnow()
            if self.chunk_index is None:
                job.progress_done, job.progress_total = done, total
            else:
                session.execute(
                    update(JobChunk)
                    .where(JobChunk.job_id == self.job_id, JobChunk.index == self.chunk_index)
                    .values(done=done, heartbeat_at=moment)
                )
                session.flush()
                job.progress_done = int(
                    session.scalar(select(func.sum(JobChunk.done)).where(JobChunk.job_id == self.job_id)) or 0
                )
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
        final = self.directory / name
        final.parent.mkdir(parents=True, exist_ok=True)
        temporary = final.with_name(f".{final.name}.{uuid.uuid4().hex[:8]}.partial")
        try:
            yield temporary
            with temporary.open("rb+") as handle:
                os.fsync(handle.fileno())
            os.replace(temporary, final)
        finally:
            temporary.unlink(missing_ok=True)
        if publish:
            self.files[name] = media_type


JobBody = Callable[[JobContext], "dict[str, Any] | Chunked"]
ChunkBody = Callable[[JobContext, int, int], None]
MergeBody = Callable[[JobContext, list[tuple[int, int]]], dict[str, Any]]


def _worker_name(task: Task) -> str:
    return f"{task.request.hostname or socket.gethostname()} (pid {os.getpid()})"


@contextmanager
def _heartbeat(
    sessions: sessionmaker[Session], job_id: str, chunk_index: int | None, *, interval_s: float
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
                    if chunk_index is not None:
                        session.execute(
                            update(JobChunk)
                            .where(JobChunk.job_id == job_id, JobChunk.index == chunk_index)
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
        with _heartbeat(sessions, job_id, context.chunk_index, interval_s=heartbeat_interval_s(context.settings)):
            return True, step()
    except JobCancelled:
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
        spec = dict(job.spec)
        add_log(session, job_id, f"{'restarted' if again else 'started'} on {worker}")
        session.commit()
    context = JobContext(job_id=job_id, spec=spec, settings=settings_of(task.app), sessions=sessions)
    ok, outcome = _run_guarded(context, lambda: body(context))
    if not ok:
        return {}
    if isinstance(outcome, Chunked):
        _dispatch_chunks(task, sessions, job_id, outcome)
        return {}
    finish(sessions, job_id, state="succeeded", result=outcome, context=context)
    return dict(outcome)


def _dispatch_chunks(task: Task, sessions: sessionmaker[Session], job_id: str, plan: Chunked) -> None:
    """Store the chunk rows (once: a second run keeps the first plan) and send a task per unfinished chunk."""
    with sessions() as session:
        query = select(JobChunk).where(JobChunk.job_id == job_id).order_by(JobChunk.index)
        chunks = list(session.scalars(query))
        if not chunks:
            chunks = [
                JobChunk(job_id=job_id, index=i, first_frame=first, stop_frame=stop)
                for i, (first, stop) in enumerate(plan.frame_ranges)
            ]
            session.add_all(chunks)
            job = session.get(Job, job_id)
            assert job is not None  # checked by run_job; the row is never deleted while its task runs
            job.progress_done = 0
            job.progress_total = sum(stop - first for first, stop in plan.frame_ranges)
            job.stage, job.stage_started_at = plan.stage, utcnow()
            longest = max(stop - first for first, stop in plan.frame_ranges)
            add_log(session, job_id, f"split into {len(chunks)} chunk(s) of up to {longest} frames")
            try:
                session.commit()
            except IntegrityError:  # a second delivery of this entry task planned them a moment ago: keep those
                session.rollback()
                chunks = list(session.scalars(query))
        pending = [c.index for c in chunks if c.state != "done"]
    signatures = [
        task.app.signature(CHUNK_TASK, args=[job_id, index]).set(task_id=chunk_task_id(job_id, index))
        for index in pending
    ]
    if signatures:
        group(signatures).apply_async(retry=True, retry_policy=WORKER_SEND_RETRY)
    else:
        _send_merge_once(task, sessions, job_id)


def run_chunk(task: Task, job_id: str, index: int, body: ChunkBody) -> None:
    """One chunk of a chunked job. Idempotent: a chunk already done is not run again."""
    sessions = sessions_of(task.app)
    with sessions() as session:
        job = session.get(Job, job_id)
        chunk = session.get(JobChunk, (job_id, index))
        if job is None or chunk is None or job.state != "running":
            _confirm_cancel(sessions, job)
            return
        if chunk.state == "done":  # redelivered after it finished: make sure the merge was sent, nothing else
            session.close()
            _after_chunk(task, sessions, job_id)
            return
        moment = utcnow()
        chunk.state, chunk.worker, chunk.started_at, chunk.heartbeat_at = "running", _worker_name(task), moment, moment
        first, stop, spec = chunk.first_frame, chunk.stop_frame, dict(job.spec)
        session.commit()
    context = JobContext(job_id=job_id, spec=spec, settings=settings_of(task.app), sessions=sessions, chunk_index=index)
    ok, _ = _run_guarded(context, lambda: body(context, first, stop))
    if not ok:
        return
    with sessions() as session:
        session.execute(
            update(JobChunk)
            .where(JobChunk.job_id == job_id, JobChunk.index == index, JobChunk.state != "done")
            .values(state="done", done=stop - first, finished_at=utcnow())
        )
        session.flush()
        job = session.get(Job, job_id)
        if job is not None:
            job.progress_done = int(
                session.scalar(select(func.sum(JobChunk.done)).where(JobChunk.job_id == job_id)) or 0
            )
        session.commit()
    _after_chunk(task, sessions, job_id)


def _after_chunk(task: Task, sessions: sessionmaker[Session], job_id: str) -> None:
    with sessions() as session:
        left = session.scalar(select(func.count()).where(JobChunk.job_id == job_id, JobChunk.state != "done"))
    if not left:
        _send_merge_once(task, sessions, job_id)


def _send_merge_once(task: Task, sessions: sessionmaker[Session], job_id: str) -> None:
    """Send the merge task, once: the chunk that claims `merge_queued_at` sends it."""
    with sessions() as session:
        claimed = session.execute(
            update(Job)
            .where(Job.id == job_id, Job.state == "running", Job.merge_queued_at.is_(None))
            .values(merge_queued_at=utcnow())
        ).rowcount  # type: ignore[attr-defined]
        session.commit()
    if not claimed:
        return
    try:
        task.app.send_task(
            MERGE_TASK,
            args=[job_id],
            task_id=merge_task_id(job_id),
            ignore_result=True,
            retry=True,
            retry_policy=WORKER_SEND_RETRY,
        )
    except Exception:  # give the claim back, so that a redelivered chunk or the reconciliation sends it
        with sessions() as session:
            session.execute(update(Job).where(Job.id == job_id).values(merge_queued_at=None))
            session.commit()
        raise


def run_merge(task: Task, job_id: str, body: MergeBody) -> dict[str, Any]:
    """The last step of a chunked job: combine the chunks' files in frame order and end the job."""
    sessions = sessions_of(task.app)
    with sessions() as session:
        job = session.get(Job, job_id)
        if job is None or job.state != "running":
            _confirm_cancel(sessions, job)
            return dict(job.result) if job else {}
        ranges = [
            (c.first_frame, c.stop_frame)
            for c in session.scalars(select(JobChunk).where(JobChunk.job_id == job_id).order_by(JobChunk.index))
        ]
        spec = dict(job.spec)
        job.worker = _worker_name(task)
        job.heartbeat_at = utcnow()  # after merge_queued_at: tells reconciliation that the merge has started
        session.commit()
    context = JobContext(job_id=job_id, spec=spec, settings=settings_of(task.app), sessions=sessions)
    ok, result = _run_guarded(context, lambda: body(context, ranges))
    if not ok:
        return {}
    finish(sessions, job_id, state="succeeded", result=result, context=context)
    return dict(result)


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
