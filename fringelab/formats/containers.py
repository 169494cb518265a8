"""The recording containers fringelab reads, and what kind a file is, without decoding a single pixel.

Everything under `containers` and its `container_*` modules reads headers and directories only (standard library +
numpy, no OpenCV), so the API process can refuse a bad upload at once and the readers (`recordings`) can trust
what they open. This module is the registry: the one list of formats and the dispatch by format.

- `FORMATS`, `UPLOAD_SUFFIXES`, `STATES_BIT_DEPTH`: the container kinds, which ones are uploaded as one file (by
  name), and which state their pixels' significant bits.
- `sniff_format(path)`: the recording format from the first bytes (not from the name).
- `recording_layout(path)` and `check_ingest_budget(...)`: frames × frame size from the headers alone, held
  against a per-upload cap and the free disk before the ingest writes anything.

One module a container: `container_zip` (a ZIP or folder of frames), `container_tiff`, `container_video` (AVI,
MP4), `container_cine` (Phantom .cine), `container_mraw` (Photron .cih/.cihx + .mraw); what they share (the
errors `UnsupportedRecording`, `UnsafeArchive`, `CorruptRecording`, `OverBudget`) is in `container_common`.
"""

from __future__ import annotations

import struct
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, cast

from fringelab.formats.container_cine import CINE_HEADER_SIZE, read_cine_header
from fringelab.formats.container_common import CorruptRecording, OverBudget, UnsupportedRecording
from fringelab.formats.container_mraw import MRAW_HEADER_SUFFIXES, MrawHeader, read_mraw_header
from fringelab.formats.container_tiff import read_tiff_layout
from fringelab.formats.container_video import check_video_container
from fringelab.formats.container_zip import ZipLimits, inspect_zip, mraw_header_in_zip
from fringelab.formats.frame_header import (
    HEADER_BYTES,
    MAX_FRAME_BYTES,
    FrameHeader,
    check_frame,
    image_header,
    tiff_header_from,
)

# Single-file recordings by name; a ZIP holds frames. A folder of frames is read from disk, not uploaded.
UPLOAD_SUFFIXES = {".zip": "zip", ".tif": "tiff", ".tiff": "tiff", ".avi": "avi", ".mp4": "mp4", ".cine": "cine"}
FORMATS = ("folder", "zip", "tiff", "avi", "mp4", "cine", "mraw")
# What an upload may be, for people: the one list every refusal names (each suffix of UPLOAD_SUFFIXES in it).
ACCEPTED_UPLOADS = (
    "a ZIP of PNG/TIFF/BMP/JPEG frames or of a Photron .cih/.cihx with its .mraw (.zip), a multi-page TIFF (.tif, "
    ".tiff), an AVI (.avi), an MP4 (.mp4) or a Phantom .cine (.cine)"
)
# Containers whose header states the significant bits of a pixel (others: measured from the largest value).
STATES_BIT_DEPTH = ("cine", "mraw")


