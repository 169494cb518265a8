"""Readers and writers of recordings: every container's frames, decoded one at a time.

A recording is opened lazily: `open_recording(path)` returns a `FrameSource`, a sequence of 2-D grey frames
(uint8 or uint16) decoded one at a time on access, so a multi-GB sequence is never held in memory. Formats:
a folder or ZIP of PNG/TIFF/BMP/JPEG frames (natural name order), a multi-page TIFF, an AVI or MP4 video, a
Phantom .cine file (uncompressed 8/16-bit grey, 24/48-bit colour, packed 10/12-bit grey) and a Photron MRAW
(.cih/.cihx + .mraw, 8/12/16-bit mono). Colour frames are converted to grey
(ITU-R BT.601 luma) and the source says so (`colour_converted`). Container checks without decoding (format
sniffing, ZIP safety, the .cine, MRAW and TIFF headers) live in `containers` and its `container_*` modules.

A source finds its sidecars (`z.csv`, `frames.csv`, `board.json`: inside the ZIP or beside the file) and hands
their text to `sidecars`, which parses and validates them.
"""

from __future__ import annotations

import lzma
import os
import threading
import zipfile
import zlib
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, cast, overload

import cv2
import numpy as np

from fringelab.formats.atomic import atomic_path
from fringelab.formats.container_cine import read_cine_header, unpack_cine_pixels
from fringelab.formats.container_common import CorruptRecording, UnsupportedRecording
from fringelab.formats.container_mraw import MrawHeader, read_mraw_header, unpack_mraw_pixels
from fringelab.formats.container_tiff import read_tiff_layout
from fringelab.formats.container_video import check_video_container
from fringelab.formats.container_zip import (
    IMAGE_SUFFIXES,
    ZipLimits,
    inspect_zip,
    is_junk_entry,
    mraw_header_in_zip,
)
from fringelab.formats.containers import sniff_format
from fringelab.formats.frame_header import (
    HEADER_BYTES,
    MAX_FRAME_BYTES,
    FrameHeader,
    check_frame,
    image_header,
    tiff_header_from,
)
from fringelab.formats.sidecars import FRAMES_CSV_COLUMNS, check_sidecar_size, read_sidecar_file
from fringelab.formats.sidecars import sidecar_text as decode_sidecar
from fringelab.science import natural_key

if TYPE_CHECKING:
    pass

__all__ = [
    "IMAGE_SUFFIXES",
    "FrameSource",
    "decode_grey",
    "natural_key",
    "open_recording",
    "write_recording",
]


def _as_grey(image: np.ndarray, *, name: str) -> tuple[np.ndarray, bool]:
    """A 2-D uint8/uint16 frame from a decoded image, and whether colour was converted."""
    if image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{name}: {image.dtype} pixels; frames must be 8- or 16-bit unsigned integers")
    if image.ndim == 2:
        return image, False
    if image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        return cv2.cvtColor(np.ascontiguousarray(image), code), True
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0], False
    raise ValueError(f"{name}: image of shape {image.shape}; expected (rows, cols) or (rows, cols, 3|4)")


def _looks_truncated(data: bytes, name: str) -> bool:
    """Decoders fill the missing rows of a truncated JPEG or BMP silently; catch those by their structure."""
    suffix = Path(name).suffix.lower()
    if suffix in (".jpg", ".jpeg"):
        return b"\xff\xd9" not in data[-64:]
    if suffix == ".png":
        return b"IEND" not in data[-16:]
    if suffix == ".bmp" and len(data) >= 6:
        return int.from_bytes(data[2:6], "little") > len(data)
    return False


def _decode(data: bytes, *, name: str, max_frame_bytes: int = MAX_FRAME_BYTES) -> tuple[np.ndarray, bool]:
    if _looks_truncated(data, name):
        raise ValueError(f"{name}: the image is truncated")
    # a small file can declare a huge image: its size from its header, refused before decoding
    check_frame(image_header(data), name=name, max_frame_bytes=max_frame_bytes)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if image is None:
        raise ValueError(f"{name}: not a readable image (corrupt, truncated or unsupported format)")
    return _as_grey(image, name=name)


