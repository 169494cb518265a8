"""Resumable (tus) uploads on the data volume: the storage behind tuspyserver's routes, and a finished upload
made a recording (`complete_upload`). The routes' hooks (who asks, refusals before a byte is written) are the
routes' own dependencies, in `backend.api.uploads`.

tuspyserver speaks the protocol (POST create, HEAD offset, PATCH append, DELETE); `TusUploadStorage` decides
where the bytes go and keeps the invariants a resume relies on:

- bytes are written as they arrive (`StreamingWriter`: bounded memory) and hashed on the way; the SHA-256 of a
  finished upload is ready without reading it again (after a restart it is computed from the file once); a
  finished upload is made durable (fdatasync) before it becomes a recording;
- the stored offset never runs ahead of the bytes on disk, and bytes beyond it (a PATCH cut short by a full
  disk or a crash) are cut off before the next PATCH appends: a resume can never corrupt the file;
- a finished upload moves into its recording (a rename) and leaves its `.info` behind with the recording id,
  so that a HEAD still answers "complete" and a repeated last PATCH finds the same recording;
- unfinished uploads expire after FRINGELAB_UPLOAD_EXPIRY_DAYS; their bytes count against the free disk;
- an upload belongs to the user who created it (kept in its `.info`, out of the client's reach): anyone else
  gets a 404 for it, checked before tuspyserver reads a PATCH body.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import threading
import time
from collections.abc import AsyncIterator
from contextvars import ContextVar
from datetime import datetime
from email.utils import parsedate_to_datetime
from pathlib import Path
from typing import Any

from fastapi import HTTPException
from tuspyserver.lock import acquire_upload_lock
from tuspyserver.storage import TusStorage

from backend.errors import error_headers, http_status
from backend.schemas.recordings import RecordingOut, recording_out_by_id
from fringelab.core.accounts import Principal
from fringelab.core.app_state import AppState
from fringelab.core.errors import Conflict, DomainError, Gone, NotFound, TooLarge
from fringelab.core.recordings import recording_of_upload, register_upload
from fringelab.core.settings import Settings
from fringelab.core.storage import (
    InsufficientStorage,
    StreamingWriter,
    UploadTooLarge,
    put_dir,
    sha256_of_file,
    truncate_file,
    tus_dir,
)
from fringelab.formats.atomic import atomic_write

TUS_VERSION = "1.0.0"
UPLOAD_ID = re.compile(r"[0-9a-f]{32}")
MAX_CREATION_BODY_BYTES = 4 << 20
SWEEP_INTERVAL_S = 600.0
# Who is making the current upload request; set by the access dependency (`backend.api.uploads`), read when an
# upload is created.
current_uploader: ContextVar[Principal | None] = ContextVar("uploader", default=None)


class UploadRefused(DomainError, HTTPException):
    """A DomainError raised from the storage while tuspyserver handles a PATCH, which only lets HTTPExceptions
    through (anything else would be swallowed and the PATCH answered 204)."""

    def __init__(self, error: DomainError) -> None:
        HTTPException.__init__(self, status_code=http_status(error), detail=error.detail, headers=error_headers(error))
        self.code, self.field, self.names_field, self.retry_after_s = error.code, None, False, error.retry_after_s
        self.job_id = error.job_id


class TusUploadStorage(TusStorage):
    """tus uploads as files under uploads/tus/, written straight to disk, checksummed, space-checked."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.directory = tus_dir(settings.data_path)
        self._hashers: dict[str, tuple[Any, int]] = {}  # upload id -> (SHA-256 of the first n bytes, n)
        self._writers: dict[str, StreamingWriter] = {}
        self._locks: dict[str, asyncio.Lock] = {}
        self._info_lock = threading.Lock()
        self._last_sweep = 0.0

    # --- paths ------------------------------------------------------------------------------------------
    def _path(self, uid: str) -> Path:
        if not UPLOAD_ID.fullmatch(uid):
            raise UploadRefused(NotFound("upload not found", code="upload_not_found"))
        return self.directory / uid

    def _info_path(self, uid: str) -> Path:
        return self.directory / f"{self._path(uid).name}.info"

    def location(self, uid: str) -> str:
        return str(self._path(uid))

    # --- data ---------------------------------------------------------------------------------------------
    async def create(self, uid: str) -> None:
        path = self._path(uid)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.touch()

    async def exists(self, uid: str) -> bool:
        return self._info_path(uid).exists()

    async def size(self, uid: str) -> int:
        path = self._path(uid)
        if path.exists():
            return path.stat().st_size
        info = self.read_info_now(uid) or {}
        return int(info.get("size") or 0)

    async def append(self, uid: str, chunk: bytes) -> None:
        writer = self._writers.get(uid)
        if writer is None:
            raise UploadRefused(Conflict("this upload is complete or was removed", code="upload_complete"))
        try:
            await writer.append(chunk)
        except UploadTooLarge as error:
            raise UploadRefused(TooLarge(str(error), code="upload_too_large")) from None
        except InsufficientStorage as error:
            raise UploadRefused(TooLarge(str(error), code="insufficient_storage")) from None

    async def flush(self, uid: str) -> None:
        writer = self._writers.get(uid)
        if writer is None:  # an empty PATCH of a finished upload (its answer was lost) is fine: nothing to write
            if "recording_id" in ((await self.read_info(uid)) or {}).get("metadata", {}):
                return
            raise UploadRefused(Conflict("this upload is complete or was removed", code="upload_complete"))
        try:
            await writer.flush()
        except InsufficientStorage as error:
            raise UploadRefused(TooLarge(str(error), code="insufficient_storage")) from None
        self._hashers[uid] = (writer.hasher.copy(), writer.size)

    async def finalize(self, uid: str) -> None:
        return None

    async def read(self, uid: str) -> bytes | None:
        return None  # never load an upload into memory; a finished one is read through its recording

    async def delete(self, uid: str) -> None:
        await asyncio.to_thread(self.delete_now, uid)

    def forget(self, uid: str) -> None:
        """Drop the in-memory state of a finished or removed upload."""
        self._hashers.pop(uid, None)
        lock = self._locks.get(uid)
        if lock is not None and not lock.locked():
            del self._locks[uid]

    def delete_now(self, uid: str) -> None:
        for path in (self._path(uid), self._info_path(uid), self.directory / ".locks" / f"{uid}.lock"):
            path.unlink(missing_ok=True)
        self.forget(uid)

    # --- info ---------------------------------------------------------------------------------------------
    def read_info_now(self, uid: str) -> dict[str, Any] | None:
        try:
            return dict(json.loads(self._info_path(uid).read_text()))
        except (OSError, ValueError):
            return None

    async def read_info(self, uid: str) -> dict[str, Any] | None:
        return await asyncio.to_thread(self.read_info_now, uid)

    def write_info_now(self, uid: str, data: dict[str, Any], *, owner: Principal | None = None) -> None:
        """Store an upload's info; the offset never goes back; its owner and recording id, once set, stay.

        tuspyserver saves the info again after a PATCH has released the upload's lock, from what it read
        before: a PATCH cut off by a dropped connection can end after the client's next PATCH and would
        otherwise put back its older offset.
        """
        with self._info_lock:
            stored = self.read_info_now(uid) or {}
            merged = dict(data)
            if "owner" in stored:
                merged["owner"] = stored["owner"]
            elif owner is not None:
                merged["owner"] = owner.user_id
            merged["offset"] = max(int(data.get("offset") or 0), int(stored.get("offset") or 0))
            recording_id = stored.get("metadata", {}).get("recording_id")
            if recording_id is not None:
                merged["metadata"] = {**data.get("metadata", {}), "recording_id": recording_id}
            try:
                atomic_write(self._info_path(uid), json.dumps(merged, default=str).encode())
            except OSError as error:  # a full disk: tell the client, keep the previous info
                refused = TooLarge(f"cannot record the upload's progress: {error}", code="insufficient_storage")
                raise UploadRefused(refused) from None

    async def write_info(self, uid: str, data: dict[str, Any]) -> None:
        await asyncio.to_thread(self.write_info_now, uid, data, owner=current_uploader.get())

    async def list_uids(self) -> list[str]:
        return [p.name for p in self.directory.glob("*") if UPLOAD_ID.fullmatch(p.name)]

    # --- PATCH ---------------------------------------------------------------------------------------------
    @contextlib.asynccontextmanager  # (tuspyserver annotates its own, also decorated, as the bare generator)
    async def lock(self, uid: str) -> AsyncIterator[None]:  # type: ignore[override]
        """One PATCH at a time per upload: an asyncio lock in this process (tuspyserver's file lock, which
        serves across processes, can let a third request in when its lock file is removed on release)."""
        local = self._locks.setdefault(uid, asyncio.Lock())
        async with local:
            held = acquire_upload_lock(str(self._path(uid)), locks_dir=str(self.directory / ".locks"), blocking=True)
            await asyncio.to_thread(held.__enter__)
            try:
                await asyncio.to_thread(self._open_writer, uid)
                yield
            finally:
                writer = self._writers.pop(uid, None)
                if writer is not None:
                    await writer.close()
                await asyncio.to_thread(held.__exit__, None, None, None)

    def _open_writer(self, uid: str) -> None:
        """Make the file agree with the stored offset, and the checksum with the file, before appending."""
        info = self.read_info_now(uid)
        path = self._path(uid)
        if info is None or not path.exists():
            return  # finished (moved into its recording) or removed: nothing may be appended
        offset = int(info.get("offset") or 0)
        size = path.stat().st_size
        if size < offset:  # only after a power cut: offsets are recorded before their bytes reach the disk
            raise UploadRefused(Gone("the bytes of this upload were lost; start it again", code="upload_lost"))
        if size > offset:
            truncate_file(path, offset)  # bytes of a PATCH that failed before its offset was recorded
        hasher, hashed = self._hashers.get(uid, (None, -1))
        if hashed != offset:
            hasher, hashed = sha256_of_file(path, length=offset), offset
        limit = min(int(info.get("size") or self.settings.max_upload_bytes), self.settings.max_upload_bytes)
        self._writers[uid] = StreamingWriter(
            path, hasher=hasher.copy(), limit_bytes=limit, reserve_bytes=self.settings.min_free_disk_bytes
        )

    # --- what the hooks need ------------------------------------------------------------------------------
    def sha256_now(self, uid: str, size: int) -> str:
        hasher, hashed = self._hashers.get(uid, (None, -1))
        if hashed != size:
            hasher = sha256_of_file(self._path(uid), length=size)
        return str(hasher.hexdigest())

    def reserved_bytes(self, owner_id: int | None) -> int:
        return reserved_upload_bytes(self.settings, owner_id)

    def sweep(self, *, now: float | None = None) -> None:
        """Delete expired uploads (and stale PUT leftovers); at most once every SWEEP_INTERVAL_S."""
        now = time.time() if now is None else now
        if now - self._last_sweep < SWEEP_INTERVAL_S:
            return
        self._last_sweep = now
        for info_path in self.directory.glob("*.info"):
            uid = info_path.stem
            info = self.read_info_now(uid) if UPLOAD_ID.fullmatch(uid) else None
            if info is not None and _expires_at(info) < now:
                self.delete_now(uid)
        sweep_put_parts(self.settings, now=now)