def sniff_format(path: str | Path) -> str:
    """The recording format of a file or folder from its content: one of `FORMATS`.

    Raises UnsupportedRecording (with what the file looks like) or CorruptRecording (an empty file, or a ZIP
    without its central directory, i.e. truncated).
    """
    path = Path(path)
    if path.is_dir():
        return "folder"
    if path.suffix.lower() in (*MRAW_HEADER_SUFFIXES, ".mraw"):
        return "mraw"  # raw pixel data has no signature; the header beside it is checked when it is read
    with path.open("rb") as handle:
        head = handle.read(16)
    if not head:
        raise CorruptRecording(f"{path.name}: the file is empty")
    if head.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        if not zipfile.is_zipfile(path):
            raise CorruptRecording(f"{path.name}: a ZIP archive without its central directory (truncated upload?)")
        return "zip"
    if head.startswith((b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")):
        return "tiff"
    if head[:2] == b"CI" and struct.unpack_from("<H", head, 2)[0] == CINE_HEADER_SIZE:
        return "cine"
    if head[:4] == b"RIFF" and head[8:12] == b"AVI ":
        return "avi"
    if head[4:8] == b"ftyp":
        return "mp4"
    kind = _single_image_kind(head)
    if kind:
        raise UnsupportedRecording(
            f"{path.name}: a single {kind} image is not a recording; upload a ZIP of frames or a multi-page TIFF"
        )
    raise UnsupportedRecording(f"{path.name}: not a recording format fringelab reads; it reads {ACCEPTED_UPLOADS}")


def _single_image_kind(head: bytes) -> str:
    if head.startswith(b"\x89PNG"):
        return "PNG"
    if head.startswith(b"\xff\xd8\xff"):
        return "JPEG"
    if head.startswith(b"BM"):
        return "BMP"
    return ""


@dataclass(frozen=True)
class RecordingLayout:
    """Frames × frame size as the container's headers state them, without decoding.

    frame_count, width_px and height_px are 0 when the headers do not say (a video without counts, a frame
    format whose size is not in its first bytes); the budget then rests on what is known.
    """

    format: str
    frame_count: int
    width_px: int
    height_px: int
    bytes_per_pixel: int = 1

    @property
    def frames_bytes(self) -> int:
        """Bytes of every frame decoded at full size."""
        return self.frame_count * self.width_px * self.height_px * self.bytes_per_pixel

    def preview_bytes(self, preview_size_px: int, thumbnail_px: int) -> int:
        """Bytes the ingest's preview store will hold: every frame at display size and as a thumbnail (uint8)."""
        longer = max(self.width_px, self.height_px, 1)
        display = min(1.0, preview_size_px / longer) ** 2 * self.width_px * self.height_px
        thumbnail = min(1.0, thumbnail_px / longer) ** 2 * self.width_px * self.height_px
        return int(self.frame_count * (display + thumbnail))


def recording_layout(path: str | Path, *, zip_limits: ZipLimits | None = None) -> RecordingLayout:
    """The layout of a recording file from its headers (for ZIP, the first frame's header), checking its
    container on the way: raises UnsupportedRecording, UnsafeArchive or CorruptRecording like the readers."""
    path = Path(path)
    format = sniff_format(path)
    if format == "zip":
        contents = inspect_zip(path, limits=zip_limits)
        if contents.mraw_entries is not None:
            return _mraw_layout(format, mraw_header_in_zip(path, contents.mraw_entries))
        first = contents.frame_names[0]
        with zipfile.ZipFile(path) as archive, archive.open(first) as entry:
            header = image_header(entry.read(HEADER_BYTES))
            if header is None and first.lower().endswith((".tif", ".tiff")):  # its directory lies further on
                header = tiff_header_from(cast(BinaryIO, entry), size=archive.getinfo(first).file_size)
        if header is None:
            return RecordingLayout(format, len(contents.frame_names), 0, 0)
        return RecordingLayout(format, len(contents.frame_names), header.width_px, header.height_px,
                               header.channels * header.bytes_per_sample)  # fmt: skip
    if format == "cine":
        cine = read_cine_header(path)
        return RecordingLayout(
            format, cine.frame_count, cine.width_px, cine.height_px, cine.channels * cine.dtype.itemsize
        )
    if format == "mraw":
        return _mraw_layout(format, read_mraw_header(path))
    if format == "tiff":
        tiff = read_tiff_layout(path)
        return RecordingLayout(format, tiff.frame_count, tiff.width_px, tiff.height_px, tiff.bytes_per_sample)
    if format in ("avi", "mp4"):
        video = check_video_container(path, format)
        return RecordingLayout(format, video.frame_count, video.width_px, video.height_px)
    return RecordingLayout(format, 0, 0, 0)


def _mraw_layout(format: str, header: MrawHeader) -> RecordingLayout:
    return RecordingLayout(format, header.frame_count, header.width_px, header.height_px, 1 if header.bits == 8 else 2)


def check_ingest_budget(
    layout: RecordingLayout,
    *,
    name: str,
    max_frames_bytes: int,
    free_bytes: int,
    reserve_bytes: int,
    preview_size_px: int,
    thumbnail_px: int,
    max_frame_bytes: int = MAX_FRAME_BYTES,
) -> None:
    """Refuse a recording one of whose frames would decode to more than `max_frame_bytes` (its first frame's
    header, for every container), whose frames would decode to more than `max_frames_bytes`, or whose preview
    store would leave less than `reserve_bytes` free on the data volume. Raises OverBudget saying which and by
    how much."""
    if layout.width_px and layout.height_px:
        frame = FrameHeader(layout.width_px, layout.height_px, 1, layout.bytes_per_pixel)
        check_frame(frame, name=f"{name}: a frame", max_frame_bytes=max_frame_bytes)
    if layout.frames_bytes > max_frames_bytes:
        raise OverBudget(
            f"{name}: {layout.frame_count} frames of {layout.width_px} × {layout.height_px} px decode to "
            f"{layout.frames_bytes} bytes, over the {max_frames_bytes}-byte limit of one recording "
            "(FRINGELAB_MAX_FRAMES_BYTES)"
        )
    previews = layout.preview_bytes(preview_size_px, thumbnail_px)
    if previews > free_bytes - reserve_bytes:
        raise OverBudget(
            f"{name}: its previews need {previews} bytes and the data volume has {free_bytes} free, of which "
            f"{reserve_bytes} are kept in reserve (FRINGELAB_MIN_FREE_DISK_BYTES); free some space"
        )