def decode_grey(data: bytes, *, name: str) -> np.ndarray:
    """Decode image bytes to a 2-D grey array (uint8 or uint16), keeping the bit depth."""
    return _decode(data, name=name)[0]


# Time stamps jitter (a .cine's by about 1 µs, 1 % of a 10 kHz step); a header's rate within 2 % of the stamps'
# median step is the same rate, a tenfold one (a .cine stating 90 000 fps with stamps 9 000 Hz apart) is not.
RATE_AGREEMENT = 0.02


def frame_rate_from_times(
    times_s: np.ndarray, *, frame_index: np.ndarray | None = None, stated_hz: float | None = None
) -> tuple[float | None, float | None]:
    """The one rule for a recording's frame rate: (rate, stated rate where it differs) from per-frame times.

    The rate is 1 / the median step between consecutive frames (frame_index (n,): the frames' positions, when the
    times are of some frames only; steps over several frames are divided by their count). stated_hz, the rate a
    header states, is returned beside it when the two differ by more than RATE_AGREEMENT, and replaces it when they
    agree (the same rate without the time stamps' jitter and round-off). Fewer than two finite, increasing times:
    (stated_hz, None).

    >>> frame_rate_from_times(np.arange(5) / 9000.0, stated_hz=90000.0)
    (9000.0, 90000.0)
    """
    times = np.asarray(times_s, np.float64)
    index = np.arange(len(times)) if frame_index is None else np.asarray(frame_index, np.float64)
    order = np.argsort(index)
    steps = np.diff(times[order]) / np.diff(index[order])
    steps = steps[np.isfinite(steps) & (steps > 0)]
    if len(steps) == 0:
        return stated_hz, None
    rate = 1.0 / float(np.median(steps))
    if stated_hz and abs(rate - stated_hz) <= RATE_AGREEMENT * stated_hz:
        return float(stated_hz), None
    return rate, (float(stated_hz) if stated_hz else None)


class FrameSource(Sequence[np.ndarray]):
    """A recording: a lazy sequence of 2-D grey frames with the facts its container states.

    format: one of `containers.FORMATS`. frame_names: one name per frame (the entry or file name for image
    sequences, "frame N" otherwise). fps: the recording's frame rate: where per-frame times exist, the one they
    give (`frame_rate_from_times`), else the one the container states, or None. fps_header: the rate the
    container's header states, kept only where it differs from fps (a .cine whose time stamps are 9 000 Hz apart
    under a header of 90 000 fps; a Photron recording saved every 36th frame), else None. bit_depth: significant
    bits of a sample as stored (8 or 16; a .cine states its real depth, e.g. 12). colour_converted: colour
    frames were met and converted to grey. frame_numbers: shape (n,), each frame's number as the camera counts
    it (0, 1, ... unless the container says otherwise, e.g. a .cine counts from its trigger). frame_times_s:
    shape (n,), each frame's time in s as the container states it (relative to the trigger), or None. notes:
    what a reader should know about how the frames were read. Use as a context manager, or call `close()`, to
    release the file.
    """

    format: str = ""

    def __init__(self, path: Path, frame_names: Sequence[str], *, fps: float | None = None, bit_depth: int = 8):
        self.path = path
        self.frame_names: tuple[str, ...] = tuple(frame_names)
        self.fps = fps
        self.fps_header: float | None = None
        self.bit_depth = bit_depth
        self.colour_converted = False
        self.frame_numbers: np.ndarray = np.arange(len(self.frame_names), dtype=np.int64)
        self.frame_times_s: np.ndarray | None = None
        self.notes: list[str] = []
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self.frame_names)

    def _set_frame_times(self, times_s: np.ndarray, note: str) -> None:
        """Per-frame times (n,) from the container: they give the frame rate, the header's beside it if it differs."""
        self.frame_times_s = np.asarray(times_s, np.float64)
        self.notes.append(note)
        stated = self.fps
        self.fps, self.fps_header = frame_rate_from_times(self.frame_times_s, stated_hz=stated)
        if self.fps_header is not None:
            self.notes.append(
                f"frame rate {self.fps:.5g} frames/s from the frame times (median step); the header states "
                f"{self.fps_header:.5g}"
            )

    @overload
    def __getitem__(self, index: int) -> np.ndarray: ...

    @overload
    def __getitem__(self, index: slice) -> list[np.ndarray]: ...

    def __getitem__(self, index: int | slice) -> np.ndarray | list[np.ndarray]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        count = len(self)
        position = index + count if index < 0 else index
        if not 0 <= position < count:
            raise IndexError(f"frame {index} out of range: the recording has {count} frames")
        with self._lock:
            frame, colour = self._read(position)
        self.colour_converted |= colour
        return frame

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(len(self)):
            yield self[i]

    def _read(self, index: int) -> tuple[np.ndarray, bool]:
        raise NotImplementedError

    def sidecar_text(self, name: str) -> str | None:
        """Text of a sidecar (`z.csv`, `frames.csv`, `board.json`), or None.

        A file of that name beside a single-file recording (or a ZIP) comes first: it is how a sidecar is
        added to a .cine, TIFF or video, or corrected for a ZIP; then the one stored inside a ZIP or folder.
        """
        beside = self.path.parent / name
        if beside.is_file():
            return read_sidecar_file(beside)
        return None

    def close(self) -> None:
        """Release open files; frames can still be read afterwards (the file is opened again)."""

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.format} {self.path.name}: {len(self)} frames>"


