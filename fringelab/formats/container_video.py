"""An AVI's RIFF chunks or an MP4's top-level boxes, checked against the file size without decoding a frame.

- `check_video_container(path, format)`: the structure, and the frame count and size the headers declare.

Not here: decoding frames (`recordings`, through OpenCV), the list of formats (`containers`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

from fringelab.formats.container_common import CorruptRecording, read_at


@dataclass(frozen=True)
class VideoLayout:
    """Frame count and size a video's headers declare (0 where they do not say)."""

    frame_count: int
    width_px: int
    height_px: int


def check_video_container(path: str | Path, format: str) -> VideoLayout:
    """Check the outer structure of an AVI (RIFF chunks) or MP4 (top-level boxes) against the file size.

    A video cut short still decodes up to the cut, so only its container shows that the end is missing.
    """
    path = Path(path)
    if format == "avi":
        return _check_avi(path)
    if format == "mp4":
        return _check_mp4(path)
    raise ValueError(f"{path.name}: {format!r} is not a video format (expected avi or mp4)")


def _check_avi(path: Path) -> VideoLayout:
    size = path.stat().st_size
    layout = VideoLayout(0, 0, 0)
    with path.open("rb") as handle:
        position = 0
        while position + 8 <= size:
            kind, length = struct.unpack("<4sI", read_at(handle, position, 8))
            if kind != b"RIFF" and position > 0:
                break  # trailing bytes after the last RIFF list (junk some writers leave) are not our business
            if position + 8 + length > size:
                raise CorruptRecording(
                    f"{path.name}: the AVI declares {position + 8 + length} bytes but the file has {size}; it is "
                    "truncated"
                )
            if position == 0:
                avih = read_at(handle, 12, 64)
                if avih[:4] == b"LIST" and avih[8:12] == b"hdrl" and avih[12:16] == b"avih":
                    (frames,) = struct.unpack_from("<I", avih, 20 + 16)  # MainAVIHeader.dwTotalFrames
                    width, height = struct.unpack_from("<II", avih, 20 + 32)  # dwWidth, dwHeight
                    layout = VideoLayout(int(frames), int(width), int(height))
            position += 8 + length + (length & 1)
    return layout


def _check_mp4(path: Path) -> VideoLayout:
    size = path.stat().st_size
    position = 0
    found_moov = False
    with path.open("rb") as handle:
        while position < size:
            head = read_at(handle, position, 16)
            if len(head) < 8:
                raise CorruptRecording(f"{path.name}: a box header is cut at byte {position}; the MP4 is truncated")
            length, kind = struct.unpack_from(">I4s", head)
            if length == 1:
                if len(head) < 16:
                    raise CorruptRecording(f"{path.name}: a box header is cut at byte {position}; truncated")
                length = struct.unpack_from(">Q", head, 8)[0]
            elif length == 0:
                length = size - position  # the last box runs to the end of the file
            if length < 8 or position + length > size:
                raise CorruptRecording(
                    f"{path.name}: the {kind.decode('latin-1')!r} box ends at byte {position + length} but the file "
                    f"has {size}; the MP4 is truncated"
                )
            found_moov |= kind == b"moov"
            position += length
    if not found_moov:
        raise CorruptRecording(f"{path.name}: the MP4 has no 'moov' box (an unfinished recording?)")
    return VideoLayout(0, 0, 0)
