"""Running a job inside a Celery task: the entry task (`run_job`), a chunk task (`run_chunk`) and a phase's merge
task (`run_merge`). Their parts live beside it: `worker.context` (the `JobContext` a body gets, heartbeats, errors,
`finish`), `worker.chunks` (a phase's chunk rows, claims, the pass in frame order, how frames are split) and
`worker.handover` (the arrays a task hands to the next).

A task body receives a `JobContext` and returns either the job's result (a JSON-able dict: the job succeeds) or
a `Chunked` plan: the job goes on as one chunk task per frame range on any worker, and a merge task, sent with
them, that takes the chunks in frame order, each as soon as it can (`chunks_in_order`, `InOrder`), and ends the
job or plans the next such phase (see `fringelab.core.jobs` for why the join is counted in the database). When
the next chunk in order is nobody's, the merge claims it and measures it in its turn, straight into its output
(no hand-over); while another process measures the next one, the merge measures a later chunk nobody has started
(handed over), else waits. A chunk task goes on from its chunk to the next one nobody has started, so the other
processes do not go back to the queue between chunks. So the pass in frame order overlaps the chunks instead of
following them, no process idles while there is work, one worker process runs a whole phase inside its merge, and
the merge never waits for a chunk that needs its own slot. A claim is an UPDATE on the chunk's row that only one
process can win; a chunk whose process is gone is taken over at once (`chunk_takeable`: on the same machine) or
once its heartbeat is stale. Everything a person must act on (ValueError, MeasurementError) becomes the job's
error text; anything else is an internal error whose traceback goes to the worker log. Acks-late work can run
twice: a job that already finished is not run again, and only one run can finish it
(`UPDATE ... WHERE finished_at IS NULL`).

What does not belong here: what a job computes (worker/jobs/) and how the API reports it.
"""

from __future__ import annotations

import logging
from functools import partial
from typing import Any

from celery import Task

from fringelab.core.job_kinds import JOB_KINDS
from fringelab.core.jobs import FINAL_STATES, add_log
from fringelab.core.models import Job, JobChunk, utcnow
from worker.chunks import (
    ChunkBody,
    MergeBody,
    after_chunk,
    announce_done,
    chunk_takeable,
    chunks_in_order,
    claim_next,
    mark_done,
    send_pending,
    start_phase,
    wait_for_a_chunk,
)
from worker.context import (
    Chunked,
    JobBody,
    JobContext,
    confirm_cancel,
    finish,
    job_spec,
    run_guarded,
    worker_name,
)
from worker.handover import drop_held, remove_chunk_files
from worker.reserve import require_reserve
from worker.runtime import sessions_of, settings_of

log = logging.getLogger(__name__)


def run_job(task: Task, job_id: str, body: JobBody) -> dict[str, Any]:
    """The entry task of a job (task id = job id): mark it running, run `body`, and end it or split it."""
    sessions = sessions_of(task.app)
    worker = worker_name(task)
    with sessions() as session:
        job = session.get(Job, job_id)
        if job is None:
            log.warning("job %s has no record; nothing to do", job_id)
            return {}
        if job.state in FINAL_STATES:  # a redelivered task whose job already ended
            confirm_cancel(sessions, job)
            return dict(job.result)
        again = job.state == "running"
        writes_files = bool(JOB_KINDS[job.kind].result_files) if job.kind in JOB_KINDS else False
        moment = utcnow()
        job.state = "running"
        job.started_at = job.started_at or moment
        job.stage_started_at = moment
        job.heartbeat_at = moment
        job.worker = worker
        job.error = ""
        try:
            spec, unread = job_spec(job), ""
        except ValueError as error:
            spec, unread = None, str(error)
        add_log(session, job_id, f"{'restarted' if again else 'started'} on {worker}")
        session.commit()
    if spec is None:
        finish(sessions, job_id, state="failed", error=unread)
        return {}
    context = JobContext(job_id=job_id, spec=spec, settings=settings_of(task.app), sessions=sessions)

    def within_reserve() -> dict[str, Any] | Chunked:
        # A kind that writes result files does not begin below the disk's reserve (its files check it again
        # as they are written: `JobContext.output`); an ingest has its own checks and must end its recording.
        if writes_files:
            require_reserve(context.settings, what="starting the job")
        return body(context)

    ok, outcome = run_guarded(context, within_reserve)
    if not ok:
        return {}
    if isinstance(outcome, Chunked):
        start_phase(task, sessions, job_id, outcome, phase=0)
        return {}
    finish(sessions, job_id, state="succeeded", result=outcome, context=context)
    return dict(outcome)