class _CheckedFrames(FrameSource):
    """Frames as image files (in a folder or a ZIP): before one is read whole and decoded, its header's size is
    held against the byte budget of a frame and against the first frame's size (`frame_header.check_frame`)."""

    def __init__(self, path: Path, frame_names: Sequence[str], *, max_frame_bytes: int = MAX_FRAME_BYTES):
        super().__init__(path, frame_names)
        self.max_frame_bytes = max_frame_bytes
        self._first: FrameHeader | None = None

    def _open_frame(self, name: str) -> tuple[BinaryIO, int]:
        """The frame file open for reading, and its size in bytes."""
        raise NotImplementedError

    def _header(self, name: str) -> FrameHeader:
        handle, size = self._open_frame(name)
        with handle:
            if size > self.max_frame_bytes + HEADER_BYTES:  # no frame file is much larger than its pixels
                raise OverBudgetFrame(
                    f"{name}: {size} bytes, more than a frame of the {self.max_frame_bytes}-byte limit "
                    "(FRINGELAB_MAX_FRAME_BYTES) can take"
                )
            try:
                header = image_header(handle.read(HEADER_BYTES))
                if header is None and Path(name).suffix.lower() in (".tif", ".tiff"):
                    header = tiff_header_from(handle, size=size)  # its directory lies further on: seek to it
            except (zipfile.BadZipFile, EOFError, OSError, zlib.error, lzma.LZMAError) as error:  # damaged data
                raise ValueError(f"{name}: cannot be read ({error})") from None
        return check_frame(header, name=name, max_frame_bytes=self.max_frame_bytes, first=self._first)

    def checked(self, index: int) -> FrameHeader:
        """Frame `index`'s header, refused (ValueError) over the budget or unlike the first frame."""
        if self._first is None:
            self._first = self._header(self.frame_names[0])
        return self._header(self.frame_names[index]) if index else self._first

    def read_bytes(self, name: str) -> bytes:
        raise NotImplementedError

    def _read(self, index: int) -> tuple[np.ndarray, bool]:
        self.checked(index)
        name = self.frame_names[index]
        return _decode(self.read_bytes(name), name=name, max_frame_bytes=self.max_frame_bytes)


class OverBudgetFrame(CorruptRecording):
    """A frame file larger than any frame within the budget could be."""


class ImageFolder(_CheckedFrames):
    """Frames as image files in a folder (not its subfolders), in natural name order."""

    format = "folder"

    def _open_frame(self, name: str) -> tuple[BinaryIO, int]:
        path = self.path / name
        return path.open("rb"), path.stat().st_size

    def read_bytes(self, name: str) -> bytes:
        return (self.path / name).read_bytes()

    def sidecar_text(self, name: str) -> str | None:
        candidate = self.path / name
        return read_sidecar_file(candidate) if candidate.is_file() else None


