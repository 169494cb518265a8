"""What kind of recording a file is, and whether its container is sound, without decoding a single pixel.

Everything here reads headers and directories only (standard library + numpy, no OpenCV), so the API process
can refuse a bad upload at once and the readers can trust what they open. Decoding frames lives in `readers`.

- `sniff_format(path)`: the recording format from the first bytes (not from the name).
- `inspect_zip(path, limits=...)`: frame and sidecar names of a ZIP, refusing path traversal, symbolic links,
  encrypted or exotic entries, truncation and ZIP bombs (total size, per-entry size, compression ratio,
  overlapping entries).
- `read_cine_header(path)`: geometry, pixel format, frame rate and frame offsets of a Phantom .cine file,
  checked against the file size (a truncated .cine is refused here).

Errors are `ValueError` subclasses that say what is wrong with the file: `UnsupportedRecording` (a format
fringelab does not read), `UnsafeArchive` (a ZIP that must not be opened) and `CorruptRecording` (damaged or
truncated).
"""

from __future__ import annotations

import re
import stat
import struct
import zipfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import BinaryIO

import numpy as np

from fringelab.science import natural_key

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg")
SIDECAR_NAMES = ("z.csv", "frames.csv", "board.json")
# Single-file recordings by name; a ZIP holds frames. A folder of frames is read from disk, not uploaded.
UPLOAD_SUFFIXES = {".zip": "zip", ".tif": "tiff", ".tiff": "tiff", ".avi": "avi", ".mp4": "mp4", ".cine": "cine"}
FORMATS = ("folder", "zip", "tiff", "avi", "mp4", "cine")

GiB = 1 << 30
MiB = 1 << 20


class UnsupportedRecording(ValueError):
    """The file is not a recording format fringelab reads."""


class UnsafeArchive(ValueError):
    """A ZIP that must not be opened: path traversal, links, or a decompression bomb."""


class CorruptRecording(ValueError):
    """The file is damaged or truncated."""


def sniff_format(path: str | Path) -> str:
    """The recording format of a file or folder from its content: one of `FORMATS`.

    Raises UnsupportedRecording (with what the file looks like) or CorruptRecording (an empty file, or a ZIP
    without its central directory, i.e. truncated).
    """
    path = Path(path)
    if path.is_dir():
        return "folder"
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
    raise UnsupportedRecording(
        f"{path.name}: not a recording format fringelab reads (accepted: ZIP of PNG/TIFF/BMP/JPEG frames, "
        "multi-page TIFF, AVI, MP4, Phantom .cine)"
    )


def _single_image_kind(head: bytes) -> str:
    if head.startswith(b"\x89PNG"):
        return "PNG"
    if head.startswith(b"\xff\xd8\xff"):
        return "JPEG"
    if head.startswith(b"BM"):
        return "BMP"
    return ""


# ---------------------------------------------------------------------------------------------------- ZIP


@dataclass(frozen=True)
class ZipLimits:
    """Bounds on what a ZIP of frames may expand to; a ZIP beyond any of them is refused as a bomb.

    max_total_bytes: sum of the uncompressed sizes of all entries. max_entry_bytes: one entry (one frame).
    max_ratio: uncompressed / compressed size of one entry (entries under 1 MiB are not held to it; deflate
    alone cannot pass ~1030, so a higher ratio means bzip2/LZMA tricks).
    """

    max_total_bytes: int = 256 * GiB
    max_entry_bytes: int = 2 * GiB
    max_ratio: float = 200.0


@dataclass(frozen=True)
class ZipContents:
    frame_names: tuple[str, ...]  # in natural order
    sidecar_names: dict[str, str]  # sidecar base name -> entry name
    uncompressed_bytes: int


_SUPPORTED_COMPRESSION = (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED, zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA)
_DRIVE = re.compile(r"^[A-Za-z]:")


def is_junk_entry(name: str) -> bool:
    """Files archivers add that are not frames: macOS resource forks, hidden files."""
    parts = PurePosixPath(name.replace("\\", "/")).parts
    return any(part == "__MACOSX" or part.startswith(".") for part in parts)


def unsafe_entry_reason(info: zipfile.ZipInfo) -> str:
    """Why a ZIP entry must not be trusted, or "" when it is fine."""
    name = info.filename
    if name.startswith(("/", "\\")) or _DRIVE.match(name):
        return f"entry {name!r} has an absolute path"
    if ".." in re.split(r"[\\/]", name):
        return f"entry {name!r} climbs out of the archive with '..'"
    if stat.S_ISLNK(info.external_attr >> 16):
        return f"entry {name!r} is a symbolic link"
    return ""


