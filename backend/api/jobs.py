"""`/api/v1/jobs`: start, list, watch (JSON and Server-Sent Events), read the log of, cancel, retry and download
the files of jobs. Thin: the rules live in `fringelab.core.jobs`; errors are `fringelab.core.jobs.job_error`s (4xx with
`{"detail", "code", "field"}`).

Access follows the job's experiment (`fringelab.core.accounts`): reading needs read access, starting, cancelling and
retrying need write access; a job of an experiment one may not read is a 404. Jobs outside any experiment
(selftest) are for admins."""

from __future__ import annotations

import logging
import threading
from collections import defaultdict
from collections.abc import AsyncIterator, Mapping, Sequence
from datetime import datetime
from functools import partial
from typing import Annotated, Any

import anyio
from fastapi import APIRouter, Body, Depends, Query, Request, Response
from fastapi.responses import FileResponse
from fastapi.security import HTTPAuthorizationCredentials
from fastapi.sse import EventSourceResponse, ServerSentEvent
from pydantic import BaseModel
from sqlalchemy import BindParameter, Row, bindparam, func, select
from sqlalchemy.orm import Session

from backend.api.deps import (
    CurrentUser,
    JobDep,
    SessionDep,
    StateDep,
    WritableJobDep,
    bearer_scheme,
    principal_of,
    request_secret,
)
from backend.errors import error_responses
from backend.polls import SharedPolls
from backend.schemas.deletion import DeletionOut, deletion_out
from backend.schemas.jobs import (
    JOB_ERRORS,
    MAX_ID,
    ChunkOut,
    ErrorOut,
    JobFileOut,
    JobList,
    JobOut,
    JobSpec,
    JobSpecSchemasOut,
    JobState,
    LogLineOut,
    Progress,
)
from backend.streams import StreamSlots
from fringelab.core.accounts import Principal, audit, readable_experiments
from fringelab.core.app_state import AppState
from fringelab.core.calibration_pairs import warnings_of
from fringelab.core.deletion import execute, plan_job
from fringelab.core.errors import Gone, NotFound, Unauthorized, Unavailable
from fringelab.core.job_kinds import named_by, spec_schemas
from fringelab.core.jobs import (
    QueueUnavailable,
    as_utc,
    cancel_job,
    eta_seconds,
    job_error,
    job_for,
    retry_job,
    start_job_as,
    terminate_unstopped,
)
from fringelab.core.models import Camera, Experiment, Job, JobChunk, JobLog, Recording, utcnow

router = APIRouter(tags=["jobs"])
log = logging.getLogger(__name__)
EVENTS_POLL_S = 0.25
EVENTS_ACCESS_CHECK_S = 2.0  # an open event stream checks its reader's token and access this often


def _seconds(start: datetime | None, end: datetime | None) -> float | None:
    start, end = as_utc(start), as_utc(end)
    return (end - start).total_seconds() if start and end else None


# What a job's answer reads of it: the list selects these columns (plain rows, no ORM objects: loading 50 jobs as
# objects was most of a list's cost), and a job loaded as an object has the same attributes, so `_job_out` makes
# both answers.
JOB_COLUMNS = (Job.id, Job.kind, Job.state, Job.spec, Job.experiment_id, Job.stage, Job.progress_done,
               Job.progress_total, Job.error, Job.worker, Job.files, Job.result, Job.provenance, Job.attempt,
               Job.retry_of, Job.created_at, Job.started_at, Job.finished_at, Job.stage_started_at)  # fmt: skip
# A row's `index` is the tuple method: the chunk's index is selected as `number`.
CHUNK_COLUMNS = (JobChunk.job_id, JobChunk.phase, JobChunk.index.label("number"), JobChunk.first_frame,
                 JobChunk.stop_frame, JobChunk.state, JobChunk.done, JobChunk.worker, JobChunk.started_at,
                 JobChunk.finished_at)  # fmt: skip