def run_chunk(task: Task, job_id: str, phase: int, index: int, body: ChunkBody) -> None:
    """This task's chunk, then every chunk of the phase that nobody has started, lowest first, until none is left:
    the process goes on without a round trip through the queue per chunk (the tasks of the chunks it took find them
    taken and end at once). A chunk whose process died is taken over (`chunk_takeable`); a redelivered task (its earlier
    run died with its process) takes its own chunk over too, unless a live process on this machine runs it (one
    that took it over first)."""
    sessions, settings = sessions_of(task.app), settings_of(task.app)
    redelivered = bool((task.request.delivery_info or {}).get("redelivered"))
    worker = worker_name(task)

    def takeable(chunk: JobChunk) -> bool:
        return chunk_takeable(chunk, settings, orphaned=lambda c: redelivered and c.index == index)

    wanted: int | None = index
    while claimed := claim_next(sessions, settings, job_id, phase, worker, wanted=wanted, takeable=takeable):
        context, first, stop = claimed
        ok, _ = run_guarded(context, partial(body, context, first, stop))
        if not ok:
            return
        assert context.chunk is not None
        mark_done(sessions, job_id, phase, context.chunk[1], stop - first)
        announce_done(task, job_id, phase, context.chunk[1])
        wanted = None
    after_chunk(task, sessions, job_id, phase)


def run_merge(
    task: Task, job_id: str, phase: int, body: MergeBody, chunk_body: ChunkBody, *, hold_steals: bool = False
) -> dict[str, Any]:
    """The in-order pass of a phase over its chunks' turns (`chunks_in_order`: measured here when nobody has
    started them, `chunk_body` for a later chunk measured while waiting), which ends the job (a result) or starts
    the next phase (a `Chunked` plan). hold_steals: the later chunks this merge measures stay in its process (no
    file, no fsync, no reading back from disk); only for a body that measures a done chunk again when its hand-over
    is gone (a merge that runs again after its process died)."""
    sessions = sessions_of(task.app)
    redelivered = bool((task.request.delivery_info or {}).get("redelivered"))
    with sessions() as session:
        job = session.get(Job, job_id)
        if job is None or job.state != "running":
            confirm_cancel(sessions, job)
            return dict(job.result) if job else {}
        if job.phase != phase:  # redelivered after it started the next phase: make sure that one is under way
            session.close()
            if job.phase == phase + 1:
                send_pending(task, sessions, job_id, phase + 1)
            return {}
        # A redelivered merge's earlier run died with its process, and with it the chunks that run was computing.
        dead_merge = job.worker if redelivered else None
        spec = job_spec(job)
        if dead_merge is not None:
            add_log(
                session, job_id, f"the pass in frame order starts again on {worker_name(task)} ({dead_merge} was lost)"
            )
        job.worker = worker_name(task)
        job.heartbeat_at = utcnow()  # after merge_queued_at: tells reconciliation that the merge has started
        session.commit()
    context = JobContext(job_id=job_id, spec=spec, settings=settings_of(task.app), sessions=sessions)
    turns = chunks_in_order(context, phase, chunk_body, worker=worker_name(task), dead_merge=dead_merge,
                             wait=lambda: wait_for_a_chunk(task, job_id, phase), hold_steals=hold_steals)  # fmt: skip
    try:
        ok, outcome = run_guarded(context, lambda: body(context, turns))
    finally:
        drop_held(job_id)
    if not ok:
        return {}
    if isinstance(outcome, Chunked):
        start_phase(task, sessions, job_id, outcome, phase=phase + 1)
        return {}
    finish(sessions, job_id, state="succeeded", result=outcome, context=context)
    remove_chunk_files(context.directory)  # after the job's end: a merge that runs again needs them until then
    return dict(outcome)
