"""Writers of real recording files in every lab format, for the tests: ZIP or folder of frames, multi-page
TIFF, AVI/MP4 and Phantom .cine (a small writer of the uncompressed layout), plus synthetic frames."""

from __future__ import annotations

import io
import struct
import zipfile
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import tifffile


def stripe_frames(n: int, *, height: int = 48, width: int = 64, dtype: type = np.uint8, seed: int = 0) -> list:
    """Frames of vertical black/white stripes (period 8 px) with a little noise, distinct per frame."""
    rng = np.random.default_rng(seed)
    top = 255 if dtype == np.uint8 else 4095  # 16-bit frames carry 12-bit data, as a lab camera writes them
    columns = (np.arange(width) // 4) % 2
    frames = []
    for i in range(n):
        base = np.where(columns, 0.8, 0.15)[None, :] * np.ones((height, 1))
        noisy = base * top + rng.normal(0, top * 0.01, (height, width)) + i
        frames.append(np.clip(noisy, 0, top).astype(dtype))
    return frames


def encode(frame: np.ndarray, suffix: str) -> bytes:
    ok, data = cv2.imencode(suffix, frame)
    assert ok, f"cannot encode {frame.dtype} as {suffix}"
    return data.tobytes()


def write_zip(
    path: Path,
    frames: Sequence[np.ndarray],
    *,
    suffix: str = ".png",
    names: Sequence[str] | None = None,
    sidecars: dict[str, str] | None = None,
    compression: int = zipfile.ZIP_STORED,
) -> Path:
    names = names or [f"frame{i}{suffix}" for i in range(len(frames))]
    with zipfile.ZipFile(path, "w", compression=compression) as archive:
        for name, frame in zip(names, frames, strict=True):
            archive.writestr(name, encode(frame, Path(name).suffix))
        for name, text in (sidecars or {}).items():
            archive.writestr(name, text)
    return path


def write_tiff_stack(path: Path, frames: Sequence[np.ndarray]) -> Path:
    with tifffile.TiffWriter(path) as tiff:
        for frame in frames:
            tiff.write(frame, photometric="rgb" if frame.ndim == 3 else "minisblack", contiguous=False)
    return path


def write_video(path: Path, frames: Sequence[np.ndarray], *, fps: float = 25.0) -> Path:
    fourcc = cv2.VideoWriter_fourcc(*("MJPG" if path.suffix == ".avi" else "mp4v"))
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), fourcc, fps, (width, height), frames[0].ndim == 3)
    assert writer.isOpened(), f"OpenCV cannot write {path.suffix}"
    for frame in frames:
        writer.write(frame)
    writer.release()
    return path


def write_cine(path: Path, frames: Sequence[np.ndarray], *, fps: int = 5000, real_bpp: int | None = None) -> Path:
    """An uncompressed Phantom .cine: header, bitmap header, a 1024-byte setup, frame offsets, frames.

    Frames are stored bottom-up as Phantom writes them; colour frames (rows, cols, 3) as BGR, 24 or 48 bits.
    """
    frame0 = frames[0]
    height, width = frame0.shape[:2]
    channels = 3 if frame0.ndim == 3 else 1
    depth = 16 if frame0.dtype == np.uint16 else 8
    bit_count = depth * channels
    setup = bytearray(1024)
    struct.pack_into("<H", setup, 0, min(fps, 65535))
    struct.pack_into("<H", setup, 142, len(setup))
    struct.pack_into("<I", setup, 768, fps)
    struct.pack_into("<I", setup, 896, real_bpp or depth)
    off_bitmap, off_setup = 44, 84
    off_offsets = off_setup + len(setup)
    first_image = off_offsets + 8 * len(frames)
    frame_bytes = width * height * channels * depth // 8
    annotation = 8
    offsets = [first_image + i * (annotation + frame_bytes) for i in range(len(frames))]
    out = io.BytesIO()
    out.write(struct.pack("<2sHHHiIiIIIIQ", b"CI", 44, 0, 1, 0, len(frames), 0, len(frames), off_bitmap,
                          off_setup, off_offsets, 0))  # fmt: skip
    out.write(struct.pack("<IiiHHIIiiII", 40, width, height, 1, bit_count, 0, frame_bytes, 0, 0, 0, 0))
    out.write(setup)
    out.write(np.asarray(offsets, dtype="<u8").tobytes())
    for frame in frames:
        out.write(struct.pack("<II", annotation, frame_bytes))
        out.write(np.ascontiguousarray(frame[::-1]).astype(frame.dtype.newbyteorder("<")).tobytes())
    path.write_bytes(out.getvalue())
    return path
