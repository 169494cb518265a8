"""What a job body runs with, and how a job step ends: the `JobContext` (its spec model, settings, sessions,
progress, cancel, log, atomic outputs), the `Chunked` answer of a body that splits, heartbeats while a step runs,
and `finish` (the job ends once; a cancel that came first wins). Every error a person must act on (ValueError,
MeasurementError) becomes the job's error text (`run_guarded`); anything else is an internal error whose traceback
goes to the worker log.

What does not belong here: the task entry points (`worker.runner`), chunks and their claims (`worker.chunks`), the
hand-over files between tasks (`worker.handover`), what a job computes (worker/jobs/).
"""

from __future__ import annotations

import errno
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
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np
from celery import Task
from pydantic import BaseModel, ValidationError
from sqlalchemy import func, select, update
from sqlalchemy.orm import Session, sessionmaker

from fringelab.core.job_kinds import spec_of
from fringelab.core.jobs import add_log, heartbeat_interval_s
from fringelab.core.models import Job, JobChunk, utcnow
from fringelab.core.settings import Settings
from fringelab.core.text import public_text
from fringelab.formats.atomic import atomic_path
from fringelab.science import Cancelled, MeasurementError
from worker.reserve import BelowReserve, require_reserve
from worker.runtime import job_dir

log = logging.getLogger(__name__)


PROGRESS_INTERVAL_S = 0.5


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
                job.progress_done = phase_done(session, self.job_id, phase)
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
        Published files are listed on the job (size, SHA-256) when it succeeds.

        Every job's files keep the disk's reserve (FRINGELAB_MIN_FREE_DISK_BYTES, `worker.reserve`): checked
        before the file is begun and once it is written, before it is renamed into place; a file that took the
        volume below the reserve, or met a full disk, is removed and the job fails saying so (BelowReserve)."""
        require_reserve(self.settings, what=f"writing {name}")
        try:
            with atomic_path(self.directory / name) as partial:
                yield partial
                require_reserve(self.settings, what=f"keeping {name} (removed)")
        except OSError as error:
            if error.errno not in (errno.ENOSPC, errno.EDQUOT):
                raise
            raise BelowReserve(f"the data volume filled up while {name} was written (removed); free some space "
                               "and retry the job") from None  # fmt: skip
        if publish:
            self.files[name] = media_type


JobBody = Callable[[JobContext[Any]], "dict[str, Any] | Chunked"]


def job_spec(job: Job) -> BaseModel:
    """The job's spec model from its stored JSON (`fringelab.core.job_kinds.spec_of`); a spec that no longer
    reads (stored by another version of fringelab) is a ValueError whose text says what to do."""
    try:
        return spec_of(job.kind, job.spec)
    except ValidationError as error:
        raise ValueError(
            f"the spec of this {job.kind} job no longer reads ({error.error_count()} error(s): "
            f"{error.errors()[0]['msg']}); start a new job"
        ) from None


def worker_name(task: Task) -> str:
    return f"{task.request.hostname or socket.gethostname()} (pid {os.getpid()})"


WORKER_NAME = re.compile(r"^(?:[^@]*@)?(?P<host>.+) \(pid (?P<pid>\d+)\)$")  # a `worker_name`: node@host (pid N)


@contextmanager
def heartbeats(
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


def run_guarded(context: JobContext, step: Callable[[], Any]) -> tuple[bool, Any]:
    """Run one step of a job; turn its errors into the job's end. (True, value) when it returned normally."""
    sessions, job_id = context.sessions, context.job_id
    try:
        with heartbeats(sessions, job_id, context.chunk, interval_s=heartbeat_interval_s(context.settings)):
            return True, step()
    except Cancelled:
        finish(sessions, job_id, state="cancelled")
    except BelowReserve as error:
        # The disk is full: the files this run had already published go too (a failed job's are never listed).
        for name in context.files:
            (context.directory / name).unlink(missing_ok=True)
        context.files.clear()
        finish(sessions, job_id, state="failed", error=str(error))
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


def confirm_cancel(sessions: sessionmaker[Session], job: Job | None) -> None:
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


def this_worker() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def finite_or_none(value: Any) -> Any:
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, list):
        return [finite_or_none(v) for v in value]
    return value


def phase_done(session: Session, job_id: str, phase: int) -> int:
    done = select(func.sum(JobChunk.done)).where(JobChunk.job_id == job_id, JobChunk.phase == phase)
    return int(session.scalar(done) or 0)