JobRow = Job | Row[Any]
# The queries of `job_outs`, built once with the ids bound at execution: building them (each id coerced into the
# statement) cost more than running them.
_IDS: BindParameter[list[Any]] = bindparam("ids", expanding=True)
CHUNKS_OF = select(*CHUNK_COLUMNS).where(JobChunk.job_id.in_(_IDS)).order_by(JobChunk.phase, JobChunk.index)
RETRIES_OF = select(Job.retry_of, Job.id).where(Job.retry_of.in_(_IDS)).order_by(Job.created_at, Job.id)
SOURCES = select(Job.id, Job.kind, Job.spec).where(Job.id.in_(_IDS))
CAMERA_NAMES = select(Recording.id, Camera.name).join(Camera, Camera.id == Recording.camera_id)
CAMERA_NAMES = CAMERA_NAMES.where(Recording.id.in_(_IDS))
EXPERIMENT_NAMES = select(Experiment.id, Experiment.name).where(Experiment.id.in_(_IDS))


def job_out(session: Session, job: Job, *, now: datetime | None = None) -> JobOut:
    return job_outs(session, [job], now=now)[0]


def job_outs(
    session: Session,
    jobs: Sequence[JobRow],
    *,
    now: datetime | None = None,
    experiment_names: Mapping[str, str | None] | None = None,
) -> list[JobOut]:
    """The jobs (objects, or rows of JOB_COLUMNS) as the API shows them, with a few queries for all of them (their
    chunks, their retries, their names), not per job: a list of 50 jobs asked 100 queries before.
    `experiment_names`: each job's experiment name when the caller has it already (the list joins it)."""
    now = now or utcnow()
    ids = [job.id for job in jobs]
    chunks_of: dict[str, list[Row[Any]]] = defaultdict(list)
    retried_by: dict[str | None, str] = {}
    if ids:
        for chunk in session.execute(CHUNKS_OF, {"ids": ids}):
            chunks_of[chunk.job_id].append(chunk)  # type: ignore[arg-type]  # a Row of CHUNK_COLUMNS
        for retry_of, retry_id in session.execute(RETRIES_OF, {"ids": ids}):
            retried_by[retry_of] = retry_id  # the newest retry last
    names = _names_of(session, jobs, experiment_names)
    return [_job_out(job, chunks_of[job.id], retried_by.get(job.id), now, names[job.id]) for job in jobs]


def _names_of(
    session: Session, jobs: Sequence[JobRow], experiment_names: Mapping[str, str | None] | None
) -> dict[str, tuple[str | None, str | None]]:
    """Each job's experiment name (from `experiment_names` when given) and camera name: the camera of the recording
    it reads, or of the recording of the job it reads (an export, a comparison), as its kind's inputs name them;
    at most three queries for all the jobs (none for what no job names). A list names what each job is about."""

    def first(ids: set[Any]) -> Any:
        return min(ids) if ids else None

    sources = {job.id: first(named_by(job.kind, job.spec, "job")) for job in jobs}
    source_ids = set(sources.values()) - {None}
    recording_of_source: dict[str, Any] = {}
    if source_ids:
        found = session.execute(SOURCES, {"ids": list(source_ids)})
        recording_of_source = {job_id: first(named_by(kind, spec, "recording")) for job_id, kind, spec in found}
    recording_of = {job.id: first(named_by(job.kind, job.spec, "recording")) for job in jobs}
    for job in jobs:
        recording_of[job.id] = recording_of[job.id] or recording_of_source.get(sources[job.id])
    recording_ids = set(recording_of.values()) - {None}
    camera_of_recording: dict[Any, str] = {}
    if recording_ids:
        found_cameras = session.execute(CAMERA_NAMES, {"ids": list(recording_ids)})
        camera_of_recording = {recording_id: name for recording_id, name in found_cameras}
    if experiment_names is None:
        experiment_ids = {job.experiment_id for job in jobs if job.experiment_id is not None}
        by_id: dict[int, str] = {}
        if experiment_ids:
            by_id = {id_: name for id_, name in session.execute(EXPERIMENT_NAMES, {"ids": list(experiment_ids)})}
        experiment_names = {job.id: by_id.get(job.experiment_id) for job in jobs if job.experiment_id is not None}
    return {
        job.id: (
            experiment_names.get(job.id) if job.experiment_id is not None else None,
            camera_of_recording.get(recording_of[job.id]),
        )
        for job in jobs
    }


