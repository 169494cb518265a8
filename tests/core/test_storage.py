"""The upload storage on its own: streamed writes with their checksum and limits, and the tus info invariants."""

from __future__ import annotations

import asyncio
import hashlib
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np
import pytest

from backend.uploads import TusUploadStorage
from fringelab.core.storage import StreamingWriter, UploadTooLarge

T = TypeVar("T")


def run(coroutine: Callable[[], Awaitable[T]]) -> T:
    """Run a coroutine in a thread of its own (Playwright's session keeps an event loop in the main thread)."""
    with ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, coroutine()).result()  # type: ignore[arg-type]


def test_streaming_writer_writes_and_hashes_everything_in_order(tmp_path):
    chunks = [np.random.default_rng(i).integers(0, 256, size, dtype=np.uint8).tobytes()
              for i, size in enumerate([1, 65536, 3 << 20, 5 << 20, 7])]  # fmt: skip
    path = tmp_path / "upload.part"

    async def write() -> StreamingWriter:
        writer = StreamingWriter(path, hasher=hashlib.sha256(), limit_bytes=1 << 30, reserve_bytes=0)
        for chunk in chunks:
            await writer.append(chunk)
        await writer.flush()
        await writer.close()
        return writer

    writer = run(write)
    whole = b"".join(chunks)
    assert path.read_bytes() == whole
    assert writer.size == len(whole) and writer.hasher.hexdigest() == hashlib.sha256(whole).hexdigest()


def test_streaming_writer_stops_at_its_limit(tmp_path):
    async def write() -> None:
        writer = StreamingWriter(tmp_path / "p", hasher=hashlib.sha256(), limit_bytes=10, reserve_bytes=0)
        try:
            await writer.append(b"123456")
            await writer.append(b"78901")
        finally:
            await writer.close()

    with pytest.raises(UploadTooLarge, match="exceeds 10 bytes"):
        run(write)


def test_a_late_info_save_never_moves_the_offset_back_nor_forgets_the_recording(settings):
    storage = TusUploadStorage(settings)
    uid = "0123456789abcdef0123456789abcdef"
    storage.write_info_now(uid, {"offset": 1000, "size": 5000, "metadata": {"filename": "a.zip"}})
    storage.write_info_now(uid, {"offset": 5000, "size": 5000, "metadata": {"filename": "a.zip", "recording_id": "7"}})
    storage.write_info_now(uid, {"offset": 1000, "size": 5000, "metadata": {"filename": "a.zip"}})  # a stale save
    info = storage.read_info_now(uid)
    assert info["offset"] == 5000 and info["metadata"] == {"filename": "a.zip", "recording_id": "7"}
