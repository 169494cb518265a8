"""A Phantom .cine file's header, checked against the file size without decoding a pixel.

- `read_cine_header(path)`: geometry, pixel format (incl. packed 10/12-bit), frame rate, trigger numbering,
  per-frame time stamps (tagged blocks) and frame offsets (a truncated .cine is refused here);
  `unpack_cine_pixels` turns one stored image into an array.

Not here: reading frames one by one (`recordings`), the list of formats (`containers`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from fringelab.formats.container_common import CorruptRecording, UnsupportedRecording, read_at, unpack_12bit_big_endian

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
        setup = read_at(handle, off_setup, min(1024, size - off_setup))
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
        block_size, block_type, _reserved = struct.unpack("<IHH", read_at(handle, offset, 8))
        if block_size < 8 or offset + block_size > stop:
            raise CorruptRecording(f"{name}: a tagged block at byte {offset} runs into the frame offsets (damaged)")
        if block_type in (_TAG_TIME_ONLY, _TAG_TIME_TOTAL) and block_size - 8 >= 8 * count:
            return np.frombuffer(read_at(handle, offset + 8, 8 * count), dtype="<u8").astype(np.uint64)
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
        annotation = struct.unpack("<I", read_at(handle, last, 4))[0]
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
            return unpack_12bit_big_endian(data).reshape(rows, cols)
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
