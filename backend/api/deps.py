"""Typed dependencies shared by the routers: state, database session, the principal and access checks (of
experiments, cameras, recordings, jobs and calibrations).

The access checks are dependencies on the path parameters (`ReadableExperiment`, `WritableCamera`, ...): FastAPI
solves dependencies before it validates a request body, so someone without access gets a 404 (or 401) whatever
they send, and never learns from a 422 that a route exists for that id. (A body that is not JSON at all is
refused with a 422 before any dependency runs; that says nothing about the object either.)
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated

import anyio
from fastapi import Depends, Path, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from backend.schemas.common import MAX_ID
from fringelab.core.accounts import LOCAL_ADMIN, AuthError, Principal, require_access
from fringelab.core.app_state import AppState
from fringelab.core.errors import Forbidden, NotFound, RateLimited, Unauthorized
from fringelab.core.jobs import job_error, job_for
from fringelab.core.models import Calibration, Camera, Experiment, Job, Recording
from fringelab.core.recordings import camera_for, recording_for

SESSION_COOKIE = "fringelab_session"
bearer_scheme = _bearer = HTTPBearer(
    auto_error=False, description="An API token (`flb_...`) or the browser's session cookie."
)


async def get_state(request: Request) -> AppState:
    """Async, as it only reads the app: FastAPI runs a plain function dependency in a worker thread, a trip that
    cost more than this does, on every request."""
    return request.app.state.fringelab


async def get_session(state: Annotated[AppState, Depends(get_state)]) -> AsyncIterator[Session]:
    """The request's session: made in the event loop (a session does no I/O before its first query; a plain
    generator would cost a trip to a worker thread to make it) and closed in a worker thread (giving its
    connection back may talk to the database), shielded, so that a cancelled request still gives it back."""
    session = state.sessions()
    try:
        yield session
    finally:
        with anyio.CancelScope(shield=True):
            await anyio.to_thread.run_sync(session.close)


StateDep = Annotated[AppState, Depends(get_state)]
SessionDep = Annotated[Session, Depends(get_session)]


def request_secret(request: Request, credentials: HTTPAuthorizationCredentials | None) -> str | None:
    return credentials.credentials if credentials else request.cookies.get(SESSION_COOKIE)


def principal_of(request: Request, state: AppState, secret: str | None, *, count: bool = True) -> Principal:
    """Who sends the request (from the token cache; no database write), counted against their request rate
    (`count`: an open event stream's re-checks are not requests). May ask the database and Redis: not on the
    event loop (`held_principal` is)."""
    principal = _held_principal(request, state, secret, count=count, ask=True)
    assert principal is not None  # asking, it always has an answer
    return principal


def held_principal(request: Request, state: AppState, secret: str | None) -> Principal | None:
    """`principal_of` when it needs to ask nothing (a token in the cache, a user with leased requests left):
    fit for the event loop; None when it would ask the database or Redis."""
    return _held_principal(request, state, secret, count=True, ask=False)


def _held_principal(
    request: Request, state: AppState, secret: str | None, *, count: bool, ask: bool
) -> Principal | None:
    if not state.settings.auth_enabled:
        return LOCAL_ADMIN
    if not secret:
        raise Unauthorized("authentication required: send `Authorization: Bearer <token>` or log in")
    try:
        principal = state.tokens.resolve(state.sessions, secret) if ask else state.tokens.cached(secret)
    except AuthError as error:
        raise Unauthorized(str(error)) from None
    if principal is None:
        return None
    limiter = request.app.state.user_limiter
    wait_s: float | None = 0.0
    if count:
        wait_s = limiter.take(principal.user_id) if ask else limiter.take_held(principal.user_id)
    if wait_s is None:
        return None
    if wait_s > 0:
        raise RateLimited(
            f"too many requests from {principal.username} (over {state.settings.user_requests_per_s:g}/s); "
            "slow down and retry",
            retry_after_s=wait_s,
        )
    return principal


async def get_principal(
    request: Request,
    state: StateDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Principal:
    """Async: most requests come with a token checked moments ago and a user with leased requests left, answered
    on the event loop; a plain function dependency cost every request a trip to a worker thread (issue 26).
    Only the others go to a thread, to ask the database or Redis."""
    secret = request_secret(request, credentials)
    principal = held_principal(request, state, secret)
    if principal is None:
        principal = await anyio.to_thread.run_sync(principal_of, request, state, secret)
    return principal


CurrentUser = Annotated[Principal, Depends(get_principal)]


def get_admin(principal: CurrentUser) -> Principal:
    if not principal.is_admin:
        raise Forbidden("this needs an admin account")
    return principal


AdminUser = Annotated[Principal, Depends(get_admin)]


def experiment_for(session: Session, principal: Principal, experiment_id: int, *, write: bool = False) -> Experiment:
    """The experiment if `principal` may read it (or write it); otherwise a 404, as if it did not exist."""
    experiment = session.get(Experiment, experiment_id)
    if experiment is None:
        raise NotFound(f"experiment {experiment_id} not found")
    require_access(session, principal, experiment, write=write, what=f"experiment {experiment_id}")
    return experiment


# Ids are 32-bit integers in the database; a larger one is a 422, not an overflow deep in the driver.
ExperimentId = Annotated[int, Path(ge=1, le=MAX_ID, description="An experiment id.")]
CameraId = Annotated[int, Path(ge=1, le=MAX_ID, description="A camera id.")]
RecordingId = Annotated[int, Path(ge=1, le=MAX_ID, description="A recording id.")]


def readable_experiment(experiment_id: ExperimentId, session: SessionDep, principal: CurrentUser) -> Experiment:
    return experiment_for(session, principal, experiment_id)


def writable_experiment(experiment_id: ExperimentId, session: SessionDep, principal: CurrentUser) -> Experiment:
    return experiment_for(session, principal, experiment_id, write=True)


def readable_camera(camera_id: CameraId, session: SessionDep, principal: CurrentUser) -> Camera:
    return camera_for(session, principal, camera_id)


def writable_camera(camera_id: CameraId, session: SessionDep, principal: CurrentUser) -> Camera:
    return camera_for(session, principal, camera_id, write=True)


def readable_recording(recording_id: RecordingId, session: SessionDep, principal: CurrentUser) -> Recording:
    return recording_for(session, principal, recording_id)


def writable_recording(recording_id: RecordingId, session: SessionDep, principal: CurrentUser) -> Recording:
    return recording_for(session, principal, recording_id, write=True)


def readable_recording_id(recording_id: RecordingId, state: StateDep, principal: CurrentUser) -> int:
    """The access check of a streaming route, in a short session of its own: a request-long session would stay
    open while the body or the response streams."""
    with state.sessions() as session:
        return recording_for(session, principal, recording_id).id


def writable_recording_id(recording_id: RecordingId, state: StateDep, principal: CurrentUser) -> int:
    with state.sessions() as session:
        return recording_for(session, principal, recording_id, write=True).id


def writable_camera_id(camera_id: CameraId, state: StateDep, principal: CurrentUser) -> int:
    with state.sessions() as session:
        return camera_for(session, principal, camera_id, write=True).id


ReadableExperiment = Annotated[Experiment, Depends(readable_experiment)]
WritableExperiment = Annotated[Experiment, Depends(writable_experiment)]
ReadableCamera = Annotated[Camera, Depends(readable_camera)]
WritableCamera = Annotated[Camera, Depends(writable_camera)]
ReadableRecording = Annotated[Recording, Depends(readable_recording)]
WritableRecording = Annotated[Recording, Depends(writable_recording)]
ReadableRecordingId = Annotated[int, Depends(readable_recording_id)]
WritableRecordingId = Annotated[int, Depends(writable_recording_id)]
WritableCameraId = Annotated[int, Depends(writable_camera_id)]


def readable_job(job_id: str, session: SessionDep, principal: CurrentUser) -> Job:
    return job_for(session, principal, job_id)


def writable_job(job_id: str, session: SessionDep, principal: CurrentUser) -> Job:
    return job_for(session, principal, job_id, write=True)


JobDep = Annotated[Job, Depends(readable_job)]


WritableJobDep = Annotated[Job, Depends(writable_job)]


def readable_calibration(
    calibration_id: Annotated[int, Path(ge=1, le=MAX_ID)], session: SessionDep, principal: CurrentUser
) -> Calibration:
    missing = job_error(NotFound, "calibration_not_found", f"there is no calibration {calibration_id}")
    row = session.get(Calibration, calibration_id)
    camera = session.get(Camera, row.camera_id) if row else None
    if row is None or camera is None:
        raise missing
    try:
        experiment_for(session, principal, camera.experiment_id)
    except NotFound:
        raise missing from None
    return row


CalibrationDep = Annotated[Calibration, Depends(readable_calibration)]
