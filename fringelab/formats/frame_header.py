"""Sizes before bytes: what one frame will take once decoded, read from its header, and the one check every reader
and the upload apply before a pixel is decoded.

A frame's header states its width, height, channels and bits per sample; decoded, it takes
width × height × channels × bytes per sample (a 0.9 MB PNG of 11000² 16-bit RGBA took 1.9 GiB; a deflated
20000² 16-bit RGB TIFF inside a ZIP 4.6 GiB, issue 26). `check_frame` refuses a frame over the byte budget
(FRINGELAB_MAX_FRAME_BYTES) and one whose size differs from the first frame's, before it is decoded.

- `FrameHeader`, `image_header(data)`: the header of a PNG, BMP, JPEG or TIFF frame from its first bytes (a TIFF
  whose directory lies further on: `tiff_header_from(handle)`, which seeks to it).
- `check_frame(header, ...)`: the budget and the first frame's size.

Not here: decoding (`recordings`), a whole container's layout (`containers`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import BinaryIO

from fringelab.formats.container_common import CorruptRecording, OverBudget, UnsupportedRecording

MAX_FRAME_BYTES = 256 * 1024 * 1024
"""Default byte budget of one decoded frame: a 16-bit grey frame of 11,585² px, 20 times a 4K high-speed frame."""
HEADER_BYTES = 64 * 1024
"""How much of a frame file its header is looked for in (a JPEG's EXIF block can come before its size)."""

_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}  # colour type -> channels as decoded (a palette becomes BGR)


@dataclass(frozen=True)
class FrameHeader:
    """What a frame's header states: its size and the decoded pixel's channels and bytes per sample."""

    width_px: int
    height_px: int
    channels: int = 1
    bytes_per_sample: int = 1

    @property
    def decoded_bytes(self) -> int:
        return self.width_px * self.height_px * self.channels * self.bytes_per_sample

    def describe(self) -> str:
        bits = 8 * self.bytes_per_sample
        if self.channels == 1:
            return f"{self.width_px} × {self.height_px} px of {bits} bits"
        return f"{self.width_px} × {self.height_px} px of {self.channels} × {bits} bits"


def image_header(data: bytes) -> FrameHeader | None:
    """The header of a PNG, BMP, JPEG or TIFF frame found in `data` (its first bytes); None when `data` holds
    none (a TIFF whose directory lies beyond `data`: see `tiff_header_from`)."""
    if data.startswith(b"\x89PNG") and len(data) >= 26:
        width, height, depth, colour = struct.unpack(">IIBB", data[16:26])
        return FrameHeader(width, height, _PNG_CHANNELS.get(colour, 4), 2 if depth == 16 else 1)
    if data.startswith(b"BM") and len(data) >= 30:
        width, height = struct.unpack("<ii", data[18:26])
        bits = struct.unpack("<H", data[28:30])[0]
        return FrameHeader(abs(width), abs(height), 4 if bits == 32 else 3)  # palettes decode to BGR
    if data.startswith(b"\xff\xd8"):
        return _jpeg_header(data)
    if data.startswith((b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")):
        import io

        try:
            return tiff_header_from(io.BytesIO(data), size=len(data))
        except CorruptRecording:
            return None
    return None


def _jpeg_header(data: bytes) -> FrameHeader | None:
    position = 2
    while position + 10 <= len(data) and data[position] == 0xFF:
        marker, length = data[position + 1], struct.unpack(">H", data[position + 2 : position + 4])[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # start of frame
            precision, height, width, components = struct.unpack(">BHHB", data[position + 4 : position + 10])
            return FrameHeader(width, height, 3 if components >= 3 else 1, 2 if precision > 8 else 1)
        position += 2 + length
    return None


def tiff_header_from(handle: BinaryIO, *, size: int) -> FrameHeader:
    """The first page's header of a TIFF read from `handle` (seekable, `size` bytes: a file or a ZIP entry being
    inflated, which seeks forward without holding what it passes). CorruptRecording when it has none."""
    from fringelab.formats.container_tiff import read_first_page_tags

    tags = read_first_page_tags(handle, size=size)
    width, height = tags.get(256, [0])[0], tags.get(257, [0])[0]
    if not width or not height:
        raise CorruptRecording("the TIFF's first page states no width or height")
    bits = max(tags.get(258, [8]))
    samples = tags.get(277, [1])[0]
    return FrameHeader(width, height, max(1, samples), max(1, (bits + 7) // 8))


def check_frame(
    header: FrameHeader | None, *, name: str, max_frame_bytes: int, first: FrameHeader | None = None
) -> FrameHeader:
    """Refuse, before decoding, a frame whose header is missing, whose decoded size is over `max_frame_bytes`
    (OverBudget), or whose size differs from the first frame's (CorruptRecording). Returns the header."""
    if header is None:
        raise UnsupportedRecording(f"{name}: its size cannot be read from its header; save it as PNG or TIFF")
    if header.decoded_bytes > max_frame_bytes:
        raise OverBudget(
            f"{name}: {header.describe()} decodes to {header.decoded_bytes} bytes, over the {max_frame_bytes}-byte "
            "limit of one frame (FRINGELAB_MAX_FRAME_BYTES)"
        )
    if first is not None and (header.width_px, header.height_px) != (first.width_px, first.height_px):
        raise CorruptRecording(
            f"{name}: {header.width_px} × {header.height_px} px, but frame 0 is {first.width_px} × "
            f"{first.height_px} px (mixed frame sizes; every frame of a recording must have the same size)"
        )
    return header
