"""Quality of recorded frames, checked before any job runs: exposure, saturation, contrast, board visibility.

Pure: frames in, numbers and warnings out. The ingest task runs these on every frame of an upload and stores
the per-frame numbers and the warnings with the recording. The chessboard check here is a yes/no QA probe
(OpenCV's `findChessboardCornersSB` on a reduced image); the calibration's corner finder lives elsewhere.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np


@dataclass(frozen=True)
class QaThresholds:
    """When a frame earns a warning.

    saturated_pct: more than this % of its pixels sit at the sensor's ceiling. dark_fraction: its mean is
    below this fraction of full scale. low_contrast: the Michelson contrast of its 5th and 95th percentiles,
    (p95 − p5) / (p95 + p5), is below this (projected stripes and a lit chessboard give 0.5–0.9).
    """

    saturated_pct: float = 1.0
    dark_fraction: float = 0.05
    low_contrast: float = 0.2


@dataclass(frozen=True)
class FrameStats:
    """Statistics of one frame in its own units (DN). at_max_pct: % of pixels equal to the frame's maximum."""

    mean: float
    max: int
    at_max_pct: float
    contrast: float


def frame_stats(frame: np.ndarray, *, max_samples: int = 1 << 16) -> FrameStats:
    """Mean, maximum, share of pixels at the maximum, and percentile contrast of a 2-D frame.

    The contrast uses a regular subsample of at most `max_samples` pixels, taken without averaging so that
    fine stripes keep their contrast.
    """
    if frame.ndim != 2:
        raise ValueError(f"frame_stats: expected a frame of shape (rows, cols), got {frame.shape}")
    peak = int(frame.max())
    at_max = float(np.count_nonzero(frame == peak)) * 100.0 / frame.size
    step = max(1, int(np.ceil(np.sqrt(frame.size / max_samples))))
    sample = frame[::step, ::step].ravel()
    low, high = np.percentile(sample, [5.0, 95.0])
    contrast = float((high - low) / (high + low)) if high + low > 0 else 0.0
    return FrameStats(mean=float(frame.mean(dtype=np.float64)), max=peak, at_max_pct=at_max, contrast=contrast)


def effective_bit_depth(max_value: int, *, stored_bits: int) -> int:
    """Bits a sensor used, from the largest value met: 16-bit containers often hold 10, 12 or 14-bit data."""
    if stored_bits <= 8:
        return 8
    for bits in (10, 12, 14):
        if max_value < (1 << bits):
            return bits
    return 16


def full_scale(bit_depth: int) -> int:
    return (1 << bit_depth) - 1


def saturated_pct(stats: FrameStats, *, full_scale_dn: int) -> float:
    """% of pixels clipped at the ceiling: those at the frame maximum when it reaches full scale.

    A maximum within 1/256 of full scale counts, for 12-bit data stored left-aligned in 16 bits (65520).
    """
    return stats.at_max_pct if stats.max >= full_scale_dn - (full_scale_dn >> 8) else 0.0


def to_uint8(frame: np.ndarray, *, full_scale_dn: int) -> np.ndarray:
    """A frame scaled so that full scale is 255 (within one grey level)."""
    if frame.dtype == np.uint8 and full_scale_dn == 255:
        return frame
    bits = full_scale_dn.bit_length()
    if full_scale_dn == (1 << bits) - 1 and bits > 8:  # 2^k − 1: a shift, 10× faster than scaling
        return np.minimum(frame >> (bits - 8), 255).astype(np.uint8)
    scaled = frame.astype(np.float32) * np.float32(255.0 / full_scale_dn)
    return np.clip(scaled + 0.5, 0, 255).astype(np.uint8)


def reduced_shape(height_px: int, width_px: int, *, max_px: int) -> tuple[int, int]:
    """(height, width) with the longer side at most `max_px`, aspect kept."""
    scale = min(1.0, max_px / max(height_px, width_px))
    return max(1, round(height_px * scale)), max(1, round(width_px * scale))


def downscale(image: np.ndarray, *, max_px: int) -> np.ndarray:
    """The image with its longer side at most `max_px` (area averaging); unchanged when already that small."""
    height, width = reduced_shape(*image.shape[:2], max_px=max_px)
    if (height, width) == image.shape[:2]:
        return image
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def board_visible(frame_u8: np.ndarray, *, cols: int, rows: int, max_px: int = 1024) -> bool:
    """Whether a chessboard of cols × rows inner corners is found in the frame (on a copy at most max_px)."""
    image = downscale(frame_u8, max_px=max_px)
    found, _corners = cv2.findChessboardCornersSB(image, (cols, rows), flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
    return bool(found)


@dataclass(frozen=True)
class QaWarning:
    """A finding a person should look at before running a job. frames: 0-based indices it concerns."""

    code: str
    message: str
    frames: tuple[int, ...] = field(default=())


def describe_frames(indices: Sequence[int] | np.ndarray, *, limit: int = 8) -> str:
    """'frame 17', 'frames 3, 5–9 and 17', or the first `limit` runs and how many frames more."""
    values = sorted(set(int(i) for i in indices))
    if not values:
        return "no frame"
    runs: list[tuple[int, int]] = []
    for value in values:
        if runs and value == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], value)
        else:
            runs.append((value, value))
    parts = [f"{a}" if a == b else f"{a}–{b}" for a, b in runs[:limit]]
    rest = sum(b - a + 1 for a, b in runs[limit:])
    noun = "frame" if len(values) == 1 else "frames"
    if rest:
        return f"{noun} {', '.join(parts)} and {rest} more"
    if len(parts) == 1:
        return f"{noun} {parts[0]}"
    return f"{noun} {', '.join(parts[:-1])} and {parts[-1]}"


def exposure_warnings(
    mean_fraction: np.ndarray,
    saturation_pct: np.ndarray,
    contrast: np.ndarray,
    *,
    contrast_of: str,
    thresholds: QaThresholds = QaThresholds(),
) -> list[QaWarning]:
    """Warnings about saturated, dark and low-contrast frames; arrays of shape (n_frames,).

    contrast_of names what the contrast is of ("stripe" or "board") in the messages.
    """
    found: list[QaWarning] = []
    saturated = np.flatnonzero(saturation_pct > thresholds.saturated_pct)
    if saturated.size:
        found.append(
            QaWarning(
                "saturated",
                f"{describe_frames(saturated)}: more than {thresholds.saturated_pct:g} % of pixels saturated "
                f"(up to {float(saturation_pct.max()):.1f} %)",
                tuple(int(i) for i in saturated),
            )
        )
    dark = np.flatnonzero(mean_fraction < thresholds.dark_fraction)
    if dark.size:
        found.append(
            QaWarning(
                "dark",
                f"{describe_frames(dark)}: dark (mean below {thresholds.dark_fraction:.0%} of full scale)",
                tuple(int(i) for i in dark),
            )
        )
    low = np.flatnonzero(contrast < thresholds.low_contrast)
    if low.size:
        found.append(
            QaWarning(
                "low_contrast",
                f"{describe_frames(low)}: low {contrast_of} contrast (below {thresholds.low_contrast:g}, "
                f"lowest {float(contrast.min()):.2f})",
                tuple(int(i) for i in low),
            )
        )
    return found