def inspect_zip(path: str | Path, *, limits: ZipLimits | None = None) -> ZipContents:
    """Check a ZIP of frames from its central directory and list its frames and sidecars.

    Raises UnsafeArchive, CorruptRecording or UnsupportedRecording naming the first offending entry.
    """
    path = Path(path)
    limits = limits or ZipLimits()
    size = path.stat().st_size
    try:
        with zipfile.ZipFile(path) as archive:
            infos = archive.infolist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError) as error:
        raise CorruptRecording(f"{path.name}: not a readable ZIP archive ({error})") from None
    total = 0
    frames: list[str] = []
    sidecars: dict[str, str] = {}
    for info in infos:
        reason = unsafe_entry_reason(info)
        if reason:
            raise UnsafeArchive(f"{path.name}: {reason}; refused")
        if info.is_dir():
            continue
        if info.flag_bits & 0x1:
            raise UnsupportedRecording(f"{path.name}: entry {info.filename!r} is encrypted")
        if info.compress_type not in _SUPPORTED_COMPRESSION:
            raise UnsupportedRecording(
                f"{path.name}: entry {info.filename!r} uses compression method {info.compress_type}; "
                "use stored, deflate, bzip2 or LZMA"
            )
        if info.file_size > limits.max_entry_bytes:
            raise UnsafeArchive(
                f"{path.name}: entry {info.filename!r} expands to {info.file_size} bytes, over the "
                f"{limits.max_entry_bytes}-byte limit of one entry"
            )
        if info.file_size > MiB and info.file_size > limits.max_ratio * max(info.compress_size, 1):
            ratio = info.file_size / max(info.compress_size, 1)
            raise UnsafeArchive(
                f"{path.name}: entry {info.filename!r} expands {ratio:.0f}× (limit {limits.max_ratio:.0f}×); "
                "refused as a ZIP bomb"
            )
        total += info.file_size
        if total > limits.max_total_bytes:
            raise UnsafeArchive(
                f"{path.name}: expands to more than {limits.max_total_bytes} bytes in total; refused as a ZIP bomb"
            )
        if info.header_offset + info.compress_size > size:
            raise CorruptRecording(f"{path.name}: entry {info.filename!r} runs past the end of the file (truncated)")
        if is_junk_entry(info.filename):
            continue
        base = PurePosixPath(info.filename).name
        if PurePosixPath(base).suffix.lower() in IMAGE_SUFFIXES:
            frames.append(info.filename)
        elif base in SIDECAR_NAMES:
            sidecars.setdefault(base, info.filename)
    _refuse_overlapping_entries(path.name, infos)
    if not frames:
        raise UnsupportedRecording(f"{path.name}: no image frames in the ZIP (accepted: {', '.join(IMAGE_SUFFIXES)})")
    return ZipContents(tuple(sorted(frames, key=natural_key)), sidecars, total)


def _refuse_overlapping_entries(name: str, infos: list[zipfile.ZipInfo]) -> None:
    """Entries whose data overlap are the trick of non-recursive ZIP bombs (one compressed stream, many names)."""
    ordered = sorted((i for i in infos if not i.is_dir()), key=lambda i: i.header_offset)
    for previous, current in zip(ordered, ordered[1:], strict=False):
        if current.header_offset < previous.header_offset + 30 + previous.compress_size:
            raise UnsafeArchive(
                f"{name}: entries {previous.filename!r} and {current.filename!r} overlap; refused as a ZIP bomb"
            )


# ---------------------------------------------------------------------------------------------------- cine

CINE_HEADER_SIZE = 44
_CINE_HEADER = struct.Struct("<2sHHHiIiIIIIQ")  # CINEFILEHEADER, 44 bytes
_BITMAP_INFO = struct.Struct("<IiiHHIIiiII")  # BITMAPINFOHEADER, 40 bytes
# Offsets of the SETUP fields we use, from the Phantom file-format documentation.
_SETUP_FRAME_RATE_16 = 0  # uint16, legacy
_SETUP_LENGTH = 142  # uint16, size of SETUP in bytes
_SETUP_FRAME_RATE = 768  # uint32
_SETUP_REAL_BPP = 896  # uint32


@dataclass(frozen=True, eq=False)
class CineHeader:
    """What a reader needs of a Phantom .cine file.

    image_offsets: shape (frame_count,), byte offset of each frame's annotation block. bit_count: bits per
    stored pixel (8 or 16 grey, 24 or 48 colour). real_bpp: significant bits of a pixel (e.g. 12).
    """

    width_px: int
    height_px: int
    bit_count: int
    real_bpp: int
    frame_rate_hz: float | None
    bottom_up: bool
    first_image_no: int
    image_offsets: np.ndarray

    @property
    def frame_count(self) -> int:
        return len(self.image_offsets)

    @property
    def channels(self) -> int:
        return 3 if self.bit_count in (24, 48) else 1

    @property
    def dtype(self) -> np.dtype:
        return np.dtype("<u2") if self.bit_count in (16, 48) else np.dtype(np.uint8)

    @property
    def frame_bytes(self) -> int:
        return self.width_px * self.height_px * self.channels * self.dtype.itemsize