def _job_out(
    job: JobRow, chunks: list[Row[Any]], retried_by: str | None, now: datetime, names: tuple[str | None, str | None]
) -> JobOut:
    total = job.progress_total
    return JobOut(
        id=job.id,
        kind=job.kind,
        state=job.state,  # type: ignore[arg-type]
        stopping=job.state == "cancelled" and job.finished_at is None,
        spec=job.spec,
        experiment_id=job.experiment_id,
        experiment_name=names[0],
        camera_name=names[1],
        progress=Progress(
            stage=job.stage,
            done=job.progress_done,
            total=total,
            # a failed job stopped where it failed: no share done to show (it is not 93 % of anything)
            fraction=job.progress_done / total if total and job.state != "failed" else None,
            eta_s=eta_seconds(job, now=now),
        ),
        error=job.error,
        worker=job.worker,
        files=[
            JobFileOut(
                name=f["name"],
                size_bytes=f["size_bytes"],
                sha256=f["sha256"],
                media_type=f["media_type"],
                url=f"/api/v1/jobs/{job.id}/files/{f['name']}",
            )
            for f in job.files
        ],
        result=job.result,
        provenance=job.provenance,
        warnings=warnings_of(job.provenance),
        attempt=job.attempt,
        retry_of=job.retry_of,
        retried_by=retried_by,
        chunks=[
            ChunkOut(
                phase=c.phase,
                index=c.number,
                first_frame=c.first_frame,
                stop_frame=c.stop_frame,
                state=c.state,
                done=c.done,
                worker=c.worker,
                started_at=as_utc(c.started_at),
                finished_at=as_utc(c.finished_at),
            )
            for c in chunks
        ],
        created_at=as_utc(job.created_at),
        started_at=as_utc(job.started_at),
        finished_at=as_utc(job.finished_at),
        duration_s=_seconds(job.started_at, job.finished_at or now),
    )


WRITE_ERRORS: dict[int | str, dict[str, Any]] = {
    **JOB_ERRORS,
    403: {"model": ErrorOut, "description": "Read-only access to the experiment (or a selftest without admin)."},
}


@router.post("/jobs", status_code=201, response_model=JobOut, responses=WRITE_ERRORS)
def start_job(spec: Annotated[JobSpec, Body()], session: SessionDep, state: StateDep, principal: CurrentUser) -> JobOut:
    """Check the spec against the recordings and calibrations it names, then queue the job."""
    job = start_job_as(session, state.celery, principal, spec)
    return job_out(session, job)


@router.get("/jobs", response_model=JobList)
def list_jobs(
    session: SessionDep,
    principal: CurrentUser,
    kind: str | None = None,
    state: JobState | None = None,
    experiment_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Query(ge=0, le=MAX_ID)] = 0,
) -> Response:
    """Jobs, newest first."""
    return json_response(_job_list(session, principal, kind, state, experiment_id, limit=limit, offset=offset))


def json_response(answer: BaseModel) -> Response:
    """`answer` as the JSON FastAPI would make of it under its route's response_model, made here: FastAPI would
    validate the model again and serialise it in a second trip to a worker thread (a hot read's largest cost after
    its queries). The OpenAPI document still takes the route's response_model."""
    return Response(answer.model_dump_json().encode(), media_type="application/json")


def _job_list(
    session: Session,
    principal: Principal,
    kind: str | None,
    state: JobState | None,
    experiment_id: int | None,
    *,
    limit: int,
    offset: int,
) -> JobList:
    """The page of jobs, newest first, with their experiments' names and the total of what the filters select,
    in one query (plus those of `job_outs`)."""
    query = select(*JOB_COLUMNS, Experiment.name.label("experiment_name"), func.count().over().label("total"))
    query = query.outerjoin(Experiment, Experiment.id == Job.experiment_id)
    if not principal.is_admin:
        query = query.where(
            Job.experiment_id.in_(select(Experiment.id).where(readable_experiments(session, principal)))
        )
    if kind is not None:
        query = query.where(Job.kind == kind)
    if state is not None:
        query = query.where(Job.state == state)
    if experiment_id is not None:
        query = query.where(Job.experiment_id == experiment_id)
    rows = session.execute(query.order_by(Job.created_at.desc(), Job.id).limit(limit).offset(offset)).all()
    if rows:
        total = rows[0].total
    else:  # a page past the end has no row to carry the total
        total = (session.scalar(select(func.count()).select_from(query.subquery())) or 0) if offset else 0
    names = {row.id: row.experiment_name for row in rows}
    return JobList(items=job_outs(session, rows, experiment_names=names), total=total)


@router.get("/jobs/specs", response_model=JobSpecSchemasOut)
def job_specs(_principal: CurrentUser) -> dict[str, Any]:
    """The JSON Schema of every job spec this server takes (made once per process)."""
    return spec_schemas()


