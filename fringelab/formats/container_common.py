"""What every recording container module shares: the errors that say what is wrong with a file, the size limit
of a sidecar, reading bytes at an offset, and 12-bit pixel unpacking (Phantom P12L and Photron 12-bit MRAW).

Belongs here: only what two or more `container_*` modules use. Not here: a container's own layout or checks (its
`container_<kind>` module), or the list of formats (`containers`).

Errors are `ValueError` subclasses: `UnsupportedRecording` (a format fringelab does not read), `UnsafeArchive` (a
ZIP that must not be opened), `CorruptRecording` (damaged or truncated) and `OverBudget` (it would expand to more
than the data volume or the per-upload cap allows).
"""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

MAX_SIDECAR_BYTES = 16 << 20  # a frames.csv row is ~40 bytes: 16 MiB holds 400k frames


class UnsupportedRecording(ValueError):
    """The file is not a recording format fringelab reads."""


class UnsafeArchive(ValueError):
    """A ZIP that must not be opened: path traversal, links, or a decompression bomb."""


class CorruptRecording(ValueError):
    """The file is damaged or truncated."""


class OverBudget(ValueError):
    """The recording would expand to more bytes than the per-upload cap or the free disk allow."""


def check_sidecar_size(size_bytes: int, *, name: str) -> None:
    """Refuse a sidecar by its size before reading it (from a ZIP directory, a file's stat, a request header).
    The parsers in `sidecars` read only what passed here."""
    if size_bytes > MAX_SIDECAR_BYTES:
        raise ValueError(f"{name}: {size_bytes} bytes, larger than the {MAX_SIDECAR_BYTES} bytes a sidecar may have")


def read_at(handle: BinaryIO, offset: int, length: int) -> bytes:
    """`length` bytes (fewer at the end of the file) from `offset` of an open binary file."""
    handle.seek(offset)
    return bytes(handle.read(max(0, length)))


def unpack_12bit_big_endian(data: bytes) -> np.ndarray:
    """Two 12-bit pixels in three bytes, most significant bits first (Phantom P12L, Photron 12-bit MRAW)."""
    b = np.frombuffer(data, dtype=np.uint8).reshape(-1, 3).astype(np.uint16)
    pixels = np.empty((len(b), 2), dtype=np.uint16)
    pixels[:, 0] = (b[:, 0] << 4) | (b[:, 1] >> 4)
    pixels[:, 1] = ((b[:, 1] & 0x0F) << 8) | b[:, 2]
    return pixels.ravel()
