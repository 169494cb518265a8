"""What kind of recording a file is, and whether its container is sound, without decoding a single pixel.

Everything here reads headers and directories only (standard library + numpy, no OpenCV), so the API process
can refuse a bad upload at once and the readers can trust what they open. Decoding frames lives in `readers`.

- `sniff_format(path)`: the recording format from the first bytes (not from the name).
- `inspect_zip(path, limits=...)`: frame and sidecar names of a ZIP, refusing path traversal, symbolic links,
  encrypted or exotic entries, truncation and ZIP bombs (total size, per-entry size, compression ratio,
  overlapping entries).
- `read_cine_header(path)`: geometry, pixel format (incl. packed 10/12-bit), frame rate, trigger numbering,
  per-frame time stamps (tagged blocks) and frame offsets of a Phantom .cine file, checked against the file size
  (a truncated .cine is refused here); `unpack_cine_pixels` turns one stored image into an array.
- `read_mraw_header(path)`: a Photron .cih/.cihx header and its .mraw checked against each other (8-, 12- and
  16-bit mono); `unpack_mraw_pixels` turns one stored frame into an array.
- `read_tiff_layout(path)`: the page chain of a (multi-page) TIFF, every IFD and every strip or tile checked
  against the file size (a truncated TIFF is refused, not read as its first pages).
- `check_video_container(path, format)`: the RIFF chunks of an AVI or the top-level boxes of an MP4 checked
  against the file size, and the frame count and size their headers declare.
- `recording_layout(path)` and `check_ingest_budget(...)`: frames × frame size from the headers alone, held
  against a per-upload cap and the free disk before the ingest writes anything.

Errors are `ValueError` subclasses that say what is wrong with the file: `UnsupportedRecording` (a format
fringelab does not read), `UnsafeArchive` (a ZIP that must not be opened), `CorruptRecording` (damaged or
truncated) and `OverBudget` (it would expand to more than the data volume or the per-upload cap allows).
"""

from __future__ import annotations

import re
import stat
import struct
import zipfile
from dataclasses import dataclass
from pathlib import Path, PurePath, PurePosixPath
from typing import BinaryIO

import numpy as np

from fringelab.science import natural_key

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg")
SIDECAR_NAMES = ("z.csv", "frames.csv", "board.json")
MAX_SIDECAR_BYTES = 16 << 20  # a frames.csv row is ~40 bytes: 16 MiB holds 400k frames
# Single-file recordings by name; a ZIP holds frames. A folder of frames is read from disk, not uploaded.
UPLOAD_SUFFIXES = {".zip": "zip", ".tif": "tiff", ".tiff": "tiff", ".avi": "avi", ".mp4": "mp4", ".cine": "cine"}
FORMATS = ("folder", "zip", "tiff", "avi", "mp4", "cine", "mraw")
# Containers whose header states the significant bits of a pixel (others: measured from the largest value).
STATES_BIT_DEPTH = ("cine", "mraw")