def _visible_jobs(session: Session, principal: Principal, experiment_id: int | None) -> Any:
    query = select(Job.id, Job.state, Job.stage, Job.progress_done, Job.worker, Job.finished_at)
    if not principal.is_admin:
        query = query.where(
            Job.experiment_id.in_(select(Experiment.id).where(readable_experiments(session, principal)))
        )
    if experiment_id is not None:
        query = query.where(Job.experiment_id == experiment_id)
    return query


def _list_marks(state: AppState, principal: Principal, experiment_id: int | None) -> dict[str, str]:
    """A mark of each job the caller may see, which changes when the job does (its worker too: a job's pass in
    frame order may run on another process than its start, and the queue page shows it): cheap enough to ask
    twice a second (and shared by every stream of the same view, see `_list_view`)."""
    with state.sessions() as session:
        rows = session.execute(_visible_jobs(session, principal, experiment_id)).all()
    return {row.id: f"{row.state}|{row.stage}|{row.progress_done}|{row.worker}|{row.finished_at}" for row in rows}


def _list_view(principal: Principal, experiment_id: int | None) -> tuple[object, ...]:
    """Which jobs list a stream watches: admins all see the same one, members each their own."""
    return ("jobs", "admin" if principal.is_admin else principal.user_id, experiment_id)


def polls_of(request: Request) -> SharedPolls:
    return request.app.state.polls


def stream_slot(request: Request, principal: CurrentUser) -> int:
    """One of the caller's event-stream slots in this process (429 beyond FRINGELAB_EVENT_STREAMS_PER_USER),
    taken before the stream's answer starts; the stream gives it back when it ends."""
    slots: StreamSlots = request.app.state.stream_slots
    return slots.take(principal.username, name=principal.username)


StreamSlot = Annotated[int, Depends(stream_slot)]


@router.get("/jobs/events", response_class=EventSourceResponse, responses=error_responses(401, 422, 429))
async def jobs_events(
    state: StateDep,
    request: Request,
    principal: CurrentUser,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)],
    slot: StreamSlot,
    experiment_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
) -> AsyncIterator[ServerSentEvent]:
    """Changes of the jobs list as Server-Sent Events: `jobs` ({"changed": [ids], "total": n}) whenever a job the
    caller may see (of `experiment_id`, or any) is added, moves on, ends or goes; the dashboard's lists and the
    queue page refresh on it instead of polling. Comments keep it alive; it closes after FRINGELAB_LIST_EVENTS_S
    and the browser's EventSource reconnects (the first event after a reconnect names every job). The reader's
    token is checked again every few seconds: once it is revoked (or the account disabled) the stream sends
    `end` with the reason and closes."""
    with request.app.state.stream_slots.held(principal.username, slot):
        async for event in _jobs_events(state, request, principal, credentials, experiment_id):
            yield event


async def _jobs_events(
    state: AppState,
    request: Request,
    principal: Principal,
    credentials: HTTPAuthorizationCredentials | None,
    experiment_id: int | None,
) -> AsyncIterator[ServerSentEvent]:
    secret = request_secret(request, credentials)
    polls = polls_of(request)
    last: dict[str, str] | None = None
    idle_s = 0.0
    checked_at_s = anyio.current_time()
    ends = anyio.current_time() + state.settings.list_events_s  # then the browser reconnects (retry)
    while anyio.current_time() < ends:
        if anyio.current_time() - checked_at_s >= EVENTS_ACCESS_CHECK_S:
            checked_at_s = anyio.current_time()
            try:  # the role may have changed too: the list then shows what the reader may see now
                principal = await anyio.to_thread.run_sync(lambda: principal_of(request, state, secret, count=False))
            except Unauthorized as error:
                yield ServerSentEvent(
                    event="end", data={"state": "forbidden", "error": f"access ended: {error.detail}"}
                )
                return
        marks = await polls.get(
            _list_view(principal, experiment_id), partial(_list_marks, state, principal, experiment_id)
        )
        if marks != last:
            changed = sorted(k for k in set(marks) | set(last or {}) if (last or {}).get(k) != marks.get(k))
            last = marks
            idle_s = 0.0
            yield ServerSentEvent(event="jobs", data={"changed": changed, "total": len(marks)}, retry=2000)
        elif idle_s >= 15.0:
            idle_s = 0.0
            yield ServerSentEvent(comment="keep-alive")
        await anyio.sleep(EVENTS_POLL_S * 2)
        idle_s += EVENTS_POLL_S * 2


