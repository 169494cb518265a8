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

from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool
from tuspyserver import create_tus_router

from backend.api.deps import CurrentUser, StateDep, WritableCameraId
from backend.errors import error_responses
from backend.schemas.common import MAX_ID
from backend.schemas.recordings import RecordingKind, RecordingOut, recording_out_by_id
from backend.streaming import declared_length, staged_body
from backend.uploads import (
    MAX_CREATION_BODY_BYTES,
    TUS_VERSION,
    UPLOAD_ID,
    TusUploadStorage,
    complete_upload,
    current_uploader,
    reserved_upload_bytes,
    sweep_put_parts,
)
from fringelab.core.app_state import AppState
from fringelab.core.errors import Conflict, DomainError, Invalid, NotFound, TooLarge
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


# ---------------------------------------------------------------------------------------------- the hooks


def _state(request: Request) -> AppState:
    return request.app.state.fringelab


def make_access_dep(storage: TusUploadStorage) -> Callable[..., Any]:
    """A dependency of every tus route: who asks, and (for one upload) whether it is theirs."""

    async def upload_access(request: Request, principal: CurrentUser) -> None:
        current_uploader.set(principal)
        if request.method != "OPTIONS" and request.headers.get("tus-resumable") != TUS_VERSION:
            # tuspyserver checks this only after a PATCH body has been written
            raise HTTPException(412, f"send Tus-Resumable: {TUS_VERSION}", headers={"Tus-Version": TUS_VERSION})
        uid = request.path_params.get("uuid")
        if uid is not None:
            info = await storage.read_info(uid) if UPLOAD_ID.fullmatch(uid) else None
            if info is not None and not (principal.is_admin or info.get("owner") == principal.user_id):
                raise NotFound("upload not found", code="upload_not_found")
            if request.method == "PATCH" and info is not None:
                _check_patch_headers(request, info)

    return upload_access


def _check_patch_headers(request: Request, info: dict[str, Any]) -> None:
    """Every header a PATCH is judged by, checked before its body is read: tuspyserver writes the body first and
    checks afterwards, so a refused PATCH (415, 409) used to keep its bytes, and a refused last one left a
    complete file and no recording."""
    if request.headers.get("content-type") != "application/offset+octet-stream":
        raise HTTPException(415, "Content-Type must be application/offset+octet-stream")
    offset = request.headers.get("upload-offset", "")
    if not offset.isdigit():
        raise Invalid("send Upload-Offset: the number of bytes already received", code="invalid_offset")
    if int(offset) != int(info.get("offset") or 0):
        raise Conflict(
            f"Upload-Offset {offset} does not match the {int(info.get('offset') or 0)} bytes received; ask HEAD",
            code="conflict",  # as tus clients know it
        )
    length = request.headers.get("content-length", "")
    if length.isdigit() and int(offset) + int(length) > int(info.get("size") or 0):
        raise TooLarge(f"the PATCH would end past Upload-Length ({info.get('size')} bytes)", code="upload_too_large")


def make_pre_create_dep(storage: TusUploadStorage) -> Callable[..., Any]:
    """tuspyserver's pre-create dependency: refuse an upload before it is created, with the reason."""

    async def pre_create_dep(
        request: Request, principal: CurrentUser
    ) -> Callable[[dict[str, str], dict[str, Any]], Any]:
        state = _state(request)

        async def check(metadata: dict[str, str], upload_info: dict[str, Any]) -> None:
            if request.headers.get("upload-concat"):
                raise DomainError("tus concatenation is not supported; send one upload", code="unsupported_extension")
            body_length = int(request.headers.get("content-length") or 0)
            if body_length > MAX_CREATION_BODY_BYTES:
                raise TooLarge("send the bytes with PATCH requests", code="creation_body_too_large")
            missing = [key for key in ("filename", "filetype", "camera_id", "kind") if not metadata.get(key)]
            if missing:
                raise DomainError(
                    f"Upload-Metadata lacks {', '.join(missing)} (send filename, filetype, camera_id and kind)",
                    code="missing_metadata",
                )
            if upload_info.get("size") is None:
                raise DomainError("send Upload-Length (a deferred length is not supported)", code="length_required")
            camera_id_text = metadata["camera_id"]
            if not (camera_id_text.isdigit() and 1 <= int(camera_id_text) <= MAX_ID):
                raise Invalid(f"camera_id must be an id from 1 to {MAX_ID}", code="invalid_metadata")
            camera_id = int(camera_id_text)
            await run_in_threadpool(storage.sweep)
            reserved = await run_in_threadpool(storage.reserved_bytes, principal.user_id)
            await run_in_threadpool(
                lambda: check_upload_request(
                    state, principal, camera_id=camera_id, kind=metadata["kind"], filename=metadata["filename"],
                    length=upload_info["size"], reserved_bytes=reserved,
                )
            )  # fmt: skip

        return check

    return pre_create_dep


def make_complete_dep(storage: TusUploadStorage) -> Callable[..., Any]:
    """tuspyserver's completion dependency: the finished upload becomes a recording and its ingest is queued.

    The last PATCH answers with `Fringelab-Recording-Id` and `Content-Location` naming the recording; a refused
    file (not a recording, unsafe ZIP, camera deleted meanwhile) is removed and the PATCH answers 4xx.
    """

    async def complete_dep(
        request: Request, response: Response, principal: CurrentUser
    ) -> Callable[[str, dict[str, Any]], Any]:
        state = _state(request)

        async def on_complete(file_path: str, _metadata: dict[str, Any]) -> None:
            recording = await run_in_threadpool(complete_upload, state, storage, Path(file_path).name, principal)
            response.headers["Fringelab-Recording-Id"] = str(recording.id)
            response.headers["Content-Location"] = f"/api/v1/recordings/{recording.id}"

        return on_complete

    return complete_dep