PUT_PART_STALE_S = 3600.0
"""A PUT's `.part` file not written to for this long belongs to a request that died (a crashed or killed web
server): a live one writes as its bytes arrive."""


def sweep_put_parts(settings: Settings, *, now: float | None = None) -> int:
    """Delete the `.part` files of dead PUT uploads (they stayed five days); how many were deleted."""
    now = time.time() if now is None else now
    deleted = 0
    for part in put_dir(settings.data_path).glob("*.part"):
        with contextlib.suppress(OSError):
            if part.stat().st_mtime < now - PUT_PART_STALE_S:
                part.unlink()
                deleted += 1
    return deleted


def reserved_upload_bytes(settings: Settings, owner_id: int | None, *, now: float | None = None) -> int:
    """Bytes that `owner_id`'s unfinished uploads have announced but not sent yet: the disk keeps room for them,
    for their owner only (an upload announcing the whole disk locked every other user out for days), and only
    for FRINGELAB_UPLOAD_RESERVATION_H after the upload's last byte (an abandoned one stops reserving)."""
    now = time.time() if now is None else now
    window_s = settings.upload_reservation_h * 3600
    directory = tus_dir(settings.data_path)
    total = 0
    for info_path in directory.glob("*.info"):
        uid = info_path.stem
        if not UPLOAD_ID.fullmatch(uid):
            continue
        try:
            info = dict(json.loads(info_path.read_text()))
            last_s = max(info_path.stat().st_mtime, _mtime(directory / uid))
        except (OSError, ValueError):
            continue
        if info.get("owner") != owner_id or "recording_id" in info.get("metadata", {}) or now - last_s > window_s:
            continue
        total += max(0, int(info.get("size") or 0) - int(info.get("offset") or 0))
    return total


