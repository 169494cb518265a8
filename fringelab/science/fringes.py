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

from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np
from scipy import ndimage, special
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

from . import MeasurementError
from .smoothing import edge_smoothing_weights

Axis = Literal["rows", "cols"]
AXIS_CHOICES = ("auto", "rows", "cols")

# Stripe periods outside this range (px along the scan line) are not "stripes": finer ones cannot be located to
# sub-pixel accuracy, coarser ones would not fit several periods into the window that sets the mid-level.
MIN_PERIOD_PX = 3.0
MAX_PERIOD_PX = 80.0
# Below this coherence of the structure tensor (1 = one gradient direction, 0 = isotropic) there is no stripe
# pattern to speak of: noise, a chessboard or an empty frame.
MIN_COHERENCE = 0.3
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
        them once, from the projector calibration, so every frame is processed alike).
    window_periods: the window (in stripe periods along the scan line) over which the local minimum and maximum
        set the mid-level (I_max + I_min)/2; > 1 so a stripe stretched by a slope still shows both levels.
    min_contrast_grey: grey levels (8-bit scale) of I_max − I_min below which a transition is rejected.
    saturation_grey: grey level (8-bit scale) at or above which a transition's bright side counts as clipped.
    dark_fraction: pixels whose neighbourhood (one period) never rises above this fraction of the frame's bright
        level are "dark" (clamp ring, hole, background); transitions within half a period of them are rejected,
        because there the mid-level is set by the dark area, not by the stripes.
    presmooth_px: Gaussian σ (px) of smoothing along the stripes before locating; it averages noise without
        moving an edge that runs along the smoothing direction.
    edge_smoothing_lines: Gaussian σ (lines) of the local quadratic fit of t against the line along each edge
        (the paper's spatial low-pass filter); 0 keeps the raw positions.
    min_edge_length_lines: linked edges shorter than this (lines) are dropped as noise.
    max_link_step_px_per_line: largest change of t between neighbouring lines for two transitions to belong to one edge
        (1 px per line is a 45° edge).
    """

    axis: str = "auto"
    period_px: float | None = None
    window_periods: float = 1.5
    min_contrast_grey: float = 20.0
    saturation_grey: float = 250.0
    dark_fraction: float = 0.3
    presmooth_px: float = 1.0
    edge_smoothing_lines: float = 3.0
    min_edge_length_lines: int = 8
    max_link_step_px_per_line: float = 1.5

    # Names these settings had in files written before they carried their units (still read).
    _FORMER_NAMES = {
        "min_contrast": "min_contrast_grey",
        "saturation_level": "saturation_grey",
        "edge_smoothing_px": "edge_smoothing_lines",
        "min_edge_length_px": "min_edge_length_lines",
        "max_link_step_px": "max_link_step_px_per_line",
    }

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> EdgeSettings:
        """Settings from a stored document (JSON in a result file), also one written under the former names."""
        return cls(**{cls._FORMER_NAMES.get(name, name): value for name, value in values.items()})

    def __post_init__(self) -> None:
        if self.axis not in AXIS_CHOICES:
            raise ValueError(f"axis: expected one of {AXIS_CHOICES}, got {self.axis!r}")
        if self.period_px is not None and not MIN_PERIOD_PX <= self.period_px <= MAX_PERIOD_PX:
            raise ValueError(f"period_px: expected {MIN_PERIOD_PX}..{MAX_PERIOD_PX} px or None, got {self.period_px}")
        if not self.window_periods >= 1.0:
            raise ValueError(f"window_periods: expected ≥ 1, got {self.window_periods}")
        for name in ("min_contrast_grey", "presmooth_px", "edge_smoothing_lines", "dark_fraction"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name}: expected ≥ 0, got {getattr(self, name)}")
        if not self.max_link_step_px_per_line > 0:
            raise ValueError(f"max_link_step_px_per_line: expected > 0, got {self.max_link_step_px_per_line}")
        if self.min_edge_length_lines < 1:
            raise ValueError(f"min_edge_length_lines: expected ≥ 1, got {self.min_edge_length_lines}")


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


def _require_grey(image: np.ndarray) -> np.ndarray:
    """The frame as an array; ValueError for anything but one 2-D grey image of a supported type."""
    array = np.asarray(image)
    if array.ndim != 2 or min(array.shape) < 8:
        raise ValueError(f"image: expected a 2-D grey image of shape (H, W) with H, W ≥ 8, got {array.shape}")
    if not (array.dtype in (np.uint8, np.uint16) or np.issubdtype(array.dtype, np.floating)):
        raise ValueError(f"image: expected uint8, uint16 or float grey levels, got dtype {array.dtype}")
    return array


def _grey_image(image: np.ndarray) -> np.ndarray:
    """The frame as float32 on the 8-bit scale; ValueError for anything but one 2-D grey image."""
    array = _require_grey(image)
    if array.dtype == np.uint8:
        return array.astype(np.float32)
    if array.dtype == np.uint16:
        return array.astype(np.float32) * np.float32(FULL_SCALE / 65535.0)
    return array.astype(np.float32)


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
    """Stripe period (px) from the mean power spectrum of every 4th scan line, or None without a clear peak."""
    lines = scan[:: max(1, scan.shape[0] // 128)].astype(np.float64)
    lines = lines - lines.mean(axis=1, keepdims=True)
    n = lines.shape[1]
    power = np.mean(np.abs(np.fft.rfft(lines * np.hanning(n), axis=1)) ** 2, axis=0)
    freqs = np.fft.rfftfreq(n)
    band = (freqs >= 1.0 / MAX_PERIOD_PX) & (freqs <= 1.0 / MIN_PERIOD_PX)
    if not np.any(band) or not np.any(power[band] > 0):
        return None
    idx = int(np.flatnonzero(band)[np.argmax(power[band])])
    # A stripe peak stands well above the spectrum around it; noise alone does not.
    if power[idx] < 8.0 * np.median(power[band]):
        return None
    if 0 < idx < len(power) - 1:
        a, b, c = np.log(power[idx - 1 : idx + 2] + 1e-30)
        denom = a - 2 * b + c
        offset = 0.5 * (a - c) / denom if denom < 0 else 0.0
    else:
        offset = 0.0
    frequency = (idx + float(np.clip(offset, -0.5, 0.5))) / n
    return float(1.0 / frequency)


def _odd(value: float) -> int:
    return int(2 * (int(round(value)) // 2) + 1)


def locate_edges(image: np.ndarray, settings: EdgeSettings | None = None) -> FrameEdges:
    """Every stripe edge of one frame at sub-pixel accuracy, linked into curves and smoothed along them.

    image: shape (H, W), uint8, uint16 or float grey levels (float on the 8-bit scale).

    A pure function of the frame and the settings, so frames can be processed in any order and on any worker.
    Steps (docs/method.md §5): Gaussian smoothing along the stripes; local mid-level (I_max + I_min)/2 over a window
    of `window_periods` periods along each scan line; every sign change of I − mid is an edge candidate, placed
    by a probit fit to the four straddling pixels; candidates with low contrast, a clipped bright
    side or near a dark area are rejected, as are pairs closer than a quarter of the edge spacing (noise
    glitches); the rest are linked line to line into curves (mutual nearest of the same polarity), short curves
    are dropped and each curve is smoothed by a local quadratic fit of t against the line.

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
    # Transposing before the conversion to float moves a quarter of the bytes.
    scan = _grey_image(image if axis == "rows" else np.ascontiguousarray(image.T))
    n_lines, n_samples = scan.shape

    half = max(1, int(np.ceil(3.0 * settings.presmooth_px)))
    if settings.presmooth_px > 0:
        kernel = cv2.getGaussianKernel(2 * half + 1, settings.presmooth_px).astype(np.float32)
        scan = cv2.sepFilter2D(scan, cv2.CV_32F, np.ones((1, 1), np.float32), kernel)

    # Dark: no bright sample within half a period either way (a dark stripe is only half a period wide). The
    # mask starts half a period inside a dark area (clamp ring, hole, background); grown by half a period
    # along the lines it covers the area itself.
    bright_level = float(np.percentile(scan[::4, ::4], 95))
    dark_window = _odd(period_px)
    dark = cv2.dilate(scan, np.ones((3, dark_window), np.uint8)) < settings.dark_fraction * bright_level
    dark_u8 = dark.astype(np.uint8)
    dark_area = cv2.dilate(dark_u8, np.ones((1, dark_window), np.uint8))

    # Envelopes I_max, I_min over the window along each line, then averaged over the window to steady them.
    # Dark-area pixels take no part: next to the clamp or a hole the minimum would otherwise be the dark area,
    # not the dark stripe, and pull the mid-level (and the last edges) off by a tenth of a pixel.
    window = _odd(settings.window_periods * period_px)
    line_kernel = np.ones((1, window), np.uint8)
    local_max = cv2.dilate(scan, line_kernel)
    local_min = cv2.erode(np.where(dark_area, np.float32(4.0 * FULL_SCALE), scan), line_kernel)
    valid = 1.0 - dark_area.astype(np.float32)
    weight = cv2.blur(valid, (window, 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        max_smooth = cv2.blur(local_max * valid, (window, 1)) / weight
        min_smooth = cv2.blur(local_min * valid, (window, 1)) / weight
    mid = 0.5 * (max_smooth + min_smooth)
    contrast = max_smooth - min_smooth
    diff = scan - mid

    # Transitions within half a period of a dark area (along the lines; across them, within the reach of the
    # smoothing along the stripes, which mixes dark lines into their neighbours) are rejected: their stripe is cut.
    grow = np.ones((2 * half + 3, 2 * dark_window - 1), np.uint8)
    near_dark = cv2.dilate(dark_u8, grow).astype(bool)
    saturated = scan >= settings.saturation_grey
    with np.errstate(invalid="ignore"):
        usable = (contrast >= settings.min_contrast_grey) & ~near_dark & (local_max < settings.saturation_grey)

    with np.errstate(invalid="ignore"):
        positive = diff > 0
    crossing = (positive[:, 1:] != positive[:, :-1]) & usable[:, 1:] & usable[:, :-1]
    if settings.presmooth_px > 0:
        # Near the first and last lines the smoothing mirrors the image, which bends an inclined edge.
        crossing[:half] = False
        crossing[-half:] = False
    # The sub-pixel fit needs one sample either side of the straddling pair.
    crossing[:, 0] = False
    crossing[:, -1] = False
    line, left = np.nonzero(crossing)
    line = line.astype(np.int32)
    t_raw = _subpixel_crossings(diff, contrast, line, left)
    polarity = np.where(diff[line, left + 1] > diff[line, left], 1, -1).astype(np.int8)

    keep = _without_glitches(line, t_raw, min_gap_px=0.25 * 0.5 * period_px)
    line, t_raw, polarity = line[keep], t_raw[keep], polarity[keep]

    chain = _link_chains(line, t_raw, polarity, n_samples=n_samples, max_step_px=settings.max_link_step_px_per_line)
    lengths = np.bincount(chain, minlength=len(chain))
    long_enough = lengths[chain] >= settings.min_edge_length_lines
    line, t_raw, polarity, chain = line[long_enough], t_raw[long_enough], polarity[long_enough], chain[long_enough]
    # Renumber the surviving curves 0..n−1 (labels are crossing indices, so at most N of them).
    renumber = np.cumsum(np.bincount(chain, minlength=len(long_enough)) > 0) - 1
    chain = renumber[chain].astype(np.int32)

    if settings.edge_smoothing_lines > 0 and len(line):
        t_px = _smooth_along_chains(line, t_raw, chain, sigma_lines=settings.edge_smoothing_lines)
        noise_px = float(np.sqrt(np.mean((t_raw - t_px) ** 2)))
    else:
        t_px = t_raw
        noise_px = float("nan")
    return FrameEdges(
        axis=axis,
        period_px=float(period_px),
        image_shape_hw_px=(int(image_shape_hw_px[0]), int(image_shape_hw_px[1])),
        line=line,
        t_px=t_px.astype(np.float32),
        polarity=polarity,
        chain=chain,
        noise_px=noise_px,
        saturated_fraction=float(np.mean(saturated)),
        dark_fraction=float(np.mean(dark)),
    )


def _subpixel_crossings(diff: np.ndarray, contrast: np.ndarray, line: np.ndarray, left: np.ndarray) -> np.ndarray:
    """Mid-level crossing between samples `left` and `left + 1` of each line, shape (N,) float64.

    Probit chord: the two straddling samples, normalised by their local envelope to
    y = (I − I_min)/(I_max − I_min) = 1/2 + (I − mid)/contrast, become z = Φ⁻¹(y), which is a straight line in
    position for a Gaussian-blurred step; the crossing is where the chord through them meets z = 0 (y = 1/2).
    The plain chord between the intensities bends with the S-shaped edge and leaves a bias that depends on the
    sub-pixel phase (pixel locking, ≈ 0.04 px at blur σ = 0.5 px); the probit chord leaves < 0.002 px for
    σ ≥ 0.5 px at the same noise. Each sample is normalised by its own envelope, so the two are on either side of
    1/2 exactly when the crossing test found them to be.
    """
    n_samples = diff.shape[1]
    flat = line.astype(np.int64) * n_samples + left
    d, c = diff.ravel(), contrast.ravel()
    y0 = np.clip(0.5 + d[flat] / c[flat], 0.005, 0.995)
    y1 = np.clip(0.5 + d[flat + 1] / c[flat + 1], 0.005, 0.995)
    z0 = special.ndtri(y0.astype(np.float64))
    z1 = special.ndtri(y1.astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        x = z0 / (z0 - z1)
    return left + np.clip(np.nan_to_num(x, nan=0.5), 0.0, 1.0)


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


def _link_chains(
    line: np.ndarray, t_px: np.ndarray, polarity: np.ndarray, *, n_samples: int, max_step_px: float
) -> np.ndarray:
    """Label, shape (N,), of the edge curve of each crossing, input sorted by (line, t).

    Two crossings on adjacent lines belong to one curve when each is the other's nearest crossing of the same
    polarity on that line and they are at most max_step_px apart. A curve is thus a run over consecutive lines
    with one crossing per line; labels are the index of the curve's first crossing.
    """
    n = len(line)
    if n == 0:
        return np.zeros(0, np.int64)
    stride = float(n_samples + 4.0 * max_step_px + 8.0)
    key = line.astype(np.float64) * stride + t_px
    forward = np.full(n, -1, np.int64)
    backward = np.full(n, -1, np.int64)
    for sign in (1, -1):
        members = np.flatnonzero(polarity == sign)
        if len(members) == 0:
            continue
        keys = key[members]
        for direction, out in ((1.0, forward), (-1.0, backward)):
            query = keys + direction * stride
            pos = np.searchsorted(keys, query)
            lo = np.clip(pos - 1, 0, len(keys) - 1)
            hi = np.minimum(pos, len(keys) - 1)
            nearest = np.where(np.abs(keys[lo] - query) <= np.abs(keys[hi] - query), lo, hi)
            ok = np.abs(keys[nearest] - query) <= max_step_px
            out[members[ok]] = members[nearest[ok]]
    # Keep mutual links only; then every crossing has at most one predecessor, and pointer jumping to the
    # first crossing of the run labels the curves in log2(run length) passes.
    predecessor = backward.copy()
    has_pred = predecessor >= 0
    predecessor[has_pred & (forward[np.maximum(predecessor, 0)] != np.arange(n))] = -1
    label = np.where(predecessor >= 0, predecessor, np.arange(n))
    while True:
        jumped = label[label]
        if np.array_equal(jumped, label):
            return label
        label = jumped


def _smooth_along_chains(line: np.ndarray, t_px: np.ndarray, chain: np.ndarray, *, sigma_lines: float) -> np.ndarray:
    """t smoothed along each chain by a Gaussian-weighted local quadratic fit in the line index, shape (N,).

    Each chain covers consecutive lines (links join adjacent lines only), so after sorting by (chain, line) the
    chains lie end to end in one 1-D array. Away from a chain's ends the local quadratic fit is a fixed linear
    filter (a Gaussian-weighted Savitzky–Golay filter); within a kernel half-width of an end the fit is solved
    with the points that are there.
    """
    half = max(1, int(np.ceil(3.0 * sigma_lines)))
    n_lines = int(line.max()) + 1
    order = np.argsort(chain.astype(np.int64) * n_lines + line, kind="stable")
    t_sorted = t_px[order].astype(np.float64)
    sorted_chain = chain[order]
    n = len(order)
    is_start = np.r_[True, sorted_chain[1:] != sorted_chain[:-1]]
    start_index = np.maximum.accumulate(np.where(is_start, np.arange(n), 0))
    is_end = np.r_[sorted_chain[1:] != sorted_chain[:-1], True]
    end_index = np.minimum.accumulate(np.where(is_end, np.arange(n), n)[::-1])[::-1]
    before = np.arange(n) - start_index
    after = end_index - np.arange(n)

    offsets = np.arange(-half, half + 1, dtype=np.float64)
    gauss = np.exp(-0.5 * (offsets / sigma_lines) ** 2)
    interior_weights = edge_smoothing_weights(sigma_lines)
    smoothed_sorted = ndimage.correlate1d(t_sorted, interior_weights, mode="nearest")

    near_end = np.flatnonzero((before < half) | (after < half))
    if len(near_end):
        idx = near_end[:, None] + offsets.astype(np.int64)[None, :]
        inside = (offsets[None, :] >= -before[near_end, None]) & (offsets[None, :] <= after[near_end, None])
        w = np.where(inside, gauss[None, :], 0.0)
        values = np.where(inside, t_sorted[np.clip(idx, 0, n - 1)], 0.0)
        s = [np.sum(w * offsets**m, axis=1) for m in range(5)]
        r = [np.sum(w * values * offsets**m, axis=1) for m in range(3)]
        det = s[0] * (s[2] * s[4] - s[3] ** 2) - s[1] * (s[1] * s[4] - s[3] * s[2]) + s[2] * (s[1] * s[3] - s[2] ** 2)
        num = r[0] * (s[2] * s[4] - s[3] ** 2) - s[1] * (r[1] * s[4] - s[3] * r[2]) + s[2] * (r[1] * s[3] - s[2] * r[2])
        with np.errstate(divide="ignore", invalid="ignore"):
            quadratic = num / det
        # A one-sided quadratic on a few points would amplify noise: use it only with ≥ 2/3 of a half-width
        # on the short side or when the chain is long on the other; else the local mean.
        mean = r[0] / s[0]
        well_posed = np.isfinite(quadratic) & (np.abs(det) > 1e-9 * s[0] ** 3 * sigma_lines**6)
        smoothed_sorted[near_end] = np.where(well_posed, quadratic, mean)
    smoothed = np.empty(n)
    smoothed[order] = smoothed_sorted
    return smoothed


@dataclass(frozen=True, eq=False)
class EdgeOrder:
    """Relative order of the edge curves of one frame.

    index: shape (n_chains,) int64, the position of each curve in the stripe sequence, counted along +t from 0
        within its component (the components' offsets to each other are unknown); −1 for curves left out.
    component: shape (n_chains,) int64, the connected group each curve belongs to (−1 left out); the largest
        group is 0.
    conflicts: number of neighbour pairs whose order disagrees with the assignment (0 for a clean frame).
    """

    index: np.ndarray
    component: np.ndarray
    conflicts: int

    def crossing_index(self, edges: FrameEdges) -> np.ndarray:
        """Index of every edge point, shape (N,) (−1 where its curve was left out)."""
        return self.index[edges.chain] if len(edges) else np.zeros(0, np.int64)


def order_edges(edges: FrameEdges, *, max_gap_periods: float = 0.8) -> EdgeOrder:
    """Put the edge curves of a frame in stripe order (docs/method.md §5: the basis of edge identity).

    Two edge points that follow each other on a scan line with opposite polarities, less than max_gap_periods
    stripe periods apart (a stripe is half a period wide, so a gap of more than ~0.8 period means a missed
    edge), say that the second curve comes one place after the first. Those statements, counted over all lines,
    link the curves into groups; a maximum-support spanning tree of each group gives every curve its place, and
    curves whose statements mostly disagree with that are left out.
    """
    n_chains = int(edges.chain.max()) + 1 if len(edges) else 0
    index = np.full(n_chains, -1, np.int64)
    component = np.full(n_chains, -1, np.int64)
    if n_chains == 0:
        return EdgeOrder(index=index, component=component, conflicts=0)
    same_line = edges.line[1:] == edges.line[:-1]
    alternating = edges.polarity[1:] != edges.polarity[:-1]
    close = np.diff(edges.t_px) < max_gap_periods * edges.period_px
    pair = same_line & alternating & close
    first = edges.chain[:-1][pair].astype(np.int64)
    second = edges.chain[1:][pair].astype(np.int64)
    different = first != second
    codes, support = np.unique(first[different] * n_chains + second[different], return_counts=True)
    before, after = codes // n_chains, codes % n_chains
    # Undirected graph with cost 1/support, so the spanning tree keeps the best-supported statements.
    graph = coo_matrix(
        (np.r_[1.0 / support, 1.0 / support], (np.r_[before, after], np.r_[after, before])), shape=(n_chains, n_chains)
    ).tocsr()
    tree = minimum_spanning_tree(graph)
    tree = tree + tree.T
    step = coo_matrix(
        (np.r_[np.ones(len(before)), -np.ones(len(before))], (np.r_[before, after], np.r_[after, before])),
        shape=(n_chains, n_chains),
    ).tocsr()
    n_groups, labels = connected_components(tree, directed=False)
    sizes = np.bincount(labels, weights=np.bincount(edges.chain, minlength=n_chains), minlength=n_groups)
    rank = np.empty(n_groups, np.int64)
    rank[np.argsort(-sizes, kind="stable")] = np.arange(n_groups)
    for group in range(n_groups):
        members = np.flatnonzero(labels == group)
        root = members[0]
        order, predecessors = breadth_first_order(tree, root, directed=False, return_predecessors=True)
        index[root] = 0
        for node in order[1:]:
            parent = predecessors[node]
            index[node] = index[parent] + int(round(step[parent, node]))
        component[members] = rank[group]
    # Check every statement against the assignment; leave out curves that are mostly contradicted.
    agrees = index[after] - index[before] == 1
    bad = np.bincount(np.r_[before[~agrees], after[~agrees]], weights=np.r_[support[~agrees], support[~agrees]],
                      minlength=n_chains)  # fmt: skip
    good = np.bincount(np.r_[before[agrees], after[agrees]], weights=np.r_[support[agrees], support[agrees]],
                       minlength=n_chains)  # fmt: skip
    left_out = bad > good
    index[left_out] = -1
    component[left_out] = -1
    # Count each group from 0 at its first curve along +t.
    kept = component >= 0
    if np.any(kept):
        lowest = np.full(n_groups, np.iinfo(np.int64).max)
        np.minimum.at(lowest, component[kept], index[kept])
        index[kept] -= lowest[component[kept]]
    return EdgeOrder(index=index, component=component, conflicts=int(np.count_nonzero(~agrees)))