class ImageZip(_CheckedFrames):
    """Frames as image entries of a ZIP, in natural order of their names; the archive stays open between reads."""

    format = "zip"

    def __init__(
        self,
        path: Path,
        frame_names: Sequence[str],
        sidecar_names: dict[str, str],
        *,
        max_frame_bytes: int = MAX_FRAME_BYTES,
    ):
        super().__init__(path, frame_names, max_frame_bytes=max_frame_bytes)
        self._sidecar_names = sidecar_names
        self._archive: zipfile.ZipFile | None = None
        self._pid = 0

    def _open(self) -> zipfile.ZipFile:
        if self._archive is None or self._pid != os.getpid():  # a forked worker opens its own handle
            self._archive = zipfile.ZipFile(self.path)
            self._pid = os.getpid()
        return self._archive

    def read_bytes(self, name: str) -> bytes:
        try:
            return self._open().read(name)
        except (zipfile.BadZipFile, EOFError, OSError, zlib.error, lzma.LZMAError) as error:  # bad CRC, damaged data
            raise ValueError(f"{name}: cannot be read from the ZIP ({error})") from None

    def _open_frame(self, name: str) -> tuple[BinaryIO, int]:
        try:
            archive = self._open()
            return cast(BinaryIO, archive.open(name)), archive.getinfo(name).file_size
        except (zipfile.BadZipFile, EOFError, OSError, zlib.error, lzma.LZMAError) as error:
            raise ValueError(f"{name}: cannot be read from the ZIP ({error})") from None

    def sidecar_text(self, name: str) -> str | None:
        beside = super().sidecar_text(name)
        if beside is not None or name not in self._sidecar_names:
            return beside
        entry = self._sidecar_names[name]
        with self._lock:
            check_sidecar_size(self._open().getinfo(entry).file_size, name=name)  # before inflating a byte
            data = self.read_bytes(entry)
        return decode_sidecar(data, name=name)

    def close(self) -> None:
        if self._archive is not None:
            self._archive.close()
            self._archive = None