GiB = 1 << 30
MiB = 1 << 20


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
    raise UnsupportedRecording(
        f"{path.name}: not a recording format fringelab reads (accepted: ZIP of PNG/TIFF/BMP/JPEG frames, "
        "multi-page TIFF, AVI, MP4, Phantom .cine, Photron .cih/.cihx + .mraw)"
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
    max_ratio: uncompressed / compressed size of one entry over 1 MiB, and of the whole archive once it
    expands to more than 1 MiB (deflate alone cannot pass ~1030, so a higher ratio means bzip2/LZMA tricks; the
    total keeps many entries each just under 1 MiB from passing one by one).
    """

    max_total_bytes: int = 256 * GiB
    max_entry_bytes: int = 2 * GiB
    max_ratio: float = 200.0


@dataclass(frozen=True)
class ZipContents:
    frame_names: tuple[str, ...]  # in natural order
    sidecar_names: dict[str, str]  # sidecar base name -> entry name
    uncompressed_bytes: int
    mraw_entries: tuple[str, str] | None = None  # (.cih/.cihx entry, stored .mraw entry): a Photron recording


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
    total = compressed = 0
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
        compressed += info.compress_size
        if total > MiB and total > limits.max_ratio * max(compressed, 1):
            raise UnsafeArchive(
                f"{path.name}: its entries expand {total / max(compressed, 1):.0f}× in total (limit "
                f"{limits.max_ratio:.0f}×); refused as a ZIP bomb"
            )
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
            try:
                check_sidecar_size(info.file_size, name=info.filename)
            except ValueError as error:
                raise UnsafeArchive(f"{path.name}: {error}; refused") from None
            sidecars.setdefault(base, info.filename)
    _refuse_overlapping_entries(path.name, infos)
    if not frames:
        mraw = _mraw_entries(path.name, infos)
        if mraw is not None:
            return ZipContents((), sidecars, total, mraw_entries=mraw)
        raise UnsupportedRecording(
            f"{path.name}: no image frames in the ZIP (accepted: {', '.join(IMAGE_SUFFIXES)}, or a Photron "
            ".cihx/.cih with its .mraw)"
        )
    return ZipContents(tuple(sorted(frames, key=natural_key)), sidecars, total)


def _mraw_entries(name: str, infos: list[zipfile.ZipInfo]) -> tuple[str, str] | None:
    """(header, data) entries of a Photron recording in a ZIP: one .mraw, stored (not compressed) so frames are
    read at their offsets, and its .cihx or .cih of the same stem."""
    data = [i for i in infos if not i.is_dir() and not is_junk_entry(i.filename)
            and i.filename.lower().endswith(".mraw")]  # fmt: skip
    if len(data) != 1:
        return None
    if data[0].compress_type != zipfile.ZIP_STORED:
        raise UnsupportedRecording(
            f"{name}: {data[0].filename} is compressed in the ZIP; store it uncompressed (zip -0) so its frames "
            "can be read where they lie"
        )
    stem = data[0].filename[: -len(".mraw")]
    by_name = {i.filename.lower(): i.filename for i in infos}
    for suffix in MRAW_HEADER_SUFFIXES:
        header = by_name.get((stem + suffix).lower())
        if header is not None:
            return header, data[0].filename
    raise UnsupportedRecording(f"{name}: {data[0].filename} has no .cihx or .cih of the same name in the ZIP")


def zip_entry_data_offset(path: Path, info: zipfile.ZipInfo) -> int:
    """Where a stored entry's bytes start in the ZIP file (after its local header, name and extra field)."""
    with path.open("rb") as handle:
        local = _read_at(handle, info.header_offset, 30)
    if len(local) < 30 or local[:4] != b"PK\x03\x04":
        raise CorruptRecording(f"{path.name}: entry {info.filename!r} has no local header (damaged)")
    name_length, extra_length = struct.unpack_from("<HH", local, 26)
    return info.header_offset + 30 + name_length + extra_length


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
_SETUP_LENGTH = 142  # uint16, size of SETUP in bytes; the tagged blocks follow it
_SETUP_FRAME_RATE = 768  # uint32
_SETUP_REAL_BPP = 896  # uint32
# CINEFILEHEADER.Compression: what the camera stored.
_CINE_COMPRESSION = {1: "JPEG-compressed", 2: "raw Bayer (uninterpolated colour)"}
# BITMAPINFOHEADER.biCompression of packed grey data: bits a pixel, name in the Phantom documentation.
_CINE_PACKINGS = {0: (0, ""), 256: (10, "P10"), 1024: (12, "P12L")}
_TAG_TIME_ONLY = 1002  # TIME64 per image
_TAG_TIME_TOTAL = 1001  # older files: the same, with the IRIG time code
_TIME64_FRACTION = float(1 << 32)


@dataclass(frozen=True, eq=False)
class CineHeader:
    """What a reader needs of a Phantom .cine file.

    image_offsets: shape (frame_count,), byte offset of each frame's annotation block. bit_count: bits per
    stored pixel of unpacked data (8 or 16 grey, 24 or 48 colour). packing: "" (one pixel a byte or two), "P10"
    (4 pixels in 5 bytes, Phantom's companded 10-bit codes) or "P12L" (2 pixels in 3 bytes, linear 12-bit).
    real_bpp: significant bits of a pixel (e.g. 12). first_image_no: the camera's number of the first stored
    frame (the trigger frame is 0, so pre-trigger frames are negative). frame_time_s: shape (frame_count,),
    time of each frame relative to the trigger from the file's time-stamp block, or None when it has none.
    """

    width_px: int
    height_px: int
    bit_count: int
    real_bpp: int
    frame_rate_hz: float | None
    bottom_up: bool
    first_image_no: int
    image_offsets: np.ndarray
    packing: str = ""
    frame_time_s: np.ndarray | None = None

    @property
    def frame_count(self) -> int:
        return len(self.image_offsets)

    @property
    def channels(self) -> int:
        return 3 if self.bit_count in (24, 48) else 1

    @property
    def dtype(self) -> np.dtype:
        return np.dtype("<u2") if self.bit_count in (16, 48) or self.packing else np.dtype(np.uint8)

    @property
    def packed_bits(self) -> int:
        return {"P10": 10, "P12L": 12}.get(self.packing, 0)

    @property
    def frame_bytes(self) -> int:
        """Bytes of one stored image (packed images take 10 or 12 bits a pixel)."""
        if self.packing:
            return self.width_px * self.height_px * self.packed_bits // 8
        return self.width_px * self.height_px * self.channels * self.dtype.itemsize

    @property
    def frame_numbers(self) -> np.ndarray:
        """The camera's number of each stored frame (first_image_no, first_image_no + 1, ...), shape (n,)."""
        return np.arange(self.frame_count, dtype=np.int64) + self.first_image_no


def read_cine_header(path: str | Path) -> CineHeader:
    """Parse and check a .cine header; refuses compressed files, unknown pixel formats and truncated files."""
    path = Path(path)
    size = path.stat().st_size
    with path.open("rb") as handle:
        raw = handle.read(_CINE_HEADER.size)
        if len(raw) < _CINE_HEADER.size:
            raise CorruptRecording(f"{path.name}: shorter than a .cine header (truncated)")
        (kind, header_size, compression, _version, _first_movie, _total, first_no, count, off_bitmap, off_setup,
         off_offsets, trigger_time64) = _CINE_HEADER.unpack(raw)  # fmt: skip
        if kind != b"CI" or header_size != CINE_HEADER_SIZE:
            raise UnsupportedRecording(f"{path.name}: not a Phantom .cine file")
        if compression != 0:
            what = _CINE_COMPRESSION.get(compression, f"compression code {compression}")
            raise UnsupportedRecording(
                f"{path.name}: a {what} .cine cannot be measured; save it from PCC as an uncompressed grey "
                "(or interpolated colour) .cine, 8/16-bit or packed 10/12-bit"
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
        packed_bits, packing = _CINE_PACKINGS.get(bi_compression, (-1, ""))
        if packed_bits < 0 or bit_count not in (8, 16, 24, 48) or (packing and bit_count not in (8, 16)):
            raise UnsupportedRecording(
                f"{path.name}: {bit_count}-bit pixels with bitmap compression {bi_compression}; fringelab reads "
                "uncompressed 8/16-bit grey, 24/48-bit colour and packed 10-bit (P10) or 12-bit (P12L) grey .cine"
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
        depth = packed_bits or (16 if bit_count in (16, 48) else 8)
        real_bpp = depth
        if usable >= _SETUP_REAL_BPP + 4:
            real_bpp = int(struct.unpack_from("<I", setup, _SETUP_REAL_BPP)[0]) or depth
        handle.seek(off_offsets)
        offsets = np.frombuffer(handle.read(8 * count), dtype="<u8").astype(np.int64)
        times = _cine_frame_times(handle, path.name, off_setup + setup_length, off_offsets, count)
    header = CineHeader(
        width_px=width,
        height_px=abs(height),
        bit_count=16 if packing else bit_count,
        real_bpp=min(real_bpp, depth),
        frame_rate_hz=frame_rate,
        bottom_up=height > 0 and not packing,  # packed images are stored top-down
        first_image_no=first_no,
        image_offsets=offsets,
        packing=packing,
        frame_time_s=_times_from_trigger(times, trigger_time64, first_no, frame_rate),
    )
    _check_cine_frames_fit(path, header, size)
    return header


def _times_from_trigger(
    stamps: np.ndarray | None, trigger_time64: int, first_image_no: int, frame_rate_hz: float | None
) -> np.ndarray | None:
    """Frame times in s relative to the trigger from TIME64 stamps (seconds since 1970 in the high 32 bits, the
    fraction in the low 32), subtracted as integers to keep TIME64's 0.23 ns; a file without a trigger time
    counts from its first frame's number and the frame rate."""
    if stamps is None:
        return None
    ticks = stamps.astype(np.int64)  # 2^-32 s; fits int64 until 2038 + 68 years
    if trigger_time64:
        return (ticks - np.int64(trigger_time64)) / _TIME64_FRACTION
    start_s = first_image_no / frame_rate_hz if frame_rate_hz else 0.0
    return (ticks - ticks[0]) / _TIME64_FRACTION + start_s


def _cine_frame_times(handle: BinaryIO, name: str, start: int, stop: int, count: int) -> np.ndarray | None:
    """TIME64 stamps (n,) uint64 of each frame from the tagged blocks between SETUP and the frame offsets, or
    None when the file has none.

    Each block: uint32 size (header included), uint16 type, uint16 reserved, data. Unknown blocks are skipped;
    a block that runs past the frame offsets means a damaged header.
    """
    offset = start
    while offset + 8 <= stop:
        block_size, block_type, _reserved = struct.unpack("<IHH", _read_at(handle, offset, 8))
        if block_size < 8 or offset + block_size > stop:
            raise CorruptRecording(f"{name}: a tagged block at byte {offset} runs into the frame offsets (damaged)")
        if block_type in (_TAG_TIME_ONLY, _TAG_TIME_TOTAL) and block_size - 8 >= 8 * count:
            return np.frombuffer(_read_at(handle, offset + 8, 8 * count), dtype="<u8").astype(np.uint64)
        offset += block_size
    return None


def _check_cine_frames_fit(path: Path, header: CineHeader, size: int) -> None:
    """Every frame's annotation and image must lie inside the file, one after another: a truncated .cine is an
    error, never a recording with fewer frames."""
    offsets = header.image_offsets
    if (offsets < CINE_HEADER_SIZE).any():
        raise CorruptRecording(f"{path.name}: a frame offset points into the file header (damaged)")
    last = int(offsets.max())
    if last + 8 > size:
        raise CorruptRecording(
            f"{path.name}: frame {header.frame_count - 1} starts past the end of the file ({size} bytes); "
            "the .cine is truncated"
        )
    # Frames follow each other without overlap: offsets pointing at one frame would make a small file decode
    # to any number of frames (the ingest would write previews for each).
    gaps = np.diff(offsets)
    if (gaps < 8 + header.frame_bytes).any():
        first_bad = int(np.flatnonzero(gaps < 8 + header.frame_bytes)[0])
        raise CorruptRecording(
            f"{path.name}: frames {first_bad} and {first_bad + 1} overlap (offsets {int(offsets[first_bad])} and "
            f"{int(offsets[first_bad + 1])}, a frame is {header.frame_bytes} bytes); the .cine is damaged"
        )
    with path.open("rb") as handle:
        annotation = struct.unpack("<I", _read_at(handle, last, 4))[0]
    if annotation < 8 or last + annotation + header.frame_bytes > size:
        raise CorruptRecording(
            f"{path.name}: the last frame ends past the end of the file ({size} bytes); the .cine is truncated"
        )


def unpack_cine_pixels(data: bytes, header: CineHeader) -> np.ndarray:
    """The pixels of one stored .cine image as a 2-D (or colour 3-D) array, rows top-down, native byte order.

    Packed data is a big-endian bit stream: P10 holds 4 pixels in 5 bytes, P12L 2 pixels in 3 bytes.
    """
    rows, cols = header.height_px, header.width_px
    if header.packing:
        packed = np.frombuffer(data, dtype=np.uint8)
        if header.packing == "P12L":
            return _unpack_12bit_big_endian(data).reshape(rows, cols)
        else:
            b = packed.reshape(-1, 5).astype(np.uint16)
            pixels = np.empty((len(b), 4), dtype=np.uint16)
            pixels[:, 0] = (b[:, 0] << 2) | (b[:, 1] >> 6)
            pixels[:, 1] = ((b[:, 1] & 0x3F) << 4) | (b[:, 2] >> 4)
            pixels[:, 2] = ((b[:, 2] & 0x0F) << 6) | (b[:, 3] >> 2)
            pixels[:, 3] = ((b[:, 3] & 0x03) << 8) | b[:, 4]
        return pixels.reshape(rows, cols)
    shape: tuple[int, ...] = (rows, cols, 3) if header.channels == 3 else (rows, cols)
    image = np.frombuffer(data, dtype=header.dtype).reshape(shape)
    if header.bottom_up:
        image = image[::-1]
    return image.astype(header.dtype.newbyteorder("="), copy=True)


def _read_at(handle: BinaryIO, offset: int, length: int) -> bytes:
    handle.seek(offset)
    return bytes(handle.read(max(0, length)))


# ---------------------------------------------------------------------------------------------------- Photron MRAW

MRAW_HEADER_SUFFIXES = (".cihx", ".cih")
_MAX_CIH_BYTES = 4 << 20


@dataclass(frozen=True)
class MrawHeader:
    """What a reader needs of a Photron MRAW recording (the .mraw data and its .cih/.cihx header).

    bits: bits a stored pixel takes (8, 12 packed big-endian 2 pixels in 3 bytes, or 16 little-endian).
    effective_bits: significant bits of a pixel (the camera's sensor depth). start_frame: the camera's number of
    the first stored frame (the trigger frame is 0). data_path: the .mraw file.
    """

    width_px: int
    height_px: int
    frame_count: int
    bits: int
    effective_bits: int
    frame_rate_hz: float | None
    start_frame: int
    data_path: Path
    header_path: PurePath  # a file, or the entry name of a header inside a ZIP
    data_offset: int = 0  # where the frames start in data_path (non-zero for an .mraw stored inside a ZIP)

    @property
    def frame_bytes(self) -> int:
        return self.width_px * self.height_px * self.bits // 8

    @property
    def frame_numbers(self) -> np.ndarray:
        return np.arange(self.frame_count, dtype=np.int64) + self.start_frame


def mraw_paths(path: str | Path) -> tuple[Path, Path]:
    """(header, data) paths of an MRAW recording named by its .cih, .cihx or .mraw file (same stem, same folder)."""
    path = Path(path)
    data = path.with_suffix(".mraw")
    if path.suffix.lower() in MRAW_HEADER_SUFFIXES:
        return path, data
    for suffix in MRAW_HEADER_SUFFIXES:
        for candidate in (path.with_suffix(suffix), path.with_suffix(suffix.upper())):
            if candidate.is_file():
                return candidate, path
    raise UnsupportedRecording(f"{path.name}: a Photron .mraw needs its .cihx or .cih header beside it (same name)")


def _cih_fields(path: PurePath, data: bytes) -> dict[str, str]:
    """The header as {key: text}: `Key : Value` lines of a .cih, or the XML of a .cihx, under the .cih names."""
    if len(data) > _MAX_CIH_BYTES:
        raise CorruptRecording(f"{path.name}: larger than {_MAX_CIH_BYTES} bytes; not a Photron header")
    if path.suffix.lower() == ".cih":
        fields: dict[str, str] = {}
        for line in data.decode("latin-1").splitlines():
            key, sep, value = line.partition(" : ")
            if sep:
                fields[key.strip()] = value.strip()
        return fields
    start, stop = data.find(b"<cih>"), data.rfind(b"</cih>")
    if start < 0 or stop < 0:
        raise CorruptRecording(f"{path.name}: no <cih> document in the .cihx (truncated or damaged)")
    import xml.etree.ElementTree as ElementTree

    try:
        root = ElementTree.fromstring(data[start : stop + len(b"</cih>")])
    except ElementTree.ParseError as error:
        raise CorruptRecording(f"{path.name}: the .cihx XML is damaged ({error})") from None
    where = {
        "Record Rate(fps)": "recordInfo/recordRate",
        "Total Frame": "frameInfo/totalFrame",
        "Start Frame": "frameInfo/startFrame",
        "Image Width": "imageDataInfo/resolution/width",
        "Image Height": "imageDataInfo/resolution/height",
        "Color Type": "imageDataInfo/colorInfo/type",
        "Color Bit": "imageDataInfo/colorInfo/bit",
        "EffectiveBit Depth": "imageDataInfo/effectiveBit/depth",
        "EffectiveBit Side": "imageDataInfo/effectiveBit/side",
        "File Format": "imageFileInfo/fileFormat",
    }
    return {key: (root.findtext(xpath) or "").strip() for key, xpath in where.items() if root.find(xpath) is not None}


def read_mraw_header(path: str | Path) -> MrawHeader:
    """Parse a Photron .cih/.cihx header and check its .mraw against it (a truncated .mraw is refused here).

    path: the .cih, .cihx or .mraw file. Refuses colour (raw Bayer) recordings and bit depths other than 8, 12
    and 16, naming what the header says.
    """
    header_path, data_path = mraw_paths(path)
    if not header_path.is_file():
        raise UnsupportedRecording(f"{header_path.name}: the Photron header is missing")
    if not data_path.is_file():
        raise CorruptRecording(f"{header_path.name}: its data file {data_path.name} is missing")
    if header_path.stat().st_size > _MAX_CIH_BYTES:
        raise CorruptRecording(f"{header_path.name}: larger than {_MAX_CIH_BYTES} bytes; not a Photron header")
    return mraw_header_from(
        header_path, header_path.read_bytes(), data_path=data_path, data_name=data_path.name,
        data_offset=0, data_bytes=data_path.stat().st_size,
    )  # fmt: skip


def mraw_header_from(
    header_path: PurePath,
    header_bytes: bytes,
    *,
    data_path: Path,
    data_name: str,
    data_offset: int,
    data_bytes: int,
) -> MrawHeader:
    """An MRAW header from the header file's bytes, checked against the span of the data it describes
    (data_bytes from data_offset in data_path: a whole .mraw, or a stored .mraw entry of a ZIP)."""
    fields = _cih_fields(header_path, header_bytes)
    name = header_path.name

    def number(key: str, *, required: bool = True) -> float | None:
        text = fields.get(key, "")
        if not text:
            if required:
                raise CorruptRecording(f"{name}: no '{key}' in the header (truncated or damaged)")
            return None
        try:
            return float(text)
        except ValueError:
            raise CorruptRecording(f"{name}: '{key}' is {text!r}, not a number") from None

    file_format = fields.get("File Format", "MRaw")
    if file_format.lower() != "mraw":
        raise UnsupportedRecording(f"{name}: the header describes a {file_format!r} recording, not MRaw")
    colour = fields.get("Color Type", "Mono")
    if colour.lower() not in ("mono", ""):
        raise UnsupportedRecording(
            f"{name}: a {colour} (raw Bayer) MRAW cannot be measured; record or save in monochrome"
        )
    width, height, count = (int(number(k) or 0) for k in ("Image Width", "Image Height", "Total Frame"))
    bits = int(number("Color Bit") or 0)
    if bits not in (8, 12, 16):
        raise UnsupportedRecording(f"{name}: {bits}-bit pixels; fringelab reads 8-, 12- and 16-bit MRAW")
    if width <= 0 or height <= 0 or count <= 0:
        raise CorruptRecording(f"{name}: {width} × {height} px, {count} frames")
    effective = int(number("EffectiveBit Depth", required=False) or bits)
    if fields.get("EffectiveBit Side", "Lower").lower() == "higher":
        effective = bits  # the significant bits sit at the top: the values span the full range
    header = MrawHeader(
        width_px=width,
        height_px=height,
        frame_count=count,
        bits=bits,
        effective_bits=min(effective, bits),
        frame_rate_hz=number("Record Rate(fps)", required=False) or None,
        start_frame=int(number("Start Frame", required=False) or 0),
        data_path=data_path,
        header_path=header_path,
        data_offset=data_offset,
    )
    size, expected = data_bytes, header.frame_bytes * count
    if size < expected:
        raise CorruptRecording(
            f"{data_name}: {size} bytes, but {count} frames of {width} × {height} px at {bits} bits need "
            f"{expected}; the .mraw is truncated"
        )
    if size > expected:
        raise CorruptRecording(
            f"{data_name}: {size} bytes, more than the {expected} its header describes; the header does not "
            "belong to this .mraw"
        )
    return header


def mraw_header_in_zip(path: Path, entries: tuple[str, str]) -> MrawHeader:
    """The header of a Photron recording uploaded as one ZIP (`ZipContents.mraw_entries`), checked against the
    stored .mraw entry, whose frames are read where they lie in the ZIP file."""
    header_name, data_name = entries
    with zipfile.ZipFile(path) as archive:
        header_bytes = archive.read(header_name)
        data_info = archive.getinfo(data_name)
    return mraw_header_from(
        PurePosixPath(header_name), header_bytes, data_path=path, data_name=data_name,
        data_offset=zip_entry_data_offset(path, data_info), data_bytes=data_info.file_size,
    )  # fmt: skip


def unpack_mraw_pixels(data: bytes, header: MrawHeader) -> np.ndarray:
    """One MRAW frame's bytes as a (rows, cols) array: uint8, or uint16 for 12-bit (unpacked) and 16-bit data."""
    shape = (header.height_px, header.width_px)
    if header.bits == 8:
        return np.frombuffer(data, dtype=np.uint8).reshape(shape).copy()
    if header.bits == 16:
        return np.frombuffer(data, dtype="<u2").reshape(shape).astype(np.uint16)
    return _unpack_12bit_big_endian(data).reshape(shape)


def _unpack_12bit_big_endian(data: bytes) -> np.ndarray:
    """Two 12-bit pixels in three bytes, most significant bits first (Phantom P12L, Photron 12-bit MRAW)."""
    b = np.frombuffer(data, dtype=np.uint8).reshape(-1, 3).astype(np.uint16)
    pixels = np.empty((len(b), 2), dtype=np.uint16)
    pixels[:, 0] = (b[:, 0] << 4) | (b[:, 1] >> 4)
    pixels[:, 1] = ((b[:, 1] & 0x0F) << 8) | b[:, 2]
    return pixels.ravel()


# ---------------------------------------------------------------------------------------------------- TIFF

MAX_TIFF_PAGES = 1_000_000
_TIFF_TYPE_SIZES = {1: 1, 3: 2, 4: 4, 13: 4, 16: 8}  # the integer types _TIFF_INT_CODES reads
_TIFF_INT_CODES = {1: "B", 3: "H", 4: "I", 13: "I", 16: "Q"}
_TAG_WIDTH, _TAG_HEIGHT, _TAG_BITS, _TAG_SAMPLES = 256, 257, 258, 277
_TAG_STRIP_OFFSETS, _TAG_STRIP_BYTES, _TAG_TILE_OFFSETS, _TAG_TILE_BYTES = 273, 279, 324, 325


@dataclass(frozen=True)
class TiffLayout:
    """What the IFD chain of a TIFF says: pages and the size and sample depth of the first."""

    frame_count: int
    width_px: int
    height_px: int
    bytes_per_sample: int


def read_tiff_layout(path: str | Path) -> TiffLayout:
    """Walk the IFD chain of a classic or Big TIFF; refuse a chain or strip that runs past the end of the file.

    A truncated multi-page TIFF still opens (its first pages are whole), so the chain itself is the only
    witness: an IFD offset, or a strip's offset + byte count, beyond the file size means bytes are missing.
    """
    path = Path(path)
    size = path.stat().st_size
    with path.open("rb") as handle:
        head = handle.read(16)
        order = "<" if head[:2] == b"II" else ">"
        if len(head) < 8 or head[:2] not in (b"II", b"MM"):
            raise CorruptRecording(f"{path.name}: shorter than a TIFF header")
        version = struct.unpack_from(order + "H", head, 2)[0]
        big = version == 43
        if big and len(head) < 16:
            raise CorruptRecording(f"{path.name}: shorter than a BigTIFF header")
        count_code, offset_code, entry_size = ("Q", "Q", 20) if big else ("H", "I", 12)
        offset_size = 8 if big else 4
        next_ifd = struct.unpack_from(order + offset_code, head, 8 if big else 4)[0]
        pages = 0
        first: dict[int, list[int]] = {}
        seen: set[int] = set()
        while next_ifd:
            if next_ifd in seen:
                raise CorruptRecording(f"{path.name}: the TIFF's page chain loops back to offset {next_ifd}")
            seen.add(next_ifd)
            if pages >= MAX_TIFF_PAGES:
                raise UnsupportedRecording(f"{path.name}: more than {MAX_TIFF_PAGES} pages")
            count_bytes = struct.calcsize(count_code)
            if next_ifd + count_bytes > size:
                raise CorruptRecording(
                    f"{path.name}: page {pages + 1} starts past the end of the file ({size} bytes); the TIFF is "
                    f"truncated after {pages} pages"
                )
            entry_count = struct.unpack(order + count_code, _read_at(handle, next_ifd, count_bytes))[0]
            table_end = next_ifd + count_bytes + entry_count * entry_size + offset_size
            if table_end > size:
                raise CorruptRecording(
                    f"{path.name}: the directory of page {pages + 1} runs past the end of the file; the TIFF is "
                    f"truncated after {pages} pages"
                )
            table = _read_at(handle, next_ifd + count_bytes, entry_count * entry_size + offset_size)
            tags = _tiff_tags(handle, table, entry_count, order=order, big=big, size=size, name=path.name)
            _check_tiff_data(tags, page=pages, size=size, name=path.name)
            if pages == 0:
                first = tags
            pages += 1
            next_ifd = struct.unpack_from(order + offset_code, table, entry_count * entry_size)[0]
    if pages == 0 or _TAG_WIDTH not in first or _TAG_HEIGHT not in first:
        raise CorruptRecording(f"{path.name}: the TIFF has no readable page")
    bits = max(first.get(_TAG_BITS, [8]))
    samples = first.get(_TAG_SAMPLES, [1])[0]
    return TiffLayout(pages, first[_TAG_WIDTH][0], first[_TAG_HEIGHT][0], max(1, bits // 8) * max(1, samples))


def _tiff_tags(
    handle: BinaryIO, table: bytes, entry_count: int, *, order: str, big: bool, size: int, name: str
) -> dict[int, list[int]]:
    """The integer tags a layout needs (size, depth, strips and tiles) of one IFD."""
    wanted = (_TAG_WIDTH, _TAG_HEIGHT, _TAG_BITS, _TAG_SAMPLES, _TAG_STRIP_OFFSETS, _TAG_STRIP_BYTES,
              _TAG_TILE_OFFSETS, _TAG_TILE_BYTES)  # fmt: skip
    entry = struct.Struct(order + ("HHQ8s" if big else "HHI4s"))
    inline = 8 if big else 4
    tags: dict[int, list[int]] = {}
    for i in range(entry_count):
        tag, kind, count, value = entry.unpack_from(table, i * entry.size)
        if tag not in wanted or kind not in _TIFF_INT_CODES:
            continue
        length = count * _TIFF_TYPE_SIZES[kind]
        if length > inline:
            offset = struct.unpack(order + ("Q" if big else "I"), value)[0]
            if offset + length > size:
                raise CorruptRecording(f"{name}: tag {tag} lies past the end of the file; the TIFF is truncated")
            value = _read_at(handle, offset, length)
        tags[tag] = list(struct.unpack_from(f"{order}{count}{_TIFF_INT_CODES[kind]}", value))
    return tags


def _check_tiff_data(tags: dict[int, list[int]], *, page: int, size: int, name: str) -> None:
    for offsets_tag, counts_tag in ((_TAG_STRIP_OFFSETS, _TAG_STRIP_BYTES), (_TAG_TILE_OFFSETS, _TAG_TILE_BYTES)):
        for offset, length in zip(tags.get(offsets_tag, []), tags.get(counts_tag, []), strict=False):
            if offset + length > size:
                raise CorruptRecording(
                    f"{name}: the pixels of page {page + 1} run past the end of the file ({size} bytes); the TIFF "
                    f"is truncated after {page} whole pages"
                )


# ---------------------------------------------------------------------------------------------------- video


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
            kind, length = struct.unpack("<4sI", _read_at(handle, position, 8))
            if kind != b"RIFF" and position > 0:
                break  # trailing bytes after the last RIFF list (junk some writers leave) are not our business
            if position + 8 + length > size:
                raise CorruptRecording(
                    f"{path.name}: the AVI declares {position + 8 + length} bytes but the file has {size}; it is "
                    "truncated"
                )
            if position == 0:
                avih = _read_at(handle, 12, 64)
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
            head = _read_at(handle, position, 16)
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


# ---------------------------------------------------------------------------------------------------- images


def declared_image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) the header of a PNG, BMP or JPEG declares; None when not found in `data`."""
    if data.startswith(b"\x89PNG") and len(data) >= 24:
        width, height = struct.unpack(">II", data[16:24])
        return int(width), int(height)
    if data.startswith(b"BM") and len(data) >= 26:
        width, height = struct.unpack("<ii", data[18:26])
        return abs(width), abs(height)
    if data.startswith(b"\xff\xd8"):
        position = 2
        while position + 9 <= len(data) and data[position] == 0xFF:
            marker, length = data[position + 1], struct.unpack(">H", data[position + 2 : position + 4])[0]
            if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # start of frame
                height, width = struct.unpack(">HH", data[position + 5 : position + 9])
                return int(width), int(height)
            position += 2 + length
    if data.startswith((b"II*\x00", b"MM\x00*")):
        return None  # a TIFF frame: its IFD may lie anywhere; the ingest checks it when decoding
    return None


# ---------------------------------------------------------------------------------------------------- budget


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
        with zipfile.ZipFile(path) as archive, archive.open(contents.frame_names[0]) as entry:
            declared = declared_image_size(entry.read(64 * 1024))
        width, height = declared or (0, 0)
        return RecordingLayout(format, len(contents.frame_names), width, height)
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
) -> None:
    """Refuse a recording whose frames would decode to more than `max_frames_bytes`, or whose preview store
    would leave less than `reserve_bytes` free on the data volume. Raises OverBudget saying which and by how much."""
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