def _mtime(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:
        return 0.0


def _expires_at(info: dict[str, Any]) -> float:
    expires = info.get("expires")
    if isinstance(expires, int | float):
        return float(expires)
    if isinstance(expires, str):
        with contextlib.suppress(TypeError, ValueError):
            return parsedate_to_datetime(expires).timestamp()
        with contextlib.suppress(ValueError):
            return datetime.fromisoformat(expires).timestamp()
    return float("inf")


def complete_upload(state: AppState, storage: TusUploadStorage, uid: str, principal: Principal) -> RecordingOut:
    info = storage.read_info_now(uid)
    if info is None:
        raise NotFound(f"upload {uid} does not exist", code="upload_not_found")
    metadata = info.get("metadata", {})
    if "recording_id" in metadata:  # the last PATCH again (its answer was lost): the same recording
        known = recording_of_upload(state, uid)
        if known is None:
            raise Gone(f"the recording of upload {uid} has been deleted", code="recording_deleted")
        return recording_out_by_id(state, known)
    size = int(info.get("size") or 0)
    try:
        recording_id = register_upload(
            state,
            principal,
            staged=Path(storage.location(uid)),
            camera_id=int(metadata["camera_id"]),
            kind=metadata["kind"],
            filename=metadata["filename"],
            sha256=storage.sha256_now(uid, size),
            size_bytes=size,
            upload_id=uid,
        )
    except DomainError:
        storage.delete_now(uid)  # a refused file cannot become acceptable by resuming it
        raise
    info["metadata"] = {**metadata, "recording_id": str(recording_id)}
    storage.write_info_now(uid, info)
    storage.forget(uid)
    return recording_out_by_id(state, recording_id)