class TiffStack(FrameSource):
    """Pages of a (multi-page) TIFF, one frame per page, decoded with tifffile (OpenCV for codecs it lacks)."""

    format = "tiff"

    def __init__(self, path: Path, *, max_frame_bytes: int = MAX_FRAME_BYTES):
        import tifffile

        self.max_frame_bytes = max_frame_bytes
        layout = read_tiff_layout(path)  # a truncated stack is refused here, not read as its first pages
        try:
            self._tiff = tifffile.TiffFile(path)
            pages = self._tiff.pages
            count = len(pages)
            first = pages.first
        except (tifffile.TiffFileError, ValueError, OSError, IndexError) as error:
            raise CorruptRecording(f"{path.name}: not a readable TIFF ({error})") from None
        if count != layout.frame_count:
            raise CorruptRecording(
                f"{path.name}: {count} pages readable of the {layout.frame_count} its page chain holds (damaged)"
            )
        super().__init__(path, [f"page {i}" for i in range(count)], bit_depth=16 if first.bitspersample > 8 else 8)

    def _read(self, index: int) -> tuple[np.ndarray, bool]:
        name = f"{self.path.name} page {index}"
        try:
            page = self._tiff.pages[index]
        except (OSError, IndexError, KeyError, ValueError) as error:
            raise ValueError(f"{name}: cannot be decoded ({error})") from None
        check_frame(self._page_header(page), name=name, max_frame_bytes=self.max_frame_bytes,
                    first=self._page_header(self._tiff.pages.first))  # fmt: skip
        try:
            image = page.asarray()
        except ValueError as error:
            if "imagecodecs" not in str(error):
                raise ValueError(f"{name}: {error}") from None
            flags = cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR
            ok, images = cv2.imreadmulti(str(self.path), start=index, count=1, flags=flags)
            if not ok or not images:
                raise ValueError(f"{name}: cannot be decoded ({error})") from None
            image = images[0]
        except (OSError, IndexError, KeyError) as error:
            raise ValueError(f"{name}: cannot be decoded ({error})") from None
        else:
            # tifffile gives RGB order; OpenCV's conversion expects BGR.
            if image.ndim == 3 and image.shape[2] in (3, 4):
                image = image[:, :, [2, 1, 0, 3][: image.shape[2]]]
        return _as_grey(image, name=name)

    @staticmethod
    def _page_header(page: object) -> FrameHeader | None:
        """A page's size from its directory (tifffile reads it without decoding), None when it states none."""
        shape = tuple(int(n) for n in getattr(page, "shape", ()))
        samples = int(getattr(page, "samplesperpixel", 1) or 1)
        bits = int(getattr(page, "bitspersample", 8) or 8)
        if len(shape) < 2:
            return None
        height, width = (shape[-3], shape[-2]) if samples > 1 and len(shape) >= 3 else (shape[-2], shape[-1])
        return FrameHeader(width, height, samples, max(1, (bits + 7) // 8))

    def close(self) -> None:
        self._tiff.close()


class VideoFrames(FrameSource):
    """Frames of an AVI or MP4 video decoded by OpenCV (8-bit); sequential reading avoids seeking."""

    def __init__(self, path: Path, format: str):
        self.format = format
        check_video_container(path, format)  # a video cut short decodes up to the cut; its container shows it
        self._capture = cv2.VideoCapture(str(path))
        if not self._capture.isOpened():
            raise CorruptRecording(f"{path.name}: OpenCV cannot open this {format.upper()} video (codec or damage)")
        count = int(self._capture.get(cv2.CAP_PROP_FRAME_COUNT))
        if count <= 0:
            count = self._count_by_grabbing()
        if count <= 0:
            raise CorruptRecording(f"{path.name}: the video holds no frames")
        fps = float(self._capture.get(cv2.CAP_PROP_FPS)) or None
        super().__init__(path, [f"frame {i}" for i in range(count)], fps=fps, bit_depth=8)
        self._next = 0

    def _count_by_grabbing(self) -> int:
        count = 0
        while self._capture.grab():
            count += 1
        self._capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
        return count

    def _read(self, index: int) -> tuple[np.ndarray, bool]:
        if index != self._next:
            self._capture.set(cv2.CAP_PROP_POS_FRAMES, index)
        ok, image = self._capture.read()
        self._next = index + 1
        if not ok or image is None:
            self._next = -1
            raise ValueError(f"{self.path.name} frame {index}: cannot be decoded (the video ends early or is damaged)")
        if image.ndim == 3 and not _channels_equal(image):
            return _as_grey(image, name=f"frame {index}")
        return (image[:, :, 0].copy() if image.ndim == 3 else image), False

    def close(self) -> None:
        self._capture.release()


def _channels_equal(image: np.ndarray) -> bool:
    return bool((image[:, :, 0] == image[:, :, 1]).all() and (image[:, :, 1] == image[:, :, 2]).all())


class CineFrames(FrameSource):
    """Frames of a Phantom .cine file, read at their offsets: uncompressed 8/16-bit grey (bottom-up rows
    flipped), 24/48-bit colour, or packed 10-bit (P10) and 12-bit (P12L) grey unpacked to uint16.

    frame_numbers are the camera's (the trigger frame is 0); frame_times_s come from the file's time-stamp block,
    else from the frame rate and those numbers. P10 pixels are Phantom's companded 10-bit codes as stored (as
    pims returns them); `notes` says so, since their grey levels are not linear in the light.
    """

    format = "cine"

    def __init__(self, path: Path):
        self.header = read_cine_header(path)
        header = self.header
        super().__init__(
            path,
            [f"frame {number}" for number in header.frame_numbers],
            fps=header.frame_rate_hz,
            bit_depth=header.real_bpp,
        )
        self.frame_numbers = header.frame_numbers
        if header.frame_time_s is not None:
            self._set_frame_times(
                header.frame_time_s, "frame times from the .cine time stamps, relative to the trigger"
            )
        elif header.frame_rate_hz:
            self._set_frame_times(
                header.frame_numbers / header.frame_rate_hz,
                "frame times from the .cine frame rate and frame numbers (no time stamps)",
            )
        if header.packing == "P10":
            self.notes.append("P10 packed .cine: grey levels are the camera's companded 10-bit codes, not linear")
        self._handle: BinaryIO | None = None
        self._pid = 0

    def _read(self, index: int) -> tuple[np.ndarray, bool]:
        if self._handle is None or self._pid != os.getpid():  # a forked worker opens its own handle
            self._handle = self.path.open("rb")
            self._pid = os.getpid()
        header = self.header
        start = int(header.image_offsets[index])
        self._handle.seek(start)
        annotation = int.from_bytes(self._handle.read(4), "little")
        self._handle.seek(start + annotation)
        data = self._handle.read(header.frame_bytes)
        if annotation < 8 or len(data) != header.frame_bytes:
            raise CorruptRecording(f"{self.path.name} frame {index}: truncated")
        image = unpack_cine_pixels(data, header)
        return _as_grey(image, name=f"{self.path.name} frame {index}")

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None


class MrawFrames(FrameSource):
    """Frames of a Photron MRAW recording (.mraw data + .cih/.cihx header): 8-bit, 12-bit (packed, unpacked to
    uint16 with numpy) or 16-bit mono, read one frame at a time at its offset. frame_numbers are the camera's
    (the header's Start Frame, then every Save Step; the trigger frame is 0); frame_times_s from those numbers and
    the record rate."""

    format = "mraw"

    def __init__(self, path: Path, *, header: MrawHeader | None = None):
        self.header = header = read_mraw_header(path) if header is None else header
        # The header file (sidecars are found beside it), or the ZIP that holds both files.
        where = header.header_path if isinstance(header.header_path, Path) else path
        super().__init__(
            where,
            [f"frame {number}" for number in header.frame_numbers],
            fps=header.frame_rate_hz,
            bit_depth=header.effective_bits,
        )
        self.frame_numbers = header.frame_numbers
        self.notes.extend(header.notes)
        if header.frame_times_s is not None:
            step = f", one frame saved every {header.save_step}" if header.save_step > 1 else ""
            self._set_frame_times(
                header.frame_times_s,
                f"frame times from the MRAW record rate and start frame{step} (relative to the trigger)",
            )
        self._handle: BinaryIO | None = None
        self._pid = 0

    def _read(self, index: int) -> tuple[np.ndarray, bool]:
        if self._handle is None or self._pid != os.getpid():  # a forked worker opens its own handle
            self._handle = self.header.data_path.open("rb")
            self._pid = os.getpid()
        size = self.header.frame_bytes
        self._handle.seek(self.header.data_offset + index * size)
        data = self._handle.read(size)
        if len(data) != size:
            raise CorruptRecording(f"{self.header.data_path.name} frame {index}: truncated")
        return unpack_mraw_pixels(data, self.header), False

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None


def _mraw_in_zip(path: Path, entries: tuple[str, str]) -> MrawFrames:
    """A Photron recording uploaded as one ZIP: its header read from the archive, its frames read where the
    stored .mraw lies in the ZIP file."""
    return MrawFrames(path, header=mraw_header_in_zip(path, entries))


def open_recording(
    path: str | Path, *, zip_limits: ZipLimits | None = None, max_frame_bytes: int = MAX_FRAME_BYTES
) -> FrameSource:
    """Open a recording lazily, whatever its format (see the module docstring). Frames of image files (a folder,
    a ZIP, a TIFF's pages) are each held against `max_frame_bytes` and the first frame's size from their headers
    before they are decoded (`frame_header`).

    Raises ValueError (`containers.UnsupportedRecording`, `UnsafeArchive`, `CorruptRecording`) when the file is
    not a recording, holds no image, or must not be opened.
    """
    path = Path(path)
    kind = sniff_format(path)
    if kind == "folder":
        names = [
            p.name
            for p in path.iterdir()
            if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES and not is_junk_entry(p.name)
        ]
        if not names:
            raise UnsupportedRecording(f"{path}: no image frames found (accepted: {', '.join(IMAGE_SUFFIXES)})")
        return ImageFolder(path, sorted(names, key=natural_key), max_frame_bytes=max_frame_bytes)
    if kind == "zip":
        contents = inspect_zip(path, limits=zip_limits)
        if contents.mraw_entries is not None:
            return _mraw_in_zip(path, contents.mraw_entries)
        return ImageZip(path, contents.frame_names, contents.sidecar_names, max_frame_bytes=max_frame_bytes)
    if kind == "tiff":
        return TiffStack(path, max_frame_bytes=max_frame_bytes)
    if kind == "cine":
        return CineFrames(path)
    if kind == "mraw":
        return MrawFrames(path)
    return VideoFrames(path, kind)


# ---------------------------------------------------------------------------------------------------- test log


@dataclass(frozen=True, eq=False)
class RecordingLog:
    """Per frame of a recording (n,): the test log columns (`FrameTable.COLUMNS`, NaN where not logged), the
    camera's frame numbers, and where time_s came from (`time_source`: "frames.csv", the container's time stamps
    or frame rate, or "none" when nothing states it)."""

    columns: dict[str, np.ndarray]
    camera_frame: np.ndarray
    time_source: str

    def row(self, index: int) -> tuple[float, float, float]:
        """(time_s, punch_displacement_mm, force_kN) of frame `index`."""
        return tuple(float(self.columns[name][index]) for name in FRAMES_CSV_COLUMNS)  # type: ignore[return-value]


def recording_log(source: Sequence[np.ndarray]) -> RecordingLog:
    """The test log of every frame: frames.csv where it has a column, else what the container states (a .cine's
    time stamps relative to the trigger), else NaN; frame numbers as the camera counts them.

    source: a `FrameSource`, or any sequence of frames with `sidecar_text(name)` (what it lacks counts as absent).
    """
    from fringelab.formats.sidecars import FrameTable, read_frames_csv

    n_frames = len(source)
    sidecar_text = getattr(source, "sidecar_text", None)
    text = sidecar_text("frames.csv") if sidecar_text is not None else None
    table = read_frames_csv(text) if text is not None else FrameTable.empty()
    columns = table.rows(list(range(n_frames)))
    time_source = "frames.csv" if table.time_s is not None else "none"
    times_s = getattr(source, "frame_times_s", None)
    if table.time_s is None and times_s is not None:
        columns["time_s"] = np.asarray(times_s, dtype=np.float64)
        notes = getattr(source, "notes", [])
        time_source = f"{getattr(source, 'format', 'recording')}: " + next(
            (note for note in notes if note.startswith("frame times")), "frame times"
        )
    camera_frame = np.asarray(getattr(source, "frame_numbers", np.arange(n_frames)), np.int64)
    return RecordingLog(columns=columns, camera_frame=camera_frame, time_source=time_source)


# ---------------------------------------------------------------------------------------------------- sidecars


def write_recording(
    path: str | Path, frames: Iterable[np.ndarray], *, sidecars: dict[str, str] | None = None, as_zip: bool = False
) -> Path:
    """Write frames one at a time as frame0000.png, ... with sidecar texts, into a folder or a ZIP (`as_zip`).

    Readable with `fringelab.formats.recordings.open_recording`. Frames are encoded as they come, so a long
    recording is never held.
    """
    path = Path(path)

    def encoded(frame: np.ndarray, index: int) -> bytes:
        ok, data = cv2.imencode(".png", frame)
        if not ok:
            raise ValueError(f"{path}: could not encode frame {index} (dtype {frame.dtype}, shape {frame.shape})")
        return data.tobytes()

    if as_zip:
        with atomic_path(path) as temp, zipfile.ZipFile(temp, "w", compression=zipfile.ZIP_STORED) as archive:
            for index, frame in enumerate(frames):
                archive.writestr(f"frame{index:04d}.png", encoded(frame, index))
            for name, text in (sidecars or {}).items():
                archive.writestr(name, text)
        return path
    path.mkdir(parents=True, exist_ok=True)
    for index, frame in enumerate(frames):
        (path / f"frame{index:04d}.png").write_bytes(encoded(frame, index))
    for name, text in (sidecars or {}).items():
        (path / name).write_text(text)
    return path
