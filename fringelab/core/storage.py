"""Where files live under the data directory, and how they get there: streamed, checksummed, temp + rename.

Layout (under `Settings.data_path`):

    uploads/tus/<upload id>          a resumable (tus) upload in progress, with <upload id>.info beside it
    uploads/put/<random>.part        a streamed PUT upload in progress (removed if it fails)
    recordings/<id>/recording.<ext>  the uploaded file as sent (.zip, .tif, .avi, .mp4, .cine)
    recordings/<id>/<sidecar>        z.csv, frames.csv or board.json added after the upload
    recordings/<id>/previews.h5      what the ingest derived (see `fringelab.formats.previews`)
    trash/                           directories on their way out (renamed here, then removed)

A file is never written in place where a reader may see it: it is written under a temporary name and renamed.
Uploads are written as they arrive (a few MiB of buffer per upload, whatever the file size), hashed (SHA-256)
on the way, and stopped when the data volume would be left with less than `min_free_disk_bytes`.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import ctypes.util
import errno
import hashlib
import os
import shutil
import uuid
from pathlib import Path
from typing import Any

RECORDING_FILE = "recording"
SUFFIX_OF_FORMAT = {"zip": ".zip", "tiff": ".tif", "avi": ".avi", "mp4": ".mp4", "cine": ".cine"}
WRITE_BUFFER_BYTES = 4 << 20
DISK_CHECK_EVERY_BYTES = 64 << 20
WRITEBACK_EVERY_BYTES = 32 << 20
IOV_MAX = 1024


class InsufficientStorage(Exception):
    """The data volume has not the room for this upload (or is full)."""


class UploadTooLarge(Exception):
    """More bytes than the upload may have."""


def tus_dir(data_path: Path) -> Path:
    return data_path / "uploads" / "tus"


def put_dir(data_path: Path) -> Path:
    return data_path / "uploads" / "put"


def recording_dir(data_path: Path, recording_id: int) -> Path:
    return data_path / "recordings" / str(recording_id)


def job_dir(data_path: Path, job_id: str) -> Path:
    """`DATA_DIR/results/jobs/<job id>`: each job (and each retry, which is a new job) writes only here."""
    return data_path / "results" / "jobs" / job_id


def recording_file_name(format: str) -> str:
    return RECORDING_FILE + SUFFIX_OF_FORMAT[format]


def free_disk_bytes(path: Path) -> int:
    """Free bytes on the volume holding `path` (or its nearest existing parent)."""
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return shutil.disk_usage(probe).free


def check_room(path: Path, needed_bytes: int, *, reserve_bytes: int) -> None:
    """Raise InsufficientStorage unless `needed_bytes` fit on the volume of `path` with `reserve_bytes` left."""
    free = free_disk_bytes(path)
    if needed_bytes + reserve_bytes > free:
        raise InsufficientStorage(
            f"not enough free space on the data volume: {needed_bytes} bytes needed, {free} free, "
            f"{reserve_bytes} kept in reserve (FRINGELAB_MIN_FREE_DISK_BYTES)"
        )


def sha256_of_file(path: Path, *, length: int | None = None) -> Any:
    """A SHA-256 hasher fed with the first `length` bytes of a file (all of it when None)."""
    hasher = hashlib.sha256()
    remaining = path.stat().st_size if length is None else length
    with path.open("rb") as handle:
        while remaining > 0:
            block = handle.read(min(WRITE_BUFFER_BYTES, remaining))
            if not block:
                break
            hasher.update(block)
            remaining -= len(block)
    return hasher


class StreamingWriter:
    """Appends an upload to a file as it arrives, hashing it; memory stays at two buffers whatever the size.

    Received chunks are collected (not copied) up to WRITE_BUFFER_BYTES and written with one writev.

    Writes and hashing run in a thread (both release the GIL) while the event loop receives the next buffer.
    `append` raises UploadTooLarge past `limit_bytes` in total and InsufficientStorage when the volume gets
    within `reserve_bytes` of full (or reports ENOSPC). The caller decides what to do with a file left part
    written; `size` is what is in it for sure after a successful `flush`. Writeback to disk is started every
    32 MiB so that the `sync_file` of a finished upload is short.
    """

    def __init__(self, path: Path, *, hasher: Any, limit_bytes: int, reserve_bytes: int) -> None:
        self.path = path
        self.hasher = hasher
        self.limit_bytes = limit_bytes
        self.reserve_bytes = reserve_bytes
        path.parent.mkdir(parents=True, exist_ok=True)
        self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o640)
        self.size = os.fstat(self._fd).st_size  # bytes written
        self._accepted = self.size  # bytes written, buffered or being written
        self._chunks: list[bytes] = []  # received, not yet handed to the writer thread
        self._buffered = 0
        self._pending: asyncio.Future[None] | None = None
        self._next_disk_check = self.size
        self._written_back = self.size

    async def append(self, chunk: bytes) -> None:
        if self._accepted + len(chunk) > self.limit_bytes:
            raise UploadTooLarge(f"the upload exceeds {self.limit_bytes} bytes")
        self._accepted += len(chunk)
        self._chunks.append(chunk)
        self._buffered += len(chunk)
        if self._buffered >= WRITE_BUFFER_BYTES:
            await self._drain()

    async def _wait(self) -> None:
        if self._pending is not None:
            pending, self._pending = self._pending, None
            await pending

    async def _drain(self) -> None:
        """Hand the buffer to the writer thread once the previous write is done (two buffers at most)."""
        await self._wait()
        if self._chunks:
            chunks, size = self._chunks, self._buffered
            self._chunks, self._buffered = [], 0
            self._pending = asyncio.ensure_future(asyncio.to_thread(self._write, chunks, size))

    def _write(self, chunks: list[bytes], size: int) -> None:
        if self.size + size >= self._next_disk_check:
            self._next_disk_check = self.size + DISK_CHECK_EVERY_BYTES
            check_room(self.path, size, reserve_bytes=self.reserve_bytes)
        try:
            _write_all(self._fd, chunks)
        except OSError as error:
            if error.errno in (errno.ENOSPC, errno.EDQUOT):
                raise InsufficientStorage(f"the data volume is full ({error.strerror})") from None
            raise
        for chunk in chunks:
            self.hasher.update(chunk)
        self.size += size
        if self.size - self._written_back >= WRITEBACK_EVERY_BYTES:
            start_writeback(self._fd, self._written_back, self.size - self._written_back)
            self._written_back = self.size

    async def flush(self) -> None:
        """Write everything appended so far (to the page cache; `sync_file` makes a finished file durable)."""
        await self._drain()
        await self._wait()

    async def close(self) -> None:
        """Stop: let a write in flight end, drop what is buffered, close the file."""
        if self._pending is not None:
            with contextlib.suppress(Exception):
                await self._pending
            self._pending = None
        self._chunks, self._buffered = [], 0
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


def _write_all(fd: int, chunks: list[bytes]) -> None:
    """Write the chunks in order with as few system calls as the kernel allows (no copy into one buffer)."""
    views = [memoryview(chunk) for chunk in chunks if chunk]
    while views:
        written = os.writev(fd, views[:IOV_MAX])
        while views and written >= len(views[0]):
            written -= len(views[0])
            views.pop(0)
        if written:
            views[0] = views[0][written:]


def _libc_sync_file_range() -> Any:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        function = libc.sync_file_range
    except (OSError, AttributeError):
        return None
    function.argtypes = [ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_uint]
    return function


_SYNC_FILE_RANGE = _libc_sync_file_range()
_SYNC_FILE_RANGE_WRITE = 2


def start_writeback(fd: int, offset: int, length: int) -> None:
    """Ask the kernel to start writing a range to disk now, without waiting (Linux `sync_file_range`).

    The disk then works while the next bytes arrive, and the `fdatasync` at the end of an upload only waits
    for the tail instead of the whole file. Elsewhere, a no-op.
    """
    if _SYNC_FILE_RANGE is not None:
        _SYNC_FILE_RANGE(fd, offset, length, _SYNC_FILE_RANGE_WRITE)


def sync_file(path: Path) -> None:
    """Make a file's bytes durable (fdatasync) before anything refers to it."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fdatasync(fd)
    finally:
        os.close(fd)


def truncate_file(path: Path, size: int) -> None:
    with path.open("r+b") as handle:
        handle.truncate(size)


def place_file(source: Path, target: Path) -> None:
    """Move a finished file to its place (same volume: a rename, no copy)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    os.replace(source, target)


def replace_with_link(existing: Path, target: Path) -> bool:
    """Make `target` a hard link to `existing` (identical bytes stored once); False where links are impossible."""
    temporary = target.with_name(f".{target.name}.{uuid.uuid4().hex}.link")
    try:
        os.link(existing, temporary)
    except OSError:
        return False
    os.replace(temporary, target)
    return True


def remove_tree(data_path: Path, directory: Path) -> None:
    """Remove a directory: renamed into trash/ first, so nothing ever sees it half deleted."""
    if not directory.exists():
        return
    trash = data_path / "trash" / f"{directory.name}-{uuid.uuid4().hex}"
    trash.parent.mkdir(parents=True, exist_ok=True)
    os.replace(directory, trash)
    shutil.rmtree(trash, ignore_errors=True)
