"""Every Celery task of fringelab: thin wrappers that run a job by id (`worker.runner`) with the body of its kind.

A task only says how to run an action as a task: it takes ids, `worker.runner` loads the job, calls the body from
`worker.jobs.<kind>`, and stores the outcome. Bodies load their inputs from storage, call the science, and write
their files atomically, so a task that runs twice (acks-late redelivery) writes the same complete files. Tasks are
registered with `shared_task` so they bind to the app the worker process created from its settings. Each job kind's
entry task, body and phases come from its entry in `fringelab.core.job_kinds` (the API sends the task by that
name); this module only registers them.
"""

from __future__ import annotations

import importlib
import os
import socket
import time
from collections.abc import Callable
from types import ModuleType
from typing import Any

from celery import Task, shared_task
from sqlalchemy import select

from fringelab.core.broker import CHUNK_TASK, DEMO_ADVANCE_TASK, DEMO_TASK, MERGE_TASK, PING_TASK
from fringelab.core.job_kinds import JOB_KINDS, JobKind
from fringelab.core.models import Job
from worker.chunks import ChunkBody, MergeBody
from worker.context import JobBody
from worker.jobs import demo as demo_job
from worker.runner import run_chunk, run_job, run_merge
from worker.runtime import sessions_of


def _module(entry: JobKind) -> ModuleType:
    return importlib.import_module(entry.module)


def _phases(entry: JobKind) -> list[tuple[ChunkBody, MergeBody, bool]]:
    module = _module(entry)
    return [(getattr(module, p.chunk), getattr(module, p.merge), p.hold_steals) for p in entry.phases]


# Per chunked kind, its phases in order (`fringelab.core.job_kinds`): (chunk body, merge body, whether the merge
# keeps the later chunks it measures itself in its process: `run_merge` hold_steals). A merge that returns a
# `Chunked` plan starts the next phase; the last one returns the result.
PHASES: dict[str, list[tuple[ChunkBody, MergeBody, bool]]] = {
    kind: _phases(entry) for kind, entry in JOB_KINDS.items() if entry.phases
}


def _kind(task: Task, job_id: str) -> str | None:
    with sessions_of(task.app)() as session:
        return session.scalar(select(Job.kind).where(Job.id == job_id))


@shared_task(name=PING_TASK)
def ping(payload: str = "pong") -> dict[str, object]:
    """A trivial end-to-end check of broker, worker and result backend."""
    return {"payload": payload, "worker_pid": os.getpid(), "host": socket.gethostname()}


def _entry_task(entry: JobKind) -> Callable[..., dict[str, Any]]:
    """The entry task of a kind (task id = job id), registered under the kind's task name: `run_job` with the
    entry body of its orchestration module."""
    body: JobBody = getattr(_module(entry), entry.body)

    def run(self: Task, job_id: str) -> dict[str, Any]:
        return run_job(self, job_id, body)

    run.__name__ = run.__qualname__ = entry.kind
    return shared_task(bind=True, name=entry.task, ignore_result=True)(run)


ENTRY_TASKS = {kind: _entry_task(entry) for kind, entry in JOB_KINDS.items()}


@shared_task(bind=True, name=CHUNK_TASK, ignore_result=True)
def job_chunk(self: Task, job_id: str, phase: int, index: int) -> None:
    kind = _kind(self, job_id)
    if kind is not None:
        run_chunk(self, job_id, phase, index, PHASES[kind][phase][0])


@shared_task(bind=True, name=MERGE_TASK, ignore_result=True)
def job_merge(self: Task, job_id: str, phase: int) -> dict[str, Any]:
    kind = _kind(self, job_id)
    if kind is None:
        return {}
    chunk_body, merge_body, hold_steals = PHASES[kind][phase]
    return run_merge(self, job_id, phase, merge_body, chunk_body, hold_steals=hold_steals)


@shared_task(bind=True, name=DEMO_TASK, ignore_result=True)
def demo(self: Task, experiment_id: int, presets: list[str], test_frames: int, scenario: str = "quasi-static") -> None:
    def first_camera_ready() -> None:  # its jobs start while the next camera is simulated
        demo_advance.apply_async(args=[experiment_id, presets, time.time()], countdown=demo_job.ADVANCE_EVERY_S)

    demo_job.simulate_demo(
        demo_job.services_of(self.app),
        experiment_id,
        presets,
        test_frames,
        scenario=scenario,
        first_camera_ready=first_camera_ready,
    )


@shared_task(bind=True, name=DEMO_ADVANCE_TASK, ignore_result=True)
def demo_advance(self: Task, experiment_id: int, presets: list[str], started: float) -> None:
    state = demo_job.services_of(self.app)
    with state.sessions() as session:
        finished = demo_job.advance(session, state, experiment_id, presets)
    if not finished and time.time() - started < demo_job.GIVE_UP_AFTER_S:
        self.apply_async(args=[experiment_id, presets, started], countdown=demo_job.ADVANCE_EVERY_S)