@router.get("/jobs/{job_id}", response_model=JobOut, responses=JOB_ERRORS)
def read_job(job: JobDep, session: SessionDep) -> Response:
    return json_response(job_out(session, job))  # polled by every open job page: no validation trip


@router.get("/jobs/{job_id}/log", response_model=list[LogLineOut], responses=JOB_ERRORS)
def read_log(
    job: JobDep,
    session: SessionDep,
    after: Annotated[int, Query(ge=0, le=2**63 - 1, description="Only lines with a larger id.")] = 0,
    limit: Annotated[int, Query(ge=1, le=5000)] = 1000,
) -> list[LogLineOut]:
    """The job's log lines, oldest first."""
    return _log_lines(session, job.id, after=after, limit=limit)


def _log_lines(session: Session, job_id: str, *, after: int, limit: int = 1000) -> list[LogLineOut]:
    lines = session.scalars(
        select(JobLog).where(JobLog.job_id == job_id, JobLog.id > after).order_by(JobLog.id).limit(limit)
    )
    return [
        LogLineOut(id=line.id, at=as_utc(line.created_at), level=line.level, message=line.message) for line in lines
    ]


def _streamable_job_id(job_id: str, state: StateDep, principal: CurrentUser) -> str:
    """The access check of the event stream, in a short session of its own: a request-long session would stay
    open while the stream runs (and keep SQLite's write-ahead log from being checkpointed)."""
    with state.sessions() as session:
        return job_for(session, principal, job_id).id


@router.get(
    "/jobs/{job_id}/events", response_class=EventSourceResponse, responses={**JOB_ERRORS, **error_responses(429)}
)
async def job_events(
    job_id: Annotated[str, Depends(_streamable_job_id)],
    state: StateDep,
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)],
    principal: CurrentUser,
    slot: StreamSlot,
) -> AsyncIterator[ServerSentEvent]:
    """Live progress as Server-Sent Events: `job` (the job as `GET /jobs/{id}` shows it) whenever it changes,
    `log` for each new log line, and `end` once the job has ended; then the stream closes. Access is checked
    again every few seconds while the stream is open: a revoked token, a disabled account or a lost share ends
    it with an `end` event whose error says so. A user holds at most FRINGELAB_EVENT_STREAMS_PER_USER streams
    per web server process (429 beyond)."""
    with request.app.state.stream_slots.held(principal.username, slot):
        async for event in _job_events(job_id, state, request, credentials):
            yield event


async def _job_events(
    job_id: str, state: AppState, request: Request, credentials: HTTPAuthorizationCredentials | None
) -> AsyncIterator[ServerSentEvent]:
    secret = request_secret(request, credentials)
    polls = polls_of(request)
    last_view: dict[str, Any] | None = None
    last_line = 0
    sequence = 0
    checked_at_s = anyio.current_time()
    while True:
        if anyio.current_time() - checked_at_s >= EVENTS_ACCESS_CHECK_S:
            checked_at_s = anyio.current_time()
            refusal = await anyio.to_thread.run_sync(_access_refusal, request, state, secret, job_id)
            if refusal:
                yield ServerSentEvent(event="end", data={"state": "forbidden", "error": refusal})
                return
        view, newest_line = await polls.get(("job", job_id), partial(_job_view, state, job_id))
        if view is None:
            return
        lines: list[LogLineOut] = []
        if newest_line > last_line:  # streams that are as far along share one read of the new lines
            lines = await polls.get(("log", job_id, last_line), partial(_log_after, state, job_id, last_line))
        for line in lines:
            last_line = line.id
            yield ServerSentEvent(event="log", data=line, id=f"log-{line.id}")
        comparable = view.model_dump(exclude={"progress": {"eta_s"}, "duration_s": True})
        if comparable != last_view:
            last_view = comparable
            sequence += 1
            yield ServerSentEvent(event="job", data=view, id=str(sequence), retry=2000)
        if view.state not in ("queued", "running") and not view.stopping:
            yield ServerSentEvent(event="end", data={"state": view.state, "error": view.error})
            return
        await anyio.sleep(EVENTS_POLL_S)


def _access_refusal(request: Request, state: AppState, secret: str | None, job_id: str) -> str:
    """Why the stream's reader may no longer see the job ("" while they may)."""
    try:
        principal = principal_of(request, state, secret, count=False)
        with state.sessions() as session:
            job_for(session, principal, job_id)
    except (Unauthorized, NotFound) as error:
        return f"access ended: {error.detail}"
    return ""


