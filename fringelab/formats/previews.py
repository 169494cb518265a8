"""The preview store of a recording (`recordings/<id>/previews.h5`): written by the ingest job, read by the API.

It holds what the dashboard shows before any job has run, so that the API never decodes a recording (and
never imports OpenCV): every frame at display size, thumbnails and the per-frame QA numbers. Layout:

    /frames               uint8 (n, h, w), one chunk per frame: every frame, its longer side at most
                          FRINGELAB_PREVIEW_SIZE_PX, scaled so that the sensor's full scale is 255
    /thumbnails           uint8 (n, th, tw), one chunk per frame: longer side at most THUMBNAIL_PX
    /qa/mean_fraction     float32 (n,): mean grey level / full scale
    /qa/saturation_pct    float32 (n,): % of pixels at the sensor's ceiling
    /qa/contrast          float32 (n,): (p95 − p5) / (p95 + p5)
    /qa/board_found       int8 (n,): 1 chessboard found, 0 not found, −1 not checked
    attributes            width_px, height_px (of the recording), full_scale_dn, bit_depth

The file is written under a temporary name and renamed when complete, so a reader sees the old store or the
new one, never a half-written one. Frames are served as PNG, encoded here (a grey 8-bit PNG needs only zlib).
"""

from __future__ import annotations

import struct
import uuid
import zlib
from pathlib import Path

import h5py
import numpy as np

PREVIEW_FILE = "previews.h5"
THUMBNAIL_PX = 160
QA_FIELDS = ("mean_fraction", "saturation_pct", "contrast", "board_found")


class PreviewWriter:
    """Builds a preview store frame by frame; `commit` renames it into place, `abort` drops it."""

    def __init__(self, path: Path, *, frame_count: int) -> None:
        self.path = path
        self.frame_count = frame_count
        self._temporary = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
        self._file = h5py.File(self._temporary, "w", locking=False)

    def unit_dataset(self, name: str, image: np.ndarray) -> h5py.Dataset:
        if name not in self._file:
            shape = (self.frame_count, *image.shape)
            # No compression: fringe and speckle images barely compress, and lzf would cost 7× the write.
            self._file.create_dataset(
                name, shape=shape, maxshape=(None, *image.shape), dtype=np.uint8, chunks=(1, *image.shape),
                fillvalue=0,
            )  # fmt: skip
        return self._file[name]

    def write_frame(self, index: int, *, display: np.ndarray, thumbnail: np.ndarray) -> None:
        """Store frame `index` at display size and as a thumbnail (2-D uint8 arrays)."""
        self.unit_dataset("frames", display)[index] = display
        self.unit_dataset("thumbnails", thumbnail)[index] = thumbnail

    def commit(self, *, frame_count: int, qa: dict[str, np.ndarray], attrs: dict[str, int]) -> None:
        """Write the per-frame QA arrays (each of shape (frame_count,)) and the attributes, then publish."""
        for name in ("frames", "thumbnails"):
            if name in self._file and self._file[name].shape[0] != frame_count:
                self._file[name].resize(frame_count, axis=0)
        group = self._file.create_group("qa")
        for name in QA_FIELDS:
            values = np.asarray(qa[name])
            if values.shape != (frame_count,):
                raise ValueError(f"qa/{name}: expected shape ({frame_count},), got {values.shape}")
            group.create_dataset(name, data=values.astype(np.int8 if name == "board_found" else np.float32))
        self._file.attrs.update(attrs)
        self._file.close()
        self._temporary.replace(self.path)

    def abort(self) -> None:
        if self._file.id.valid:
            self._file.close()
        self._temporary.unlink(missing_ok=True)


def read_preview(path: Path, index: int, *, max_px: int | None = None) -> np.ndarray:
    """Frame `index` at display size (uint8, 2-D), shrunk to at most `max_px` on its longer side.

    Raises FileNotFoundError without a store and IndexError for a frame it does not hold.
    """
    with h5py.File(path, "r", locking=False) as store:
        frames = store["frames"]
        thumbnails = store["thumbnails"]
        source = thumbnails if max_px is not None and max_px <= max(thumbnails.shape[1:]) else frames
        if not 0 <= index < source.shape[0]:
            raise IndexError(f"frame {index} out of range: the recording has {source.shape[0]} frames")
        image = source[index]
    return shrink(image, max_px=max_px) if max_px else image


def read_qa(path: Path) -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """The per-frame QA arrays and the store's attributes."""
    with h5py.File(path, "r", locking=False) as store:
        arrays = {name: store["qa"][name][()] for name in QA_FIELDS}
        attrs = {key: int(value) for key, value in store.attrs.items()}
    return arrays, attrs


def shrink(image: np.ndarray, *, max_px: int) -> np.ndarray:
    """Block-average a 2-D image by the smallest integer factor that brings its longer side to at most max_px."""
    factor = -(-max(image.shape) // max_px)
    if factor <= 1:
        return image
    rows, cols = image.shape[0] // factor, image.shape[1] // factor
    if rows == 0 or cols == 0:
        return image[::factor, ::factor]
    blocks = image[: rows * factor, : cols * factor].reshape(rows, factor, cols, factor)
    return (blocks.mean(axis=(1, 3)) + 0.5).astype(np.uint8)


def encode_png(image: np.ndarray, *, level: int = 3) -> bytes:
    """A grey 8-bit PNG of a 2-D uint8 image (Sub filter on every row)."""
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"encode_png: expected a 2-D uint8 image, got shape {image.shape} of {image.dtype}")
    height, width = image.shape
    rows = np.empty((height, width + 1), dtype=np.uint8)
    rows[:, 0] = 1  # filter type Sub: each byte minus the one to its left, modulo 256
    rows[:, 1] = image[:, 0]
    rows[:, 2:] = np.diff(image, axis=1)

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(rows.tobytes(), level))
        + chunk(b"IEND", b"")
    )
