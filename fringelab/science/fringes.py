"""Stripe edges of one image: orientation and period, sub-pixel edge location, linking and smoothing
(docs/method.md §5).

Belongs here: finding the stripe direction and period of an image (`detect_stripes`), and `locate_edges`, a pure
function of one frame that returns every dark/bright transition at sub-pixel accuracy, linked into edge curves
and smoothed along them. Not here: edge identity across frames or Z steps (`projector.py`, `topography.py`),
anything that needs a camera.

Scan frame. Edges are located along scan lines that cross the stripes: image rows when the stripes run roughly
vertically (``axis="rows"``), image columns when they run roughly horizontally (``axis="cols"``). Whichever image
axis is closer to the stripe normal is used, so any stripe angle is handled; the crossing along a scan line is
then at most √2 times wider than across the stripe. An edge point is ``(line, t_px)``: the scan-line index
(the row for ``"rows"``, the column for ``"cols"``) and the sub-pixel position along it (the column for
``"rows"``, the row for ``"cols"``), both in pixels with (0, 0) at the centre of the top-left pixel. Polarity is
+1 where the intensity rises with increasing t (dark → bright) and −1 where it falls.
"""

from __future__ import annotations

import functools
import threading
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numba
import numpy as np

from . import MeasurementError
from .order_statistics import median, percentile
from .smoothing import edge_smoothing_weights, smoothing_noise_tables

Axis = Literal["rows", "cols"]
AXIS_CHOICES = ("auto", "rows", "cols")
MID_LEVEL_CHOICES = ("means", "envelopes")

# Stripe periods outside this range (px along the scan line) are not "stripes": finer ones cannot be located to
# sub-pixel accuracy, coarser ones would not fit several periods into the window that sets the mid-level.
MIN_PERIOD_PX = 3.0
MAX_PERIOD_PX = 80.0
# A period the caller fixes (`EdgeSettings.period_px`) may be far wider: a Gray code's bit frames have stripes of
# hundreds to thousands of pixels (the shared real scan's: 580–4600 px). Beyond MAX_PERIOD_PX the mid-level and
# the contrast are set over the window of a MAX_PERIOD_PX period (1.5 × 80 px): what sets an edge is its own two
# sides, within a blur width of it, and a window of a whole wide stripe would span other surfaces, lit otherwise
# (a ball's highlight sets the mid-level of the screen behind it).
MAX_FIXED_PERIOD_PX = 8192.0
# A detected period is confirmed by the transitions themselves: the spacing of neighbouring same-polarity mid-level
# crossings must agree with it to this fraction (a harmonic or the lit area's envelope is off by 50 % or more),
# from at least this many spacings.
PERIOD_AGREEMENT = 0.2
MIN_PERIOD_SPACINGS = 16
# Below this coherence of the structure tensor (1 = one gradient direction, 0 = isotropic) there is no stripe
# pattern to speak of: noise, a chessboard or an empty frame.
MIN_COHERENCE = 0.3
# A pixel is black (a crack, a scratch, a gap narrower than a stripe) below this fraction of the level the dark
# stripes have beside it and at least this many grey levels below it.
BLACK_FRACTION = 0.6
BLACK_MARGIN_GREY = 8.0
# Beside a dark area, a transition is a stripe edge only where the stripe it closes on its lit side is whole: at
# least this share of the width of the previous stripe of the same kind on its line (`_whole_beside_dark`). A
# stripe cut by the rim of a dark area that is not black (a shadow under room light) is narrower; stripes narrow
# by far less than this from one to the next with slope and perspective.
WHOLE_STRIPE_SHARE = 0.75
# Why no edge can be located in a block of pixels (`FrameEdges.unusable`), in increasing precedence.
UNUSABLE_NONE = 0
UNUSABLE_LOW_CONTRAST = 1
UNUSABLE_DARK = 2
UNUSABLE_BLACK = 3
# Stripes there, but the light changes too fast for the mid-level to follow (a soft shadow's rim): the least of
# the reasons, given only where none of the others applies.
UNUSABLE_UNEVEN_LIGHT = 4
UNUSABLE_BLOCK_PX = 4
# Grey levels are expressed on the 8-bit scale whatever the bit depth, so settings read the same for 16-bit frames.
FULL_SCALE = 255.0


class NoStripesError(MeasurementError):
    """No stripe pattern was found in a frame (dark, blank, out of focus, or not a fringe recording)."""


@dataclass(frozen=True)
class StripeGeometry:
    """Stripe direction and spacing of an image.

    axis: the scan axis ("rows": stripes roughly vertical, scanned along rows; "cols": roughly horizontal).
    period_px: the stripe period (one dark + one bright stripe) measured along the scan line.
    angle_deg: the angle of the stripes from the image column axis (0 = vertical, ±90 = horizontal).
    coherence: structure-tensor coherence in [0, 1]; how strongly one direction dominates.
    """

    axis: Axis
    period_px: float
    angle_deg: float
    coherence: float

    @property
    def edge_spacing_px(self) -> float:
        """Nominal distance between neighbouring edges (of either polarity) along the scan line."""
        return 0.5 * self.period_px


@dataclass(frozen=True)
class EdgeSettings:
    """Settings of `locate_edges`; defaults suit ~6–20 px stripe periods in 8-bit frames with σ ≈ 2 noise.

    axis, period_px: fixed stripe geometry; "auto" / None detect it in each frame (a recording's pipeline fixes
        them once, from the projector calibration, so every frame is processed alike). Detection finds periods
        of MIN_PERIOD_PX..MAX_PERIOD_PX; a fixed period may be up to MAX_FIXED_PERIOD_PX (Gray-code bit frames).
    window_periods: the window (in stripe periods along the scan line) over which the local minimum and maximum
        set the contrast I_max − I_min; > 1 so a stripe stretched by a slope still shows both levels.
    min_contrast_grey: grey levels (8-bit scale) of I_max − I_min below which a transition is rejected.
    max_uneven_light_shift_px: a transition is rejected ("uneven light") where the light bends within a period so
        that the mid-level cannot follow it and the edge would move by more than this (px along the line): the
        shift `uneven_light_shift_px` predicts from the light's bend there and the crossing's
        slope. Every kept edge carries half that shift in its σ (`_edge_sigma`). None (the default) rejects none:
        at 0.25 px the worst soft-shadow point stays 3.9 mm off while good edges beside the punch's own shadow
        are refused, and a frame's peak before perforation goes unmeasured. 0.08 px keeps no point of the
        soft-shadow renders more than 1 mm off (0.73 mm; 3.9 mm at 0.25 px), but it also refuses good edges in the
        punch's own shadow beside the dome top, which moves the dome's centroid 1.7 mm off the punch axis in the
        virtual Kodak test; measured in docs/method.md §5. Beyond MAX_PERIOD_PX (a Gray code's wide bits) no shift is
        predicted: the neighbours of the same polarity lie a whole period away and say nothing of the light at the edge.
    max_departure_px: an edge is rejected ("uneven light") where it departs from the cubic through its neighbours
        on its scan line (two either side) by more than this (px), or by 1.5 times this next to the end of its run
        of neighbouring edges (`edge_departures_px`). A soft shadow's rim dims one flank of a stripe and moves its
        edges by up to 3 px, which the light's bend does not see: at 0.3 px (with `max_end_departure_px` at 0.8)
        no point of the soft-shadow renders is more than 1 mm off (0.86 mm; 3.9 mm with none rejected), masking
        less than half what the bend's 0.08 px does. None (the
        default) rejects none: beside the punch, where the dome's stripes fold, good edges depart by up to 2.7 px
        and a frame's peak goes unmeasured; measured in docs/method.md §5.
    max_end_departure_px: the same at the end of a run (its four neighbours on one side only: the last lit edge
        before a shadow's dark interior, whose bend is not judged), against the cubic through those four, whose
        own noise is 6 times a centred one's; and an edge alone on its line is rejected. On by default: no edge
        where the dome's stripes fold departs so, and the worst soft-shadow point of the deep shadow falls from
        3.9 to 1.7 mm. None rejects none of them. Both departures are judged at periods up to MAX_PERIOD_PX only:
        beyond it (a Gray code's wide bits) a run's neighbours lie a stripe, hundreds of px, away across other surfaces,
        and a line may hold a single edge by design (the most significant bit's), which would be rejected as alone.
        On a Gray code's finer bits (given their true period, `graycode.coded_edges`) the end departure is right: on
        the virtual rig's sphere (tests/science/procam/test_virtual_rig.py) it refuses 293 of 25 822 points, whose
        errors are 4 times the rest's at the 90th percentile (0.056 against 0.014 mm).
    max_width_alternation_px: an edge is rejected ("uneven light"), with its two neighbours on its line and the
        points of its curve within `ALTERNATION_ALONG_CURVE_LINES` lines (the rim crosses the stripes at an angle
        and moves the same edge on the next lines, less), where the stripe widths either side of it alternate by
        more than this (px; `width_alternations_px`): a misplaced edge (a stripe's flank dimmed by a soft shadow's
        rim) widens one of its stripes and narrows the other, making one a local maximum and the other a local
        minimum of the widths along the line, where a surface's slope, even where the dome's stripes fold, makes
        them change monotonically. On by default at 0.2 px (no edge of the shadow-free renders up to 55 mm reaches
        0.12 px): no point of the soft-shadow renders is more than 1 mm off (0.97 mm; 1.30 mm without the curves'
        lines, 3.3 mm without the rule); None rejects none. Judged at periods up to MAX_PERIOD_PX only (beyond, a
        run of five edges spans other surfaces). It assumes stripes on one continuous surface: a stripe that crosses
        a silhouette (a camera–projector scan's ball before its screen) may take any width, and the rule refuses
        good edges beside it. On the virtual rig's sphere it refuses 794 of 25 822 points (3 %), as accurate as the
        rest (median error 0.0052 against 0.0047 mm); 84–100 % of the edges it flags have the other surface within
        1.5 periods. Hence `graycode.GRAY_EDGE_SETTINGS` sets it None: not that a Gray bit's stripes differ in width
        (inside the projector they do not, but by a projector pixel where band_px is not whole, a constant
        alternation the duty takes out).
    saturation_grey: grey level (8-bit scale) at or above which a transition's bright side counts as clipped.
    dark_fraction: pixels whose neighbourhood (one period) never rises above this fraction of the frame's bright
        level are "dark" (clamp ring, hole, background, a wide dark stripe); transitions inside them, or within
        a period of a black sample (darker than the dark stripes: a hole's or the clamp's rim, a crack), are
        rejected. The lit edge beside a dark area that is not black is kept where its stripe is whole
        (`_whole_beside_dark`; see `locate_edges`), flagged `FrameEdges.beside_dark`: it carries no fringe order
        to its neighbours (`order_edges`).
    presmooth_px: Gaussian σ (px) of smoothing along the stripes before locating; it averages noise without
        moving an edge that runs along the smoothing direction.
    edge_smoothing_lines: Gaussian σ (lines) of the local quadratic fit of t against the line along each edge
        (the paper's spatial low-pass filter); 0 keeps the raw positions.
    min_edge_length_lines: linked edges shorter than this (lines) are dropped as noise.
    max_link_step_px_per_line: largest change of t between neighbouring lines for two transitions to belong to one edge
        (1 px per line is a 45° edge).
    mid_level: "means", the mean grey level over one and over two periods, averaged (follows light that changes
        along the line; needs stripes of about `period_px`), or "envelopes", (I_max + I_min)/2 of the window's
        envelopes (for Gray-code bit frames, whose stripes are wider than any period the locator takes and whose
        neighbouring stripes differ in width, so a window of whole periods does not hold as much bright as dark).
    link_across_lost_crossing: a curve broken by one lost crossing is linked across it (`_link_chains`). Off by
        default: on the real scan's Gray bits it finds 0.7–2.6 points more of the edges in five of seven frames
        (pieces shorter than `min_edge_length_lines` joined to their curves), but in soft shadows such pieces are
        the misplaced crossings the length filter drops: on `test_soft_shadows.py`'s frames with the strict
        refusal the worst point went from 0.73 to 3.9 mm (docs/method.md §5).
    """

    axis: str = "auto"
    period_px: float | None = None
    window_periods: float = 1.5
    min_contrast_grey: float = 20.0
    max_uneven_light_shift_px: float | None = None
    max_departure_px: float | None = None
    max_end_departure_px: float | None = 0.8
    max_width_alternation_px: float | None = 0.2
    saturation_grey: float = 250.0
    dark_fraction: float = 0.3
    presmooth_px: float = 1.0
    edge_smoothing_lines: float = 3.0
    min_edge_length_lines: int = 8
    max_link_step_px_per_line: float = 1.5
    mid_level: str = "means"
    link_across_lost_crossing: bool = False

    # Names these settings had in files written before they carried their units (still read).
    _FORMER_NAMES = {
        "min_contrast": "min_contrast_grey",
        "saturation_level": "saturation_grey",
        "edge_smoothing_px": "edge_smoothing_lines",
        "min_edge_length_px": "min_edge_length_lines",
        "max_link_step_px": "max_link_step_px_per_line",
    }
    # Settings of former files that no longer exist and are read as the defaults: max_uneven_light_fraction (a
    # threshold on the bend over the contrast, off by default) became max_uneven_light_shift_px, off by default.
    _DROPPED_NAMES = ("max_uneven_light_fraction",)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> EdgeSettings:
        """Settings from a stored document (JSON in a result file), also one written under the former names."""
        return cls(**{cls._FORMER_NAMES.get(name, name): value for name, value in values.items()
                      if name not in cls._DROPPED_NAMES})  # fmt: skip

    def __post_init__(self) -> None:
        if self.axis not in AXIS_CHOICES:
            raise ValueError(f"axis: expected one of {AXIS_CHOICES}, got {self.axis!r}")
        if self.period_px is not None and not MIN_PERIOD_PX <= self.period_px <= MAX_FIXED_PERIOD_PX:
            raise ValueError(
                f"period_px: expected {MIN_PERIOD_PX}..{MAX_FIXED_PERIOD_PX} px or None, got {self.period_px}"
            )
        if not self.window_periods >= 1.0:
            raise ValueError(f"window_periods: expected ≥ 1, got {self.window_periods}")
        for name in (
            "min_contrast_grey",
            "presmooth_px",
            "edge_smoothing_lines",
            "dark_fraction",
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name}: expected ≥ 0, got {getattr(self, name)}")
        if self.max_uneven_light_shift_px is not None and not self.max_uneven_light_shift_px > 0:
            raise ValueError(f"max_uneven_light_shift_px: expected > 0 or None, got {self.max_uneven_light_shift_px}")
        for name in ("max_departure_px", "max_end_departure_px", "max_width_alternation_px"):
            if getattr(self, name) is not None and not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected > 0 or None, got {getattr(self, name)}")
        if not self.max_link_step_px_per_line > 0:
            raise ValueError(f"max_link_step_px_per_line: expected > 0, got {self.max_link_step_px_per_line}")
        if self.min_edge_length_lines < 1:
            raise ValueError(f"min_edge_length_lines: expected ≥ 1, got {self.min_edge_length_lines}")
        if self.mid_level not in MID_LEVEL_CHOICES:
            raise ValueError(f"mid_level: expected one of {MID_LEVEL_CHOICES}, got {self.mid_level!r}")


@dataclass(frozen=True, eq=False)
class FrameEdges:
    """The stripe edges of one frame, sorted by (line, t_px).

    axis, period_px: the scan geometry used (see the module docstring).
    image_shape_hw_px: (height, width) of the frame.
    line: shape (N,) int32, scan-line index of each edge point.
    t_px: shape (N,) float32, sub-pixel position along the line, smoothed along the edge.
    polarity: shape (N,) int8, +1 dark → bright with increasing t, −1 bright → dark.
    chain: shape (N,) int32, label of the linked edge curve within this frame (0..n_chains−1).
    noise_px: RMS of raw − smoothed positions (px), a per-frame estimate of the location noise.
    saturated_fraction: fraction of pixels at or above the saturation level.
    dark_fraction: fraction of pixels in the dark mask (clamp, hole, background).
    unusable: shape (ceil(n_lines / 4), ceil(n_samples / 4)) uint8, why no edge can be located in each block of
        4 × 4 px (scan frame: [line // 4, t // 4]): UNUSABLE_NONE, UNUSABLE_BLACK (as dark as the background: a
        hole, a crack, something black in front), UNUSABLE_DARK (no projected light but not black: a shadow),
        UNUSABLE_LOW_CONTRAST (stripes too faint, or clipped by a highlight); the worst in the block; where none
        of those applies, UNUSABLE_UNEVEN_LIGHT where a transition was rejected because the light changes too
        fast (a soft shadow's rim, `uneven_light_shift_px`), it departs from its neighbours
        (`edge_departures_px`) or its stripes alternate in width (`width_alternations_px`). None for edges stored
        before it existed.
    sigma_px: shape (N,) float32, σ (px) of each smoothed position t_px, from the edge's own slope, the noise
        its neighbours along the edge show and the evenness of the light around it (`_edge_sigma`): how sure the
        edge is. None for edges stored before it existed: `uncertainty.edge_sigmas_px` then gives every edge the
        frame's σ from noise_px.
    contrast_grey: shape (N,) float32, the stripes' contrast I_max − I_min at each edge (grey levels, 8-bit
        scale). None for edges stored before it existed.
    beside_dark: shape (N,) bool, the lit edges kept beside a dark area that is not black (within a period of it;
        `locate_edges`): their stripe is whole, but one side of their window is the area, and a link resting on
        them never carries the fringe order (`order_edges`). None for edges stored before it existed (then none
        was kept at fringe periods).
    """

    axis: Axis
    period_px: float
    image_shape_hw_px: tuple[int, int]
    line: np.ndarray
    t_px: np.ndarray
    polarity: np.ndarray
    chain: np.ndarray
    noise_px: float
    saturated_fraction: float
    dark_fraction: float
    unusable: np.ndarray | None = None
    sigma_px: np.ndarray | None = None
    contrast_grey: np.ndarray | None = None
    beside_dark: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.line)

    @property
    def n_lines(self) -> int:
        """Number of scan lines (image rows for "rows", columns for "cols")."""
        return self.image_shape_hw_px[0] if self.axis == "rows" else self.image_shape_hw_px[1]

    @property
    def n_samples(self) -> int:
        """Length of a scan line (px)."""
        return self.image_shape_hw_px[1] if self.axis == "rows" else self.image_shape_hw_px[0]

    def q_px(self) -> np.ndarray:
        """Edge points as pixels (u, v), shape (N, 2)."""
        t = self.t_px.astype(np.float64)
        s = self.line.astype(np.float64)
        return np.column_stack([t, s] if self.axis == "rows" else [s, t])


