"""Uploads of recordings: resumable (tus 1.0, for the browser and scripts) and a plain streamed PUT.

tus: `POST /api/v1/uploads` with `Upload-Length` and `Upload-Metadata` (filename, filetype, camera_id, kind)
creates an upload; `PATCH /api/v1/uploads/{id}` appends at `Upload-Offset`; `HEAD` tells the offset to resume
from; `DELETE` abandons it. The last PATCH turns the file into a recording and answers with its id in
`Fringelab-Recording-Id` (also findable later with `GET /api/v1/recordings?upload_id={id}`).

PUT: `PUT /api/v1/uploads/cameras/{camera_id}/{filename}?kind=...` with the file as the body answers 201 with
the recording. It does not resume: an interrupted PUT leaves nothing behind and is sent again.

Both need write access to the camera's experiment; a tus upload belongs to whoever created it (anyone else
gets a 404 for it, before any byte of theirs is written).

Either way the bytes go to the data volume as they arrive (bounded memory), within FRINGELAB_MAX_UPLOAD_BYTES
and the free disk, checksummed (SHA-256); the recording is `ingesting` until its ingest job makes it `ready`
or `invalid`.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool
from tuspyserver import create_tus_router

from backend.api.deps import CurrentUser, StateDep, WritableCameraId
from backend.errors import error_responses
from backend.schemas.recordings import RecordingKind, RecordingOut, recording_out_by_id
from backend.streaming import declared_length, staged_body
from backend.uploads import (
    TusUploadStorage,
    make_access_dep,
    make_complete_dep,
    make_pre_create_dep,
    reserved_upload_bytes,
    sweep_put_parts,
)
from fringelab.core.app_state import AppState
from fringelab.core.recordings import check_upload_request, register_upload
from fringelab.core.storage import tus_dir


def create_router(state: AppState) -> APIRouter:
    """The upload routes of one API process (the tus storage keeps per-upload checksums in memory)."""
    settings = state.settings
    storage = TusUploadStorage(settings)
    router = APIRouter()
    # Registered before tuspyserver's own OPTIONS, which advertises extensions this server refuses.
    for path in ("/uploads", "/uploads/"):
        router.add_api_route(path, tus_options, methods=["OPTIONS"], status_code=204, tags=["uploads"])
    router.include_router(
        create_tus_router(
            prefix="uploads",
            files_dir=str(tus_dir(settings.data_path)),
            max_size=settings.max_upload_bytes,
            days_to_keep=settings.upload_expiry_days,
            pre_create_dep=make_pre_create_dep(storage),
            upload_complete_dep=make_complete_dep(storage),
            tags=["uploads"],
            storage=storage,
        ),
        # Before tuspyserver's own dependencies: a PATCH body is written before its `auth` dependency runs.
        dependencies=[Depends(make_access_dep(storage))],
    )
    router.add_api_route(
        "/uploads/cameras/{camera_id}/{filename}",
        put_recording,
        methods=["PUT"],
        status_code=201,
        response_model=RecordingOut,
        tags=["uploads"],
        responses=error_responses(400, 401, 403, 404, 413, 415, 422),
        openapi_extra={
            "requestBody": {
                "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}},
                "required": True,
            }
        },
    )
    return router


TUS_EXTENSIONS = "creation,creation-with-upload,expiration,termination"


def tus_options(state: StateDep) -> Response:
    """The tus capabilities of this server: no concatenation, no deferred length."""
    return Response(
        status_code=204,
        headers={
            "Tus-Resumable": "1.0.0",
            "Tus-Version": "1.0.0",
            "Tus-Extension": TUS_EXTENSIONS,
            "Tus-Max-Size": str(state.settings.max_upload_bytes),
        },
    )


async def put_recording(
    camera_id: WritableCameraId,
    filename: str,
    request: Request,
    state: StateDep,
    principal: CurrentUser,
    kind: Annotated[RecordingKind, Query(description="camera_calibration, projector_calibration, test or coded")],
) -> JSONResponse:
    """Upload a recording in one streamed request (e.g. `curl -T plate.cine URL?kind=test`)."""
    settings = state.settings
    length = declared_length(request)
    await run_in_threadpool(sweep_put_parts, settings)
    # The uploader's own unfinished resumable uploads keep their room; other users' do not count against them.
    reserved = await run_in_threadpool(reserved_upload_bytes, settings, principal.user_id)
    await run_in_threadpool(
        lambda: check_upload_request(
            state, principal, camera_id=camera_id, kind=kind, filename=filename, length=length, reserved_bytes=reserved
        )  # fmt: skip
    )
    async with staged_body(request, settings, length) as body:
        recording_id = await run_in_threadpool(
            register_upload,
            state,
            principal,
            staged=body.path,
            camera_id=camera_id,
            kind=kind,
            filename=filename,
            sha256=body.sha256,
            size_bytes=body.size_bytes,
            upload_id=None,
        )
    recording = await run_in_threadpool(recording_out_by_id, state, recording_id)
    return JSONResponse(
        recording.model_dump(mode="json"),
        status_code=201,
        headers={"Location": f"/api/v1/recordings/{recording.id}"},
    )
