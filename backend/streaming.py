"""Receiving one streamed request body onto the data volume: the single-request uploads (recordings, simulations).

Bytes go to a staging file as they arrive, checksummed, within the declared length, FRINGELAB_MAX_UPLOAD_BYTES and
the free disk; anything short or interrupted is an error and leaves nothing behind.
"""

from __future__ import annotations

import hashlib
import uuid
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path

from starlette.requests import ClientDisconnect, Request

from fringelab.core.errors import DomainError, TooLarge
from fringelab.core.settings import Settings
from fringelab.core.storage import InsufficientStorage, StreamingWriter, UploadTooLarge, put_dir


def declared_length(request: Request) -> int | None:
    """The Content-Length the client sent, if it sent a plain one."""
    header = request.headers.get("content-length")
    return int(header) if header and header.isdigit() else None


@dataclass(frozen=True)
class StagedBody:
    path: Path
    sha256: str
    size_bytes: int


@asynccontextmanager
async def staged_body(request: Request, settings: Settings, length: int | None) -> AsyncIterator[StagedBody]:
    """The request body, whole, in a staging file on the data volume; the file is removed when the block ends
    (the block moves it into its place to keep it)."""
    staged = put_dir(settings.data_path) / f"{uuid.uuid4().hex}.part"
    writer = StreamingWriter(
        staged,
        hasher=hashlib.sha256(),
        limit_bytes=min(length or settings.max_upload_bytes, settings.max_upload_bytes),
        reserve_bytes=settings.min_free_disk_bytes,
    )
    try:
        try:
            async for chunk in request.stream():
                await writer.append(chunk)
            await writer.flush()
        except ClientDisconnect:
            raise DomainError(
                "the connection closed before the upload ended; nothing was kept", code="upload_interrupted"
            ) from None
        except UploadTooLarge as error:
            raise TooLarge(str(error), code="upload_too_large") from None
        except InsufficientStorage as error:
            raise TooLarge(str(error), code="insufficient_storage") from None
        finally:
            await writer.close()
        if writer.size == 0:
            raise DomainError("the upload is empty (0 bytes)", code="empty_upload")
        if length is not None and writer.size != length:
            raise DomainError(f"received {writer.size} of {length} bytes", code="upload_incomplete")
        yield StagedBody(staged, writer.hasher.hexdigest(), writer.size)
    finally:
        staged.unlink(missing_ok=True)