class _FrameScratch(threading.local):
    """Working arrays of `locate_edges` kept from one frame to the next, one set per thread: full-frame ones
    (`array`) and growable ones for the crossings and edges (`buffer`).

    Fresh frame-sized arrays cost more than their use: the allocator hands their pages back to the system when a
    frame's arrays are freed and the next frame faults them in again, zeroed (at 1024² about 4 000 minor faults and
    11–18 ms of system time a frame of 60–65 ms). Only intermediate arrays come from here, never one a caller
    gets; each name is one array alive within a frame. What a thread keeps once a frame is done is bounded
    (`trim`, SCRATCH_KEPT_MAX_BYTES): beyond, the largest are allocated afresh for each frame."""

    def __init__(self) -> None:
        self.arrays: dict[str, np.ndarray] = {}

    def array(self, name: str, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
        """The thread's array `name` of that shape and dtype, its values left from its last use."""
        array = self.arrays.get(name)
        if array is None or array.shape != shape or array.dtype != dtype:
            array = self.arrays[name] = np.empty(shape, dtype)
        return array

    def buffer(self, name: str, length: int, dtype: Any, *, kept: int = 0) -> np.ndarray:
        """The thread's 1-D array `name` of that dtype with room for at least `length` items, its values left from
        its last use; one too short is replaced by one of max(length, twice its length) items, its first `kept`
        values copied (a buffer filled in steps)."""
        array = self.arrays.get(name)
        if array is None or array.ndim != 1 or array.dtype != dtype:
            array = self.arrays[name] = np.empty(length, dtype)
        elif len(array) < length:
            grown = self.arrays[name] = np.empty(max(length, 2 * len(array)), dtype)
            grown[:kept] = array[:kept]
            array = grown
        return array

    def trim(self, max_bytes: int) -> None:
        """Let go of the largest arrays until those kept hold at most `max_bytes` (a worker that once measured a
        huge recording does not keep its frames' working memory for the process's life)."""
        kept_bytes = sum(array.nbytes for array in self.arrays.values())
        for name, array in sorted(self.arrays.items(), key=lambda item: item[1].nbytes, reverse=True):
            if kept_bytes <= max_bytes:
                break
            del self.arrays[name]
            kept_bytes -= array.nbytes


_SCRATCH = _FrameScratch()
# The most a thread keeps of `locate_edges`' working arrays between frames: 128 MiB, all of a 1024² frame's (about
# 60 MB) and half of a 2048² frame's, whose largest then fault in afresh each frame.
SCRATCH_KEPT_MAX_BYTES = 128 * 2**20
# Grey-level types `cv2.transpose` takes (others, as long double, are transposed by numpy).
_CV_TRANSPOSABLE = tuple(np.dtype(t) for t in (np.uint8, np.uint16, np.float16, np.float32, np.float64))


def _require_grey(image: np.ndarray) -> np.ndarray:
    """The frame as an array; ValueError for anything but one 2-D grey image of a supported type."""
    array = np.asarray(image)
    if array.ndim != 2 or min(array.shape) < 8:
        raise ValueError(f"image: expected a 2-D grey image of shape (H, W) with H, W ≥ 8, got {array.shape}")
    if not (array.dtype in (np.uint8, np.uint16) or np.issubdtype(array.dtype, np.floating)):
        raise ValueError(f"image: expected uint8, uint16 or float grey levels, got dtype {array.dtype}")
    return array


def _grey_image(image: np.ndarray, *, out: np.ndarray | None = None) -> np.ndarray:
    """The frame as float32 on the 8-bit scale (in `out`, float32 of the image's shape, where given); ValueError
    for anything but one 2-D grey image."""
    array = _require_grey(image)
    grey = np.empty(array.shape, np.float32) if out is None else out
    np.copyto(grey, array, casting="unsafe")
    if array.dtype == np.uint16:
        grey *= np.float32(FULL_SCALE / 65535.0)
    return grey


def detect_stripes(image: np.ndarray, *, axis: str = "auto") -> StripeGeometry:
    """Direction and period of the stripes in `image`, shape (H, W).

    Direction from the structure tensor of the whole image; period from the peak of the mean power spectrum of
    scan lines. Raises NoStripesError when there is no dominant stripe direction or period.
    """
    if axis not in AXIS_CHOICES:
        raise ValueError(f"axis: expected one of {AXIS_CHOICES}, got {axis!r}")
    grey = _grey_image(image)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    jxx, jyy, jxy = float(np.mean(gx * gx)), float(np.mean(gy * gy)), float(np.mean(gx * gy))
    trace = jxx + jyy
    if not trace > 0:
        raise NoStripesError("no stripes found: the frame is uniform (no intensity gradient at all)")
    coherence = float(np.hypot(jxx - jyy, 2.0 * jxy) / trace)
    # Dominant gradient direction (from +u toward +v); the stripes run perpendicular to it.
    gradient_angle = 0.5 * np.arctan2(2.0 * jxy, jxx - jyy)
    angle_deg = float(np.rad2deg(gradient_angle))
    if axis == "auto" and coherence < MIN_COHERENCE:
        raise NoStripesError(
            f"no stripes found: no dominant stripe direction (coherence {coherence:.2f} < {MIN_COHERENCE}); "
            "check that the projector is on and the stripes are in focus"
        )
    chosen: Axis
    if axis == "auto":
        chosen = "rows" if abs(np.cos(gradient_angle)) >= abs(np.sin(gradient_angle)) else "cols"
    else:
        chosen = "rows" if axis == "rows" else "cols"
    scan = grey if chosen == "rows" else grey.T
    period_px = _period_along_lines(scan)
    if period_px is None:
        raise NoStripesError(
            f"no stripes found: no stripe period between {MIN_PERIOD_PX:g} and {MAX_PERIOD_PX:g} px along the "
            f"image {chosen}"
        )
    return StripeGeometry(axis=chosen, period_px=period_px, angle_deg=angle_deg, coherence=coherence)


def _period_along_lines(scan: np.ndarray) -> float | None:
    """Stripe period (px) along the scan lines, or None when no period is both a clear peak of the spectrum and the
    spacing of the stripes' own transitions.

    Candidates are the peaks of the mean power spectrum of up to 128 scan lines that stand well above the spectrum
    around them (noise alone does not), strongest first. A dim pattern of fine stripes inside a small lit area has
    its strongest peak at the lit area's envelope, and a square wave has peaks at its odd harmonics: so each
    candidate is checked against the spacing of the mid-level crossings it gives (`_crossing_period`), and where
    the crossings say another period (a multiple or a fraction of the candidate), the spectral peak there is
    checked next. The first candidate its crossings agree with (within PERIOD_AGREEMENT) is the period.
    """
    lines = np.ascontiguousarray(scan[:: max(1, scan.shape[0] // 128)], np.float32)
    centred = lines.astype(np.float64) - lines.mean(axis=1, keepdims=True)
    n = lines.shape[1]
    power = np.mean(np.abs(np.fft.rfft(centred * np.hanning(n), axis=1)) ** 2, axis=0)
    freqs = np.fft.rfftfreq(n)
    in_band = (freqs >= 1.0 / MAX_PERIOD_PX) & (freqs <= 1.0 / MIN_PERIOD_PX)
    band = np.flatnonzero(in_band)
    if len(band) == 0 or not np.any(power[band] > 0):
        return None
    floor = 8.0 * float(np.median(power[band]))
    padded = np.r_[0.0, power, 0.0]
    is_peak = (power >= padded[:-2]) & (power >= padded[2:]) & (power >= floor) & in_band
    candidates = [int(i) for i in np.flatnonzero(is_peak)[np.argsort(-power[is_peak], kind="stable")][:4]]
    checked: set[int] = set()
    while candidates and len(checked) < 6:
        idx = candidates.pop(0)
        if idx in checked:
            continue
        checked.add(idx)
        period_px = _refined_period(power, idx, n)
        crossing_period_px = _crossing_period(lines, period_px)
        if crossing_period_px is None:
            continue
        if abs(crossing_period_px / period_px - 1.0) <= PERIOD_AGREEMENT:
            return period_px
        # The transitions are spaced otherwise: a harmonic or the envelope. Look at the spectrum where they say.
        near = np.flatnonzero(in_band & (np.abs(freqs * crossing_period_px - 1.0) <= PERIOD_AGREEMENT))
        if len(near) and power[near].max() >= floor:
            candidates.insert(0, int(near[np.argmax(power[near])]))
    return None


def _refined_period(power: np.ndarray, idx: int, n: int) -> float:
    """The period (px) of a peak of a power spectrum of n-sample lines at bin idx, refined to a fraction of a bin
    by a parabola through the log power of the bin and its neighbours."""
    if 0 < idx < len(power) - 1:
        a, b, c = np.log(power[idx - 1 : idx + 2] + 1e-30)
        denom = a - 2 * b + c
        offset = 0.5 * (a - c) / denom if denom < 0 else 0.0
    else:
        offset = 0.0
    return float(n / (idx + float(np.clip(offset, -0.5, 0.5))))


def _crossing_period(lines: np.ndarray, period_px: float) -> float | None:
    """The median spacing (px) of neighbouring same-polarity mid-level crossings of `lines` (S, T) float32 when the
    mid-level is set over 1.5 × period_px, or None when fewer than MIN_PERIOD_SPACINGS are seen.

    Only strong transitions count: where the window's contrast is at least half the largest within 1.5 periods
    either way (a window narrower than a stripe, a harmonic's, sees noise in the middle of the stripe) and above
    the noise of a dark background (0.15 of the frame's 99th percentile of contrast), and pairs
    of crossings closer than an eighth of the period (noise on one slow transition) are dropped. The window of a
    sub-harmonic still spans both levels, so its crossings are the stripes' own: a candidate is only confirmed
    by crossings at its own spacing.
    """
    window = _odd(1.5 * period_px)
    kernel = np.ones((1, window), np.uint8)
    high, low = cv2.dilate(lines, kernel), cv2.erode(lines, kernel)
    contrast = high - low
    floor = max(2.0, 0.15 * float(np.percentile(contrast, 99)))
    strong = (contrast >= 0.5 * cv2.dilate(contrast, np.ones((1, _odd(3.0 * period_px)), np.uint8))) & (
        contrast >= floor
    )
    above = lines > 0.5 * (high + low)
    line, j = np.nonzero((above[:, 1:] != above[:, :-1]) & strong[:, 1:] & strong[:, :-1])
    keep = _without_glitches(line, j.astype(np.float64), min_gap_px=0.125 * period_px)
    line, j = line[keep], j[keep]
    triple = line[2:] == line[:-2]
    spacing = (j[2:] - j[:-2])[triple]
    if len(spacing) < MIN_PERIOD_SPACINGS:
        return None
    return float(np.median(spacing))


def _odd(value: float) -> int:
    return int(2 * (int(round(value)) // 2) + 1)


# Up to this width (samples) OpenCV's dilation along the lines, whose cost grows with the width, is the faster;
# beyond it the running maximum of `_running_max_kernel`, whose cost does not (wide fixed periods).
_OPENCV_MAX_WIDTH = 161


def _dilate_along_lines(a: np.ndarray, width: int, *, lines: int = 1, out: np.ndarray | None = None) -> np.ndarray:
    """The maximum of `a` (S, T) over `width` samples along each line (odd, centred; clipped at the line's ends)
    and then over `lines` lines (odd, centred), as `cv2.dilate` with a (lines, width) box, any width at a cost
    that does not grow with it; in `out` (like `a`) where given and the width is OpenCV's."""
    if width <= _OPENCV_MAX_WIDTH:
        return cv2.dilate(a, np.ones((lines, width), np.uint8), dst=out)
    along = _running_max_kernel(np.ascontiguousarray(a), width // 2)
    return along if lines == 1 else cv2.dilate(along, np.ones((lines, 1), np.uint8))


@numba.njit(cache=True, nogil=True)
def _running_max_kernel(a: np.ndarray, half: int) -> np.ndarray:
    """max(a[i, j − half … j + half]) within the line, by van Herk and Gil–Werman's blocks of 2·half + 1
    samples: the maximum from each block's start and from its end, three comparisons a sample."""
    n_lines, n = a.shape
    size = 2 * half + 1
    out = np.empty_like(a)
    forward = np.empty(n, a.dtype)
    backward = np.empty(n, a.dtype)
    for i in range(n_lines):
        row = a[i]
        for j in range(n):
            forward[j] = row[j] if j % size == 0 else max(forward[j - 1], row[j])
        for j in range(n - 1, -1, -1):
            backward[j] = row[j] if (j % size == size - 1 or j == n - 1) else max(backward[j + 1], row[j])
        for j in range(n):
            lo, hi = max(j - half, 0), min(j + half, n - 1)
            if lo // size != hi // size:
                out[i, j] = max(backward[lo], forward[hi])  # the end of lo's block, the start of hi's
            elif lo % size == 0:
                out[i, j] = forward[hi]  # one block from its start (a full window, or clipped at the line's start)
            else:
                out[i, j] = backward[lo]  # clipped at the line's end, where the backward maxima restart
    return out


def locate_edges(image: np.ndarray, settings: EdgeSettings | None = None) -> FrameEdges:
    """Every stripe edge of one frame at sub-pixel accuracy, linked into curves and smoothed along them.

    image: shape (H, W), uint8, uint16 or float grey levels (float on the 8-bit scale).

    A pure function of the frame and the settings, so frames can be processed in any order and on any worker.
    Steps (docs/method.md §5): Gaussian smoothing along the stripes; local mid-level, the mean grey level over one
    and over two stripe periods along each scan line, averaged (`_mid_and_contrast`), and contrast I_max − I_min
    from the envelopes over `window_periods` periods; every sign change of I − mid is an edge candidate, placed
    by a probit fit to the four straddling pixels; candidates with low contrast, a clipped bright
    side, inside a dark area or within a period of a black one are rejected (those kept beside a dark area are
    flagged, `FrameEdges.beside_dark`), as are pairs closer than a quarter of the edge spacing (noise
    glitches) and both ends of a stripe less than half as wide as both its neighbours (a stripe cut by a crack
    narrower than a stripe); the rest are linked line to line into curves (mutual nearest of the same polarity),
    short curves are dropped and each curve is smoothed by a local quadratic fit of t against the line.

    Raises NoStripesError when the frame shows no stripes.
    """
    settings = EdgeSettings() if settings is None else settings
    image = _require_grey(image)
    if settings.axis == "auto" or settings.period_px is None:
        geometry = detect_stripes(image, axis=settings.axis)
        axis: Axis = geometry.axis
        period_px = geometry.period_px if settings.period_px is None else settings.period_px
    else:
        axis = settings.axis  # type: ignore[assignment]
        period_px = settings.period_px
    image_shape_hw_px = image.shape
    # The working arrays are the thread's from the frame before (`_FrameScratch`); none of them is returned.
    shape = image.shape if axis == "rows" else image.shape[::-1]

    def scratch(name: str, dtype: Any) -> np.ndarray:
        return _SCRATCH.array(name, shape, dtype)

    # Transposing before the conversion to float moves a quarter of the bytes; OpenCV's blocked transpose takes
    # 0.07 ms a 1024² uint8 frame where numpy's strided copy took 1.3 ms.
    if axis != "rows":
        transposed = scratch("transposed", image.dtype)
        if image.dtype in _CV_TRANSPOSABLE:
            cv2.transpose(image, dst=transposed)
        else:
            np.copyto(transposed, image.T)
        image = transposed
    half = max(1, int(np.ceil(3.0 * settings.presmooth_px)))
    if settings.presmooth_px > 0:
        kernel = cv2.getGaussianKernel(2 * half + 1, settings.presmooth_px).astype(np.float32)
        # 8-bit frames go to OpenCV as they are: its pass along the lines (× 1) makes them float32 exactly, the
        # same scan as from a float32 copy, which took 0.04 ms a 512 × 480 frame.
        as_is = image.dtype == np.uint8 and image.flags.c_contiguous
        grey = image if as_is else _grey_image(image, out=scratch("grey", np.float32))
        scan = cv2.sepFilter2D(grey, cv2.CV_32F, np.ones((1, 1), np.float32), kernel, dst=scratch("scan", np.float32))
    else:
        scan = _grey_image(image, out=scratch("grey", np.float32))
    n_lines, n_samples = scan.shape

    # Dark: no bright sample within half a period either way (a dark stripe is only half a period wide). The
    # mask starts half a period inside a dark area (clamp ring, hole, background); grown by half a period
    # along the lines it covers the area itself.
    # The levels from every 4th sample of every 4th line, taken while the frame is in the cache (the black level
    # at the end of the frame took 0.15 ms a 512 × 480 frame, mostly reading it back).
    sampled_scan = np.ravel(scan[::4, ::4])
    bright_level = percentile(sampled_scan, 95)
    black_level = percentile(sampled_scan, 1)
    dark_window = _odd(period_px)
    stripe_max = _dilate_along_lines(scan, dark_window, out=scratch("stripe_max", np.float32))
    dark, area_u8 = scratch("dark", np.bool_), scratch("area", np.uint8)
    any_area = _dim_across(stripe_max, np.float32(settings.dark_fraction * bright_level), dark, area_u8)
    # Black: well below the dark stripes around it. A crack or a cut narrower than a stripe is not "dark" by the
    # test above (bright stripes lie within half a period of it), but it is darker than any dark stripe, and
    # an edge that touches it is the crack's rim, not a stripe edge. The margin of 8 grey levels keeps noise
    # (σ ≈ 2, less after the smoothing along the stripes) out of it where the dark stripes are dim themselves.
    # The dark stripes' level is a fixed share of the bright stripes' beside them (the projector's slide), whatever
    # the shading, so it is expected from the brightest sample within a period along the line.
    if dark_window <= _OPENCV_MAX_WIDTH:
        line_min = cv2.erode(scan[::4], np.ones((1, dark_window), np.uint8))
    else:
        line_min = -_dilate_along_lines(-scan[::4], dark_window)
    ratios = _SCRATCH.buffer("ratios", len(sampled_scan), np.float32)
    n_lit = _lit_ratios_into(ratios, line_min, stripe_max, dark, 4)
    dark_share = median(ratios[:n_lit]) if n_lit else 0.0
    black = scratch("black", np.bool_)
    n_saturated = _black(scan, stripe_max, dark_share, black, np.float32(settings.saturation_grey))
    # Beside a wide dark area (the clamp ring, a hole) the rim of the area is black too, but it is no part of the
    # dark mask (the area is): counting it would mark a stripe more along the plate's edge as dark.
    # Black samples are few (0.6 % of a 512 × 480 frame): the area is looked for around each of them
    # (`_cracks_into`) rather than dilated over the frame (0.16 ms with the selections).
    black_bytes = black.reshape(-1).view(np.uint8)
    black_words = black_bytes[: len(black_bytes) // 8 * 8].view(np.uint64)
    any_crack = _cracks_into(dark, black_bytes, black_words, area_u8, dark_window, any_area)
    dark_u8 = dark.view(np.uint8) if any_crack else area_u8  # 0 and 1, as dark is not changed again
    # The dark area as the mid-level leaves it out (see below). A window of wide stripes (beyond MAX_PERIOD_PX) holds
    # no dark stripe but the edge's own: there the first half period of a dark area (the dark side of the lit edge
    # beside it) takes part unless it is black (darker than the dark stripes: the rim of a hole, the clamp).
    if period_px <= MAX_PERIOD_PX:
        dark_area = _dilate_along_lines(dark_u8, dark_window, out=scratch("dark_area", np.uint8))
    else:
        dark_area = dark_u8 | black.astype(np.uint8)

    # The contrast from the envelopes I_max, I_min over the window along each line, averaged over the window to
    # steady them; the mid-level from the mean grey level over one and over two periods (`_mid_and_contrast`).
    # Dark-area pixels take no part: next to the clamp or a hole the minimum would otherwise be the dark area,
    # not the dark stripe, and pull the mid-level (and the last edges) off by a tenth of a pixel.
    # What sets an edge lies within a blur width of it: beyond MAX_PERIOD_PX (Gray-code bit frames) the windows
    # and reaches below are those of a MAX_PERIOD_PX period (see MAX_FIXED_PERIOD_PX).
    local_period_px = min(float(period_px), MAX_PERIOD_PX)
    window = _odd(settings.window_periods * local_period_px)
    line_kernel = np.ones((1, window), np.uint8)
    if dark_window <= window <= _OPENCV_MAX_WIDTH:
        # The maximum over the window is the maximum over the period's window (stripe_max) of those over the rest
        # (both clipped alike at the line's ends): a dilation 5 samples wide instead of 15 at a 10 px period.
        local_max = cv2.dilate(stripe_max, np.ones((1, window - dark_window + 1), np.uint8),
                               dst=scratch("local_max", np.float32))  # fmt: skip
    else:
        local_max = cv2.dilate(scan, line_kernel, dst=scratch("local_max", np.float32))
    lit_or_not = _where_dark(scan, dark_area, np.float32(4.0 * FULL_SCALE), scratch("float", np.float32))
    local_min = cv2.erode(lit_or_not, line_kernel, dst=scratch("local_min", np.float32))
    mid, contrast = scratch("mid", np.float32), scratch("contrast", np.float32)
    _mid_and_contrast(
        scan, local_max, local_min, dark_area, window, float(period_px), settings.mid_level == "means", mid, contrast
    )

    # Near dark areas (along the lines; across them, within the reach of the smoothing along the stripes, which
    # mixes dark lines into their neighbours). The dark mask starts half a period inside a dark area; transitions
    # within a period of it (half a period beside the area) or of a crack have their stripe cut by it, and are
    # rejected, but the lit edge beside a dark area that is not black is kept: where the area is black (a hole,
    # the clamp, a black shadow: darker than the dark stripes beside it; a black sample within a period) its rim
    # may cut a stripe anywhere, and they are rejected; where it is not (the background of a dim scene, whose dark
    # stripes are as dark), only those inside it (within a quarter period of the mask) are, and the rest
    # (`beside`) are kept where their stripe is whole (`_whole_beside_dark`). From one side a rim that cut a
    # stripe looks like a stripe edge, so the kept ones are flagged (`FrameEdges.beside_dark`) and no link
    # resting on them carries the fringe order (`order_edges`; docs/method.md §5).
    reach_lines = 2 * half + 3
    grow = np.ones((reach_lines, 2 * dark_window - 1), np.uint8)
    quarter = 2 * max(1, int(round(0.25 * local_period_px))) + 1
    if (any_area or any_crack) and period_px <= MAX_PERIOD_PX and dark_window <= _OPENCV_MAX_WIDTH:
        # dark_area is dark_u8 dilated by dark_window along the lines: dilated by dark_window more (and across the
        # lines) it is the same as dark_u8 by grow (2·dark_window − 1), at a narrower kernel (0.067 -> 0.049 ms).
        cut = cv2.dilate(dark_area, np.ones((reach_lines, dark_window), np.uint8), dst=scratch("cut", np.uint8))
    elif any_area or any_crack:
        cut = _dilate_along_lines(dark_u8, grow.shape[1], lines=reach_lines, out=scratch("cut", np.uint8))
    else:
        cut = scratch("cut", np.uint8)
        cut.fill(0)
    saturated_fraction = n_saturated / scan.size
    # Near the first and last lines the smoothing along the stripes mirrors the image, which bends an inclined
    # edge: no crossings there.
    margin_lines = half if settings.presmooth_px > 0 else 0
    keep_beside = any_area
    line, t_raw, polarity, mid_at, slope_at, contrast_at = _crossings(
        scan, mid, contrast, local_max, None if keep_beside else cut,
        min_contrast_grey=float(settings.min_contrast_grey), saturation_grey=float(settings.saturation_grey),
        margin_lines=margin_lines,
    )  # fmt: skip
    # Decided per crossing (few lie within the cut's reach) rather than per pixel: no dilation more.
    beside = np.zeros(len(line), bool)
    # The crossings kept, as indices into _crossings' arrays where some are dropped here: the arrays the rules below
    # do not read are selected once, after them (each selection is a fresh array, faulted in page by page).
    index = None
    if keep_beside:
        near = _near_dark_kernel(cut, area_u8, black, line, t_raw, reach_lines // 2, quarter // 2, grow.shape[1] // 2)
        kept = near != NEAR_DARK_REJECTED
        if not kept.all():
            index = np.flatnonzero(kept)
            line, t_raw, near = line[index], t_raw[index], near[index]
        beside = near == NEAR_DARK_BESIDE

    keep = _without_glitches(line, t_raw, min_gap_px=0.25 * 0.5 * local_period_px)
    if keep_beside:
        at = beside[keep]
        whole = _without_slivers(line[keep], t_raw[keep], beside=at, lone_is_sliver=period_px <= MAX_PERIOD_PX)
        keep[keep] = whole
        keep[keep] = _whole_beside_dark(line[keep], t_raw[keep], at[whole], period_px=float(period_px))
    else:
        keep[keep] = _without_slivers(line[keep], t_raw[keep], lone_is_sliver=period_px <= MAX_PERIOD_PX)
    line, t_raw, beside = line[keep], t_raw[keep], beside[keep]
    index = keep if index is None else index[keep]
    polarity, mid_at, slope_at, contrast_at = (a[index] for a in (polarity, mid_at, slope_at, contrast_at))
    # Where the light bends within a period (a soft shadow's rim) the mid-level cannot follow it: the edge moves by
    # the shift this predicts, half of which enters its σ (SIGMA_PER_SHIFT); where the shift is beyond the setting,
    # the edge is rejected.
    # The mid-level is the means' where the two periods reach no dark area nor the line's end, else the envelopes'
    # (`_mid_and_contrast`): the two differ by a few grey levels, so a crossing's bend is measured against
    # neighbours whose mid-level is of its own kind only.
    # Stripes wider than MAX_PERIOD_PX (Gray-code bits) are placed from their own two sides only (the windows stay
    # at that size): their neighbours lie a whole stripe away, so the line through their mid-levels says nothing
    # about the light at this edge, and no shift is predicted.
    if period_px > MAX_PERIOD_PX:
        shift_px = np.zeros(len(line))
    else:
        shift_px = uneven_light_shift_px(
            dark_area, line, t_raw, polarity, mid_at, slope_at, period_px=float(period_px),
            from_means=settings.mid_level == "means",
        )  # fmt: skip
    even = np.ones(len(line), bool)
    if settings.max_uneven_light_shift_px is not None:
        even = shift_px <= settings.max_uneven_light_shift_px
    uneven_blocks = (line[~even] // UNUSABLE_BLOCK_PX, t_raw[~even].astype(np.int64) // UNUSABLE_BLOCK_PX)
    if not even.all():
        line, t_raw, polarity, shift_px, beside = line[even], t_raw[even], polarity[even], shift_px[even], beside[even]
        slope_at, contrast_at = slope_at[even], contrast_at[even]

    chain = _link_chains(line, t_raw, polarity, n_samples=n_samples, max_step_px=settings.max_link_step_px_per_line,
                         across_gaps=settings.link_across_lost_crossing)  # fmt: skip
    long_enough, chain = _long_chains(chain, int(settings.min_edge_length_lines))
    line, t_raw, polarity, shift_px, beside, slope_at, contrast_at = _selected(
        long_enough, len(chain), line, t_raw, polarity, shift_px, beside, slope_at, contrast_at
    )

    if settings.edge_smoothing_lines > 0 and len(line):
        t_px, by_chain = _smooth_along_chains(line, t_raw, chain, sigma_lines=settings.edge_smoothing_lines)
        # the residuals in the thread's buffer: a fresh one is faulted in page by page (np.square is numpy's ** 2)
        residual = np.subtract(t_raw, t_px, out=_SCRATCH.buffer("residual", len(t_raw), np.float64)[: len(t_raw)])
        noise_px = float(np.sqrt(np.mean(np.square(residual, out=residual))))
    else:
        t_px, by_chain = t_raw, None
        noise_px = float("nan")
    # An edge that departs from its neighbours on its line (a stripe's flank dimmed by a shadow's rim the bend does
    # not see) is rejected, said as uneven light, and so is one whose stripes either side alternate in width (one
    # widened, the other narrowed by the same rim), with its neighbours on the line. Judged on the smoothed
    # positions of every kept edge at once: rejecting some first would leave their neighbours unjudged.
    judged = settings.max_departure_px is not None or settings.max_end_departure_px is not None
    if (judged or settings.max_width_alternation_px is not None) and period_px <= MAX_PERIOD_PX and len(line):
        alternating, departing = _uneven_edges(line, t_px, polarity, period_px=float(period_px), settings=settings)
        # The rim that moved an edge crosses the stripes at an angle: on the lines beside it it moves the same edge
        # less, by too little for its widths to alternate, but enough beside a deep shadow's interior, where the
        # stripes fold (`ALTERNATION_ALONG_CURVE_LINES`).
        if ALTERNATION_ALONG_CURVE_LINES > 0 and alternating.any():
            first, order = by_chain if by_chain is not None else _by_chain(chain, int(chain.max()) + 1)
            alternating |= _along_curves(_int_labels(line), first, order, alternating, ALTERNATION_ALONG_CURVE_LINES)
        even = ~(alternating | departing)
        if not even.all():
            uneven_blocks = (
                np.concatenate([uneven_blocks[0], line[~even] // UNUSABLE_BLOCK_PX]),
                np.concatenate([uneven_blocks[1], t_raw[~even].astype(np.int64) // UNUSABLE_BLOCK_PX]),
            )
            line, t_raw, t_px, polarity, chain, shift_px, beside, slope_at, contrast_at = (
                a[even] for a in (line, t_raw, t_px, polarity, chain, shift_px, beside, slope_at, contrast_at)
            )
            if by_chain is None:
                chain = _dense_labels(chain, int(chain.max()) + 1)
            else:  # the kept points' chain order is the old one's, less the rest
                chain, by_chain = _kept_by_chain(by_chain[0], by_chain[1], even)
    sigma_px = _edge_sigma(slope_at, line, t_raw, t_px, chain, shift_px, n_samples=n_samples, settings=settings,
                           by_chain=by_chain, shift_share=SIGMA_PER_SHIFT)  # fmt: skip
    unusable = _unusable_blocks(scan, dark, contrast, local_max, grow, black_level=black_level, settings=settings)
    unusable[uneven_blocks] = np.where(unusable[uneven_blocks] == UNUSABLE_NONE, UNUSABLE_UNEVEN_LIGHT,
                                       unusable[uneven_blocks])  # fmt: skip
    _SCRATCH.trim(SCRATCH_KEPT_MAX_BYTES)
    return FrameEdges(
        axis=axis,
        period_px=float(period_px),
        image_shape_hw_px=(int(image_shape_hw_px[0]), int(image_shape_hw_px[1])),
        line=line,
        t_px=t_px.astype(np.float32),
        polarity=polarity,
        chain=chain,
        noise_px=noise_px,
        saturated_fraction=saturated_fraction,
        dark_fraction=np.count_nonzero(dark) / dark.size,
        unusable=unusable,
        sigma_px=sigma_px,
        contrast_grey=contrast_at,
        beside_dark=beside,
    )


def _edge_sigma(
    slope_grey: np.ndarray,
    line: np.ndarray,
    t_raw: np.ndarray,
    t_px: np.ndarray,
    chain: np.ndarray,
    shift_px: np.ndarray,
    *,
    n_samples: int,
    settings: EdgeSettings,
    by_chain: tuple[np.ndarray, np.ndarray] | None = None,
    shift_share: float = 1.0,
) -> np.ndarray:
    """Each edge point's σ (px) of its smoothed position, (N,) float32, from the frame itself (docs/method.md §5,
    "How sure an edge is"). slope_grey (N,) float32: |I₁ − I₀| of the samples straddling each raw position
    (`_crossings`, gathered there in the scan lines' order); n_samples: samples a scan line.

    A crossing placed between the straddling samples I₀, I₁ (a fraction x of the way) by the chord moves by
    δt = (δI₀·(1 − x) + δI₁·x) / (I₁ − I₀) for noise δI on the presmoothed samples: with the local grey noise σ_I
    its σ is σ_I·√((1 − x)² + x²) / |I₁ − I₀|, so a faint or blurred edge (small slope) is less sure. σ_I is not
    assumed: the raw − smoothed residuals of the positions along the edge (over ±2 smoothing half-widths) say how
    much the edge actually jitters, and divided by what that model predicts for unit noise they give σ_I there,
    drawn toward the frame's own value where the stretch is short (8 points' weight), since few residuals
    estimate it poorly. The smoothing then reduces it by its noise gain at that point (`smoothing_noise_tables`:
    more at an edge's end, where the fit is one-sided). An error the smoothing cannot reduce comes from the
    mid-level where the light bends within a period (a shadow's rim, a highlight): the shift that bend predicts,
    shift_share × shift_px (N,) (`uneven_light_shift_px`), is added in quadrature. NaN σ (but the contrast)
    without smoothing along the edges. by_chain: the points grouped by chain as `_smooth_along_chains` gave them
    (`_by_chain`'s first and order), None to group them here.
    """
    sigma = np.full(len(line), np.nan, np.float32)
    if len(line) == 0:
        return sigma
    smoothing = settings.edge_smoothing_lines
    if smoothing > 0:
        gain, residual = smoothing_noise_tables(float(smoothing), presmooth_px=float(settings.presmooth_px))
    else:
        gain = residual = np.full((1, 1), np.nan)
    first, order = by_chain if by_chain is not None else (np.zeros(0, np.int64), np.zeros(0, np.int64))
    # The kernel's working arrays are the thread's (`_FrameScratch`): fresh, their 80 bytes a point were faulted in
    # page by page each frame (2.1 of 3.9 ms a 1024² frame).
    n = len(line)

    def work(name: str, length: int) -> np.ndarray:
        return _SCRATCH.buffer(name, length, np.float64)

    _edge_sigma_kernel(
        np.ascontiguousarray(slope_grey, np.float32), int(n_samples), _int_labels(line),
        np.ascontiguousarray(t_raw, np.float64), np.ascontiguousarray(t_px, np.float64),
        _int_labels(chain), gain, residual, np.ascontiguousarray(shift_px, np.float64), float(shift_share), sigma,
        first, order, work("sigma_point", 5 * n), work("sigma_sums", 3 * (n + 1)), work("sigma_terms", 2 * n),
    )  # fmt: skip
    return sigma


# Weight, in edge points, of the frame's own noise level against an edge's local one (`_edge_sigma`).
FRAME_NOISE_WEIGHT_POINTS = 20.0


@numba.njit(cache=True, nogil=True)
def _by_chain(chain: np.ndarray, n_chains: int) -> tuple[np.ndarray, np.ndarray]:
    """Points grouped by chain (a counting sort): order (N,) lists chain c's points at order[first[c]:first[c + 1]],
    first (n_chains + 1,); a chain's points keep their input order (line order, the input being sorted by line)."""
    n = len(chain)
    first = np.zeros(n_chains + 1, np.int64)
    for i in range(n):
        first[chain[i] + 1] += 1
    for c in range(n_chains):
        first[c + 1] += first[c]
    order = np.empty(n, np.int64)
    fill = first[:-1].copy()
    for i in range(n):
        order[fill[chain[i]]] = i
        fill[chain[i]] += 1
    return first, order


@numba.njit(cache=True, nogil=True)
def _selected(
    keep: np.ndarray,
    m: int,
    line: np.ndarray,
    t: np.ndarray,
    polarity: np.ndarray,
    shift: np.ndarray,
    beside: np.ndarray,
    slope: np.ndarray,
    contrast: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The crossings' arrays (N,) at keep (N,) bool, of which m are true, in one pass (seven boolean selections took
    0.1 ms a 512 × 480 frame)."""
    out = (
        np.empty(m, line.dtype), np.empty(m, t.dtype), np.empty(m, polarity.dtype), np.empty(m, shift.dtype),
        np.empty(m, beside.dtype), np.empty(m, slope.dtype), np.empty(m, contrast.dtype),
    )  # fmt: skip
    k = 0
    for i in range(len(keep)):
        if keep[i]:
            out[0][k], out[1][k], out[2][k], out[3][k] = line[i], t[i], polarity[i], shift[i]
            out[4][k], out[5][k], out[6][k] = beside[i], slope[i], contrast[i]
            k += 1
    return out


@numba.njit(cache=True, nogil=True)
def _long_chains(chain: np.ndarray, min_length: int) -> tuple[np.ndarray, np.ndarray]:
    """The crossings of chains of at least min_length crossings, chain (N,) labels below N (`_link_chains`): which,
    (N,) bool, and their chains renumbered 0..n_chains − 1 in the order of the labels, (M,) int32 (as `_dense_labels`
    of theirs), in one counting pass (a bincount, a gather, a selection and a renumbering took 0.4 ms a 1024² frame)."""
    n = len(chain)
    dense = np.zeros(n, np.int64)  # each label's count, then its new label (−1: dropped)
    for i in range(n):
        dense[chain[i]] += 1
    n_chains = 0
    for label in range(n):
        if dense[label] > 0 and dense[label] >= min_length:
            dense[label] = n_chains
            n_chains += 1
        else:
            dense[label] = -1
    keep = np.empty(n, np.bool_)
    m = 0
    for i in range(n):
        keep[i] = dense[chain[i]] >= 0
        m += keep[i]
    kept = np.empty(m, np.int32)
    k = 0
    for i in range(n):
        if keep[i]:
            kept[k] = dense[chain[i]]
            k += 1
    return keep, kept


def _dense_labels(chain: np.ndarray, n_labels: int) -> np.ndarray:
    """Chain labels (N,) below n_labels renumbered 0..n_chains − 1 in the order of the labels, (N,) int32."""
    renumber = np.cumsum(np.bincount(chain, minlength=n_labels) > 0) - 1
    return renumber[chain].astype(np.int32)


@numba.njit(cache=True, nogil=True)
def _kept_by_chain(
    first: np.ndarray, order: np.ndarray, keep: np.ndarray
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """The points kept (keep (N,) bool) of chains grouped by `_by_chain` (first, order): their chain labels
    renumbered 0..n − 1 in the old labels' order (chains left empty dropped), (M,) int32, and `_by_chain`'s first
    and order of them (M = keep.sum()), without sorting again."""
    n = len(keep)
    index = np.empty(n, np.int64)  # each kept point's index among the kept
    m = 0
    for p in range(n):
        index[p] = m
        m += keep[p]
    chain = np.empty(m, np.int32)
    new_first = np.zeros(len(first), np.int64)
    new_order = np.empty(m, np.int64)
    c_new = 0
    q_new = 0
    for c in range(len(first) - 1):
        start = q_new
        for q in range(first[c], first[c + 1]):
            p = order[q]
            if keep[p]:
                new_order[q_new] = index[p]
                chain[index[p]] = c_new
                q_new += 1
        if q_new > start:
            c_new += 1
            new_first[c_new] = q_new
    return chain, (new_first[: c_new + 1].copy(), new_order)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _edge_sigma_kernel(
    slope_grey: np.ndarray,
    n_samples: int,
    line: np.ndarray,
    t_raw: np.ndarray,
    t_px: np.ndarray,
    chain: np.ndarray,
    gain: np.ndarray,
    residual: np.ndarray,
    shift: np.ndarray,
    shift_share: float,
    sigma_out: np.ndarray,
    first: np.ndarray,
    order: np.ndarray,
    point_buffer: np.ndarray,
    cum_buffer: np.ndarray,
    terms_buffer: np.ndarray,
) -> None:
    """`_edge_sigma`; first and order: `_by_chain` of chain, or empty to compute them here; point_buffer,
    cum_buffer, terms_buffer: float64 room for 5N, 3(N + 1) and 2N items, the working arrays below."""
    n = len(line)
    half = gain.shape[0] - 1
    smoothed = np.isfinite(gain[0, 0])
    if not smoothed:
        return
    n_chains = chain.max() + 1
    if len(first) != n_chains + 1:
        first, order = _by_chain(chain, n_chains)
    # Lines each chain starts and ends on (a curve may skip a line: `_link_chains`).
    ends = np.empty((n_chains, 2), np.int64)
    for c in range(n_chains):
        ends[c, 0], ends[c, 1] = line[order[first[c]]], line[order[first[c + 1] - 1]]
    # Per point, in line order, what the passes in chain order below take of it, side by side: its raw − smoothed
    # residual², the model's residual² and the model² (the σ of its raw position for unit grey noise, px), its
    # smoothing's gain² and its shift². Those passes visit the points a line's worth of points apart in memory: one
    # cache line a point instead of one for each array (3.5 → 2.3 ms a 1024² frame), and no read of its line.
    point = point_buffer[: 5 * n].reshape((n, 5))
    for p in range(n):
        j = min(max(int(t_raw[p]), 0), n_samples - 2)
        x = t_raw[p] - j
        slope = max(slope_grey[p], 1e-3)
        m = np.sqrt((1.0 - x) ** 2 + x * x) / slope
        r = t_raw[p] - t_px[p]
        # Lines of the curve before and after the point.
        b, a = min(line[p] - ends[chain[p], 0], half), min(ends[chain[p], 1] - line[p], half)
        point[p, 0] = r * r
        point[p, 1] = (m * residual[b, a]) ** 2
        point[p, 2] = m * m
        point[p, 3] = gain[b, a] ** 2
        point[p, 4] = (shift_share * shift[p]) ** 2
    # Prefix sums along the sorted order of: residual², the model's residual² for unit noise, the model².
    cum = cum_buffer[: 3 * (n + 1)].reshape((n + 1, 3))  # rows 1..n are written below, chain after chain
    cum[0] = 0.0
    # What the second pass needs of each point besides the sums, in the sorted order too: it reads nothing by point
    # (a cache miss each at 1024²) but writes σ.
    terms = terms_buffer[: 2 * n].reshape((n, 2))
    for q in range(n):
        p = order[q]
        cum[q + 1, 0] = cum[q, 0] + point[p, 0]
        cum[q + 1, 1] = cum[q, 1] + point[p, 1]
        cum[q + 1, 2] = cum[q, 2] + point[p, 2]
        terms[q, 0], terms[q, 1] = point[p, 3], point[p, 4]
    frame_noise2 = cum[n, 0] / cum[n, 1] if cum[n, 1] > 0 else np.nan
    reach = 3 * half
    for c in range(n_chains):
        lo, hi = first[c], first[c + 1]
        for q in range(lo, hi):
            w_lo, w_hi = max(q - reach, lo), min(q + reach + 1, hi)
            pred = cum[w_hi, 1] - cum[w_lo, 1]
            prior = FRAME_NOISE_WEIGHT_POINTS * pred / (w_hi - w_lo)
            noise2 = frame_noise2
            if pred > 0:
                noise2 = (cum[w_hi, 0] - cum[w_lo, 0] + prior * frame_noise2) / (pred + prior)
            s_lo, s_hi = max(q - half, lo), min(q + half + 1, hi)
            model2 = (cum[s_hi, 2] - cum[s_lo, 2]) / (s_hi - s_lo)
            sigma_out[order[q]] = np.sqrt(terms[q, 0] * noise2 * model2 + terms[q, 1])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _mid_and_contrast(
    scan: np.ndarray,
    local_max: np.ndarray,
    local_min: np.ndarray,
    dark_area: np.ndarray,
    window: int,
    period: float,
    from_means: bool,
    mid: np.ndarray,
    contrast: np.ndarray,
) -> None:
    """The mid-level and the contrast along each scan line, written into mid and contrast, each (S, T) float32 (NaN
    where the whole window is dark).

    Contrast: the envelopes averaged over `window` samples along the line, dark-area samples left out,
    I_max − I_min (mirrored at the line ends without repeating the end sample, OpenCV's BORDER_REFLECT_101).

    Mid-level: the mean grey level over one period and over two periods centred on the sample, averaged:
    (⟨I⟩_P + ⟨I⟩_2P)/2. A window of a whole number of periods holds as much bright stripe as dark whatever its
    phase, and centred on an edge it does so whatever the local period (the stripe on either side is cut alike),
    so under even light the mean is the mid-level exactly. Under light L(u) that changes along the line, the
    one-period mean is off by −L′(1 − d)P/8 at an edge (d: the dark stripes' share of the bright ones; the
    bright stripe is on one side of the edge) and the two-period mean by +L′(1 − d)P/8: their average follows
    the light to first order, where the envelopes' mid-level (I_max + I_min)/2 follows the brightest stripe in
    the window and misplaced edges by a pixel and more at a soft shadow's rim. What is left is the light's
    curvature over a period. Noise is averaged over 1.5 periods of samples instead of picked
    by a maximum. Where the two periods reach a dark area or the line's end, the envelopes' (I_max + I_min)/2
    is taken instead. The window is fractional: sample k covers [k − ½, k + ½].
    """
    n_lines, n_samples = local_max.shape
    half = window // 2
    grey_sum = np.empty(n_samples + 1)
    dark_sum = np.empty(n_samples + 1)
    first, sample, fraction, regular_end = _period_ends(n_samples, period)
    for i in range(n_lines):
        count = 0.0
        sum_max = 0.0
        sum_min = 0.0
        for j in range(-half, half):
            k = _reflect_101(j, n_samples)
            if dark_area[i, k] == 0:
                count += 1.0
                sum_max += local_max[i, k]
                sum_min += local_min[i, k]
        grey_sum[0] = dark_sum[0] = grey = dark = 0.0
        for j in range(n_samples):
            # The cumulative sums for the means, in the same pass (an independent chain of additions).
            grey += scan[i, j]
            dark += dark_area[i, j]
            grey_sum[j + 1], dark_sum[j + 1] = grey, dark
            entering = _reflect_101(j + half, n_samples)
            if dark_area[i, entering] == 0:
                count += 1.0
                sum_max += local_max[i, entering]
                sum_min += local_min[i, entering]
            if count > 0:
                high, low = sum_max / count, sum_min / count
                mid[i, j] = 0.5 * (high + low)
                contrast[i, j] = high - low
            else:
                mid[i, j] = contrast[i, j] = np.nan
                sum_max = sum_min = 0.0  # no rounding residue carried past a dark stretch
            leaving = _reflect_101(j - half, n_samples)
            if dark_area[i, leaving] == 0:
                count -= 1.0
                sum_max -= local_max[i, leaving]
                sum_min -= local_min[i, leaving]
        if from_means:
            _means_of_line(grey_sum, dark_sum, mid[i], first, period, sample, fraction, regular_end)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _period_ends(n_samples: int, period: float) -> tuple[int, np.ndarray, np.ndarray, int]:
    """Where the means over one and over two periods centred on samples j = first … n_samples − first − 1 start and
    end, as the same for every line: first; sample (4, J) int64 and fraction (4, J) float64, for the ends
    j + P/2, j − P/2, j + P, j − P, such that the integral of a line's grey levels from −½ to the end is
    cumulative[sample] + fraction·(cumulative[sample + 1] − cumulative[sample]) (sample k covers [k − ½, k + ½];
    cumulative[k] is the sum of samples 0..k−1); and regular_end, the j up to which (exclusive) each end's sample
    is j plus a constant (the case `_means_of_line` computes with contiguous loads)."""
    first = int(np.ceil(period - 0.5))
    count = max(n_samples - 2 * first, 0)
    sample = np.empty((4, count), np.int64)
    fraction = np.empty((4, count))
    regular_end = first + count
    for q in range(count):
        j = first + q
        for e in range(4):
            position = (
                j + 0.5 * period if e == 0 else j - 0.5 * period if e == 1 else j + period if e == 2 else j - period
            )
            u = position + 0.5
            k = min(int(u), n_samples - 1)
            sample[e, q], fraction[e, q] = k, u - k
            if k - j != sample[e, 0] - first and regular_end == first + count:
                regular_end = j
    return first, sample, fraction, regular_end


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _means_of_line(
    grey_sum: np.ndarray,
    dark_sum: np.ndarray,
    mid_row: np.ndarray,
    first: int,
    period: float,
    sample: np.ndarray,
    fraction: np.ndarray,
    regular_end: int,
) -> None:
    """The mid-level of one line from its means over one and two periods (`_mid_and_contrast`), written into
    mid_row where the two periods touch no dark-area sample; grey_sum, dark_sum (T + 1,) the line's cumulative sums.
    Up to regular_end each end's sample is j plus a constant, so the loads are contiguous and the loop vectorises."""
    n_samples = len(mid_row)
    count = regular_end - first
    if count > 0:
        a = sample[:, 0] - first
        g0, g1, g2, g3 = (
            grey_sum[first + a[0] :],
            grey_sum[first + a[1] :],
            grey_sum[first + a[2] :],
            grey_sum[first + a[3] :],
        )
        f0, f1, f2, f3 = fraction[0], fraction[1], fraction[2], fraction[3]
        # Samples the two periods touch, inclusive: j − first … j + first.
        dark_after, dark_before = dark_sum[2 * first + 1 :], dark_sum[:]
        out = mid_row[first:]
        for q in range(count):
            one = (g0[q] + f0[q] * (g0[q + 1] - g0[q])) - (g1[q] + f1[q] * (g1[q + 1] - g1[q]))
            two = (g2[q] + f2[q] * (g2[q + 1] - g2[q])) - (g3[q] + f3[q] * (g3[q + 1] - g3[q]))
            value = np.float32(0.5 * (one + 0.5 * two) / period)
            out[q] = value if dark_after[q] == dark_before[q] else out[q]
    for j in range(max(regular_end, first), n_samples - first):
        q = j - first
        if dark_sum[j + first + 1] - dark_sum[j - first] > 0:
            continue
        k0, k1, k2, k3 = sample[0, q], sample[1, q], sample[2, q], sample[3, q]
        one = (grey_sum[k0] + fraction[0, q] * (grey_sum[k0 + 1] - grey_sum[k0])) - (
            grey_sum[k1] + fraction[1, q] * (grey_sum[k1 + 1] - grey_sum[k1])
        )
        two = (grey_sum[k2] + fraction[2, q] * (grey_sum[k2 + 1] - grey_sum[k2])) - (
            grey_sum[k3] + fraction[3, q] * (grey_sum[k3 + 1] - grey_sum[k3])
        )
        mid_row[j] = 0.5 * (one + 0.5 * two) / period


@numba.njit(cache=True, nogil=True)
def _reflect_101(index: int, n: int) -> int:
    """The sample an index beyond a line of n samples mirrors to (…, 2, 1 | 0, 1, …, n − 1 | n − 2, …)."""
    if n == 1:
        return 0
    while index < 0 or index >= n:
        index = -index if index < 0 else 2 * (n - 1) - index
    return index


@numba.njit(cache=True, nogil=True)
def _dim_across(stripe_max: np.ndarray, level: np.float32, dark: np.ndarray, area: np.ndarray) -> bool:
    """dark (S, T) bool and area (S, T) uint8 (0 or 1), both filled: stripe_max (S, T) float32 below level (compared
    in float32) on the line and on the lines either side that exist, i.e. its maximum over three lines below it, in
    one pass (OpenCV's 3 × 1 dilation and the comparison took 0.19 ms a 512 × 480 frame); whether any is."""
    n_lines, n_samples = stripe_max.shape
    found = np.uint8(0)
    for i in range(n_lines):
        before, here, after = stripe_max[max(i - 1, 0)], stripe_max[i], stripe_max[min(i + 1, n_lines - 1)]
        row, area_row = dark[i], area[i]
        for j in range(n_samples):
            is_dark = (before[j] < level) & (here[j] < level) & (after[j] < level)
            row[j] = is_dark
            area_row[j] = is_dark
            found |= area_row[j]
    return found != 0


@numba.njit(cache=True, nogil=True)
def _cracks_into(
    dark: np.ndarray, black: np.ndarray, black_words: np.ndarray, area: np.ndarray, half_width: int, any_area: bool
) -> bool:
    """Marks in dark (S, T) bool the cracks: the black samples (black, the (S·T,) bytes of an (S, T) bool, and
    black_words, its first ⌊S·T/8⌋ eight-byte words) with no
    dark-area sample (area (S, T) uint8, any_area whether it has one) on their line or the lines either side within
    half_width samples along the line (clipped at the frame's edges: OpenCV's 3 × (2·half_width + 1) dilation of
    the area, at the black samples only); whether there was one. Black samples are few: eight bytes are skipped at
    a time where none is."""
    n_lines, n_samples = dark.shape
    n = n_lines * n_samples
    flat_dark = dark.reshape(n)
    found = False
    n_words = len(black_words)
    for word in range(n_words + (n > 8 * n_words)):
        if word < n_words and black_words[word] == 0:
            continue
        for index in range(8 * word, min(8 * word + 8, n)):
            if black[index] == 0:
                continue
            i, j = index // n_samples, index % n_samples
            beside = False
            if any_area:
                lo, hi = max(j - half_width, 0), min(j + half_width, n_samples - 1)
                for r in range(max(i - 1, 0), min(i + 1, n_lines - 1) + 1):
                    area_row = area[r]
                    for k in range(lo, hi + 1):
                        if area_row[k] != 0:
                            beside = True
                            break
                    if beside:
                        break
            if not beside:
                flat_dark[index] = True
                found = True
    return found


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lit_ratios_into(
    out: np.ndarray, sampled: np.ndarray, denominator: np.ndarray | None, dark: np.ndarray, step: int
) -> int:
    """Gathers into out (≥ M,) float32 the samples of every step-th sample of every step-th line (sampled
    (⌈S/step⌉, T) float32: those lines) that are not dark (dark (S, T) bool), divided (in float32) by denominator
    (S, T) float32 there where given and only where it is positive, in the lines' order; returns M, the number
    gathered (a boolean selection of each strided view and a division took 0.2 ms a 512 × 480 frame)."""
    m = 0
    for i in range(0, dark.shape[0], step):
        row, dark_row = sampled[i // step], dark[i]
        if denominator is None:
            for j in range(0, dark.shape[1], step):
                if not dark_row[j]:
                    out[m] = row[j]
                    m += 1
        else:
            below = denominator[i]
            for j in range(0, dark.shape[1], step):
                if not dark_row[j] and below[j] > 0:
                    out[m] = np.float32(row[j] / below[j])  # rounded once from float64: float32's quotient
                    m += 1
    return m


@numba.njit(cache=True, nogil=True)
def _where_dark(scan: np.ndarray, dark_area: np.ndarray, value: np.float32, out: np.ndarray) -> np.ndarray:
    """out (S, T) float32, filled and returned: `value` where dark_area (S, T) uint8 is non-zero, scan elsewhere, in
    one pass (a copy and a masked fill took 0.5 ms a 1024² frame)."""
    n_lines, n_samples = scan.shape
    for i in range(n_lines):
        scan_row, dark_row, out_row = scan[i], dark_area[i], out[i]
        for j in range(n_samples):
            out_row[j] = value if dark_row[j] else scan_row[j]
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _black(
    scan: np.ndarray, stripe_max: np.ndarray, dark_share: float, black: np.ndarray, saturation: np.float32
) -> int:
    """black (S, T) bool, filled: below BLACK_FRACTION of the dark stripes' level expected there (dark_share of the
    brightest sample within a period) and more than BLACK_MARGIN_GREY below it (see `locate_edges`). Returns the
    number of samples at or above saturation (compared in float32, as numpy did), counted in the same pass."""
    n_lines, n_samples = scan.shape
    n_saturated = 0
    for i in range(n_lines):
        for j in range(n_samples):
            dark_level = dark_share * stripe_max[i, j]
            black[i, j] = scan[i, j] < BLACK_FRACTION * dark_level and dark_level - scan[i, j] > BLACK_MARGIN_GREY
            n_saturated += scan[i, j] >= saturation
    return n_saturated


def _unusable_blocks(
    scan: np.ndarray,
    dark: np.ndarray,
    contrast: np.ndarray,
    local_max: np.ndarray,
    grow: np.ndarray,
    *,
    black_level: float,
    settings: EdgeSettings,
) -> np.ndarray:
    """Why no edge can be located, per block of UNUSABLE_BLOCK_PX² pixels (see `FrameEdges.unusable`).

    Black: dark and within 8 grey levels (or a quarter of the way to the dark stripes) of the frame's black level
    (black_level, the 1st percentile of every 4th sample of every 4th line: the background beyond the clamp, a
    hole); dark but brighter than that: a shadow (the plate lit by the room but not by the projector); low contrast:
    neither, but the stripes' contrast is below min_contrast_grey or their bright side clipped.
    """
    lit = _SCRATCH.buffer("lit", -(-scan.shape[0] // 4) * -(-scan.shape[1] // 4), np.float32)
    n_lit = _lit_ratios_into(lit, scan[::4], None, dark, 4)
    stripes_dark = percentile(lit[:n_lit], 10) if n_lit else black_level
    margin = max(BLACK_MARGIN_GREY, 0.25 * (stripes_dark - black_level))
    block = UNUSABLE_BLOCK_PX
    # The worst reason in each block, then as far as edges are rejected near dark areas (see `locate_edges`; the
    # larger code wins), at the blocks' scale.
    worst = _worst_reason_per_block(
        scan, dark, contrast, local_max, float(settings.min_contrast_grey), float(settings.saturation_grey),
        black_level + margin,
    )  # fmt: skip
    reach = _dilate_along_lines(worst, -(-grow.shape[1] // block) | 1, lines=-(-grow.shape[0] // block) | 1)
    return np.ascontiguousarray(reach)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _worst_reason_per_block(
    scan: np.ndarray,
    dark: np.ndarray,
    contrast: np.ndarray,
    local_max: np.ndarray,
    min_contrast: float,
    saturation: float,
    black_below: float,
) -> np.ndarray:
    """The largest UNUSABLE_* code of the pixels of each UNUSABLE_BLOCK_PX² block, shape (⌈H/b⌉, ⌈W/b⌉)."""
    block = UNUSABLE_BLOCK_PX  # a constant to the compiler: the divisions below become shifts
    height, width = scan.shape
    n_blocks = (width + block - 1) // block
    worst = np.zeros(((height + block - 1) // block, n_blocks), np.uint8)
    # Each row's codes first (selects, no branches: the loop vectorises), then their maximum per block.
    codes = np.zeros(n_blocks * block, np.uint8)
    for y in range(height):
        scan_row, dark_row, contrast_row, max_row = scan[y], dark[y], contrast[y], local_max[y]
        for x in range(width):
            dark_code = np.uint8(UNUSABLE_BLACK) if scan_row[x] < black_below else np.uint8(UNUSABLE_DARK)
            usable = contrast_row[x] >= min_contrast and max_row[x] < saturation
            lit_code = np.uint8(UNUSABLE_NONE) if usable else np.uint8(UNUSABLE_LOW_CONTRAST)
            codes[x] = dark_code if dark_row[x] else lit_code
        worst_row = worst[y // block]
        for b in range(n_blocks):
            code = worst_row[b]
            for q in range(block):
                code = max(code, codes[b * block + q])
            worst_row[b] = code
    return worst


def _crossings(
    scan: np.ndarray,
    mid: np.ndarray,
    contrast: np.ndarray,
    local_max: np.ndarray,
    near_dark: np.ndarray | None,
    *,
    min_contrast_grey: float,
    saturation_grey: float,
    margin_lines: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every mid-level crossing of the scan lines between two usable samples, sorted by (line, t): line (N,)
    int32, t (N,) float64 px, polarity (N,) int8 (+1 where the grey level rises along +t), the mid-level there
    (N,) float64 grey levels (interpolated between the straddling samples), and, for the edges' σ and the light's
    bend, the slope |I₁ − I₀| between the samples j = int(t), j + 1 and their mean contrast, each (N,) float32 grey
    levels (gathered here, where the lines are read in order, rather than later from the whole frame). They are views
    of the thread's buffers, valid until its next call.

    scan, mid, contrast, local_max: (S, T) float32; near_dark: (S, T) uint8, non-zero where edges are rejected, or
    None where none is (no frame of zeros to read).
    A sample is usable where the contrast reaches min_contrast_grey, the window's brightest sample stays below
    saturation_grey and no dark area is near. The first and last `margin_lines` lines and the first and last
    sample of every line give none (the sub-pixel fit needs a sample either side of the straddling pair).

    Sub-pixel position, the probit chord: the two straddling samples, normalised by their local envelope to
    y = (I − I_min)/(I_max − I_min) = 1/2 + (I − mid)/contrast, become z = Φ⁻¹(y), which is a straight line in
    position for a Gaussian-blurred step; the crossing is where the chord through them meets z = 0 (y = 1/2).
    The plain chord between the intensities bends with the S-shaped edge and leaves a bias that depends on the
    sub-pixel phase (pixel locking, ≈ 0.04 px at blur σ = 0.5 px); the probit chord leaves < 0.002 px for
    σ ≥ 0.5 px at the same noise. Each sample is normalised by its own envelope, so the two are on either side of
    1/2 exactly when the crossing test found them to be.
    """
    # The thread's buffers of the frame before, views of which are returned (the caller's first selection copies
    # them: `locate_edges`): fresh, they were faulted in page by page each frame (`_FrameScratch`). Where the next
    # line might not fit (a crossing a sample), the kernel stops there and they grow.
    n_lines, n_samples = scan.shape
    names = ("crossing_line", "crossing_t", "crossing_polarity", "crossing_mid", "crossing_slope", "crossing_contrast")
    types = (np.int32, np.float64, np.int8, np.float64, np.float32, np.float32)
    near = np.zeros((1, n_samples), np.uint8) if near_dark is None else near_dark  # one line of zeros read for all
    m, next_line, end_line = 0, margin_lines, n_lines - margin_lines
    length = n_samples
    while True:
        buffers = tuple(_SCRATCH.buffer(name, length, dtype, kept=m) for name, dtype in zip(names, types, strict=True))
        m, next_line = _crossings_kernel(scan, mid, contrast, local_max, near, near_dark is not None, min_contrast_grey,
                                         saturation_grey, next_line, end_line, m, *buffers)  # fmt: skip
        if next_line >= end_line:
            return tuple(buffer[:m] for buffer in buffers)  # type: ignore[return-value]
        length = m + n_samples


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _probit(y: float) -> float:
    """Φ⁻¹(y) for 0.005 ≤ y ≤ 0.995: Wichura's AS241 (PPND16), accurate to about 1e-16 (its central and
    intermediate-tail branches; |Φ⁻¹| ≤ 2.58 needs no other)."""
    q = y - 0.5
    if abs(q) <= 0.425:
        r = 0.180625 - q * q
        num = (((((((2.5090809287301226727e3 * r + 3.3430575583588128105e4) * r + 6.7265770927008700853e4) * r
                   + 4.5921953931549871457e4) * r + 1.3731693765509461125e4) * r + 1.9715909503065514427e3) * r
                + 1.3314166789178437745e2) * r + 3.3871328727963666080e0)  # fmt: skip
        den = (((((((5.2264952788528545610e3 * r + 2.8729085735721942674e4) * r + 3.9307895800092710610e4) * r
                   + 2.1213794301586595867e4) * r + 5.3941960214247511077e3) * r + 6.8718700749205790830e2) * r
                + 4.2313330701600911252e1) * r + 1.0)  # fmt: skip
        return q * num / den
    r = np.sqrt(-np.log(y if q < 0 else 1.0 - y)) - 1.6
    num = (((((((7.74545014278341407640e-4 * r + 2.27238449892691845833e-2) * r + 2.41780725177450611770e-1) * r
               + 1.27045825245236838258e0) * r + 3.64784832476320460504e0) * r + 5.76949722146069140550e0) * r
            + 4.63033784615654529590e0) * r + 1.42343711074968357734e0)  # fmt: skip
    den = (((((((1.05075007164441684324e-9 * r + 5.47593808499534494600e-4) * r + 1.51986665636164571966e-2) * r
               + 1.48103976427480074590e-1) * r + 6.89767334985100004550e-1) * r + 1.67638483018380384940e0) * r
            + 2.05319162663775882187e0) * r + 1.0)  # fmt: skip
    value = num / den
    return -value if q < 0 else value


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _crossings_kernel(
    scan: np.ndarray,
    mid: np.ndarray,
    contrast: np.ndarray,
    local_max: np.ndarray,
    near_dark: np.ndarray,
    by_line: bool,
    min_contrast: float,
    saturation: float,
    first_line: int,
    end_line: int,
    m: int,
    line_out: np.ndarray,
    t_out: np.ndarray,
    polarity_out: np.ndarray,
    mid_out: np.ndarray,
    slope_out: np.ndarray,
    contrast_out: np.ndarray,
) -> tuple[int, int]:
    """`_crossings` of lines first_line … end_line − 1 (near_dark: (S, T) by_line, else its one line for every line),
    written into the buffers (each of one length) from item m on: the number of items written in all and the line
    before which it stopped, because that line might not fit (a crossing a sample), or end_line."""
    capacity = min(len(line_out), len(t_out), len(polarity_out), len(mid_out), len(slope_out), len(contrast_out))
    n_samples = scan.shape[1]
    usable = np.empty(n_samples, np.uint8)
    above = np.empty(n_samples, np.uint8)
    flag = np.empty(n_samples, np.uint8)
    for i in range(first_line, end_line):
        if m + n_samples > capacity:
            return m, i
        scan_row, mid_row, contrast_row, max_row = scan[i], mid[i], contrast[i], local_max[i]
        near_row = near_dark[i if by_line else 0]
        # Branch-free first: which samples are usable and above the mid-level (vectorised), then which pairs
        # straddle it; the crossings, a few per period, are placed in a second loop over those pairs only.
        for j in range(n_samples):
            usable[j] = (
                np.uint8(contrast_row[j] >= min_contrast)
                & np.uint8(max_row[j] < saturation)
                & np.uint8(near_row[j] == 0)
            )
            above[j] = np.uint8((scan_row[j] - mid_row[j]) > 0)
        for j in range(1, n_samples - 2):
            flag[j] = usable[j] & usable[j + 1] & (above[j] ^ above[j + 1])
        for j in range(1, n_samples - 2):
            if flag[j] == 0:
                continue
            # The first sample's quotient in float64, the second's in float32 (c and the difference are float32), as
            # the loop carrying one sample's difference to the next did: the same positions to the last bit.
            here_diff = np.float64(scan_row[j] - mid_row[j])
            next_diff = scan_row[j + 1] - mid_row[j + 1]
            c = contrast_row[j + 1]
            y0 = min(max(0.5 + here_diff / contrast_row[j], 0.005), 0.995)
            y1 = min(max(0.5 + next_diff / c, 0.005), 0.995)
            z0, z1 = _probit(y0), _probit(y1)
            x = z0 / (z0 - z1)
            if not np.isfinite(x):
                x = 0.5
            x = min(max(x, 0.0), 1.0)
            t = j + x
            line_out[m] = i
            t_out[m] = t
            polarity_out[m] = 1 if next_diff > here_diff else -1
            mid_out[m] = mid_row[j] + x * (mid_row[j + 1] - mid_row[j])
            # The pair int(t), int(t) + 1: j + 1 where x rounds t up to it (j + 2 < n_samples).
            k = min(max(int(t), 0), n_samples - 2)
            slope_out[m] = abs(scan_row[k + 1] - scan_row[k])
            contrast_out[m] = 0.5 * (contrast_row[k] + contrast_row[k + 1])
            m += 1
    return m, end_line


# The mid-level's error at a crossing per grey level of the light's bend there (`uneven_light_shift_px`): the edge
# moves by this times the bend over the crossing's slope. Measured on soft rims along the stripes, straight stripes of
# 10 px under rims 6–20 px wide dimming them to 20–40 %: the edges' errors were 0.2–0.9 × |bend| / slope (median
# about 0.5; docs/method.md §5).
UNEVEN_LIGHT_SHIFT_PER_BEND = 0.5
# The share of the expected shift an edge's σ takes: the mid-level's error is about 0.2 of the bend where light
# curves smoothly and 0.5 at a shadow's rim (the expected shift's factor), and three mid-levels cannot tell the two
# apart. With the whole shift in σ, edges of the dome top beside the punch's own shadow (within 0.25 mm of the
# truth) passed max_edge_sigma_px and a frame's peak before perforation went unmeasured in the virtual tests.
SIGMA_PER_SHIFT = 0.5


def uneven_light_shift_px(
    dark_area: np.ndarray,
    line: np.ndarray,
    t_px: np.ndarray,
    polarity: np.ndarray,
    mid_grey: np.ndarray,
    slope_grey: np.ndarray,
    *,
    period_px: float,
    from_means: bool,
) -> np.ndarray:
    """How far uneven light moves each crossing, shape (N,) float64 px ≥ 0 (0 where not judged): the one measure of
    uneven light, which feeds each edge's σ and its refusal (docs/method.md §5).

    The light's **bend** at a crossing is its mid-level minus the straight line through the mid-levels of its
    nearest crossings of the same polarity on its line, one period either side (within 1.5 periods); with a
    neighbour on one side only, the line through the next two on that side, where the other side has no stripes
    (no crossing within 1.5 periods nor one of its polarity within 2.5: too faint or dark, a shadow beyond the rim).
    Where the other side's stripes are only wider (a steep slope stretches them, as beside the punch), the line
    through one side does not say how the light runs on the other, and the crossing is not judged. Only neighbours
    whose mid-level is of the crossing's own kind are compared: the envelopes' where the two periods of the means
    reach a dark area (`dark_area` (S, T) uint8 non-zero) or the line's end, the means' otherwise (when
    `from_means`); the two differ by a few grey levels. The mid-level follows light that changes linearly along
    the line, so under such light the bend is zero up to the noise of the mid-levels (a few tenths of a grey
    level); what is left is the light's bend within a period, which moves the mid-level by about half of it
    (`UNEVEN_LIGHT_SHIFT_PER_BEND`) and the edge by that over the slope of the scan line between the two samples
    that straddle it (a mid-level off by a given amount moves a blurred or faint edge further than a sharp one,
    which a fraction of the contrast does not say).

    line, t_px, polarity, mid_grey: (N,) the crossings sorted by (line, t), their raw positions and the mid-level at
    each (`_mid_and_contrast`); slope_grey: (N,) float32, |I₁ − I₀| of the presmoothed samples straddling each
    (`_crossings`).
    """
    if len(line) == 0:
        return np.zeros(0)
    # Whether the means' two periods around a sample reach a dark area, by OpenCV's dilation (uint8, vectorised)
    # read at the crossings: a sweep along the lines through dark_area took 0.17 ms a 512 × 480 frame.
    dark_reach = dark_area
    if from_means:
        width = 2 * int(np.ceil(period_px - 0.5)) + 1
        dark_reach = _dilate_along_lines(dark_area, width, out=_SCRATCH.array("dark_reach", dark_area.shape, np.uint8))
    return _uneven_light_shift_kernel(
        dark_reach, line, t_px, polarity, mid_grey, np.ascontiguousarray(slope_grey, np.float32), float(period_px),
        bool(from_means), UNEVEN_LIGHT_SHIFT_PER_BEND,
    )  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _uneven_light_shift_kernel(
    dark_reach: np.ndarray,
    line: np.ndarray,
    t: np.ndarray,
    polarity: np.ndarray,
    mid: np.ndarray,
    slope_grey: np.ndarray,
    period: float,
    from_means: bool,
    per_bend: float,
) -> np.ndarray:
    """`uneven_light_shift_px` in one pass: the kind of each crossing's mid-level read at the crossings themselves,
    then the bend and the shift it predicts. dark_reach (S, T) uint8: where means are taken (from_means), the dark
    area dilated by `first` = ⌈P − ½⌉ samples either way along the lines (non-zero: a dark-area sample within the
    two periods of the means centred there); unread otherwise."""
    n = len(line)
    n_samples = dark_reach.shape[1]
    from_envelopes = np.ones(n, np.bool_)
    if from_means:
        first = int(np.ceil(period - 0.5))
        for p in range(n):
            j = min(max(int(t[p]), 0), n_samples - 2)
            if j < first or j + 1 >= n_samples - first:
                continue
            # a dark-area sample in [j − first, j + first + 1], the two periods of either straddling sample
            from_envelopes[p] = (dark_reach[line[p], j] | dark_reach[line[p], j + 1]) != 0
    # Each crossing's nearest crossing of its polarity on its line before and after it (−1: none), by one sweep
    # each way, without a walk per crossing (branch mispredictions).
    before = _same_polarity_sweep(line, polarity, 0, n, 1)
    after = _same_polarity_sweep(line, polarity, n - 1, -1, -1)
    reach = 1.5 * period
    kind = from_envelopes
    shift = np.zeros(n)
    for i in range(n):
        # One side only: judged by the next two on that side where the other side has no stripes (no crossing
        # within 1.5 periods, none of i's polarity within 2.5).
        a = _kept_neighbour(t, kind, i, before[i], reach)
        b = _kept_neighbour(t, kind, i, after[i], reach)
        if a < 0 and b >= 0:
            k = i - 1
            if (k >= 0 and line[k] == line[i] and abs(t[k] - t[i]) <= 1.5 * period) or _kept_neighbour(
                t, kind, i, before[i], 2.5 * period
            ) >= 0:
                continue
            a = _kept_neighbour(t, kind, b, after[b], reach)
        elif b < 0 and a >= 0:
            k = i + 1
            if (k < n and line[k] == line[i] and abs(t[k] - t[i]) <= 1.5 * period) or _kept_neighbour(
                t, kind, i, after[i], 2.5 * period
            ) >= 0:
                continue
            b = _kept_neighbour(t, kind, a, before[a], reach)
        if a < 0 or b < 0:
            continue
        bend = mid[i] - (mid[a] + (mid[b] - mid[a]) / (t[b] - t[a]) * (t[i] - t[a]))
        if np.isfinite(bend):
            slope = max(slope_grey[i], 1e-3)
            shift[i] = per_bend * abs(bend) / slope
    return shift


# What a departure is measured against, by where the edge lies in its run of neighbouring edges on its line (column 1
# of `edge_departures_px`): 0 centred (two neighbours either side), 1 next to the run's end, 2 at its end, 3 alone.
# Centred and next to the end the levels are multiples of `EdgeSettings.max_departure_px` (the departure's noise
# grows off-centre: σ_t times 1.4 and 2.1), at the end `max_end_departure_px` (σ_t times 8.4; measured on the
# soft-shadow renders of tests/science/structured_light/test_soft_shadows.py: 0.3, 0.45 and 0.8 px; docs/method.md
# §5). An edge alone on its line (no stripe of the expected width either side) is rejected where either is set.
DEPARTURE_LEVELS = np.array([1.0, 1.5])
# Neighbouring edges of a run: opposite polarity, 0.2–1.5 periods apart (a steep slope stretches a stripe; the order
# takes neighbours within 0.8 of a period).
DEPARTURE_GAP_PERIODS = (0.2, 1.5)


def edge_departures_px(line: np.ndarray, t_px: np.ndarray, polarity: np.ndarray, *, period_px: float) -> np.ndarray:
    """How far each edge departs from its neighbours on its scan line, shape (N, 2) float64: column 0 the departure
    (px along the line; NaN where not judged), column 1 where the edge lies in its run (0 centred, 1 next to the
    run's end, 2 at its end, 3 alone; `DEPARTURE_LEVELS`).

    A run is a sequence of edges of alternating polarity on one line, each within `DEPARTURE_GAP_PERIODS` of the
    next. The departure is the fourth difference over the five edges of the run nearest the edge (two either side
    where the run allows) divided by the edge's own coefficient in it (6 centred, −4 one from the end, 1 at the
    end): the edge's distance from the cubic through the other four. A smooth surface makes positions that a
    cubic follows (but where its stripes fold, beside the punch), so what is left is the edge's own misplacement (a
    stripe's flank dimmed by a shadow's rim moves its edge; 4/6 of that shows at each centred neighbour), and 4/3
    of any offset between the rising and the falling edges. Edges of runs shorter than five are not judged (NaN,
    place 0) unless alone.

    line, t_px, polarity: (N,) the edges sorted by (line, t).
    """
    return _edge_departures_kernel(
        _int_labels(line), np.ascontiguousarray(t_px, np.float64),
        polarity if polarity.dtype == np.int8 else np.ascontiguousarray(polarity, np.int64),
        DEPARTURE_GAP_PERIODS[0] * period_px,
        DEPARTURE_GAP_PERIODS[1] * period_px,
    )  # fmt: skip


def _uneven_edges(line: np.ndarray, t_px: np.ndarray, polarity: np.ndarray, *, period_px: float,
                  settings: EdgeSettings) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(N,) bool each, by the width alternation and by the departure: the edges `locate_edges` rejects as moved by
    uneven light, all judged at once on the smoothed
    positions (a misplaced edge bends its neighbours' cubics by 4/6 of its own departure, and rejecting it first
    would leave them unjudged): where the stripe widths alternate beyond `max_width_alternation_px`
    (`width_alternations_px`), with their neighbours in the run (the rim that moved the edge dims their stripes too:
    their errors are about half the edge's own, of the other sign), and where the edge departs from its neighbours
    (`edge_departures_px`) beyond its level (`DEPARTURE_LEVELS`; None: not judged there). The runs are found once
    and each measure is compared with its level as it is made (no (N,) measures)."""
    inner = np.inf if settings.max_departure_px is None else settings.max_departure_px
    end = np.inf if settings.max_end_departure_px is None else settings.max_end_departure_px
    max_alternation = settings.max_width_alternation_px
    return _uneven_edges_kernel(
        _int_labels(line), np.ascontiguousarray(t_px, np.float64),
        polarity if polarity.dtype == np.int8 else np.ascontiguousarray(polarity, np.int64),
        DEPARTURE_GAP_PERIODS[0] * period_px, DEPARTURE_GAP_PERIODS[1] * period_px,
        np.inf if max_alternation is None else float(max_alternation), max_alternation is not None,
        np.array([inner * DEPARTURE_LEVELS[0], inner * DEPARTURE_LEVELS[1], end, 0.0]),
        settings.max_departure_px is not None or settings.max_end_departure_px is not None,
    )  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _uneven_edges_kernel(
    line: np.ndarray,
    t: np.ndarray,
    polarity: np.ndarray,
    min_gap: float,
    max_gap: float,
    max_alternation: float,
    alternations: bool,
    levels: np.ndarray,
    departures: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """`_uneven_edges`; levels (4,): the departure's level at each place in the run."""
    n = len(line)
    alternating = np.zeros(n, np.bool_)
    uneven = np.zeros(n, np.bool_)
    linked = _linked(line, t, polarity, min_gap, max_gap)
    if alternations:
        _width_alternations_kernel(t, polarity, linked, max_alternation, np.empty(0), alternating)
    if departures:
        # Where the levels of the edges inside a run (centred, next to its end) are infinite (only the ends judged,
        # the default), only each run's first and last edge can be rejected: the rest are not measured.
        ends_only = levels[0] == np.inf and levels[1] == np.inf
        start = 0
        while start < n:
            stop = start
            while linked[stop]:
                stop += 1
            i = start
            while i <= stop:
                departure, place = _departure(t, i, min(i - start, 4), min(stop - i, 4))
                uneven[i] |= (abs(departure) > levels[place]) | (place == 3)
                i = stop if ends_only and i < stop else i + 1
            start = stop + 1
    return alternating, uneven


# Lines either side along its curve (edge chain) over which an edge rejected by the width alternation takes its
# curve's points with it. On tests/science/structured_light/test_soft_shadows.py's frames the deep shadow at w0 55 mm
# kept points 1.30 mm off without it: the same edge on the next lines, 0.4-0.7 px off, whose widths still change
# monotonically where the rim lies on the dome's fold, and which no local measure tells from the fold's good edges
# (docs/method.md §5); with 1 to 4 lines 0.67 mm, 2 for a margin (the errors along that curve fall by 0.3 px a line:
# −0.92, −0.66, −0.37 px), masking 5 843 mm² as uneven light in the 8 frames instead of 4 183 (1 line: 5 029).
# Frames without a rejection (the shadow-free ones) are unchanged.
ALTERNATION_ALONG_CURVE_LINES = 2


@numba.njit(cache=True, nogil=True)
def _along_curves(line: np.ndarray, first: np.ndarray, order: np.ndarray, rejected: np.ndarray, reach_lines: int
                  ) -> np.ndarray:  # fmt: skip
    """(N,) bool: the points of a curve within reach_lines lines of one of its rejected points (rejected (N,) bool);
    the curves grouped by `_by_chain` (first, order: each curve's points in line order)."""
    near = np.zeros(len(line), np.bool_)
    for c in range(len(first) - 1):
        for q in range(first[c], first[c + 1]):
            p = order[q]
            if not rejected[p]:
                continue
            r = q - 1
            while r >= first[c] and line[p] - line[order[r]] <= reach_lines:
                near[order[r]] = True
                r -= 1
            r = q + 1
            while r < first[c + 1] and line[order[r]] - line[p] <= reach_lines:
                near[order[r]] = True
                r += 1
    return near


# Stripes either side of an edge whose alternating part (bright minus dark width) is set over this many stripes
# either side: the median of their own, which a misplaced edge among them does not move.
DUTY_REACH_STRIPES = 8
# Slots of `_width_alternations_kernel`'s sorted window: two more than the 2·DUTY_REACH_STRIPES + 2 it needs (the rest
# stay +inf). A length known to the compiler and not that minimum lets LLVM vectorise the window's loops: at 18 or a
# length known at run time only they stayed scalar (2.8 ms a 1024² frame against 1.5 at 20; 1.9 at 24).
_DUTY_WINDOW_SLOTS = 2 * DUTY_REACH_STRIPES + 4


def width_alternations_px(line: np.ndarray, t_px: np.ndarray, polarity: np.ndarray, *, period_px: float) -> np.ndarray:
    """How much the stripe widths alternate at each edge, shape (N,) float64 px (NaN where not judged).

    Along a run of neighbouring edges on a line (`DEPARTURE_GAP_PERIODS`), a misplaced edge between stripes u and v
    (a stripe's flank dimmed by a soft shadow's rim) widens one and narrows the other by its misplacement δ: the
    wider becomes a local maximum of the widths and the narrower a local minimum. The alternation is
    min(u − w₋, w₊ − v, (u − v)/2) for u > v (w₋, w₊ the stripes beyond them; mirrored for u < v): about δ for a
    misplaced edge, ≤ 0 where the widths change monotonically, as a slope makes them (also where the dome's stripes
    fold beside the punch, compressed on one side and stretched on the other, which a cubic through the neighbours
    does not follow: `edge_departures_px`). The bright stripes may be wider than the dark ones by a constant
    (blur and mid-level), which alternates every width alike: it is taken out first, half from each stripe, as the
    median of (w_i − (w_{i−1} + w_{i+1})/2) signed by kind over `DUTY_REACH_STRIPES` stripes either side. Judged
    where the run has a stripe beyond each of u and v.

    line, t_px, polarity: (N,) the edges sorted by (line, t).
    """
    line = np.ascontiguousarray(line, np.int64)
    t = np.ascontiguousarray(t_px, np.float64)
    polarity = np.ascontiguousarray(polarity, np.int64)
    linked = _linked(line, t, polarity, DEPARTURE_GAP_PERIODS[0] * period_px, DEPARTURE_GAP_PERIODS[1] * period_px)
    alternation = np.full(len(t), np.nan)
    _width_alternations_kernel(t, polarity, linked, np.inf, alternation, np.zeros(len(t), bool))
    return alternation


@numba.njit(cache=True, nogil=True)
def _linked(line: np.ndarray, t: np.ndarray, polarity: np.ndarray, min_gap: float, max_gap: float) -> np.ndarray:
    """(N + 1,) bool: edge i and edge i + 1 are neighbours in a run (the last entry False)."""
    n = len(line)
    linked = np.zeros(n + 1, np.bool_)
    for i in range(n - 1):
        gap = t[i + 1] - t[i]
        linked[i] = line[i + 1] == line[i] and polarity[i + 1] != polarity[i] and min_gap < gap < max_gap
    return linked


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _width_alternations_kernel(
    t: np.ndarray,
    polarity: np.ndarray,
    linked: np.ndarray,
    max_alternation: float,
    alternation: np.ndarray,
    uneven: np.ndarray,
) -> None:
    """`width_alternations_px` over every run (`_linked`): written into alternation (N,) where it is not empty (NaN
    where not judged, as it comes), and edges whose widths alternate beyond max_alternation marked in uneven (N,)
    bool with their neighbours in the run."""
    n = len(t)
    # Per stripe of a run: its width, its kind's sign (+1 bright), its own alternating part and its width without
    # the duty; sized for the longest run a line can hold.
    width = np.empty(n)
    kind = np.empty(n)
    own = np.empty(n)
    even = np.empty(n)
    # The window's values (2·reach + 2 at most, between a stripe's gain and its loss) sorted in window[1 : size + 1],
    # +inf in the slots beyond them, between a −inf and a +inf; in one of two rows (a stripe gained and one lost in
    # one pass write the other). Both are constants to the compiler (`_DUTY_WINDOW_SLOTS`).
    reach = DUTY_REACH_STRIPES
    size = _DUTY_WINDOW_SLOTS
    rows = np.empty((2, size + 2))
    start = 0
    while start < n:
        stop = start
        while linked[stop]:
            stop += 1
        # Edges start..stop form a run; stripe j (0 ≤ j < m) lies between edges start + j and start + j + 1.
        m = stop - start
        if m >= 4:
            for j in range(m):
                width[j] = t[start + j + 1] - t[start + j]
                kind[j] = 1.0 if polarity[start + j] > 0 else -1.0
            for j in range(1, m - 1):
                own[j] = kind[j] * (width[j] - 0.5 * (width[j - 1] + width[j + 1]))
            # The median of own[lo:hi] (lo = max(1, j − reach), hi = min(m − 1, j + reach + 1)) for each stripe j, from
            # a sorted window that gains a stripe at hi and loses one at lo as j moves on. Both updates are the same
            # few operations on every slot, without branches (they vectorise): a search for the place and a shift
            # mispredicted two or three branches a stripe (1.1 of 1.25 ms a 512 × 480 frame). Positions are finite.
            rows[:] = np.inf
            rows[:, 0] = -np.inf
            row = 0
            window = rows[row]
            count = 0
            lo, hi = 1, 1
            for j in range(m):
                new_lo, new_hi = max(1, j - reach), min(m - 1, j + reach + 1)
                if hi + 1 == new_hi and lo + 1 == new_lo:
                    # Inside a run, one stripe in and one out, in one pass: each slot of the window less the lost
                    # value (the slot's own or its right's, as below), then with the gained one (as below).
                    gained, lost = own[hi], own[lo]
                    spare = rows[1 - row]
                    for q in range(1, size + 1):
                        below = window[q - 1] if window[q - 1] < lost else window[q]
                        here = window[q] if window[q] < lost else window[q + 1]
                        here = here if here < gained else gained
                        spare[q] = below if below > here else here
                    row = 1 - row
                    window = spare
                    hi += 1
                    lo += 1
                while hi < new_hi:
                    value = own[hi]
                    for q in range(size, 0, -1):  # each slot takes max(left, min(itself, value))
                        below, here = window[q - 1], window[q]
                        here = here if here < value else value
                        window[q] = below if below > here else here
                    count += 1
                    hi += 1
                while lo < new_lo:
                    value = own[lo]
                    for q in range(1, size + 1):  # from the first slot not below the value, each takes its right's
                        window[q] = window[q] if window[q] < value else window[q + 1]
                    count -= 1
                    lo += 1
                duty = 0.5 * (window[1 + (count - 1) // 2] + window[1 + count // 2]) if count > 0 else 0.0
                even[j] = width[j] - 0.5 * kind[j] * duty
            for k in range(2, m - 1):
                u, v = even[k - 1], even[k]
                # Both sides, then one chosen without a branch (u > v half the time: mispredicted).
                wider_first = min(u - even[k - 2], even[k + 1] - v, 0.5 * (u - v))
                wider_second = min(even[k - 2] - u, v - even[k + 1], 0.5 * (v - u))
                value = wider_first if u > v else wider_second
                if len(alternation) > 0:
                    alternation[start + k] = value
                if value > max_alternation:  # edges start + k − 1 … start + k + 1 are all in the run
                    uneven[start + k - 1] = uneven[start + k] = uneven[start + k + 1] = True
        start = stop + 1


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _edge_departures_kernel(
    line: np.ndarray, t: np.ndarray, polarity: np.ndarray, min_gap: float, max_gap: float
) -> np.ndarray:
    n = len(line)
    out = np.empty((n, 2))
    linked = _linked(line, t, polarity, min_gap, max_gap)
    start = 0
    while start < n:
        stop = start
        while linked[stop]:
            stop += 1
        for i in range(start, stop + 1):
            out[i, 0], place = _departure(t, i, min(i - start, 4), min(stop - i, 4))
            out[i, 1] = place
        start = stop + 1
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _departure(t: np.ndarray, i: int, before: int, after: int) -> tuple[float, int]:
    """`edge_departures_px` of edge i, which has `before` and `after` edges of its run either side (up to 4 counted):
    its departure (NaN where not judged, +inf alone) and its place in its run."""
    if before == 0 and after == 0:
        return np.inf, 3
    if before >= 2 and after >= 2:
        lo, place = i - 2, 0
    elif before == 1 and after >= 3:
        lo, place = i - 1, 1
    elif after == 1 and before >= 3:
        lo, place = i - 3, 1
    elif before == 0 and after >= 4:
        lo, place = i, 2
    elif after == 0 and before >= 4:
        lo, place = i - 4, 2
    else:
        return np.nan, 0
    d4 = t[lo] - 4.0 * t[lo + 1] + 6.0 * t[lo + 2] - 4.0 * t[lo + 3] + t[lo + 4]
    coefficient = 6.0 if i - lo == 2 else (-4.0 if i - lo in (1, 3) else 1.0)
    return d4 / coefficient, place


@numba.njit(cache=True, nogil=True)
def _same_polarity_sweep(line: np.ndarray, polarity: np.ndarray, start: int, stop: int, step: int) -> np.ndarray:
    """For each crossing, the index of the last crossing of its polarity on its line met sweeping from `start` to
    `stop` by `step` (its nearest before it for step 1, after it for −1), or −1."""
    out = np.empty(len(line), np.int32)
    row = -1
    rising = falling = -1
    for i in range(start, stop, step):
        if line[i] != row:
            row = line[i]
            rising = falling = -1
        if polarity[i] > 0:
            out[i] = rising
            rising = i
        else:
            out[i] = falling
            falling = i
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _kept_neighbour(t: np.ndarray, kind: np.ndarray, i: int, k: int, reach: float) -> int:
    """k where it is a crossing (k ≥ 0) within `reach` px of crossing i with a mid-level of i's kind, else −1.
    The three tests are evaluated together, without branches (k = −1 reads the last crossing, harmlessly): as
    short-circuits they cost a branch misprediction every few crossings, 0.55 of the 1.0 ms that
    `_uneven_light_shift_kernel` took a 512 × 480 frame."""
    return k if (k >= 0) & (abs(t[k] - t[i]) <= reach) & (kind[k] == kind[i]) else -1


def _without_glitches(line: np.ndarray, t_px: np.ndarray, *, min_gap_px: float) -> np.ndarray:
    """Mask, shape (N,), dropping both members of any pair of neighbouring crossings closer than min_gap_px.

    Noise on a slow transition makes it cross the mid-level three times within a fraction of a pixel; the
    outer crossing of such a triple is the edge, the close pair is not.
    """
    keep = np.ones(len(line), bool)
    if len(line) < 2:
        return keep
    close = (line[1:] == line[:-1]) & (np.diff(t_px) < min_gap_px)
    keep[:-1] &= ~close
    keep[1:] &= ~close
    return keep


def _without_slivers(
    line: np.ndarray,
    t_px: np.ndarray,
    *,
    ratio: float = 0.5,
    beside: np.ndarray | None = None,
    lone_is_sliver: bool = True,
) -> np.ndarray:
    """Mask, shape (N,), dropping both ends of any stripe less than `ratio` times as wide as both its neighbours
    on the line; where the stripe has a neighbour on one side only and its end on the other is beside a dark area
    (`beside`, shape (N,) bool), only that end (the area's rim cut the stripe; its other end is a stripe edge).
    A stripe alone on its line is a sliver (`lone_is_sliver`) where a line holds many stripes: a fragment cut at
    both ends; not where a line may hold one (stripes wider than MAX_PERIOD_PX).

    Stripes narrow gradually with slope and perspective, so neighbouring stripes are alike; a sliver next to
    wider ones is a stripe cut by something narrower than a stripe (a crack, a scratch, the edge of a shadow),
    and one of its ends is that cut, not a stripe edge.
    """
    if len(line) < 4:
        return np.ones(len(line), bool)
    if beside is None:
        beside = np.zeros(len(line), bool)
    return _without_slivers_kernel(np.ascontiguousarray(line), np.ascontiguousarray(t_px), float(ratio),
                                   np.ascontiguousarray(beside, np.bool_), lone_is_sliver)  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _without_slivers_kernel(
    line: np.ndarray, t: np.ndarray, ratio: float, beside: np.ndarray, lone_is_sliver: bool
) -> np.ndarray:
    n = len(line)
    keep = np.ones(n, np.bool_)
    for i in range(n - 1):
        gap = float(t[i + 1] - t[i]) if line[i + 1] == line[i] else np.inf  # no stripe across lines
        if not np.isfinite(gap):
            continue
        previous = float(t[i] - t[i - 1]) if i > 0 and line[i - 1] == line[i] else np.inf
        following = float(t[i + 2] - t[i + 1]) if i + 2 < n and line[i + 2] == line[i + 1] else np.inf
        open_start, open_end = not np.isfinite(previous), not np.isfinite(following)
        # A neighbour missing (line end, or another line) does not count against the stripe.
        if open_start:
            previous = following
        if open_end:
            following = previous
        if not (gap < ratio * previous and gap < ratio * following):
            continue
        if open_start and open_end and not lone_is_sliver:
            continue  # no neighbour on either side: none to be narrower than
        if open_end and not open_start and beside[i + 1]:
            keep[i + 1] = False  # cut by the dark area its end is beside
        elif open_start and not open_end and beside[i]:
            keep[i] = False
        else:
            keep[i] = keep[i + 1] = False
    return keep


NEAR_DARK_AWAY, NEAR_DARK_BESIDE, NEAR_DARK_REJECTED = 0, 1, 2


@numba.njit(cache=True, nogil=True)
def _near_dark_kernel(
    cut: np.ndarray,
    area: np.ndarray,
    black: np.ndarray,
    line: np.ndarray,
    t: np.ndarray,
    half_lines: int,
    half_inside: int,
    half_black: int,
) -> np.ndarray:
    """Per crossing, shape (N,) uint8: NEAR_DARK_REJECTED where either straddling sample lies within the reach of a
    dark area (`cut`, non-zero) and within half_inside samples of the dark mask (`area`) or half_black of a black
    sample (each ± half_lines lines); NEAR_DARK_BESIDE where its sample lies within the reach but neither holds;
    NEAR_DARK_AWAY elsewhere (see `locate_edges`)."""
    n_lines, n_samples = cut.shape
    code = np.zeros(len(line), np.uint8)
    for k in range(len(line)):
        i = line[k]
        first = min(int(t[k]), n_samples - 1)
        in_first = cut[i, first] != 0
        in_second = first + 1 < n_samples and cut[i, first + 1] != 0
        if not (in_first or in_second):
            continue
        # Either sample rejects the crossing: where both lie within the reach, their windows are read as one (they
        # differ by one sample; read apart, a kept crossing's were read twice).
        low = first if in_first else first + 1
        high = first + 1 if in_second else first
        rejected = False
        for ii in range(max(i - half_lines, 0), min(i + half_lines + 1, n_lines)):
            for ss in range(max(low - half_inside, 0), min(high + half_inside + 1, n_samples)):
                rejected |= area[ii, ss] != 0
            if rejected:
                break
            for ss in range(max(low - half_black, 0), min(high + half_black + 1, n_samples)):
                if black[ii, ss]:
                    rejected = True
                    break
            if rejected:
                break
        if rejected:
            code[k] = NEAR_DARK_REJECTED
        elif in_first:
            code[k] = NEAR_DARK_BESIDE
    return code


def _whole_beside_dark(line: np.ndarray, t_px: np.ndarray, beside: np.ndarray, *, period_px: float) -> np.ndarray:
    """Mask, shape (N,), dropping each crossing beside a dark area (`beside`, shape (N,) bool) where the stripe it
    closes on either side is less than WHOLE_STRIPE_SHARE as wide as the stripe of the same kind before that one
    (input sorted by (line, t); the three stripes on its line within two periods of it).

    Beside a dark area a transition is either the lit edge of a stripe whose neighbour runs into the area (a
    stripe edge, its stripe whole) or the area's rim cutting a stripe short (not an edge of the pattern). A side
    with fewer stripes than that (the dark area itself, a line's end, a frame of few wide stripes) says nothing.
    """
    t = np.ascontiguousarray(t_px, np.float64)
    return _whole_beside_dark_kernel(line, t, np.ascontiguousarray(beside, np.bool_), float(period_px))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _whole_beside_dark_kernel(line: np.ndarray, t: np.ndarray, beside: np.ndarray, period: float) -> np.ndarray:
    """`_whole_beside_dark` in one pass over the crossings beside a dark area (few), where numpy's dozen passes over
    them cost 0.13 ms a 512 × 480 frame in calls alone."""
    n = len(line)
    keep = np.ones(n, np.bool_)
    for at in range(n):
        if not beside[at]:
            continue
        for side in (-1, 1):
            third = at + 3 * side
            if third < 0 or third >= n or line[third] != line[at] or not abs(t[third] - t[at]) <= 2.0 * period:
                continue
            width = abs(t[at + side] - t[at])
            before = abs(t[third] - t[at + 2 * side])
            if width < WHOLE_STRIPE_SHARE * before:
                keep[at] = False
    return keep


def _link_chains(
    line: np.ndarray,
    t_px: np.ndarray,
    polarity: np.ndarray,
    *,
    n_samples: int,
    max_step_px: float,
    across_gaps: bool = False,
) -> np.ndarray:
    """Label, shape (N,), of the edge curve of each crossing, input sorted by (line, t).

    Two crossings on adjacent lines belong to one curve when each is the other's nearest crossing of the same
    polarity on that line (the nearer on the lower t when two are as near) and they are at most max_step_px
    apart. With `across_gaps` (`EdgeSettings.link_across_lost_crossing`), a curve broken by one lost crossing is
    joined across it: a curve that ends on line s and one that starts on line s + 2, of one polarity, at most
    2 × max_step_px apart and each the other's nearest such end. A curve is thus a run over increasing lines with
    one crossing per line (and, across gaps, single lines skipped); labels are the index of the curve's first
    crossing. `n_samples` is the length of a line (positions lie in [0, n_samples)).
    """
    if len(line) == 0:
        return np.zeros(0, np.int64)
    if n_samples <= 0:
        raise ValueError(f"n_samples: expected > 0, got {n_samples}")
    line = np.ascontiguousarray(line, np.int64)
    starts = np.searchsorted(line, np.arange(int(line[-1]) + 3))
    return _link_chains_kernel(line, np.ascontiguousarray(t_px, np.float64), np.ascontiguousarray(polarity, np.int8),
                               starts, float(max_step_px), across_gaps)  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _nearest_on_line(
    t: np.ndarray,
    polarity: np.ndarray,
    lo: int,
    hi: int,
    query_lo: int,
    query_hi: int,
    max_step: float,
    nearest: np.ndarray,
) -> np.ndarray:
    """For each crossing in [query_lo, query_hi) (sorted by t), the index in [lo, hi) (sorted by t) of the crossing
    of its polarity nearest to it (the lower t on a tie), −1 when none lies within max_step, in nearest[:query_hi −
    query_lo] (int64, reused from line to line: two allocations a line cost 0.1–0.2 ms a frame), which is returned.
    The queries come in increasing t, so the search position only moves forward."""
    nearest = nearest[: query_hi - query_lo]
    nearest[:] = -1
    a = lo
    for q in range(query_lo, query_hi):
        while a < hi and t[a] < t[q]:
            a += 1
        below = a - 1
        while below >= lo and polarity[below] != polarity[q]:
            below -= 1
        above = a
        while above < hi and polarity[above] != polarity[q]:
            above += 1
        best = -1
        best_gap = np.inf
        if below >= lo:
            best, best_gap = below, t[q] - t[below]
        if above < hi and t[above] - t[q] < best_gap:
            best, best_gap = above, t[above] - t[q]
        if best_gap <= max_step:
            nearest[q - query_lo] = best
    return nearest


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _link_chains_kernel(
    line: np.ndarray, t: np.ndarray, polarity: np.ndarray, starts: np.ndarray, max_step: float, across_gaps: bool
) -> np.ndarray:
    n = len(line)
    label = np.arange(n)
    linked_after = np.zeros(n, np.bool_)
    most = 0  # crossings on the fullest line
    for this_line in range(len(starts) - 1):
        most = max(most, starts[this_line + 1] - starts[this_line])
    backward_buffer, forward_buffer = np.empty(most, np.int64), np.empty(most, np.int64)
    for this_line in range(1, len(starts) - 1):
        lo, mid, hi = starts[this_line - 1], starts[this_line], starts[this_line + 1]
        if mid == hi:
            continue
        if lo < mid:
            backward = _nearest_on_line(t, polarity, lo, mid, mid, hi, max_step, backward_buffer)
            forward = _nearest_on_line(t, polarity, mid, hi, lo, mid, max_step, forward_buffer)
            # Mutual links only; then the predecessor's label, set before (lines in order), runs on.
            for i in range(mid, hi):
                j = backward[i - mid]
                if j >= 0 and forward[j - lo] == i:
                    label[i] = label[j]
                    linked_after[j] = True
        if not across_gaps or this_line < 2:
            continue
        # Across one lost crossing: a curve that ends on the line before the last and one that starts on this one,
        # of one polarity, within two steps of each other, each the other's nearest such end.
        lo2 = starts[this_line - 2]
        for i in range(mid, hi):
            if label[i] != i:
                continue
            best, best_gap = -1, 2.0 * max_step
            for j in range(lo2, lo):
                if not linked_after[j] and polarity[j] == polarity[i] and abs(t[j] - t[i]) <= best_gap:
                    best, best_gap = j, abs(t[j] - t[i])
            if best < 0:
                continue
            mutual = True
            for k in range(mid, hi):
                if k != i and label[k] == k and polarity[k] == polarity[i] and abs(t[k] - t[best]) < best_gap:
                    mutual = False
                    break
            if mutual:
                label[i] = label[best]
                linked_after[best] = True
    return label


def _smooth_along_chains(
    line: np.ndarray, t_px: np.ndarray, chain: np.ndarray, *, sigma_lines: float
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """t smoothed along each chain by a Gaussian-weighted local quadratic fit in the line index, shape (N,), and the
    points grouped by chain (`_by_chain`'s first and order, for `_edge_sigma` to reuse).

    line, t_px, chain: shape (N,), sorted by (line, t); chain labels 0..n_chains − 1, each chain one point per line
    over increasing lines, single lines skipped where a crossing was lost (`_link_chains`). Away from a chain's ends
    and its skipped lines the local quadratic fit is a fixed linear filter (a Gaussian-weighted Savitzky–Golay
    filter, `edge_smoothing_weights`); within a kernel half-width (in lines) of an end or a skipped line the fit is
    solved with the points that are there, each at its own line offset, and where a one-sided
    quadratic on a few points would amplify noise (less than 2/3 of a half-width on the short side and a short
    chain on the other, i.e. an ill-conditioned fit) the local weighted mean is taken instead.
    """
    interior, gauss = _smoothing_weights(float(sigma_lines))
    return _smooth_along_chains_kernel(
        _int_labels(line), np.ascontiguousarray(t_px, np.float64), _int_labels(chain), interior, gauss,
        float(sigma_lines),
    )  # fmt: skip


@functools.lru_cache(maxsize=16)
def _smoothing_weights(sigma_lines: float) -> tuple[np.ndarray, np.ndarray]:
    """`_smooth_along_chains`'s interior weights (`edge_smoothing_weights`) and Gaussian weights (2h + 1,), h = ⌈3σ⌉,
    computed once per σ (read-only)."""
    half = max(1, int(np.ceil(3.0 * sigma_lines)))
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    gauss = np.exp(-0.5 * (offsets / sigma_lines) ** 2)
    interior = edge_smoothing_weights(sigma_lines)
    interior.flags.writeable = gauss.flags.writeable = False
    return interior, gauss


def _int_labels(values: np.ndarray) -> np.ndarray:
    """Line indices or chain labels as the kernels take them: int32 as they come (no copy), else int64."""
    if values.dtype == np.int32 and values.flags.c_contiguous:
        return values
    return np.ascontiguousarray(values, np.int64)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _smooth_along_chains_kernel(
    line: np.ndarray, t: np.ndarray, chain: np.ndarray, interior: np.ndarray, gauss: np.ndarray, sigma_lines: float
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    n = len(t)
    half = len(gauss) // 2
    n_chains = chain.max() + 1
    first, order = _by_chain(chain, n_chains)
    t_sorted = t[order]
    line_sorted = line[order]
    smoothed = np.empty(n)
    for c in range(n_chains):
        lo, hi = first[c], first[c + 1]
        p = lo
        while p < hi:
            before, after = p - lo, hi - 1 - p
            # Four interior points at once: their sums are independent chains of additions, each in the order of one
            # point's alone (the same values), that the processor overlaps (one at a time waits on each addition).
            if (
                before >= half
                and after >= half + 3
                and line_sorted[p + half] - line_sorted[p - half] == 2 * half
                and line_sorted[p + 1 + half] - line_sorted[p + 1 - half] == 2 * half
                and line_sorted[p + 2 + half] - line_sorted[p + 2 - half] == 2 * half
                and line_sorted[p + 3 + half] - line_sorted[p + 3 - half] == 2 * half
            ):
                v0 = v1 = v2 = v3 = 0.0
                base = p - half
                for m in range(2 * half + 1):
                    w = interior[m]
                    v0 += w * t_sorted[base + m]
                    v1 += w * t_sorted[base + m + 1]
                    v2 += w * t_sorted[base + m + 2]
                    v3 += w * t_sorted[base + m + 3]
                smoothed[order[p]], smoothed[order[p + 1]] = v0, v1
                smoothed[order[p + 2]], smoothed[order[p + 3]] = v2, v3
                p += 4
                continue
            if before >= half and after >= half and line_sorted[p + half] - line_sorted[p - half] == 2 * half:
                value = 0.0
                for m in range(2 * half + 1):
                    value += interior[m] * t_sorted[p - half + m]
                smoothed[order[p]] = value
                p += 1
                continue
            # Near an end, or where the curve skips a line (linked across a lost crossing): the fit over the
            # points within a half-width in lines, each at its own line offset.
            first_q = p
            while first_q > lo and line_sorted[p] - line_sorted[first_q - 1] <= half:
                first_q -= 1
            s0 = s1 = s2 = s3 = s4 = r0 = r1 = r2 = 0.0
            for q in range(first_q, hi):
                offset = line_sorted[q] - line_sorted[p]
                if offset > half:
                    break
                w = gauss[offset + half]
                d = float(offset)
                v = t_sorted[q]
                s0 += w
                s1 += w * d
                s2 += w * d * d
                s3 += w * d * d * d
                s4 += w * d * d * d * d
                r0 += w * v
                r1 += w * v * d
                r2 += w * v * d * d
            det = s0 * (s2 * s4 - s3 * s3) - s1 * (s1 * s4 - s3 * s2) + s2 * (s1 * s3 - s2 * s2)
            num = r0 * (s2 * s4 - s3 * s3) - s1 * (r1 * s4 - s3 * r2) + s2 * (r1 * s3 - s2 * r2)
            quadratic = num / det if abs(det) > 1e-9 * s0**3 * sigma_lines**6 else np.nan
            smoothed[order[p]] = quadratic if np.isfinite(quadratic) else r0 / s0
            p += 1
    return smoothed, (first, order)


@dataclass(frozen=True, eq=False)
class EdgeOrder:
    """Relative order of the edge curves of one frame.

    The order is carried by parts of curves: a curve is cut where it runs through a stretch of unsure points
    (`order_edges`), and each stretch and each sure piece between them is a part.
    part: shape (N,) int64, the part each edge point belongs to (0..n_parts−1).
    part_index: shape (n_parts,) int64, the position of each part in the stripe sequence, counted along +t from 0
        within its component (the components' offsets to each other are unknown); −1 for parts left out.
    part_component: shape (n_parts,) int64, the connected group each part belongs to (−1 left out); the largest
        group is 0. Groups are joined only through sure links, so a region reached only through unsure ones is a
        group of its own.
    conflicts: number of neighbour statements within a group that disagree with the assignment (0 for a clean
        frame).
    n_unsure_links: number of statements between curves that were not sure enough to carry the order.
    """

    part: np.ndarray
    part_index: np.ndarray
    part_component: np.ndarray
    conflicts: int
    n_unsure_links: int = 0

    def crossing_index(self, edges: FrameEdges) -> np.ndarray:
        """Index of every edge point, shape (N,) (−1 where its part was left out)."""
        self._require_same_points(edges)
        return self.part_index[self.part]

    def crossing_component(self, edges: FrameEdges) -> np.ndarray:
        """Group of every edge point, shape (N,) (−1 where its part was left out)."""
        self._require_same_points(edges)
        return self.part_component[self.part]

    def _require_same_points(self, edges: FrameEdges) -> None:
        if len(edges) != len(self.part):
            raise ValueError(f"edges: expected the {len(self.part)} points this order was made from, got {len(edges)}")


# A link between two edges is sure (`order_edges`) when each edge's σ is at most this share of the edge spacing
# (half a period): missing or inventing an edge, which is what miscounts the order, takes an error of a whole
# spacing, 30 σ for a sure edge, and σ grows together with the odds of it, as the contrast falls against the local
# noise or the light changes within the window (`FrameEdges.sigma_px`). Measured on the `dim` scenario (512 × 480):
# 99 % of the edges have σ ≤ 0.07 px, those in a band at 25 % of the light a median of 0.2 px.
SURE_SIGMA_SPACINGS = 1.0 / 30.0
# ... and the gap between them is within this factor of each neighbouring gap on the line (a skipped or invented
# stripe makes one gap about three times or a third of its neighbours).
SURE_GAP_RATIO = 2.0
# Fewest sure neighbour pairs (scan lines) a statement needs to carry the order from one curve to another.
MIN_SURE_PAIRS = 3
# A curve is cut where this many consecutive points (lines) or more are unsure: the order carried along a curve
# crosses no longer unsure stretch than it would between curves.
MIN_UNSURE_RUN_LINES = 3
# An unsure stretch that ends a curve keeps the curve's order up to this many points (lines): the reach of the
# smoothing along the curve (3 σ of its default 3 lines), over which σ grows toward the end as the fit turns
# one-sided.
MAX_END_STRETCH_LINES = 10


def order_edges(
    edges: FrameEdges,
    *,
    max_gap_periods: float = 0.8,
    sure_sigma_spacings: float = SURE_SIGMA_SPACINGS,
    min_sure_pairs: int = MIN_SURE_PAIRS,
) -> EdgeOrder:
    """Put the edge curves of a frame in stripe order (docs/method.md §5: the basis of edge identity).

    Two edge points that follow each other on a scan line with opposite polarities, less than max_gap_periods
    stripe periods apart (a stripe is half a period wide, so a gap of more than ~0.8 period means a missed
    edge), say that the second curve comes one place after the first. Only sure statements carry the order: a
    pair of points is sure when both edges are sure (σ at most `sure_sigma_spacings` of the edge spacing,
    `FrameEdges.sigma_px`; edges without a σ count as sure) and their gap is within a factor SURE_GAP_RATIO of the
    gaps beside it on the line; a statement is sure with at least `min_sure_pairs` sure pairs. Curves are cut
    into parts where MIN_UNSURE_RUN_LINES or more consecutive points are unsure, so a curve does not carry the
    order through a dim band either. The sure statements, counted over all lines, link the parts into groups; a
    maximum-support spanning tree of each group gives every part its place, and parts whose statements within
    the group mostly disagree with that are left out. An unsure stretch of a curve takes its curve's place where
    the sure pieces either side of it are in one group at one place, or where it ends the curve within
    MAX_END_STRETCH_LINES. Edges beside a dark area (`FrameEdges.beside_dark`) are never sure, cut their curve
    however few they are, and take no place from it (nor, in `order.order_frame`, from the rim's votes). A region
    reached only through unsure links
    is a group of its own: never guessed, `order.order_frame` masks it as "order unresolved" unless it has an
    anchor of its own.
    """
    n = len(edges)
    if n == 0 or not _n_chains(edges):
        empty = np.zeros(0, np.int64)
        return EdgeOrder(part=empty, part_index=empty, part_component=empty, conflicts=0)
    if not sure_sigma_spacings > 0 or min_sure_pairs < 1:
        raise ValueError(
            f"sure_sigma_spacings, min_sure_pairs: expected > 0 and ≥ 1, got {sure_sigma_spacings}, {min_sure_pairs}"
        )
    beside = beside_dark_points(edges)
    sure = _sure_points(edges, sure_sigma_spacings) & ~beside
    n_chains = _n_chains(edges)
    if np.all(sure):  # nothing to cut (most frames in even light): the parts are the curves
        part, part_chain = np.ascontiguousarray(edges.chain, np.int64), np.arange(n_chains)
        cut_run = part_beside = np.zeros(n_chains, np.bool_)
    else:
        part, part_chain, cut_run, part_beside = _curve_parts(
            np.ascontiguousarray(edges.chain), sure, beside, n_chains, MIN_UNSURE_RUN_LINES
        )
    n_parts = len(part_chain)
    before, after, support, sure_support = _order_statements(
        np.ascontiguousarray(edges.line, np.int64), np.ascontiguousarray(edges.t_px, np.float64),
        np.ascontiguousarray(edges.polarity, np.int8), part, sure, n_parts,
        float(max_gap_periods * edges.period_px), SURE_GAP_RATIO,
    )  # fmt: skip
    carries = sure_support >= min_sure_pairs
    # The best-supported sure statements first (ties in a fixed order), each kept when it joins two groups: a
    # maximum-support spanning forest, which gives every part its place relative to its group's root.
    tree_order = np.lexsort((before * n_parts + after, -sure_support))
    tree_order = tree_order[carries[tree_order]]
    index, root = _spanning_forest(before[tree_order], after[tree_order], n_parts)
    # Check every statement within a group against the assignment; leave out parts that are mostly contradicted.
    # (Between groups an unsure statement says nothing: the groups' places are not comparable.)
    within = root[before] == root[after]
    agrees = index[after] - index[before] == 1
    against, agreeing = within & ~agrees, within & agrees
    support_against, support_agreeing = support[against], support[agreeing]
    bad = np.bincount(np.concatenate((before[against], after[against])),
                      weights=np.concatenate((support_against, support_against)), minlength=n_parts)  # fmt: skip
    good = np.bincount(np.concatenate((before[agreeing], after[agreeing])),
                       weights=np.concatenate((support_agreeing, support_agreeing)), minlength=n_parts)  # fmt: skip
    left_out = bad > good
    # An unsure stretch of a curve between two sure pieces of it that the sure links put in one group at one place
    # is that place too (the curve is confirmed around it). One that ends its curve, no longer than the reach of the
    # smoothing along it (where σ grows because the fit is one-sided), keeps its curve's place: nothing lies beyond
    # it that could take a wrong order from it. Otherwise it stays a group of its own.
    stretch = np.flatnonzero(cut_run)
    curve = part_chain[stretch]
    before_it, after_it = np.maximum(stretch - 1, 0), np.minimum(stretch + 1, n_parts - 1)
    has_before = (stretch > 0) & (part_chain[before_it] == curve)
    has_after = (stretch < n_parts - 1) & (part_chain[after_it] == curve)
    sure_before, sure_after = has_before & ~left_out[before_it], has_after & ~left_out[after_it]
    between = sure_before & sure_after & (root[before_it] == root[after_it]) & (index[before_it] == index[after_it])
    part_size = np.bincount(part, minlength=n_parts)
    short = part_size[stretch] <= MAX_END_STRETCH_LINES
    at_end = short & ((sure_before & ~has_after) | (sure_after & ~has_before))
    # A stretch beside a dark area takes no order from its curve: where a hole's rim that is not black runs along a
    # stripe, the curve follows the rim for a few lines and back (on the virtual Kodak test, 10–28 lines beside the
    # perforation, points up to 4 mm off with their curve's order), and `order.order_frame` takes no rim vote from
    # it either: it stays unresolved.
    take = (between | at_end) & (root[stretch] == stretch) & ~part_beside[stretch]  # alone: no sure statement
    source = np.where(sure_before, before_it, after_it)[take]
    root[stretch[take]] = root[source]
    index[stretch[take]] = index[source]
    # Groups numbered by their size in edge points, largest first (ties: the group of the lowest part first).
    roots, group = np.unique(root, return_inverse=True)
    sizes = np.bincount(group, weights=part_size)
    lowest_part = np.full(len(roots), n_parts)
    np.minimum.at(lowest_part, group, np.arange(n_parts))
    rank = np.empty(len(roots), np.int64)
    rank[np.lexsort((lowest_part, -sizes))] = np.arange(len(roots))
    component = rank[group]
    index[left_out] = -1
    component[left_out] = -1
    # Count each group from 0 at its first part along +t.
    kept = component >= 0
    if np.any(kept):
        lowest = np.full(len(roots), np.iinfo(np.int64).max)
        np.minimum.at(lowest, component[kept], index[kept])
        index[kept] -= lowest[component[kept]]
    return EdgeOrder(
        part=part, part_index=index, part_component=component, conflicts=int(np.count_nonzero(against)),
        n_unsure_links=int(np.count_nonzero(~carries)),
    )  # fmt: skip


def _sure_points(edges: FrameEdges, sure_sigma_spacings: float) -> np.ndarray:
    """(N,) bool: the edge points whose σ is at most `sure_sigma_spacings` of the edge spacing. Edges without a σ
    (stored before edges had one) and a NaN σ (edges not smoothed along their curves) count as sure."""
    if edges.sigma_px is None:
        return np.ones(len(edges), np.bool_)
    return np.asarray(~(edges.sigma_px > sure_sigma_spacings * 0.5 * edges.period_px))


def beside_dark_points(edges: FrameEdges) -> np.ndarray:
    """(N,) bool: the edge points kept beside a dark area (`FrameEdges.beside_dark`); none for edges stored
    before the flag existed."""
    if edges.beside_dark is None:
        return np.zeros(len(edges), np.bool_)
    return np.asarray(edges.beside_dark, np.bool_)


def _n_chains(edges: FrameEdges) -> int:
    """Number of edge curves of a frame (labels 0..n − 1)."""
    return int(edges.chain.max()) + 1 if len(edges) else 0


# Kinds of edge point for cutting curves into parts (`_curve_parts`).
POINT_SURE, POINT_UNSURE, POINT_BESIDE_DARK = 0, 1, 2


@numba.njit(cache=True, nogil=True)
def _curve_parts(
    chain: np.ndarray, sure: np.ndarray, beside: np.ndarray, n_chains: int, min_run: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The part (N,) of every point, input sorted by (line, t): each curve cut before and after every run of at
    least min_run consecutive unsure points (neither `sure` nor `beside` (N,) bool) and every run of points beside
    a dark area (`beside`, however short); with, per part, its curve, whether it is such a cut run, and whether
    that run lies beside a dark area. Parts of one curve are numbered consecutively along it, curve by curve.

    One pass over the points in input order finds each curve's runs of one kind (POINT_SURE, POINT_UNSURE,
    POINT_BESIDE_DARK) and the run of every point; the parts are then made from the runs, curve by curve, and
    handed to the points: no grouping of the points by curve (a counting sort and a gather through it cost twice
    as much on a Kodak frame)."""
    n = len(chain)
    run_kind = np.empty(n, np.int8)
    run_length = np.empty(n, np.int64)
    run_next = np.empty(n, np.int64)  # the curve's next run, −1 for its last
    first_run = np.full(n_chains, -1, np.int64)
    last_run = np.full(n_chains, -1, np.int64)
    point_run = np.empty(n, np.int64)
    n_runs = 0
    for i in range(n):
        c = chain[i]
        kind = POINT_SURE if sure[i] else (POINT_BESIDE_DARK if beside[i] else POINT_UNSURE)
        r = last_run[c]
        if r >= 0 and run_kind[r] == kind:
            run_length[r] += 1
        else:
            run_kind[n_runs], run_length[n_runs], run_next[n_runs] = kind, 1, -1
            if r >= 0:
                run_next[r] = n_runs
            else:
                first_run[c] = n_runs
            last_run[c] = n_runs
            r = n_runs
            n_runs += 1
        point_run[i] = r
    run_part = np.empty(n_runs, np.int64)
    part_chain = np.empty(n_runs, np.int64)
    cut_run = np.zeros(n_runs, np.bool_)
    part_beside = np.zeros(n_runs, np.bool_)
    n_parts = 0
    for c in range(n_chains):
        in_run = False
        was_beside = False
        start_new = True
        r = first_run[c]
        while r >= 0:
            is_beside = run_kind[r] == POINT_BESIDE_DARK
            is_cut = is_beside or (run_kind[r] == POINT_UNSURE and run_length[r] >= min_run)
            if start_new or is_cut != in_run or is_beside != was_beside:
                part_chain[n_parts] = c
                cut_run[n_parts] = is_cut
                part_beside[n_parts] = is_beside
                n_parts += 1
            in_run = is_cut
            was_beside = is_beside
            start_new = False
            run_part[r] = n_parts - 1
            r = run_next[r]
    part = np.empty(n, np.int64)
    for i in range(n):
        part[i] = run_part[point_run[i]]
    return part, part_chain[:n_parts].copy(), cut_run[:n_parts].copy(), part_beside[:n_parts].copy()


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _order_statements(
    line: np.ndarray,
    t: np.ndarray,
    polarity: np.ndarray,
    part: np.ndarray,
    sure: np.ndarray,
    n_parts: int,
    max_gap_px: float,
    gap_ratio: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The distinct statements "part `after` comes one place after part `before`" of a frame, how many
    neighbouring pairs of edge points on scan lines make each, and how many of those are sure (see
    `order_edges`); sorted by (before, after)."""
    # A pair of parts repeats on line after line: runs of one pair are counted where they occur, so only the
    # runs (a few per pair) are sorted, not every pair of points.
    run_code = np.empty(max(len(line) - 1, 0), np.int64)
    run_count = np.empty(max(len(line) - 1, 0), np.int64)
    run_sure = np.empty(max(len(line) - 1, 0), np.int64)
    last_run = np.full(n_parts, -1, np.int64)  # the latest run of each `before` part
    n_runs = 0
    for i in range(len(line) - 1):
        if (
            line[i + 1] == line[i]
            and polarity[i + 1] != polarity[i]
            and t[i + 1] - t[i] < max_gap_px
            and part[i + 1] != part[i]
        ):
            gap = t[i + 1] - t[i]
            pair_sure = sure[i] and sure[i + 1]
            if pair_sure and i > 0 and line[i - 1] == line[i]:
                beside = t[i] - t[i - 1]
                pair_sure = beside < gap_ratio * gap and gap < gap_ratio * beside
            if pair_sure and i + 2 < len(line) and line[i + 2] == line[i]:
                beside = t[i + 2] - t[i + 1]
                pair_sure = beside < gap_ratio * gap and gap < gap_ratio * beside
            code = part[i] * n_parts + part[i + 1]
            run = last_run[part[i]]
            if run >= 0 and run_code[run] == code:
                run_count[run] += 1
                run_sure[run] += 1 if pair_sure else 0
            else:
                run_code[n_runs], run_count[n_runs], run_sure[n_runs] = code, 1, 1 if pair_sure else 0
                last_run[part[i]] = n_runs
                n_runs += 1
    by_code = np.argsort(run_code[:n_runs], kind="mergesort")
    codes = run_code[:n_runs][by_code]
    counts = run_count[:n_runs][by_code]
    sure_counts = run_sure[:n_runs][by_code]
    m = n_runs
    n_distinct = 0
    for i in range(m):
        if i == 0 or codes[i] != codes[i - 1]:
            n_distinct += 1
    before = np.empty(n_distinct, np.int64)
    after = np.empty(n_distinct, np.int64)
    support = np.zeros(n_distinct, np.int64)
    sure_support = np.zeros(n_distinct, np.int64)
    j = -1
    for i in range(m):
        if i == 0 or codes[i] != codes[i - 1]:
            j += 1
            before[j] = codes[i] // n_parts
            after[j] = codes[i] % n_parts
        support[j] += counts[i]
        sure_support[j] += sure_counts[i]
    return before, after, support, sure_support


@numba.njit(cache=True, nogil=True)
def _find(parent: np.ndarray, offset: np.ndarray, node: int) -> tuple[int, int]:
    """Root of a node and the node's place relative to it, compressing the path on the way."""
    root, place = node, 0
    while parent[root] != root:
        place += offset[root]
        root = parent[root]
    # Second pass: point every node on the path at the root with its place relative to it.
    remaining = place
    while parent[node] != node:
        following, step = parent[node], offset[node]
        parent[node], offset[node] = root, remaining
        remaining -= step
        node = following
    return root, place


@numba.njit(cache=True, nogil=True)
def _spanning_forest(before: np.ndarray, after: np.ndarray, n_chains: int) -> tuple[np.ndarray, np.ndarray]:
    """Place of every curve relative to the root of its group, and that root, from statements taken in the
    order given, each kept when it joins two groups (union–find with offsets)."""
    parent = np.arange(n_chains)
    offset = np.zeros(n_chains, np.int64)
    for e in range(len(before)):
        root_a, place_a = _find(parent, offset, before[e])
        root_b, place_b = _find(parent, offset, after[e])
        if root_a != root_b:
            # place(after) = place(before) + 1
            parent[root_b] = root_a
            offset[root_b] = place_a + 1 - place_b
    index = np.empty(n_chains, np.int64)
    root = np.empty(n_chains, np.int64)
    for node in range(n_chains):
        root[node], index[node] = _find(parent, offset, node)
    return index, root
