"""Gray-code pattern sequences of a digital projector: per-pixel decoding and sub-pixel coded edges
(docs/procam.md §2-3).

Belongs here: the description of a coded sequence (`PatternSequence`, what a `patterns.json` holds), decoding the
Gray-code bit frames of a recording into a per-pixel code with a validity mask and its reasons (shading too low,
a bit that is not clear), the optional N-step phase unwrapped by the code, and the stripe edges of the bit frames
located by the edge locator (`fringes.locate_edges`) and named by the codes on their two sides. Not here: reading
`patterns.json` (`fringelab.formats.patterns`), geometry (`procam.py`), whole scans (`scan.py`).

Projector coordinates. A projector pixel (x, y) has (0, 0) at the centre of its top-left pixel, as a camera's.
The code runs along x (projector columns, vertical stripes: ``axis="columns"``) or along y (``"rows"``). Projector
pixel i along the code's axis shows code value ⌊i / band_px⌋ (band_px projector pixels per code value), so the
boundary between code values k − 1 and k lies at ⌈k·band_px⌉ − ½, and a pixel that decodes to k sees some point of
the band from ⌈k·band_px⌉ − ½ to ⌈(k + 1)·band_px⌉ − ½. Gray bits are given most significant first; bit frame i of n
is bright where bit n − 1 − i of the reflected binary (Gray) code of the pixel's value is 1. Between values k − 1
and k exactly one Gray bit flips: the one at the position of k's lowest set bit, so each boundary is an edge of
exactly one bit frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from . import MeasurementError
from .fringes import MAX_FIXED_PERIOD_PX, MIN_PERIOD_PX, EdgeSettings, locate_edges
from .uncertainty import edge_sigma_px

CodeAxis = Literal["columns", "rows"]
CODE_AXES: tuple[str, ...] = ("columns", "rows")

# Why a pixel has no code (`Decoding.reason`), in increasing precedence.
DECODED = 0
UNCLEAR_BIT = 1  # some bit frame is too close to its threshold (a stripe edge, blur, a reflection)
LOW_SHADING = 2  # the projector's light there is too weak against the ambient light (shadow, dark surface)
OUTSIDE_PROJECTOR = 3  # the code names a band beyond the projector's size
REASON_LABELS = {
    DECODED: "decoded",
    UNCLEAR_BIT: "a bit not clear",
    LOW_SHADING: "shading too low",
    OUTSIDE_PROJECTOR: "beyond the projector",
}


class DecodingError(MeasurementError):
    """A coded sequence cannot be decoded: no valid pixel at all, or codes the projector cannot show."""


@dataclass(frozen=True)
class WhiteBlack:
    """Threshold from an all-white and an all-black frame: (white + black) / 2, shading white − black."""

    white: int
    black: int


@dataclass(frozen=True)
class InverseFrames:
    """Threshold of each bit from its inverse frame (same order as the bits): the bit is 1 where I > I_inverse."""

    frames: tuple[int, ...]


@dataclass(frozen=True)
class MeanOf:
    """Threshold from the mean of frames whose average is mid-grey (e.g. N-step sinusoids); the shading is
    2√2 times their standard deviation, the peak-to-peak of a sinusoid sampled at N equal steps."""

    frames: tuple[int, ...]


Threshold = WhiteBlack | InverseFrames | MeanOf


@dataclass(frozen=True)
class PhaseFrames:
    """N-step sinusoids along the code's axis, unwrapped by the code.

    Frame n (n = 0..N−1) shows ½ + ½·cos(2π(x − offset_px)/period_px − 2πn/N) at projector coordinate x, so the
    phase φ = atan2(Σ I_n sin(2πn/N), Σ I_n cos(2πn/N)) is 2π(x − offset_px)/period_px modulo 2π.
    offset_px: None to fit it to the decoded code (the median of the code's coordinate minus the phase's;
    reported in the decoding's QA), as for recordings whose pattern generator does not say.
    """

    frames: tuple[int, ...]
    period_px: float
    offset_px: float | None = None

    def __post_init__(self) -> None:
        if len(self.frames) < 3:
            raise ValueError(f"phase frames: expected at least 3 (N-step, N ≥ 3), got {len(self.frames)}")
        if not self.period_px > 0:
            raise ValueError(f"phase period_px: expected > 0, got {self.period_px}")


@dataclass(frozen=True)
class PatternSequence:
    """A coded sequence of one recording (what `patterns.json` holds; frames numbered from 0 in recording order).

    axis: "columns" (the code runs along projector x, vertical stripes) or "rows" (along y).
    projector_size_wh_px: (width, height) of the projector in pixels.
    gray_frames: the Gray-code bit frames, most significant first.
    band_px: projector pixels per code value.
    threshold: how each bit's threshold is found (`WhiteBlack`, `InverseFrames` or `MeanOf`).
    phase: optional N-step sinusoids unwrapped by the code.
    """

    axis: CodeAxis
    projector_size_wh_px: tuple[int, int]
    gray_frames: tuple[int, ...]
    band_px: float
    threshold: Threshold
    phase: PhaseFrames | None = None

    def __post_init__(self) -> None:
        if self.axis not in CODE_AXES:
            raise ValueError(f"axis: expected one of {CODE_AXES}, got {self.axis!r}")
        if len(self.projector_size_wh_px) != 2 or min(self.projector_size_wh_px) < 1:
            raise ValueError(f"projector_size_px: expected [width, height] ≥ 1, got {list(self.projector_size_wh_px)}")
        if not 1 <= len(self.gray_frames) <= 16:
            raise ValueError(f"gray_frames: expected 1 to 16 bit frames, got {len(self.gray_frames)}")
        if not self.band_px > 0:
            raise ValueError(f"band_px: expected > 0 projector pixels per code value, got {self.band_px}")
        if isinstance(self.threshold, InverseFrames) and len(self.threshold.frames) != len(self.gray_frames):
            raise ValueError(
                f"threshold.inverse_frames: expected one inverse per bit frame ({len(self.gray_frames)}), "
                f"got {len(self.threshold.frames)}"
            )

    @property
    def n_bits(self) -> int:
        return len(self.gray_frames)

    @property
    def extent_px(self) -> int:
        """Projector pixels along the code's axis."""
        return self.projector_size_wh_px[0 if self.axis == "columns" else 1]

    @property
    def n_codes(self) -> int:
        """Code values the projector holds: ⌈extent / band_px⌉."""
        return int(np.ceil(self.extent_px / self.band_px - 1e-9))

    def frames_used(self) -> tuple[int, ...]:
        """Every frame index the sequence names."""
        used = list(self.gray_frames)
        if isinstance(self.threshold, WhiteBlack):
            used += [self.threshold.white, self.threshold.black]
        else:
            used += list(self.threshold.frames)
        if self.phase is not None:
            used += list(self.phase.frames)
        return tuple(used)

    def boundary_px(self, k: np.ndarray) -> np.ndarray:
        """Projector coordinate of the boundary between code values k − 1 and k: ⌈k·band_px⌉ − ½."""
        return np.ceil(np.asarray(k, np.float64) * self.band_px - 1e-9) - 0.5

    def band_centre_px(self, k: np.ndarray) -> np.ndarray:
        """Projector coordinate of the middle of code value k's band."""
        return 0.5 * (self.boundary_px(k) + self.boundary_px(np.asarray(k) + 1))

    def band_width_px(self, k: np.ndarray) -> np.ndarray:
        return self.boundary_px(np.asarray(k) + 1) - self.boundary_px(k)


def gray_from_binary(value: np.ndarray) -> np.ndarray:
    """The reflected binary (Gray) code of non-negative integers.

    >>> gray_from_binary(np.arange(4)).tolist()
    [0, 1, 3, 2]
    """
    value = np.asarray(value, np.int64)
    return value ^ (value >> 1)


def binary_from_gray(gray: np.ndarray, n_bits: int) -> np.ndarray:
    """Inverse of `gray_from_binary` for codes of n_bits bits.

    >>> binary_from_gray(np.array([0, 1, 3, 2]), 2).tolist()
    [0, 1, 2, 3]
    """
    value = np.asarray(gray, np.int64).copy()
    shift = 1
    while shift < n_bits:
        value ^= value >> shift
        shift *= 2
    return value


def gray_pattern_values(sequence: PatternSequence, coordinate_px: np.ndarray) -> np.ndarray:
    """What each Gray bit frame shows at projector coordinates along the code's axis (integer pixel indices):
    shape (n_bits, *coordinate.shape) of 0/1, most significant bit first. For virtual rigs and tests."""
    code = np.floor((np.asarray(coordinate_px, np.float64) + 0.5) / sequence.band_px + 1e-9).astype(np.int64)
    gray = gray_from_binary(code)
    n = sequence.n_bits
    return np.stack([(gray >> (n - 1 - i)) & 1 for i in range(n)]).astype(np.uint8)


@dataclass(frozen=True)
class DecodeSettings:
    """Settings of the decoding.

    min_shading_grey: pixels whose shading (white − black, 8-bit scale) is below this get no code (too little of
        the projector's light: shadow, a dark or steep surface, the background).
    clear_fraction: a bit is clear when |I − threshold| ≥ clear_fraction · shading; 0.1 leaves the ~1 px either
        side of a blurred stripe edge undecided and keeps noise of σ = 2 grey from flipping bits at shading ≥ 60.
    """

    min_shading_grey: float = 12.0
    clear_fraction: float = 0.1

    def __post_init__(self) -> None:
        if not self.min_shading_grey >= 0:
            raise ValueError(f"min_shading_grey: expected ≥ 0, got {self.min_shading_grey}")
        if not 0 <= self.clear_fraction < 0.5:
            raise ValueError(f"clear_fraction: expected 0 ≤ f < 0.5, got {self.clear_fraction}")


@dataclass(frozen=True, eq=False)
class Decoding:
    """Per-pixel decoding of one coded sequence on the camera grid, arrays of shape (H, W).

    code: int32 code value, −1 where the pixel has none. reason: uint8 why not (DECODED, UNCLEAR_BIT, LOW_SHADING,
    OUTSIDE_PROJECTOR). shading_grey: float32 white − black (8-bit scale). normalised: float32 (n_bits, H, W),
    each bit frame's (I − threshold) / (shading / 2), the input of the edge location.
    phase_px: float64 projector coordinate from the unwrapped phase (NaN without phase or code); phase_sigma_px
    its σ from the frames' noise; phase_offset_px the offset used (given or fitted); phase_noise_grey the noise
    assumed for it.
    """

    sequence: PatternSequence
    code: np.ndarray
    reason: np.ndarray
    shading_grey: np.ndarray
    normalised: np.ndarray
    phase_px: np.ndarray | None = None
    phase_sigma_px: np.ndarray | None = None
    phase_offset_px: float | None = None

    @property
    def valid(self) -> np.ndarray:
        return self.code >= 0

    @property
    def valid_share(self) -> float:
        return float(np.mean(self.valid))

    def code_centre_px(self) -> np.ndarray:
        """(H, W) projector coordinate of each pixel's band centre (NaN where no code)."""
        centre = self.sequence.band_centre_px(np.maximum(self.code, 0))
        return np.where(self.valid, centre, np.nan)

    def code_sigma_px(self) -> np.ndarray:
        """(H, W) σ of the band centre as the pixel's projector coordinate: band width / √12 (uniform)."""
        width = self.sequence.band_width_px(np.maximum(self.code, 0))
        return np.where(self.valid, width / np.sqrt(12.0), np.nan)


def _grey(frame: np.ndarray, name: str) -> np.ndarray:
    array = np.asarray(frame)
    if array.ndim != 2:
        raise ValueError(f"{name}: expected a grey image of shape (H, W), got {array.shape}")
    if array.dtype == np.uint16:
        return array.astype(np.float32) * np.float32(255.0 / 65535.0)
    return array.astype(np.float32)


def decode(
    frames: Sequence[np.ndarray], sequence: PatternSequence, *, settings: DecodeSettings | None = None
) -> Decoding:
    """Decode a recording's coded sequence: frames in recording order (grey, all of one shape).

    Raises ValueError when the sequence names frames the recording lacks (the file layer words it for its file),
    DecodingError when no pixel decodes or when valid pixels decode to bands beyond the projector's size.
    """
    settings = DecodeSettings() if settings is None else settings
    missing = sorted({i for i in sequence.frames_used() if not 0 <= i < len(frames)})
    if missing:
        raise ValueError(
            f"the pattern sequence names frames {missing} but the recording has {len(frames)} frames "
            f"(0–{len(frames) - 1})"
        )
    shape = np.asarray(frames[0]).shape
    bits = [_grey(frames[i], f"frame {i}") for i in sequence.gray_frames]
    for i, image in zip(sequence.gray_frames, bits, strict=True):
        if image.shape != shape:
            raise ValueError(f"frame {i}: expected shape {shape} like frame 0, got {image.shape}")
    threshold = sequence.threshold
    if isinstance(threshold, WhiteBlack):
        white, black = _grey(frames[threshold.white], "white"), _grey(frames[threshold.black], "black")
        shading = white - black
        thresholds = [0.5 * (white + black)] * len(bits)
    elif isinstance(threshold, InverseFrames):
        inverses = [_grey(frames[i], f"frame {i}") for i in threshold.frames]
        thresholds = [0.5 * (b + inv) for b, inv in zip(bits, inverses, strict=True)]
        # Each pair shows one bright and one dark value: |I − I_inv| is the shading except at the pair's edges,
        # so the largest over the bits is the shading wherever at least one bit is off its edge.
        shading = np.max(np.stack([np.abs(b - inv) for b, inv in zip(bits, inverses, strict=True)]), axis=0)
    else:
        stack = np.stack([_grey(frames[i], f"frame {i}") for i in threshold.frames])
        mean = stack.mean(axis=0)
        shading = (2.0 * np.sqrt(2.0) * stack.std(axis=0)).astype(np.float32)
        thresholds = [mean] * len(bits)
    half = np.maximum(0.5 * shading, 1e-6)
    normalised = np.stack([(b - t) / half for b, t in zip(bits, thresholds, strict=True)]).astype(np.float32)
    clear = np.all(np.abs(normalised) >= 2.0 * settings.clear_fraction, axis=0)
    lit = shading >= settings.min_shading_grey
    gray = np.zeros(shape, np.int64)
    for plane in normalised:
        gray = (gray << 1) | (plane > 0)
    code = binary_from_gray(gray, sequence.n_bits)
    reason = np.full(shape, DECODED, np.uint8)
    reason[~clear] = UNCLEAR_BIT
    reason[~lit] = LOW_SHADING
    ok = reason == DECODED
    beyond = ok & (code >= sequence.n_codes)
    if np.count_nonzero(ok) == 0:
        raise DecodingError(
            "the coded sequence decodes to no valid pixel: "
            + ("the shading (white − black) is below "
               f"{settings.min_shading_grey:g} grey everywhere" if not np.any(lit) else "no pixel has every bit clear")
            + "; check the frame numbers and the threshold frames"
        )  # fmt: skip
    if np.count_nonzero(beyond) > 0.01 * np.count_nonzero(ok):
        worst = int(code[beyond].max())
        start = float(sequence.boundary_px(np.array(worst))) + 0.5
        raise DecodingError(
            f"projector_size_px {list(sequence.projector_size_wh_px)} is smaller than the code needs: "
            f"{np.count_nonzero(beyond)} pixels decode to code value {worst} (projector "
            f"{'column' if sequence.axis == 'columns' else 'row'} {start:g} and "
            f"beyond), but the projector holds {sequence.n_codes} values of {sequence.band_px:g} px"
        )
    reason[beyond] = OUTSIDE_PROJECTOR
    code = np.where(reason == DECODED, code, -1).astype(np.int32)
    decoding = Decoding(
        sequence=sequence, code=code, reason=reason, shading_grey=shading.astype(np.float32), normalised=normalised
    )
    if sequence.phase is not None:
        decoding = _with_phase(decoding, frames)
    return decoding


def _with_phase(decoding: Decoding, frames: Sequence[np.ndarray]) -> Decoding:
    """The decoding with the phase's projector coordinate, unwrapped by the code."""
    phase = decoding.sequence.phase
    assert phase is not None
    stack = np.stack([_grey(frames[i], f"frame {i}") for i in phase.frames]).astype(np.float64)
    n = len(phase.frames)
    delta = 2.0 * np.pi * np.arange(n) / n
    s = np.tensordot(np.sin(delta), stack, axes=1)
    c = np.tensordot(np.cos(delta), stack, axes=1)
    wrapped = np.arctan2(s, c) / (2.0 * np.pi) * phase.period_px  # x − offset modulo the period
    modulation = 2.0 / n * np.hypot(s, c)  # the sinusoid's amplitude B (grey)
    # Residual of the frames from the fitted sinusoid: the noise σ of one sample, per pixel.
    mean = stack.mean(axis=0)
    fitted = mean + modulation * np.cos(np.arctan2(s, c)[None] - delta[:, None, None])
    dof = max(n - 3, 1)
    noise = np.sqrt(np.sum((stack - fitted) ** 2, axis=0) / dof) if n > 3 else np.full(mean.shape, np.nan)
    coarse = decoding.code_centre_px()
    valid = decoding.valid
    offset = phase.offset_px
    if offset is None:
        diffs = (coarse - wrapped)[valid]
        # The median of the wrapped difference on the circle: mean direction first, then the median around it.
        angle = 2.0 * np.pi * diffs / phase.period_px
        centre = np.arctan2(np.mean(np.sin(angle)), np.mean(np.cos(angle)))
        around = np.mod(angle - centre + np.pi, 2.0 * np.pi) - np.pi
        offset = float((centre + np.median(around)) / (2.0 * np.pi) * phase.period_px)
    unwrapped = wrapped + offset
    unwrapped = unwrapped + phase.period_px * np.round((coarse - unwrapped) / phase.period_px)
    # σ of the phase of N-step sinusoids under noise σ_I: σ_φ = σ_I √(2/N) / B (rad).
    if n <= 3:
        # Three steps fit exactly: take the noise from the frames' local scatter, 2 grey for 8-bit frames at least.
        noise = np.full(mean.shape, 2.0)
    sigma_px = noise * np.sqrt(2.0 / n) / np.maximum(modulation, 1e-6) * phase.period_px / (2.0 * np.pi)
    ok = valid & (modulation > 0)
    return Decoding(
        sequence=decoding.sequence, code=decoding.code, reason=decoding.reason, shading_grey=decoding.shading_grey,
        normalised=decoding.normalised, phase_px=np.where(ok, unwrapped, np.nan),
        phase_sigma_px=np.where(ok, sigma_px, np.nan), phase_offset_px=offset,
    )  # fmt: skip


def scan_axis_of(decoding: Decoding) -> Literal["rows", "cols"]:
    """The image axis along which the code changes most ("rows": scan along image rows, the code's stripes run
    roughly vertically in the image). Codes are compared SCAN_AXIS_GAP_PX apart, across the undecided pixels
    that line every stripe edge."""
    code = decoding.code.astype(np.int64)
    valid = decoding.valid
    gap = SCAN_AXIS_GAP_PX
    du = np.abs(code[:, gap:] - code[:, :-gap])[valid[:, gap:] & valid[:, :-gap]]
    dv = np.abs(code[gap:] - code[:-gap])[valid[gap:] & valid[:-gap]]
    return "rows" if (du.mean() if du.size else 0.0) >= (dv.mean() if dv.size else 0.0) else "cols"


@dataclass(frozen=True, eq=False)
class CodedEdges:
    """Stripe edges of the bit frames named by their codes, N points.

    scan_axis: "rows" or "cols" (as `fringes.FrameEdges`); line, t_px: the scan line and the sub-pixel position
    along it; q_px: (N, 2) camera pixels (u, v); boundary: (N,) code value k of the boundary between k − 1 and k;
    projector_px: (N,) its projector coordinate along the code's axis (exact: the pattern puts it there);
    sigma_t_px: (N,) σ of the position along the scan line (the bit frame's edge noise); bit: (N,) which bit frame
    (index into gray_frames). n_rejected: edge points whose two sides did not decode to neighbouring codes of
    that bit.
    """

    scan_axis: Literal["rows", "cols"]
    line: np.ndarray
    t_px: np.ndarray
    q_px: np.ndarray
    boundary: np.ndarray
    projector_px: np.ndarray
    sigma_t_px: np.ndarray
    bit: np.ndarray
    n_rejected: int

    def __len__(self) -> int:
        return len(self.line)


SCAN_AXIS_GAP_PX = 8
# The normalised bit frame as the locator sees it: n = ±1 (the white and black levels) at 190 ± 40 grey; an edge
# needs half the full swing of contrast.
EDGE_GREY_MID = 190.0
EDGE_GREY_PER_UNIT = 40.0
# How far (px along the scan line) the codes on an edge's two sides are looked for: past the undecided pixels
# around the edge (clear_fraction) and the blur.
SIDE_SEARCH_PX = 8
# Edges closer than this (px along the scan line) to a neighbouring edge whose code is not the next one (an
# occlusion, the rim of a shadow, a mixed pixel at a silhouette) or closer than MIN_EDGE_GAP_PX to any, are left
# out: there the crossing is a blend of two surfaces, not a stripe edge.
NEIGHBOUR_CHECK_PX = 6.0
MIN_EDGE_GAP_PX = 1.0
# Gray-code stripes are wide: no smoothing along them before locating (it only correlates the lines' noise); on
# the virtual rig this gives 0.011 mm RMS on a sphere against 0.013 mm with the default 1 px. The mid-level is the
# envelopes' (both flat sides of a bit's stripe lie within the window): the means over whole periods took the
# virtual rig's sphere from 0.019 to 0.050 mm RMS and the real ball's from 0.22 to 0.41 mm. The locator is given
# each bit's true period (`coded_edges`), so its rules that judge an edge by its neighbours know the stripes'
# geometry: at periods beyond MAX_PERIOD_PX it judges none (the rules' own docs say why); at finer bits those on by
# default are right but the width alternation, which a scene's silhouettes defeat (`EdgeSettings`).
GRAY_EDGE_SETTINGS = EdgeSettings(
    presmooth_px=0.0,
    mid_level="envelopes",
    max_width_alternation_px=None,
)


def coded_edges(decoding: Decoding, *, edge_settings: EdgeSettings | None = None) -> CodedEdges:
    """The stripe edges of every Gray bit frame, located by `fringes.locate_edges` on the normalised frame and named
    by the decoded codes beside them (see the module docstring).

    The normalised frame n = (I − threshold) / (shading / 2) takes out shading and albedo; it is shown to the
    locator as grey EDGE_GREY_MID + EDGE_GREY_PER_UNIT·n (no-code pixels at the mid-grey), so the locator's own
    local mid-level ((max + min)/2 over its window) decides where the edge is, not the threshold (a mean of
    sinusoids is off by the projector's gamma). The grey levels keep the dark side above the locator's "black"
    test (a crack darker than the dark stripes beside it), which wide bands would otherwise trip. Each bit is
    located at its true period in the camera (up to MAX_FIXED_PERIOD_PX), so the locator's rules know its
    stripes' geometry; beyond MAX_PERIOD_PX its windows stay those of that period, so the mid-level window spans
    both sides within half a window of each edge.
    """
    sequence = decoding.sequence
    scan_axis = scan_axis_of(decoding)
    code = decoding.code
    n_bits = sequence.n_bits
    lines: list[np.ndarray] = []
    ts: list[np.ndarray] = []
    bounds: list[np.ndarray] = []
    sigmas: list[np.ndarray] = []
    bits: list[np.ndarray] = []
    rejected = 0
    scan_code = code if scan_axis == "rows" else code.T
    band_cam_px = _band_width_camera_px(scan_code)
    lit = decoding.reason != LOW_SHADING
    for i, plane in enumerate(decoding.normalised):
        position = n_bits - 1 - i  # bit position from the least significant
        # Gray bit p has period 2^(p+2) code values (bright over two bands each side of the reflections).
        period_cam = band_cam_px * 2.0 ** (position + 2)
        if period_cam < MIN_PERIOD_PX * 1.5:
            continue  # finer than the camera resolves: its edges would not be located, only guessed
        image = np.where(lit, np.clip(EDGE_GREY_MID + EDGE_GREY_PER_UNIT * plane, 0.0, 249.0), EDGE_GREY_MID)
        settings = replace(
            edge_settings or GRAY_EDGE_SETTINGS, axis=scan_axis, period_px=float(min(period_cam, MAX_FIXED_PERIOD_PX)),
            min_contrast_grey=EDGE_GREY_PER_UNIT,
            dark_fraction=0.0,
        )  # fmt: skip
        edges = locate_edges(image.astype(np.float32), settings)
        if len(edges) == 0:
            continue
        line = edges.line.astype(np.int64)
        t = edges.t_px.astype(np.float64)
        left = _side_code(scan_code, line, np.floor(t).astype(np.int64), -1)
        right = _side_code(scan_code, line, np.ceil(t).astype(np.int64), +1)
        k = np.maximum(left, right)
        ok = (left >= 0) & (right >= 0) & (np.abs(left - right) == 1)
        # The boundary k is an edge of the bit at k's lowest set bit; any other is a misnamed edge.
        lowest = np.where(k > 0, np.log2(np.maximum(k & -k, 1)).astype(np.int64), -1)
        ok &= lowest == position
        rejected += int(np.count_nonzero(~ok))
        sigma = edge_sigma_px(edges.noise_px, settings) if np.isfinite(edges.noise_px) else 0.1
        lines.append(line[ok])
        ts.append(t[ok])
        bounds.append(k[ok])
        sigmas.append(np.full(np.count_nonzero(ok), sigma))
        bits.append(np.full(np.count_nonzero(ok), i))
    line = np.concatenate(lines) if lines else np.zeros(0, np.int64)
    t = np.concatenate(ts) if ts else np.zeros(0)
    k = np.concatenate(bounds) if bounds else np.zeros(0, np.int64)
    reach = int(np.ceil(2.0 * (edge_settings or GRAY_EDGE_SETTINGS).edge_smoothing_lines)) + 1
    keep = _consistent_with_neighbours(line, t, k) & _smooth_across_lines(scan_code, line, t, k, reach_lines=reach)
    rejected += int(np.count_nonzero(~keep))
    line, t, k = line[keep], t[keep], k[keep]
    sigmas = [np.concatenate(sigmas)[keep]] if sigmas else []
    bits = [np.concatenate(bits)[keep]] if bits else []
    q = np.column_stack([t, line] if scan_axis == "rows" else [line, t]).astype(np.float64)
    return CodedEdges(
        scan_axis=scan_axis, line=line, t_px=t, q_px=q.reshape(-1, 2), boundary=k,
        projector_px=sequence.boundary_px(k), sigma_t_px=np.concatenate(sigmas) if sigmas else np.zeros(0),
        bit=np.concatenate(bits) if bits else np.zeros(0, np.int64), n_rejected=rejected,
    )  # fmt: skip


def _consistent_with_neighbours(line: np.ndarray, t: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(N,) bool: no other edge on the same scan line within NEIGHBOUR_CHECK_PX whose boundary is not k ± 1,
    and none closer than MIN_EDGE_GAP_PX."""
    keep = np.ones(len(line), bool)
    if len(line) < 2:
        return keep
    order = np.lexsort((t, line))
    ls, ts, ks = line[order], t[order], k[order]
    same = ls[1:] == ls[:-1]
    gap = ts[1:] - ts[:-1]
    bad_pair = same & (gap < NEIGHBOUR_CHECK_PX) & ((np.abs(ks[1:] - ks[:-1]) != 1) | (gap < MIN_EDGE_GAP_PX))
    bad = np.zeros(len(ls), bool)
    bad[1:] |= bad_pair
    bad[:-1] |= bad_pair
    keep[order[bad]] = False
    return keep


def _smooth_across_lines(
    scan_code: np.ndarray, line: np.ndarray, t: np.ndarray, k: np.ndarray, *, reach_lines: int
) -> np.ndarray:
    """(N,) bool: within `reach_lines` lines either side (how far the smoothing along an edge reaches) and 2 px
    along them, every decoded code is within 2 of the boundary's: no occlusion or silhouette where the smoothing
    would mix another surface's edge into this one."""
    n_lines, n_samples = scan_code.shape
    keep = np.ones(len(line), bool)
    centre = np.rint(t).astype(np.int64)
    for dl in range(-reach_lines, reach_lines + 1):
        for dt in (-2, 0, 2):
            li, ti = line + dl, centre + dt
            inside = (li >= 0) & (li < n_lines) & (ti >= 0) & (ti < n_samples)
            values = np.full(len(line), -1, np.int64)
            values[inside] = scan_code[li[inside], ti[inside]]
            keep &= ~((values >= 0) & (np.abs(values - k) > 2))
    return keep


def _band_width_camera_px(scan_code: np.ndarray) -> float:
    """Median width (camera px along the scan lines) of one code value: SCAN_AXIS_GAP_PX over the mean change
    of the code across that gap (the undecided pixels at each edge are skipped, not counted)."""
    gap = SCAN_AXIS_GAP_PX
    valid = (scan_code[:, gap:] >= 0) & (scan_code[:, :-gap] >= 0)
    change = np.abs(scan_code[:, gap:].astype(np.int64) - scan_code[:, :-gap])[valid]
    if change.size == 0 or change.mean() == 0:
        return float(scan_code.shape[1])
    return float(gap / change.mean())


def _side_code(scan_code: np.ndarray, line: np.ndarray, start: np.ndarray, direction: int) -> np.ndarray:
    """The first decoded code along each line from `start` in `direction`, within SIDE_SEARCH_PX; −1 if none."""
    n_samples = scan_code.shape[1]
    out = np.full(len(line), -1, np.int64)
    for step in range(SIDE_SEARCH_PX + 1):
        index = start + direction * step
        inside = (index >= 0) & (index < n_samples) & (out < 0)
        values = np.full(len(line), -1, np.int64)
        values[inside] = scan_code[line[inside], index[inside]]
        out = np.where(inside & (values >= 0), values, out)
    return out