def read_cine_header(path: str | Path) -> CineHeader:
    """Parse and check a .cine header; refuses compressed or packed pixel formats and truncated files."""
    path = Path(path)
    size = path.stat().st_size
    with path.open("rb") as handle:
        raw = handle.read(_CINE_HEADER.size)
        if len(raw) < _CINE_HEADER.size:
            raise CorruptRecording(f"{path.name}: shorter than a .cine header")
        (kind, header_size, compression, _version, _first_movie, _total, first_no, count, off_bitmap, off_setup,
         off_offsets, _trigger) = _CINE_HEADER.unpack(raw)  # fmt: skip
        if kind != b"CI" or header_size != CINE_HEADER_SIZE:
            raise UnsupportedRecording(f"{path.name}: not a Phantom .cine file")
        if compression != 0:
            raise UnsupportedRecording(
                f"{path.name}: compressed or raw-Bayer .cine (compression {compression}); export it uncompressed"
            )
        if count == 0:
            raise CorruptRecording(f"{path.name}: the .cine holds no frames")
        for name, offset, length in (("bitmap header", off_bitmap, _BITMAP_INFO.size), ("setup", off_setup, 2),
                                     ("frame offsets", off_offsets, 8 * count)):  # fmt: skip
            if offset + length > size:
                raise CorruptRecording(f"{path.name}: the {name} lies past the end of the file (truncated)")
        handle.seek(off_bitmap)
        (_bi_size, width, height, _planes, bit_count, bi_compression, _image_size, *_rest) = _BITMAP_INFO.unpack(
            handle.read(_BITMAP_INFO.size)
        )
        if bit_count not in (8, 16, 24, 48) or bi_compression != 0:
            raise UnsupportedRecording(
                f"{path.name}: {bit_count}-bit pixels with bitmap compression {bi_compression}; only uncompressed "
                "8- and 16-bit (and 24/48-bit colour) .cine files are read; export unpacked"
            )
        if width <= 0 or height == 0:
            raise CorruptRecording(f"{path.name}: frame size {width} × {height} px")
        setup = _read_at(handle, off_setup, min(1024, size - off_setup))
        setup_length = struct.unpack_from("<H", setup, _SETUP_LENGTH)[0] if len(setup) >= _SETUP_LENGTH + 2 else 0
        usable = min(len(setup), setup_length)
        frame_rate: float | None = None
        if usable >= _SETUP_FRAME_RATE + 4:
            frame_rate = float(struct.unpack_from("<I", setup, _SETUP_FRAME_RATE)[0]) or None
        elif len(setup) >= 2:
            frame_rate = float(struct.unpack_from("<H", setup, _SETUP_FRAME_RATE_16)[0]) or None
        depth = 16 if bit_count in (16, 48) else 8
        real_bpp = depth
        if usable >= _SETUP_REAL_BPP + 4:
            real_bpp = int(struct.unpack_from("<I", setup, _SETUP_REAL_BPP)[0]) or depth
        handle.seek(off_offsets)
        offsets = np.frombuffer(handle.read(8 * count), dtype="<u8").astype(np.int64)
    header = CineHeader(
        width_px=width,
        height_px=abs(height),
        bit_count=bit_count,
        real_bpp=min(real_bpp, depth),
        frame_rate_hz=frame_rate,
        bottom_up=height > 0,
        first_image_no=first_no,
        image_offsets=offsets,
    )
    # Each frame: annotation block (its size first, uint32), then image bytes; the last must fit in the file.
    last = int(offsets.max())
    if (offsets < CINE_HEADER_SIZE).any() or last + 8 > size:
        raise CorruptRecording(f"{path.name}: a frame offset lies outside the file (truncated or damaged)")
    with path.open("rb") as handle:
        annotation = struct.unpack("<I", _read_at(handle, last, 4))[0]
    if annotation < 8 or last + annotation + header.frame_bytes > size:
        raise CorruptRecording(
            f"{path.name}: the last frame ends past the end of the file ({size} bytes); the .cine is truncated"
        )
    return header


def _read_at(handle: BinaryIO, offset: int, length: int) -> bytes:
    handle.seek(offset)
    return bytes(handle.read(max(0, length)))
