"""Atomic writes: a file is either absent or whole under its final name, even after a crash or a power loss.

The one way fringelab writes a file that someone may read while it is written or after a crash: a temporary file
beside the target (same folder, so the rename cannot cross volumes), flushed to disk, renamed over the target, and
the folder flushed so the rename itself survives a power loss. Readers see the old file or the new one, never a
part. Every writer of every format goes through here.
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from fringelab.formats.hdf5 import json_text

PARTIAL_SUFFIX = ".partial"


def partial_path(path: str | Path) -> Path:
    """A fresh temporary name beside `path` (hidden, unique, ending in .partial); its folder is created."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}{PARTIAL_SUFFIX}")


def _fsync_folder(folder: Path) -> None:
    if os.name != "posix":  # Windows cannot open a folder to flush it; NTFS journals the rename itself
        return
    handle = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(handle)
    finally:
        os.close(handle)


def commit_partial(partial: Path, path: str | Path) -> Path:
    """Flush a finished temporary file to disk and rename it over `path`; the rename is flushed too."""
    path = Path(path)
    with partial.open("rb+") as handle:
        os.fsync(handle.fileno())
    os.replace(partial, path)
    _fsync_folder(path.parent)
    return path


class FlushBehind:
    """Writes a growing temporary file's data to disk behind its writer: an fdatasync in a thread each time
    `step_bytes` more have been written (`poke` after writing), so that `commit_partial`'s fsync at the end waits
    for the last part only instead of the whole file. `close` waits for the flush under way."""

    def __init__(self, path: str | Path, *, step_bytes: int = 16 << 20) -> None:
        self._fd = os.open(path, os.O_RDONLY)
        self._step_bytes = step_bytes
        self._flushed_bytes = 0
        self._running: Future[None] | None = None
        self._thread = ThreadPoolExecutor(1, thread_name_prefix="flush-behind")

    def poke(self) -> None:
        if self._running is not None and not self._running.done():
            return
        size = os.fstat(self._fd).st_size
        if size - self._flushed_bytes >= self._step_bytes:
            self._flushed_bytes = size
            self._running = self._thread.submit(getattr(os, "fdatasync", os.fsync), self._fd)

    def close(self) -> None:
        self._thread.shutdown(wait=True)
        if self._running is not None:
            self._running.result()  # a disk error surfaces here, before the file is committed
        os.close(self._fd)


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside `path` for the block to write; committed over `path` when the block completes,
    removed when it raises."""
    partial = partial_path(path)
    try:
        yield partial
        commit_partial(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def atomic_write(path: str | Path, data: bytes | str) -> Path:
    """Write bytes (or UTF-8 text) to `path` atomically; returns the path."""
    with atomic_path(path) as partial:
        partial.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
    return Path(path)


def write_json(path: str | Path, document: Any) -> Path:
    """Write a JSON document atomically (NaN and infinities become null)."""
    return atomic_write(path, json.dumps(json.loads(json_text(document)), indent=1) + "\n")
