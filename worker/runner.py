"""Running a job inside a Celery task: state transitions, progress, heartbeats, cancel, errors and chunks.

A task body receives a `JobContext` and returns either the job's result (a JSON-able dict: the job succeeds) or
a `Chunked` plan: the job goes on as one chunk task per frame range on any worker, then a merge task that ends
the job or plans the next such phase (see `fringelab.core.jobs` for why the join is counted in the database).
Everything a person must act on (ValueError, MeasurementError) becomes the job's error text; anything else is an
internal error whose traceback goes to the worker log. Acks-late work can run twice: a job that already
finished is not run again, and only one run can finish it (`UPDATE ... WHERE finished_at IS NULL`).

What does not belong here: what a job computes (worker/jobs/) and how the API reports it.
"""

from __future__ import annotations

import hashlib
import logging
import os
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from celery import Task, group
from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, sessionmaker

from fringelab.core.jobs import (
    CHUNK_TASK,
    FINAL_STATES,
    MERGE_TASK,
    WORKER_SEND_RETRY,
    add_log,
    chunk_task_id,
    heartbeat_interval_s,
    merge_task_id,
)
from fringelab.core.models import Job, JobChunk, utcnow
from fringelab.core.settings import Settings
from fringelab.formats.atomic import atomic_path
from fringelab.science import Cancelled, MeasurementError
from worker.runtime import job_dir, sessions_of, settings_of

log = logging.getLogger(__name__)
PROGRESS_INTERVAL_S = 0.5


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
    chunk: tuple[int, int] | None = None  # (phase, index) of the chunk this context runs, if any
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


JobBody = Callable[[JobContext], "dict[str, Any] | Chunked"]
ChunkBody = Callable[[JobContext, int, int], None]
MergeBody = Callable[[JobContext, list[tuple[int, int]]], "dict[str, Any] | Chunked"]


def _worker_name(task: Task) -> str:
    return f"{task.request.hostname or socket.gethostname()} (pid {os.getpid()})"


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
        spec = dict(job.spec)
        add_log(session, job_id, f"{'restarted' if again else 'started'} on {worker}")
        session.commit()
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
    """Send the tasks of the phase's unfinished chunks (a Celery group over every worker), or its merge."""
    with sessions() as session:
        pending = [c.index for c in _phase_chunks(session, job_id, phase) if c.state != "done"]
    if not pending:
        _send_merge_once(task, sessions, job_id, phase)
        return
    signatures = [
        task.app.signature(CHUNK_TASK, args=[job_id, phase, index]).set(task_id=chunk_task_id(job_id, phase, index))
        for index in pending
    ]
    group(signatures).apply_async(retry=True, retry_policy=WORKER_SEND_RETRY)


def run_chunk(task: Task, job_id: str, phase: int, index: int, body: ChunkBody) -> None:
    """One chunk of a phase of a chunked job. Idempotent: a chunk already done is not run again."""
    sessions = sessions_of(task.app)
    with sessions() as session:
        job = session.get(Job, job_id)
        chunk = session.get(JobChunk, (job_id, phase, index))
        if job is None or chunk is None or job.state != "running" or job.phase != phase:
            _confirm_cancel(sessions, job)
            return
        if chunk.state == "done":  # redelivered after it finished: make sure the merge was sent, nothing else
            session.close()
            _after_chunk(task, sessions, job_id, phase)
            return
        moment = utcnow()
        chunk.state, chunk.worker, chunk.started_at, chunk.heartbeat_at = "running", _worker_name(task), moment, moment
        first, stop, spec = chunk.first_frame, chunk.stop_frame, dict(job.spec)
        session.commit()
    context = JobContext(
        job_id=job_id, spec=spec, settings=settings_of(task.app), sessions=sessions, chunk=(phase, index)
    )
    ok, _ = _run_guarded(context, lambda: body(context, first, stop))
    if not ok:
        return
    with sessions() as session:
        session.execute(
            update(JobChunk)
            .where(JobChunk.job_id == job_id, JobChunk.phase == phase, JobChunk.index == index)
            .where(JobChunk.state != "done")
            .values(state="done", done=stop - first, finished_at=utcnow())
        )
        session.flush()
        job = session.get(Job, job_id)
        if job is not None:
            job.progress_done = _phase_done(session, job_id, phase)
        session.commit()
    _after_chunk(task, sessions, job_id, phase)


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
    """Send the phase's merge task, once: the chunk that claims `merge_queued_at` sends it."""
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


