"""Camera against camera: the peak deflection of two cameras' results of one test, compared only where both
measured it.

Belongs here: pairing one camera's frames with the other's instants and the rule of what is compared
(`peaks_against`). Not here: reading the results (`fringelab.formats.topography`) or whether a peak was measured
(`peaks.py`, whose flag both sides carry).

A frame is compared only when this camera measured its peak and the other camera measured its peak at both of
its frames around that instant (the other's peak is interpolated linearly in time between them; by frame number
where either result has no times). Every other frame is left out with the reason, never drawn as a difference:
a gap in one camera is not a difference between the cameras.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .arrays import checked_array

NOT_MEASURED_HERE = "this camera did not measure the peak (a lower bound)"
UNKNOWN_HERE = "this camera's result does not say whether its peak was measured (written before the flag)"
NOT_MEASURED_THERE = "the other camera did not measure the peak at this instant"
UNKNOWN_THERE = "the other camera's result does not say whether its peak was measured (written before the flag)"
NO_FRAME_THERE = "the other camera has no frame at this instant"
NO_TIME_HERE = "this frame has no time, the other camera's have"


@dataclass(frozen=True, eq=False)
class PeakSeries:
    """One camera's peaks: frames (n,) recording indices, time_s (n,) (NaN: not logged), peak_w_mm (n,) the largest
    measured w, measured (n,) 1.0 / 0.0 / NaN (unknown), as `formats.topography.TopographyResult` reads them."""

    frames: np.ndarray
    time_s: np.ndarray
    peak_w_mm: np.ndarray
    measured: np.ndarray


@dataclass(frozen=True, eq=False)
class PeaksAgainst:
    """Per frame of this camera: the other camera's peak at its instant and the difference (NaN where not
    compared), other_frame (the other's nearest frame, −1: none), left_out (the reason, "" where compared); and
    how the frames were paired ("time" or "frame")."""

    aligned_by: str
    other_peak_w_mm: np.ndarray
    difference_w_mm: np.ndarray
    other_frame: np.ndarray
    left_out: tuple[str, ...]

    @property
    def compared(self) -> np.ndarray:
        return np.array([reason == "" for reason in self.left_out], bool)

    @property
    def rms_difference_mm(self) -> float:
        d = self.difference_w_mm[self.compared]
        return float(np.sqrt(np.mean(d**2))) if len(d) else float("nan")

    @property
    def largest_difference_mm(self) -> float:
        """The largest |this − other| over the compared frames only (NaN when none)."""
        d = self.difference_w_mm[self.compared]
        return float(np.max(np.abs(d))) if len(d) else float("nan")


def peaks_against(mine: PeakSeries, other: PeakSeries) -> PeaksAgainst:
    """This camera's peaks against the other's, frame by frame (the module's rule)."""
    n = len(checked_array(mine.frames, shape=(None,), name="frames"))
    for series in (mine, other):
        for name in ("time_s", "peak_w_mm", "measured"):
            checked_array(getattr(series, name), shape=(len(series.frames),), name=name)
    by_time = bool(np.any(np.isfinite(mine.time_s)) and len(other.frames) and np.all(np.isfinite(other.time_s)))
    if by_time:
        order = np.argsort(other.time_s, kind="stable")
        x_other, x_mine = other.time_s[order], mine.time_s
    else:
        order = np.argsort(other.frames, kind="stable")
        x_other, x_mine = other.frames[order].astype(np.float64), mine.frames.astype(np.float64)
    peaks_other, measured_other, frames_other = other.peak_w_mm[order], other.measured[order], other.frames[order]
    # Half the other camera's typical frame step: how far beyond its first or last frame an instant still has one.
    steps = np.diff(x_other)
    reach = 0.5 * float(np.median(steps)) if len(steps) else 0.0
    other_peak = np.full(n, np.nan)
    other_frame = np.full(n, -1, np.int64)
    reasons: list[str] = []
    for i in range(n):
        x = x_mine[i]
        if not np.isfinite(x):
            reasons.append(NO_TIME_HERE)
            continue
        if not len(x_other) or x < x_other[0] - reach or x > x_other[-1] + reach:
            reasons.append(NO_FRAME_THERE)
            continue
        if x <= x_other[0] or x >= x_other[-1]:  # at or just beyond an end: that frame alone
            lo = hi = 0 if x <= x_other[0] else len(x_other) - 1
        else:
            hi = int(np.searchsorted(x_other, x))
            lo = hi if x_other[hi] == x else hi - 1
        nearest = lo if abs(x - x_other[lo]) <= abs(x_other[hi] - x) else hi
        other_frame[i] = int(frames_other[nearest])
        if np.isnan(mine.measured[i]):
            reasons.append(UNKNOWN_HERE)
        elif mine.measured[i] == 0.0 or not np.isfinite(mine.peak_w_mm[i]):
            reasons.append(NOT_MEASURED_HERE)
        elif np.any(np.isnan(measured_other[[lo, hi]])):
            reasons.append(UNKNOWN_THERE)
        elif np.any(measured_other[[lo, hi]] == 0.0) or not np.all(np.isfinite(peaks_other[[lo, hi]])):
            reasons.append(NOT_MEASURED_THERE)
        else:
            t = 0.0 if hi == lo else (x - x_other[lo]) / (x_other[hi] - x_other[lo])
            other_peak[i] = (1.0 - t) * peaks_other[lo] + t * peaks_other[hi]
            reasons.append("")
    compared = np.array([r == "" for r in reasons], bool)
    difference = np.where(compared, mine.peak_w_mm - other_peak, np.nan)
    return PeaksAgainst(
        aligned_by="time" if by_time else "frame",
        other_peak_w_mm=np.where(compared, other_peak, np.nan),
        difference_w_mm=difference,
        other_frame=other_frame,
        left_out=tuple(reasons),
    )