def _job_view(state: AppState, job_id: str) -> tuple[JobOut | None, int]:
    """The job as its event stream shows it (None once deleted) and the id of its newest log line."""
    with state.sessions() as session:
        job = session.get(Job, job_id)
        if job is None:
            return None, 0
        newest = session.scalar(select(func.max(JobLog.id)).where(JobLog.job_id == job_id)) or 0
        return job_out(session, job), newest


def _log_after(state: AppState, job_id: str, after: int) -> list[LogLineOut]:
    with state.sessions() as session:
        return _log_lines(session, job_id, after=after)


@router.get("/jobs/{job_id}/deletion", response_model=DeletionOut, responses=WRITE_ERRORS)
def job_deletion(writable: WritableJobDep, session: SessionDep, state: StateDep) -> DeletionOut:
    """What deleting the job takes with it (its files, log, calibration, exports), and the jobs that stop it now
    (itself while queued or running, jobs using its calibration or result); nothing is deleted."""
    return deletion_out(plan_job(session, state.settings, writable))


@router.delete("/jobs/{job_id}", status_code=204, responses=WRITE_ERRORS)
def remove_job(writable: WritableJobDep, session: SessionDep, state: StateDep, principal: CurrentUser) -> Response:
    """Deletes a finished job with its result files, log, calibration and exports; 409 `in_use` while it is
    queued or running (cancel it first) or a queued or running job uses its calibration or result."""
    plan = plan_job(session, state.settings, writable)
    execute(session, state.settings, principal, plan, kind="job", id=writable.id)
    return Response(status_code=204)


@router.post("/jobs/{job_id}/cancel", response_model=JobOut, responses=WRITE_ERRORS)
def cancel(writable: WritableJobDep, session: SessionDep, state: StateDep, principal: CurrentUser) -> JobOut:
    """Cancel a queued or running job. A running task stops after its current frame; one that has not stopped
    after FRINGELAB_CANCEL_GRACE_S has its worker process terminated (prefork workers)."""
    job = cancel_job(session, state.celery, writable.id)
    audit(session, principal, "cancel", "job", job.id)
    session.commit()
    if job.finished_at is None:
        _terminate_later(state, job.id)
    return job_out(session, job)


def _terminate_later(state: AppState, job_id: str) -> None:
    grace_s = state.settings.cancel_grace_s

    def terminate() -> None:
        try:
            with state.sessions() as session:
                terminate_unstopped(session, state.celery, job_id, grace_s=grace_s)
        except Exception:  # the next API start-up closes the job instead (fringelab.core.reconcile)
            log.exception("could not terminate the task of cancelled job %s", job_id)

    timer = threading.Timer(grace_s, terminate)
    timer.daemon = True
    timer.start()


@router.post("/jobs/{job_id}/retry", status_code=201, response_model=JobOut, responses=WRITE_ERRORS)
def retry(writable: WritableJobDep, session: SessionDep, state: StateDep, principal: CurrentUser) -> JobOut:
    """A new attempt of a failed or cancelled job with the same spec (checked again), linked by `retry_of`."""
    try:
        job = retry_job(session, state.celery, writable.id)
    except QueueUnavailable as error:
        raise job_error(Unavailable, "queue_unavailable", str(error)) from None
    audit(session, principal, "retry", "job", job.id, retry_of=writable.id)
    session.commit()
    return job_out(session, job)


@router.get(
    "/jobs/{job_id}/files/{name:path}",
    response_class=FileResponse,
    responses={
        **JOB_ERRORS,
        200: {"content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}},
        410: {"model": ErrorOut, "description": "The file is no longer on disk; retry the job."},
    },
)
def download(job: JobDep, name: str, state: StateDep) -> FileResponse:
    """A result file of the job, streamed."""
    entry = next((f for f in job.files if f["name"] == name), None)
    if entry is None:
        raise job_error(NotFound, "file_not_found", f"job {job.id} has no file {name!r}; see its `files`")
    path = state.settings.data_path / entry["path"]
    if not path.is_file():
        raise job_error(Gone, "file_missing", f"{name} of job {job.id} is no longer on disk; retry the job")
    return FileResponse(path, media_type=entry["media_type"], filename=path.name)