def run_merge(task: Task, job_id: str, phase: int, body: MergeBody) -> dict[str, Any]:
    """The end of a phase: a pass in frame order over what its chunks stored, which ends the job (a result) or
    starts the next phase (a `Chunked` plan)."""
    sessions = sessions_of(task.app)
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
        ranges = [(c.first_frame, c.stop_frame) for c in _phase_chunks(session, job_id, phase)]
        spec = dict(job.spec)
        job.worker = _worker_name(task)
        job.heartbeat_at = utcnow()  # after merge_queued_at: tells reconciliation that the merge has started
        session.commit()
    context = JobContext(job_id=job_id, spec=spec, settings=settings_of(task.app), sessions=sessions)
    ok, outcome = _run_guarded(context, lambda: body(context, ranges))
    if not ok:
        return {}
    if isinstance(outcome, Chunked):
        _start_phase(task, sessions, job_id, outcome, phase=phase + 1)
        return {}
    finish(sessions, job_id, state="succeeded", result=outcome, context=context)
    return dict(outcome)


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


def frame_ranges(count: int, chunk_frames: int) -> list[tuple[int, int]]:
    """Split positions `0..count-1` into consecutive `[first, stop)` ranges of at most `chunk_frames`."""
    if count < 1 or chunk_frames < 1:
        raise ValueError(f"need at least one frame and one frame per chunk, got {count} and {chunk_frames}")
    return [(first, min(first + chunk_frames, count)) for first in range(0, count, chunk_frames)]


# A job that names no chunk size and has fewer frames than SPREAD_CHUNKS chunks of FRINGELAB_CHUNK_FRAMES is split
# into SPREAD_CHUNKS chunks (of at least MIN_CHUNK_FRAMES), so that the worker processes share a short job too; each
# chunk costs a task, its inputs and its hand-over, so they are not made smaller than that.
SPREAD_CHUNKS = 8
MIN_CHUNK_FRAMES = 5


def chunk_frames_of(spec: dict[str, Any], settings: Settings, n_frames: int | None = None) -> int:
    """Frames per chunk: the job's own `chunk_frames`; else FRINGELAB_CHUNK_FRAMES, or fewer for a job of
    `n_frames` frames that would make fewer than SPREAD_CHUNKS chunks of it (see there)."""
    if spec.get("chunk_frames"):
        return int(spec["chunk_frames"])
    most = int(settings.chunk_frames)
    if n_frames is None:
        return most
    return min(most, max(MIN_CHUNK_FRAMES, -(-n_frames // SPREAD_CHUNKS)))


def this_worker() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def remove_chunk_files(directory: Path) -> None:
    chunk_dir = directory / "chunks"
    if chunk_dir.is_dir():
        for path in chunk_dir.iterdir():
            path.unlink(missing_ok=True)
        chunk_dir.rmdir()


def save_arrays(context: JobContext, name: str, **arrays: np.ndarray) -> None:
    """Arrays a task hands over (to `load_arrays`), in one file written atomically (one `array_records` record)."""
    with array_records(context, name) as write:
        write(**arrays)


def load_arrays(context: JobContext, name: str) -> dict[str, np.ndarray]:
    return next(read_array_records(context, name))


@contextmanager
def array_records(context: JobContext, name: str) -> Iterator[Callable[..., None]]:
    """A hand-over file written record by record (`write(**arrays)`, e.g. one per frame, so that what a chunk holds
    does not grow with its frames), committed when the block completes: each record is its names, then each array
    as a .npy record (no ZIP: read back at the speed of the disk cache, no checksum per read)."""
    from numpy.lib import format as npy

    with context.output(name, publish=False) as path, path.open("wb") as handle:

        def write(**arrays: Any) -> None:
            npy.write_array(handle, np.array(list(arrays), dtype=str), allow_pickle=False)
            for value in arrays.values():
                npy.write_array(handle, np.asarray(value), allow_pickle=False)

        yield write


def read_array_records(context: JobContext, name: str) -> Iterator[dict[str, np.ndarray]]:
    """The records of a hand-over file (`array_records`), one at a time."""
    from numpy.lib import format as npy

    path = context.directory / name
    if not path.is_file():
        raise RuntimeError(f"the intermediate file {name} is missing")
    with path.open("rb") as handle:
        size = path.stat().st_size
        while handle.tell() < size:
            names = npy.read_array(handle, allow_pickle=False)
            yield {str(key): npy.read_array(handle, allow_pickle=False) for key in names}


def finite_or_none(value: Any) -> Any:
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, list):
        return [finite_or_none(v) for v in value]
    return value
