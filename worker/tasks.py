"""Every Celery task of fringelab: thin wrappers that run a job by id (`worker.runner`) with the body of its kind.

A task only says how to run an action as a task: it takes ids, `worker.runner` loads the job, calls the body from
`worker.jobs.<kind>`, and stores the outcome. Bodies load their inputs from storage, call the science, and write
their files atomically, so a task that runs twice (acks-late redelivery) writes the same complete files. Tasks are
registered with `shared_task` so they bind to the app the worker process created from its settings; their names
are `fringelab.core.jobs.TASK_NAMES`, the API sends them by name.
"""

from __future__ import annotations

import os
import socket
import time
from typing import Any

from celery import Task, shared_task
from sqlalchemy import select

from fringelab.core.jobs import CHUNK_TASK, DEMO_ADVANCE_TASK, DEMO_TASK, MERGE_TASK, PING_TASK, TASK_NAMES
from fringelab.core.models import Job
from worker.jobs import camera_calibration as camera_calibration_job
from worker.jobs import comparison as comparison_job
from worker.jobs import demo as demo_job
from worker.jobs import export as export_job
from worker.jobs import ingest as ingest_job
from worker.jobs import projector_calibration as projector_calibration_job
from worker.jobs import selftest as selftest_job
from worker.jobs import topography as topography_job
from worker.runner import ChunkBody, MergeBody, run_chunk, run_job, run_merge
from worker.runtime import sessions_of

# Per chunked kind, its phases in order: (chunk body, merge body, whether the merge keeps the later chunks it measures
# itself in its process: `run_merge` hold_steals). A merge that returns a `Chunked` plan starts the next phase; the
# last one returns the result.
PHASES: dict[str, list[tuple[ChunkBody, MergeBody, bool]]] = {
    "selftest": [
        (selftest_job.selftest_compute, selftest_job.selftest_chain, False),
        (selftest_job.selftest_verify, selftest_job.selftest_write, False),
    ],
    "topography": [(topography_job.topography_measure, topography_job.topography_write, True)],
}


def _kind(task: Task, job_id: str) -> str | None:
    with sessions_of(task.app)() as session:
        return session.scalar(select(Job.kind).where(Job.id == job_id))


@shared_task(name=PING_TASK)
def ping(payload: str = "pong") -> dict[str, object]:
    """A trivial end-to-end check of broker, worker and result backend."""
    return {"payload": payload, "worker_pid": os.getpid(), "host": socket.gethostname()}


@shared_task(bind=True, name=TASK_NAMES["ingest"])
def ingest(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, ingest_job.ingest_recording)


@shared_task(bind=True, name=TASK_NAMES["selftest"], ignore_result=True)
def selftest(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, selftest_job.selftest_entry)


@shared_task(bind=True, name=TASK_NAMES["camera_calibration"], ignore_result=True)
def camera_calibration(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, camera_calibration_job.camera_calibration_body)


@shared_task(bind=True, name=TASK_NAMES["projector_calibration"], ignore_result=True)
def projector_calibration(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, projector_calibration_job.projector_calibration_body)


@shared_task(bind=True, name=TASK_NAMES["topography"], ignore_result=True)
def topography(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, topography_job.topography_entry)


@shared_task(bind=True, name=TASK_NAMES["export"], ignore_result=True)
def export(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, export_job.export_body)


@shared_task(bind=True, name=TASK_NAMES["comparison"], ignore_result=True)
def comparison(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, comparison_job.comparison_body)


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
