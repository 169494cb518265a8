"""Recordings: list, read, update, delete; re-run the ingest; add a sidecar; frame previews, QA and the file.

Uploads (tus and PUT) are in `backend.api.uploads`. Frames are served from the preview store the ingest wrote
(`fringelab.formats.previews`): display size at most FRINGELAB_PREVIEW_SIZE_PX, 8-bit; the original file, with its
frames at full resolution and bit depth, is downloaded whole from `/recordings/{id}/file`.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, Request, Response
from fastapi.responses import FileResponse
from sqlalchemy import select
from starlette.concurrency import run_in_threadpool

from backend.api.deps import (
    CurrentUser,
    ReadableCamera,
    ReadableRecording,
    ReadableRecordingId,
    SessionDep,
    StateDep,
    WritableRecording,
    WritableRecordingId,
)
from backend.errors import error_responses
from backend.schemas.common import MAX_ID
from backend.schemas.deletion import DeletionOut, deletion_out
from backend.schemas.recordings import (
    FrameQa,
    RecordingKind,
    RecordingOut,
    RecordingQa,
    RecordingState,
    RecordingUpdate,
    SidecarName,
    recording_out,
)
from fringelab.core.accounts import Principal, audit, readable_experiments
from fringelab.core.deletion import plan_recording
from fringelab.core.errors import Conflict, Invalid, NotFound
from fringelab.core.models import Camera, Experiment, Recording
from fringelab.core.recordings import delete_recording, recording_for, refuse_if_in_use, start_ingest, submit_ingest
from fringelab.core.storage import recording_dir
from fringelab.formats.atomic import atomic_write
from fringelab.formats.previews import PREVIEW_FILE, encode_png, read_preview, read_qa

router = APIRouter(tags=["recordings"])


@router.get("/recordings", response_model=list[RecordingOut], responses=error_responses(401, 422))
def list_recordings(
    session: SessionDep,
    principal: CurrentUser,
    experiment_id: int | None = Query(None, ge=1, le=MAX_ID),
    camera_id: int | None = Query(None, ge=1, le=MAX_ID),
    kind: RecordingKind | None = None,
    state: RecordingState | None = None,
    upload_id: str | None = Query(None, description="The tus upload a recording came from."),
    limit: int = Query(500, ge=1, le=5000),
    offset: int = Query(0, ge=0, le=MAX_ID),
) -> list[RecordingOut]:
    """The recordings the caller may read, oldest first, filtered by any of the parameters."""
    query = select(Recording).join(Camera).join(Experiment).where(readable_experiments(session, principal))
    query = query.order_by(Recording.id)
    for column, value in (
        (Camera.experiment_id, experiment_id),
        (Recording.camera_id, camera_id),
        (Recording.kind, kind),
        (Recording.state, state),
        (Recording.upload_id, upload_id),
    ):
        if value is not None:
            query = query.where(column == value)
    return [recording_out(r) for r in session.scalars(query.limit(limit).offset(offset))]


@router.get(
    "/cameras/{camera_id}/recordings", response_model=list[RecordingOut], responses=error_responses(401, 404, 422)
)
def list_camera_recordings(camera: ReadableCamera) -> list[RecordingOut]:
    return [recording_out(r) for r in sorted(camera.recordings, key=lambda r: r.id)]


@router.get("/recordings/{recording_id}", response_model=RecordingOut, responses=error_responses(401, 404, 422))
def read_recording(recording: ReadableRecording) -> RecordingOut:
    return recording_out(recording)


@router.patch(
    "/recordings/{recording_id}", response_model=RecordingOut, responses=error_responses(401, 403, 404, 409, 422)
)
def update_recording(
    recording: WritableRecording, body: RecordingUpdate, session: SessionDep, state: StateDep
) -> RecordingOut:
    """A new kind re-runs the ingest (board detection, Z checks depend on it); refused while a job uses it."""
    if body.filename is not None:
        recording.filename = body.filename
    if body.kind is not None and body.kind != recording.kind:
        refuse_if_in_use(session, f"recording {recording.id}", recording_ids=[recording.id])
        recording.kind = body.kind
        submit_ingest(session, state, recording)
    session.commit()
    return recording_out(recording)


@router.get(
    "/recordings/{recording_id}/deletion", response_model=DeletionOut, responses=error_responses(401, 403, 404, 422)
)
def recording_deletion(recording: WritableRecording, session: SessionDep, state: StateDep) -> DeletionOut:
    """What deleting the recording takes with it, and the jobs that stop it now (nothing is deleted)."""
    return deletion_out(plan_recording(session, state.settings, recording))


@router.delete("/recordings/{recording_id}", status_code=204, responses=error_responses(401, 403, 404, 409, 422))
def remove_recording(
    recording: WritableRecording, session: SessionDep, state: StateDep, principal: CurrentUser
) -> Response:
    """Deletes the recording and its files, and the finished jobs on it with their results; 409 `in_use` naming
    the jobs while a queued or running job (its ingest too) uses it."""
    delete_recording(session, state.settings, principal, recording)
    return Response(status_code=204)


@router.post(
    "/recordings/{recording_id}/ingest",
    status_code=202,
    response_model=RecordingOut,
    responses=error_responses(401, 403, 404, 409, 422, 503),
)
def reingest_recording(recording: WritableRecording, session: SessionDep, state: StateDep) -> RecordingOut:
    """Checks the recording again (new job; `ingest_job_id` names it)."""
    return recording_out(start_ingest(session, state, recording))


@router.put(
    "/recordings/{recording_id}/sidecars/{name}",
    status_code=202,
    response_model=RecordingOut,
    responses=error_responses(401, 403, 404, 409, 413, 422, 503),
    openapi_extra={
        "requestBody": {
            "content": {"text/plain": {"schema": {"type": "string"}, "example": "frame,z_mm\n0,0.0\n1,2.0\n2,4.0\n"}},
            "required": True,
        }
    },
)
async def put_sidecar(
    recording_id: WritableRecordingId, name: SidecarName, request: Request, state: StateDep, principal: CurrentUser
) -> RecordingOut:
    """Adds or replaces `z.csv`, `frames.csv` or `board.json` (the body, UTF-8 text, at most
    FRINGELAB_MAX_JSON_BYTES) and re-runs the ingest, which validates it against the frames. A sidecar added
    this way wins over one inside a ZIP."""
    body = await request.body()
    return await run_in_threadpool(_store_sidecar, state, principal, recording_id, name, body)


def _store_sidecar(state: StateDep, principal: Principal, recording_id: int, name: str, data: bytes) -> RecordingOut:
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        raise Invalid(f"{name}: not UTF-8 text", code="invalid_sidecar") from None
    with state.sessions() as session:
        recording = recording_for(session, principal, recording_id, write=True)
        refuse_if_in_use(session, f"recording {recording.id}", recording_ids=[recording.id])
        atomic_write(recording_dir(state.settings.data_path, recording.id) / name, data)
        audit(session, principal, "upload", "sidecar", recording.id, name=name, size_bytes=len(data))
        return recording_out(submit_ingest(session, state, recording))


@router.get(
    "/recordings/{recording_id}/frames/{index}",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}}, **error_responses(401, 404, 409, 422)},
)
async def frame_png(
    recording_id: ReadableRecordingId,
    index: Annotated[int, Path(ge=0, le=MAX_ID, description="Frame number, 0-based.")],
    state: StateDep,
    principal: CurrentUser,
    max_px: int | None = Query(None, ge=16, le=8192, description="Longer side at most this (default: stored)."),
) -> Response:
    """Frame `index` (0-based) as a grey 8-bit PNG, from the previews the ingest stored."""
    png, tag = await run_in_threadpool(_frame_png, state, principal, recording_id, index, max_px)
    return Response(png, media_type="image/png", headers={"Cache-Control": "private, max-age=3600", "ETag": tag})


def _frame_png(
    state: StateDep, principal: Principal, recording_id: int, index: int, max_px: int | None
) -> tuple[bytes, str]:
    with state.sessions() as session:
        recording = recording_for(session, principal, recording_id)
        if recording.state != "ready":
            raise Conflict(f"recording {recording_id} is {recording.state}; previews come with ready", code="not_ready")
        tag = f'"{recording.ingest_job_id}-{index}-{max_px}"'
    path = recording_dir(state.settings.data_path, recording_id) / PREVIEW_FILE
    try:
        image = read_preview(path, index, max_px=max_px)
    except IndexError as error:
        raise NotFound(str(error), code="frame_not_found") from None
    except (FileNotFoundError, KeyError, OSError):
        raise Conflict(f"recording {recording_id} has no previews; run its ingest again", code="not_ready") from None
    return encode_png(image), tag


@router.get("/recordings/{recording_id}/qa", response_model=RecordingQa, responses=error_responses(401, 404, 409, 422))
def recording_qa(recording: ReadableRecording, state: StateDep) -> RecordingQa:
    """The QA summary (warnings, notes) and the per-frame numbers behind it."""
    recording_id = recording.id
    if recording.state != "ready":
        reason = f": {recording.error}" if recording.error else ""
        raise Conflict(f"recording {recording_id} is {recording.state}{reason}", code="not_ready")
    try:
        arrays, attrs = read_qa(recording_dir(state.settings.data_path, recording_id) / PREVIEW_FILE)
    except (FileNotFoundError, KeyError, OSError):
        raise Conflict(f"recording {recording_id} has no QA; run its ingest again", code="not_ready") from None
    out = recording_out(recording)
    return RecordingQa(
        recording_id=recording.id,
        state=out.state,
        full_scale_dn=attrs.get("full_scale_dn", 0),
        warnings=out.warnings,
        notes=out.notes,
        error=recording.error,
        frames=FrameQa(
            mean_fraction=[round(float(v), 5) for v in arrays["mean_fraction"]],
            saturation_pct=[round(float(v), 4) for v in arrays["saturation_pct"]],
            contrast=[round(float(v), 4) for v in arrays["contrast"]],
            board_found=[None if v < 0 else bool(v) for v in arrays["board_found"]],
        ),
    )


@router.get(
    "/recordings/{recording_id}/file",
    response_class=FileResponse,
    responses={200: {"content": {"application/octet-stream": {}}}, **error_responses(401, 404, 422)},
)
def download_recording(recording: ReadableRecording, state: StateDep) -> FileResponse:
    """The uploaded file as it was sent (full resolution and bit depth), streamed."""
    recording_id = recording.id
    path = state.settings.data_path / recording.path
    if not recording.path or not path.is_file():
        raise NotFound(f"recording {recording_id} has no stored file", code="file_not_found")
    return FileResponse(path, filename=recording.filename, media_type="application/octet-stream")
