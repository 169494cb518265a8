"""Projector calibration: the look-up table of every stripe edge's image position against Z (docs/method.md §4).

Belongs here: building the table from a flat-plate Z-stack (edge identity kept consistent over all Z steps),
checking it (monotonic in Z, sensitive enough, covering the field), fitting Z as a low-order polynomial of the
edge position for every (edge, scan line), and looking Z up without ever extrapolating. Not here: locating edges
in one frame (`fringes.py`), tracking them through a test (`topography.py`), files (`fringelab.formats.topography.py`).

Table. Edge k (k = 0, 1, ... in stripe order along +t, polarity alternating) on scan line s of the flat plate at
height Z_j has position `lut_t_px[k, s, j]` along the line (NaN where not seen). For each (k, s) with enough
samples over a contiguous run of Z steps, `Z = Σ_i c_i τ^i` with τ = (t − t_centre)/t_scale is fitted by least
squares. `t_lo_px..t_hi_px` is the sampled range widened by a noise margin of `range_margin_mm` of Z (0.1 mm,
about five times the noise of one measured Z): a flat plate resting exactly at the lowest calibrated Z must not
lose half of its points to noise. Outside it nothing is looked up, and the polynomial is never evaluated further
out.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal, Protocol

import numba
import numpy as np

from . import Cancelled, MeasurementError
from .calibration import ProgressCallback
from .camera import Camera, InverseModel, backproject_to_z, fit_inverse_model
from .fringes import Axis, EdgeSettings, FrameEdges, detect_stripes, locate_edges, order_edges
from .uncertainty import contiguous_index_array, table_sigma_z_mm


class ProjectorCalibrationError(MeasurementError):
    """The projector look-up table cannot be built or is unusable (too few Z steps, stripes that do not move
    with Z, Z steps too coarse for the stripe period, edges lost between steps)."""


class CalibrationMismatchError(MeasurementError):
    """Recordings and calibrations do not belong together (image size, camera, stripe direction)."""


class CameraModel(Protocol):
    """What the topography needs of a camera calibration: the camera and its inverse model.

    A `calibration.CameraCalibration` (from `fringelab.formats.camera.read_camera_json`) is one;
    `exact_camera_model` makes
    one from a bare `Camera`.
    """

    @property
    def camera(self) -> Camera: ...

    @property
    def inverse(self) -> InverseModel: ...


@dataclass(frozen=True)
class ExactCamera:
    """A `CameraModel` of a known camera (synthetic data, tests)."""

    camera: Camera
    inverse: InverseModel


def exact_camera_model(camera: Camera) -> ExactCamera:
    """The camera with its fitted inverse model, usable wherever a camera calibration is expected."""
    return ExactCamera(camera=camera, inverse=fit_inverse_model(camera))


def camera_fingerprint(camera: Camera) -> str:
    """A short hash of the camera's parameters: calibrations made with one camera model carry the same one."""
    text = ",".join(f"{name}={value!r}" for name, value in sorted(asdict(camera).items()))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class ProjectorSettings:
    """Settings of the projector calibration.

    edges: edge location settings (axis and period are detected on the reference frame when left automatic,
        then fixed for every frame of the calibration and of the tests that use it).
    reference_z_mm: the Z at which edge k is counted (the flat test plate's rest height, usually 0).
    poly_degree: degree of Z as a polynomial in t per (edge, line); 3 follows the mild curvature of t(Z) that
        perspective gives while averaging the noise of ~40 Z steps.
    min_z_samples: fewest Z steps an (edge, line) needs in a contiguous run to get a table entry.
    min_sensitivity_px_per_mm: entries whose edge moves less than this per mm of Z are left out: their Z would
        be noise (0.05 px/mm turns 0.01 px of edge noise into 0.2 mm).
    max_reversal_px: a step of t against the entry's trend larger than this marks the entry non-monotonic.
    max_step_fraction: the largest edge shift between consecutive Z steps, as a fraction of the stripe period,
        for which identity is carried safely from step to step.
    range_margin_mm: how far (in Z) each entry's range is widened for noise (see the module docstring); 0 looks
        up strictly within the sampled positions.
    """

    edges: EdgeSettings = field(default_factory=EdgeSettings)
    reference_z_mm: float = 0.0
    poly_degree: int = 3
    min_z_samples: int = 6
    min_sensitivity_px_per_mm: float = 0.05
    max_reversal_px: float = 0.1
    max_step_fraction: float = 0.35
    range_margin_mm: float = 0.1

    def __post_init__(self) -> None:
        if not 1 <= self.poly_degree <= 5:
            raise ValueError(f"poly_degree: expected 1..5, got {self.poly_degree}")
        if self.min_z_samples < self.poly_degree + 2:
            raise ValueError(
                f"min_z_samples: expected ≥ poly_degree + 2 = {self.poly_degree + 2}, got {self.min_z_samples}"
            )
        if not self.range_margin_mm >= 0:
            raise ValueError(f"range_margin_mm: expected ≥ 0, got {self.range_margin_mm}")
        if not 0 < self.max_step_fraction <= 0.5:
            raise ValueError(f"max_step_fraction: expected 0 < f ≤ 0.5, got {self.max_step_fraction}")


@dataclass(frozen=True, eq=False)
class PatternEdges:
    """Which projector stripe edge each table edge is, for a table generated from a camera–projector model
    (`procam_table.py`): axis "columns" (projector x) or "rows" (y), and projector_px (K,) the projector coordinate of
    table edge k along it. What a Gray code recorded at rest names its stripe edges by (`order.
    identify_reference_from_code`); a Z-stack's table has none (its edges are counted from the first one seen)."""

    axis: Literal["columns", "rows"]
    projector_px: np.ndarray


@dataclass(frozen=True)
class ProjectorQA:
    """Quality numbers of a projector calibration.

    coverage: fraction of the (edge, line) points seen at the reference Z that have a table entry.
    n_entries: number of (edge, line) table entries; n_edges: number of edges K.
    sensitivity_px_per_mm: percentiles 5, 50, 95 of |dt/dZ| over the entries (how far an edge moves per mm).
    fit_rms_mm: RMS residual in Z of the polynomial fits over all entries; fit_p95_mm: their 95th percentile.
    n_non_monotonic: entries left out because t reversed against its trend in Z.
    n_insensitive: entries left out for too small a sensitivity.
    max_step_shift_periods: largest median edge shift between consecutive Z steps, in stripe periods.
    edge_noise_px: median over frames of the per-frame edge noise estimate.
    z_range_mm: (lowest, highest) calibrated Z.
    xy_extent_mm: (X_min, X_max, Y_min, Y_max) of the entries back-projected at the reference Z.
    """

    coverage: float
    n_entries: int
    n_edges: int
    sensitivity_px_per_mm: tuple[float, float, float]
    fit_rms_mm: float
    fit_p95_mm: float
    n_non_monotonic: int
    n_insensitive: int
    max_step_shift_periods: float
    edge_noise_px: float
    z_range_mm: tuple[float, float]
    xy_extent_mm: tuple[float, float, float, float]


@dataclass(frozen=True, eq=False)
class ProjectorCalibration:
    """The look-up table and its fits (see the module docstring); arrays are (K, S[, ...]) with K edges and S
    scan lines.

    edges: the edge settings used, with axis and period fixed; tests must be processed with them.
    z_mm: (J,) calibration heights in increasing order; polarity: (K,) int8 of each edge.
    lut_t_px: (K, S, J) float32, the table; reference_t_px: (K, S) positions at the reference Z.
    coefficients: (K, S, D+1); t_centre_px, t_scale_px, t_lo_px, t_hi_px, z_lo_mm, z_hi_mm,
    sensitivity_px_per_mm, fit_rms_mm: (K, S), NaN where there is no entry.
    """

    image_shape_hw_px: tuple[int, int]
    edges: EdgeSettings
    reference_z_mm: float
    z_mm: np.ndarray
    polarity: np.ndarray
    lut_t_px: np.ndarray
    reference_t_px: np.ndarray
    coefficients: np.ndarray
    t_centre_px: np.ndarray
    t_scale_px: np.ndarray
    t_lo_px: np.ndarray
    t_hi_px: np.ndarray
    z_lo_mm: np.ndarray
    z_hi_mm: np.ndarray
    sensitivity_px_per_mm: np.ndarray
    fit_rms_mm: np.ndarray
    qa: ProjectorQA
    camera_fingerprint: str
    provenance: dict[str, Any] = field(default_factory=dict)
    pattern_edges: PatternEdges | None = None

    @property
    def axis(self) -> Axis:
        return "rows" if self.edges.axis == "rows" else "cols"  # fixed at calibration: never "auto"

    @property
    def period_px(self) -> float:
        assert self.edges.period_px is not None  # fixed at calibration
        return float(self.edges.period_px)

    @property
    def n_edges(self) -> int:
        return int(self.lut_t_px.shape[0])

    @property
    def n_lines(self) -> int:
        return int(self.lut_t_px.shape[1])

    @functools.cached_property
    def table_sigma_z_mm(self) -> np.ndarray:
        """(K, S) σ_Z (mm) of each table entry's prediction (`uncertainty.table_sigma_z_mm`)."""
        return table_sigma_z_mm(
            fit_rms_mm=self.fit_rms_mm, n_heights=np.count_nonzero(np.isfinite(self.lut_t_px), axis=-1),
            n_coefficients=self.coefficients.shape[-1],
        )  # fmt: skip

    @functools.cached_property
    def n_heights_by_line(self) -> np.ndarray:
        """(S, K) int64: how many calibration heights each table entry was fitted to, laid out as `lookup_table`."""
        return np.ascontiguousarray(np.count_nonzero(np.isfinite(self.lut_t_px), axis=-1).T.astype(np.int64))

    @functools.cached_property
    def reference_lines(self) -> EdgeLines:
        """The reference positions line by line (`match_to_reference`)."""
        return EdgeLines.from_positions(self.reference_t_px)

    @functools.cached_property
    def valid(self) -> np.ndarray:
        """(K, S) bool, read-only: where the table has an entry."""
        valid = np.isfinite(self.t_lo_px)
        valid.flags.writeable = False
        return valid

    def z_from_t(self, k: np.ndarray, line: np.ndarray, t_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Z (mm) of edge points, each shape (N,): edge index k, scan line, position t (px).

        Returns z_mm (NaN where not looked up) and status (int8): 0 looked up, 1 outside the calibrated range of
        that (edge, line) (never extrapolated), 2 no table entry for that (edge, line).
        """
        return _z_from_t_kernel(
            np.ascontiguousarray(k, np.int64), np.ascontiguousarray(line, np.int64),
            np.ascontiguousarray(t_px, np.float64), self.lookup_table,
        )  # fmt: skip

    @functools.cached_property
    def lookup_table(self) -> np.ndarray:
        """The table packed for the look-up of many points (`table_z_at`), shape (S, K, 6 + D + 1): per scan line
        and edge t_lo, t_hi, t_centre, t_scale, the sensitivity (px/mm), the table's σ_Z (mm) and the
        coefficients, the edges of a line next to each other as the points of a frame come (along the lines)."""
        fields = [self.t_lo_px, self.t_hi_px, self.t_centre_px, self.t_scale_px, self.sensitivity_px_per_mm,
                  self.table_sigma_z_mm]  # fmt: skip
        packed = np.concatenate([np.stack(fields, axis=-1), self.coefficients], axis=-1).astype(np.float64)
        return np.ascontiguousarray(packed.transpose(1, 0, 2))


# Fields of `ProjectorCalibration.lookup_table` besides the bounds and the polynomial.
TABLE_SENSITIVITY = 4  # dt/dZ (px/mm)
TABLE_SIGMA_Z = 5  # the table's σ_Z (mm)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def table_z_at(table: np.ndarray, k: int, line: int, t_px: float) -> tuple[float, int]:
    """Z (mm) and status of one edge point from `ProjectorCalibration.lookup_table`, as `z_from_t` gives them: for
    compiled loops over many points."""
    value, status, _ = table_z_tau_at(table, k, line, t_px)
    return value, status


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def table_z_tau_at(table: np.ndarray, k: int, line: int, t_px: float) -> tuple[float, int, float]:
    """`table_z_at`, and the point's place τ in the entry's fitted range (the polynomial's variable; NaN where the
    status is not 0), for loops that need both (one division, not two)."""
    n_lines, n_edges, n_fields = table.shape
    if k < 0 or k >= n_edges or line < 0 or line >= n_lines:
        return np.nan, 2, np.nan
    entry = table[line, k]
    if not np.isfinite(entry[0]):
        return np.nan, 2, np.nan
    if not (entry[0] <= t_px <= entry[1]):
        return np.nan, 1, np.nan
    tau = (t_px - entry[2]) / entry[3]
    value = entry[n_fields - 1]
    for j in range(n_fields - 2, TABLE_SIGMA_Z, -1):
        value = value * tau + entry[j]
    return value, 0, tau


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _z_from_t_kernel(
    k: np.ndarray, line: np.ndarray, t: np.ndarray, table: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    z = np.empty(len(t))
    status = np.empty(len(t), np.int8)
    for i in range(len(t)):
        z[i], status[i] = table_z_at(table, k[i], line[i], t[i])
    return z, status


# --------------------------------------------------------------------------------------------------------------
# Building the table


@dataclass(frozen=True, eq=False)
class EdgeLines:
    """Edge positions (K, S) rearranged line by line in t order, for nearest-edge look-ups.

    start: (S + 1,) where each line's entries begin; t_px, k: (M,) the finite positions and their edge index.
    """

    start: np.ndarray
    t_px: np.ndarray
    k: np.ndarray

    @classmethod
    def from_positions(cls, positions_t_px: np.ndarray) -> EdgeLines:
        """From positions (K, S) (NaN = none)."""
        kk, ss = np.nonzero(np.isfinite(positions_t_px))
        t = positions_t_px[kk, ss].astype(np.float64)
        order = np.lexsort((t, ss))
        start = np.searchsorted(ss[order], np.arange(positions_t_px.shape[1] + 1))
        return cls(start=start.astype(np.int64), t_px=np.ascontiguousarray(t[order]), k=kk[order].astype(np.int64))


def match_to_reference(
    line: np.ndarray,
    t_px: np.ndarray,
    polarity: np.ndarray,
    reference: EdgeLines,
    reference_polarity: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """For each edge point, the nearest reference edge of the same polarity on the same line (the one at lower t
    when two are as near).

    line, t_px, polarity: shape (N,) edge points; reference: the reference edges (`EdgeLines.from_positions`);
    reference_polarity: (K,). Returns k (N,) (−1 where the line has no reference edge of that polarity) and the
    signed distance t − reference (N,) in px (NaN where k is −1).
    """
    # A frame's line (int32) and t (float32) go in as they are, widened as they are read (compared and subtracted
    # in float64, as converted copies were).
    t_px = np.asarray(t_px)
    t_type = np.float32 if t_px.dtype == np.float32 else np.float64
    return _match_kernel(
        contiguous_index_array(line), np.ascontiguousarray(t_px, t_type),
        np.ascontiguousarray(polarity, np.int8), reference.start, reference.t_px,
        np.ascontiguousarray(reference_polarity, np.int8)[reference.k], reference.k,
    )  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _match_kernel(
    line: np.ndarray,
    t: np.ndarray,
    polarity: np.ndarray,
    start: np.ndarray,
    ref_t: np.ndarray,
    ref_polarity: np.ndarray,
    ref_k: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    n = len(line)
    k_out = np.full(n, -1, np.int64)
    distance = np.full(n, np.nan)
    n_lines = len(start) - 1
    for i in range(n):
        if line[i] < 0 or line[i] >= n_lines:
            continue
        lo, hi = start[line[i]], start[line[i] + 1]
        a, b = lo, hi
        while a < b:  # first entry with t >= the point's
            mid = (a + b) // 2
            if ref_t[mid] < t[i]:
                a = mid + 1
            else:
                b = mid
        below = a - 1
        while below >= lo and ref_polarity[below] != polarity[i]:
            below -= 1
        above = a
        while above < hi and ref_polarity[above] != polarity[i]:
            above += 1
        best = -1
        if below >= lo:
            best = below
        if above < hi and (best < 0 or ref_t[above] - t[i] < t[i] - ref_t[below]):
            best = above
        if best >= 0:
            k_out[i] = ref_k[best]
            distance[i] = t[i] - ref_t[best]
    return k_out, distance


def _assign_by_votes(
    edges: FrameEdges, predicted_t_px: np.ndarray, polarity: np.ndarray
) -> tuple[np.ndarray, float, float]:
    """Edge index of every point of a frame from its stripe order and the predicted positions of the table's
    edges: every point votes for the nearest predicted edge of its polarity, and each component of the frame's
    order takes the offset most of its points vote for.

    Returns k (N,) (−1 unassigned), the fraction of voting points that agree with their component's offset
    (a split vote means the stripes moved about half a period: ambiguous), and the median |t − prediction| of
    the assigned points (px).
    """
    order = order_edges(edges)
    relative = order.crossing_index(edges)
    component = order.crossing_component(edges)
    k_near, distance = match_to_reference(
        edges.line, edges.t_px, edges.polarity, EdgeLines.from_positions(predicted_t_px), polarity
    )
    votes_ok = (k_near >= 0) & (relative >= 0)
    k = np.full(len(edges), -1, np.int64)
    agreeing = 0
    voting = 0
    for comp in np.unique(component[votes_ok]):
        members = votes_ok & (component == comp)
        offsets, counts = np.unique(k_near[members] - relative[members], return_counts=True)
        best = int(np.argmax(counts))
        voting += int(counts.sum())
        agreeing += int(counts[best])
        # A component must be carried by a clear majority of its own points.
        if counts[best] >= 0.6 * counts.sum() and counts[best] >= 10:
            in_comp = (component == comp) & (relative >= 0)
            k[in_comp] = relative[in_comp] + offsets[best]
    agreement = agreeing / voting if voting else 0.0
    matched = (k >= 0) & (k == k_near)
    median_distance = float(np.median(np.abs(distance[matched]))) if np.any(matched) else float("nan")
    return k, agreement, median_distance


def _scatter(k: np.ndarray, line: np.ndarray, t_px: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Dense (K, S) array of positions; (k, line) pairs that occur twice in a frame are dropped (NaN)."""
    return _scatter_kernel(np.ascontiguousarray(k, np.int64), np.ascontiguousarray(line, np.int64),
                           np.ascontiguousarray(t_px, np.float64), shape[0], shape[1])  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _scatter_kernel(k: np.ndarray, line: np.ndarray, t_px: np.ndarray, n_edges: int, n_lines: int) -> np.ndarray:
    out = np.full((n_edges, n_lines), np.nan)
    seen = np.zeros((n_edges, n_lines), np.uint8)
    for i in range(len(k)):
        if 0 <= k[i] < n_edges and 0 <= line[i] < n_lines:
            seen[k[i], line[i]] = min(seen[k[i], line[i]] + 1, 2)
            out[k[i], line[i]] = t_px[i] if seen[k[i], line[i]] == 1 else np.nan
    return out


def build_projector_calibration(
    frames: Iterable[np.ndarray],
    z_mm: Sequence[float],
    camera_model: CameraModel,
    *,
    settings: ProjectorSettings | None = None,
    provenance: dict[str, Any] | None = None,
    progress: ProgressCallback | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> ProjectorCalibration:
    """The look-up table of a flat-plate Z-stack (docs/method.md §4).

    frames: the grey frames in recording order (read one at a time); z_mm: the stage Z of each frame, strictly
    monotonic. camera_model: the camera the frames were taken with (image size check, object-space QA, and a
    fingerprint so tests can be checked against it).

    Identity: the frame nearest to reference_z_mm is put in stripe order (edges counted k = 0, 1, ... along
    +t); every further frame, in order of Z away from it, is put in order on its own and its offset found by the
    majority vote of its points against the positions predicted from the previous two steps. The Z steps must
    move the edges by less than settings.max_step_fraction of a stripe period (QA: max_step_shift_periods);
    steps of more than about 0.6 period alias (each edge looks like its neighbour moving the other way, the same
    for all of them), which no single image reveals; the edges' positions over Z do, as they bend off the
    straight lines they follow in space (`_refuse_aliased_steps`), and the calibration is refused. Raises
    ProjectorCalibrationError when identity cannot be carried (steps too coarse), when the stripes do not move
    with Z, or when too little of the field gets a table entry; CalibrationMismatchError when the frames are not
    of the camera's size.
    """
    settings = ProjectorSettings() if settings is None else settings
    z = np.asarray(z_mm, dtype=np.float64)
    if z.ndim != 1 or len(z) < settings.min_z_samples:
        raise ProjectorCalibrationError(
            f"projector calibration needs at least {settings.min_z_samples} Z steps, got {z.size}"
        )
    steps = np.diff(z)
    if not (np.all(steps > 0) or np.all(steps < 0)):
        raise ValueError("z_mm: expected strictly monotonic stage heights (one per frame)")
    camera = camera_model.camera
    expected_shape = (camera.image_height_px, camera.image_width_px)
    frame_list = frames if isinstance(frames, Sequence) else list(frames)
    n_frames = len(z)
    if len(frame_list) != n_frames:
        raise ValueError(f"z_mm has {n_frames} heights but the recording has {len(frame_list)} frames")
    sorted_j = np.argsort(z)  # position in Z order → recording index
    z_sorted = z[sorted_j]
    j_ref = int(np.argmin(np.abs(z_sorted - settings.reference_z_mm)))
    visit = [j_ref, *range(j_ref + 1, n_frames), *range(j_ref - 1, -1, -1)]
    total = n_frames + 1

    def frame_at(j: int) -> np.ndarray:
        image = np.asarray(frame_list[int(sorted_j[j])])
        if image.shape[:2] != expected_shape:
            raise CalibrationMismatchError(
                f"frame {int(sorted_j[j])} is {image.shape[1]} × {image.shape[0]} px but the camera calibration is "
                f"for {expected_shape[1]} × {expected_shape[0]} px: use the camera calibration of this camera"
            )
        return image

    reference_image = frame_at(j_ref)
    edge_settings = settings.edges
    if edge_settings.axis == "auto" or edge_settings.period_px is None:
        geometry = detect_stripes(reference_image, axis=edge_settings.axis)
        edge_settings = replace(
            edge_settings,
            axis=geometry.axis,
            period_px=geometry.period_px if edge_settings.period_px is None else edge_settings.period_px,
        )
    assert edge_settings.period_px is not None
    period = float(edge_settings.period_px)

    positions: dict[int, np.ndarray] = {}  # j → (K_cap, S) positions, k shifted by `k_offset`
    noise: list[float] = []
    step_shifts: list[float] = []
    polarity: np.ndarray | None = None
    n_lines = expected_shape[0] if edge_settings.axis == "rows" else expected_shape[1]
    for done, j in enumerate(visit):
        if should_cancel is not None and should_cancel():
            raise Cancelled(f"cancelled after {done} of {n_frames} frames")
        image = reference_image if j == j_ref else frame_at(j)
        edges = locate_edges(image, edge_settings)
        noise.append(edges.noise_px)
        if j == j_ref:
            order = order_edges(edges)
            k = order.crossing_index(edges)
            keep = (k >= 0) & (order.crossing_component(edges) == 0)
            if np.count_nonzero(keep) < 0.5 * len(edges) or len(edges) == 0:
                raise ProjectorCalibrationError(
                    f"the stripes of the reference frame (Z = {z_sorted[j]:g} mm) could not be put in order: only "
                    f"{np.count_nonzero(keep)} of {len(edges)} edge points form one connected stripe pattern"
                )
            k = np.where(keep, k, -1)
            n_k = int(k.max()) + 1
            polarity = np.zeros(n_k, np.int8)
            polarity[k[keep]] = edges.polarity[keep]
            positions[j] = _scatter(k, edges.line.astype(np.int64), edges.t_px.astype(np.float64), (n_k, n_lines))
        else:
            assert polarity is not None
            previous = j - 1 if j > j_ref else j + 1
            before_previous = previous - 1 if j > j_ref else previous + 1
            predicted = positions[previous].copy()
            if before_previous in positions:
                rate = (positions[previous] - positions[before_previous]) / (
                    z_sorted[previous] - z_sorted[before_previous]
                )
                moved = predicted + rate * (z_sorted[j] - z_sorted[previous])
                predicted = np.where(np.isfinite(moved), moved, predicted)
            k, agreement, median_distance = _assign_by_votes(edges, predicted, polarity)
            shift = median_distance / period if np.isfinite(median_distance) else float("nan")
            step_shifts.append(shift)
            if (
                agreement < 0.9
                or not shift <= settings.max_step_fraction
                or np.count_nonzero(k >= 0) < 0.5 * len(edges)
            ):
                raise ProjectorCalibrationError(
                    f"edge identity could not be carried from Z = {z_sorted[previous]:g} mm to Z = {z_sorted[j]:g} mm: "
                    f"the edges moved {shift:.2f} stripe periods from where they were expected ({agreement:.0%} of "
                    f"the edge points agree on which edge is which; at most {settings.max_step_fraction:g} periods "
                    "can be followed safely); record the projector calibration with finer Z steps"
                )
            # Edges that came into view outside the reference frame's range get indices beyond it: grow the table.
            lowest, highest = int(k[k >= 0].min()), int(k.max())
            if lowest < 0 or highest >= len(polarity):
                shift = max(0, -lowest)
                new_n = max(len(polarity), highest + 1) + shift
                polarity = _grown_polarity(polarity, shift, new_n)
                positions = {jj: _grown(p, shift, new_n) for jj, p in positions.items()}
                k = np.where(k >= 0, k + shift, k)
            fits = (k >= 0) & (polarity[np.maximum(k, 0)] == edges.polarity)
            k = np.where(fits, k, -1)
            positions[j] = _scatter(
                k, edges.line.astype(np.int64), edges.t_px.astype(np.float64), (len(polarity), n_lines)
            )
        if progress is not None:
            progress(done + 1, total, "edges")
    assert polarity is not None
    lut = np.stack([positions[j] for j in range(n_frames)], axis=-1).astype(np.float32)
    _refuse_aliased_steps(lut, z_sorted, j_ref, camera_model, axis=edge_settings.axis, period_px=period,
                          max_step_fraction=settings.max_step_fraction)  # fmt: skip
    calibration = _fit_table(
        lut,
        z_sorted,
        polarity,
        j_ref=j_ref,
        settings=settings,
        edge_settings=edge_settings,
        image_shape_hw_px=expected_shape,
        camera_model=camera_model,
        noise_px=float(np.nanmedian(noise)) if noise else float("nan"),
        max_step_shift=float(max(step_shifts, default=0.0)),
        provenance=dict(provenance or {}),
    )
    if progress is not None:
        progress(total, total, "done")
    return calibration


def calibration_from_positions(
    lut_t_px: np.ndarray,
    z_mm: np.ndarray,
    polarity: np.ndarray,
    camera_model: CameraModel,
    *,
    settings: ProjectorSettings,
    edge_settings: EdgeSettings,
    image_shape_hw_px: tuple[int, int],
    provenance: dict[str, Any] | None = None,
    pattern_edges: PatternEdges | None = None,
) -> ProjectorCalibration:
    """The table's fits and QA from edge positions known already, (K, S, J) over heights z_mm (J,) in increasing
    order, in stripe order along +t: what a camera–projector model gives (`procam_table.py`) instead of a Z-stack.
    The reference is the height nearest settings.reference_z_mm; there is no edge noise (NaN) and no step shift.
    pattern_edges: the projector coordinate of each of the K edges, when known."""
    z = np.asarray(z_mm, dtype=np.float64)
    if z.ndim != 1 or not np.all(np.diff(z) > 0):
        raise ValueError("z_mm: expected strictly increasing heights")
    j_ref = int(np.argmin(np.abs(z - settings.reference_z_mm)))
    if pattern_edges is not None and np.shape(pattern_edges.projector_px) != (np.shape(lut_t_px)[0],):
        raise ValueError(
            f"pattern_edges.projector_px: expected shape ({np.shape(lut_t_px)[0]},), got "
            f"{np.shape(pattern_edges.projector_px)}"
        )
    table = _fit_table(
        np.asarray(lut_t_px, np.float32), z, np.asarray(polarity, np.int8), j_ref=j_ref, settings=settings,
        edge_settings=edge_settings, image_shape_hw_px=image_shape_hw_px, camera_model=camera_model,
        noise_px=float("nan"), max_step_shift=0.0, provenance=dict(provenance or {}),
    )  # fmt: skip
    return table if pattern_edges is None else replace(table, pattern_edges=pattern_edges)


def _refuse_aliased_steps(
    lut: np.ndarray,
    z_sorted: np.ndarray,
    j_ref: int,
    camera_model: CameraModel,
    *,
    axis: str,
    period_px: float,
    max_step_fraction: float,
    window: int = 9,
) -> None:
    """ProjectorCalibrationError when the Z steps moved the stripes by whole periods more than the images show.

    Identity is carried to the nearest edge of the same polarity, so a step that moved the stripes (n + a)
    periods reads as a: every edge is taken for the one n stripes over, the same for all of them, and the table
    runs backwards or too slowly. No single image shows it, but geometry does: an edge's points over Z, back-
    projected to their plane Z, lie on one straight line in space (its light plane cut by the scan line's viewing
    plane), while the relabelled points of an aliased table bend away from it by about n·(change of the period
    with Z) per step. For n in −2 … 2 the table's identities over `window` steps from the reference are shifted
    by n stripes per step and the median straightness (RMS off a fitted line, mm) compared: the calibration is
    refused when n ≠ 0 is clearly straighter than the identities as carried.
    """
    side = 1 if len(z_sorted) - 1 - j_ref >= j_ref else -1
    n_steps = min(window, j_ref + 1 if side < 0 else len(z_sorted) - j_ref)
    if n_steps < 4:
        return
    steps = j_ref + side * np.arange(n_steps)
    z = z_sorted[steps]
    n_k, n_s = lut.shape[:2]
    lines = np.arange(0, n_s, max(1, n_s // 64))
    t = lut[:, lines][:, :, steps].astype(np.float64)  # (K, S', W)
    xy = np.full((*t.shape, 2), np.nan)
    for m in range(n_steps):
        kk, ss = np.nonzero(np.isfinite(t[:, :, m]))
        q = np.column_stack([t[kk, ss, m], lines[ss]] if axis == "rows" else [lines[ss], t[kk, ss, m]])
        xy[kk, ss, m] = backproject_to_z(camera_model.camera, q, float(z[m]), inverse=camera_model.inverse)[:, :2]
    design = np.column_stack([np.ones(n_steps), z - z.mean()])
    off_line = np.eye(n_steps) - design @ np.linalg.pinv(design)  # residual of a straight line in Z
    straightness = {}
    for n in range(-2, 3):
        shifted = np.full_like(xy, np.nan)
        for m in range(n_steps):
            shift = 2 * n * m
            lo, hi = max(0, -shift), min(n_k, n_k - shift)
            if lo < hi:
                shifted[lo:hi, :, m] = xy[lo + shift : hi + shift, :, m]
        whole = np.all(np.isfinite(shifted), axis=(2, 3))
        if np.count_nonzero(whole) < 50:
            continue
        residual = np.einsum("ij,ejc->eic", off_line, shifted[whole])
        straightness[n] = float(np.median(np.sqrt(np.mean(residual**2, axis=(1, 2)))))
    if 0 not in straightness or len(straightness) < 2:
        return
    n_best = min(straightness, key=lambda n: straightness[n])
    if n_best == 0 or straightness[0] < 3.0 * straightness[n_best]:
        return
    dz_mm = float(np.median(np.abs(np.diff(z_sorted))))
    seen = np.isfinite(lut[:, :, steps[0]]) & np.isfinite(lut[:, :, steps[1]])
    apparent = (lut[:, :, steps[1]] - lut[:, :, steps[0]])[seen].astype(np.float64) / period_px * side
    true_shift = np.abs(apparent + n_best)  # periods per step, per (edge, line)
    largest = float(np.percentile(true_shift, 95))
    raise ProjectorCalibrationError(
        f"the Z steps ({dz_mm:g} mm) are too coarse for these stripes: each step moved the edges about "
        f"{float(np.median(true_shift)):.2f} stripe periods (up to {largest:.2f}), but the images show only "
        f"{float(np.median(np.abs(apparent))):.2f}: edges are followed from step to step by the nearest edge of the "
        f"same polarity, so {abs(n_best)} whole period(s) more per step cannot be seen in them. The geometry shows "
        "it: an edge's positions over Z lie on a straight line in space only when each step is counted "
        f"{abs(n_best)} period(s) more ({straightness[n_best]:.3f} mm off a line, against {straightness[0]:.3f} mm as "
        "followed), and a table built as followed would give wrong Z everywhere. Record the projector calibration "
        f"again with Z steps of at most {max_step_fraction * dz_mm / largest:.1f} mm (each step must move the "
        f"stripes less than {max_step_fraction:g} period)"
    )


def _grown(array: np.ndarray, shift: int, n: int) -> np.ndarray:
    out = np.full((n, array.shape[1]), np.nan)
    out[shift : shift + array.shape[0]] = array
    return out


def _grown_polarity(polarity: np.ndarray, shift: int, n: int) -> np.ndarray:
    out = np.zeros(n, np.int8)
    out[shift : shift + len(polarity)] = polarity
    # Polarity alternates with k: fill the new edges from the parity of a known one.
    known = int(np.flatnonzero(out)[0])
    parity_sign = out[known] * (1 if known % 2 == 0 else -1)
    ks = np.arange(n)
    return np.where(out != 0, out, np.where(ks % 2 == 0, parity_sign, -parity_sign)).astype(np.int8)


def _longest_valid_run(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (exclusive) along the last axis of the longest run of True in each row of `valid`."""
    n = valid.shape[-1]
    flat = valid.reshape(-1, n)
    best_start = np.zeros(len(flat), np.int64)
    best_len = np.zeros(len(flat), np.int64)
    run_start = np.zeros(len(flat), np.int64)
    run_len = np.zeros(len(flat), np.int64)
    for j in range(n):
        on = flat[:, j]
        run_start = np.where(on & (run_len == 0), j, run_start)
        run_len = np.where(on, run_len + 1, 0)
        longer = run_len > best_len
        best_len = np.where(longer, run_len, best_len)
        best_start = np.where(longer, run_start, best_start)
    shape = valid.shape[:-1]
    return best_start.reshape(shape), (best_start + best_len).reshape(shape)


@dataclass(frozen=True, eq=False)
class _BlockFit:
    enough: np.ndarray
    valid: np.ndarray
    sensitivity: np.ndarray
    monotonic: np.ndarray
    start: np.ndarray
    end: np.ndarray
    t_min: np.ndarray
    t_max: np.ndarray
    centre: np.ndarray
    scale: np.ndarray
    coefficients: np.ndarray
    fit_rms: np.ndarray


def _fit_block(lut_block: np.ndarray, z_sorted: np.ndarray, settings: ProjectorSettings) -> _BlockFit:
    """Checks and polynomial fits of a block of table rows, lut_block shape (k, S, J)."""
    n_j = lut_block.shape[-1]
    t = lut_block.astype(np.float64)
    start, end = _longest_valid_run(np.isfinite(t))
    j_index = np.arange(n_j)
    in_run = (j_index >= start[..., None]) & (j_index < end[..., None])
    enough = in_run.sum(axis=-1) >= settings.min_z_samples
    weights = np.where(in_run & enough[..., None], 1.0, 0.0)
    t_filled = np.where(weights > 0, t, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        t_min = np.where(weights > 0, t, np.inf).min(axis=-1)
        t_max = np.where(weights > 0, t, -np.inf).max(axis=-1)
        n = np.maximum(weights.sum(-1), 1)
        # Linear fit t = a + b·Z: the sensitivity b (px/mm) and the trend whose reversals are checked.
        z_mean = (weights * z_sorted).sum(-1) / n
        t_mean = (weights * t_filled).sum(-1) / n
        dz = (z_sorted - z_mean[..., None]) * weights
        sensitivity = (dz * (t_filled - t_mean[..., None])).sum(-1) / (dz * dz).sum(-1)
    sensitive = enough & (np.abs(sensitivity) >= settings.min_sensitivity_px_per_mm)
    # Monotonic: no step within the run goes against the trend by more than max_reversal_px.
    steps = np.diff(t, axis=-1)
    step_in_run = in_run[..., 1:] & in_run[..., :-1]
    against = np.where(step_in_run, -np.sign(sensitivity)[..., None] * steps, -np.inf)
    monotonic = np.nan_to_num(against, nan=-np.inf).max(axis=-1) <= settings.max_reversal_px
    valid = sensitive & monotonic

    # Z as a polynomial of τ = (t − centre)/scale per entry, by weighted least squares (batched normal equations).
    with np.errstate(invalid="ignore"):  # inf − inf where a row has no run
        centre = np.where(valid, 0.5 * (t_min + t_max), 0.0)
        scale = np.where(valid, np.maximum(0.5 * (t_max - t_min), 1e-3), 1.0)
    tau = (t_filled - centre[..., None]) / scale[..., None]
    degree = settings.poly_degree
    powers = tau[..., None] ** np.arange(degree + 1)  # (k, S, J, D+1)
    w = np.where(valid[..., None], weights, 0.0)
    normal = np.einsum("ksj,ksja,ksjb->ksab", w, powers, powers)
    rhs = np.einsum("ksj,ksja,j->ksa", w, powers, z_sorted)
    normal[~valid] = np.eye(degree + 1)
    rhs[~valid] = 0.0
    coefficients = np.linalg.solve(normal, rhs[..., None])[..., 0]
    fitted = np.einsum("ksja,ksa->ksj", powers, coefficients)
    residual = np.where(w > 0, fitted - z_sorted, 0.0)
    fit_rms = np.sqrt((residual**2).sum(-1) / np.maximum(w.sum(-1), 1))
    return _BlockFit(
        enough=enough, valid=valid, sensitivity=sensitivity, monotonic=monotonic, start=start, end=end,
        t_min=t_min, t_max=t_max, centre=centre, scale=scale, coefficients=coefficients, fit_rms=fit_rms,
    )  # fmt: skip


def _fit_table(
    lut: np.ndarray,
    z_sorted: np.ndarray,
    polarity: np.ndarray,
    *,
    j_ref: int,
    settings: ProjectorSettings,
    edge_settings: EdgeSettings,
    image_shape_hw_px: tuple[int, int],
    camera_model: CameraModel,
    noise_px: float,
    max_step_shift: float,
    provenance: dict[str, Any],
) -> ProjectorCalibration:
    n_k, n_s, n_j = lut.shape
    # Blocks of a few edges keep the (k, S, J, D+1) temporaries small (tens of MB at 1024 lines).
    block = max(1, int(2e6 // max(n_s * n_j * (settings.poly_degree + 1), 1)))
    parts = [_fit_block(lut[k0 : k0 + block], z_sorted, settings) for k0 in range(0, n_k, block)]

    def joined(name: str) -> np.ndarray:
        return np.concatenate([getattr(part, name) for part in parts], axis=0)

    enough, valid, sensitivity, monotonic = (
        joined("enough"),
        joined("valid"),
        joined("sensitivity"),
        joined("monotonic"),
    )
    start, end, t_min, t_max = joined("start"), joined("end"), joined("t_min"), joined("t_max")
    centre, scale, coefficients, fit_rms = joined("centre"), joined("scale"), joined("coefficients"), joined("fit_rms")
    sensitive = enough & (np.abs(sensitivity) >= settings.min_sensitivity_px_per_mm)
    n_insensitive = int(np.count_nonzero(enough & ~sensitive))
    n_non_monotonic = int(np.count_nonzero(sensitive & ~monotonic))
    if np.count_nonzero(enough) and n_insensitive > 0.5 * np.count_nonzero(enough):
        median = float(np.nanmedian(np.abs(sensitivity[enough])))
        raise ProjectorCalibrationError(
            f"the stripe edges hardly move with Z (median {median:.3f} px per mm, below "
            f"{settings.min_sensitivity_px_per_mm} px/mm): the stripes run along the camera–projector baseline, "
            "so the table cannot resolve Z; turn the ruling (or the projector) so the stripes cross the baseline"
        )

    nan = np.nan
    entry = valid
    margin_px = settings.range_margin_mm * np.abs(sensitivity)
    z_lo = np.where(entry, z_sorted[np.minimum(start, n_j - 1)], nan)
    z_hi = np.where(entry, z_sorted[np.maximum(end - 1, 0)], nan)
    reference_t = lut[:, :, j_ref].astype(np.float64)
    seen_at_ref = np.isfinite(reference_t)
    coverage = np.count_nonzero(entry & seen_at_ref) / max(int(np.count_nonzero(seen_at_ref)), 1)
    if not np.any(entry):
        raise ProjectorCalibrationError(
            f"no (edge, line) got a table entry: every edge needs ≥ {settings.min_z_samples} consecutive Z steps "
            "with a monotonic, Z-sensitive position"
        )
    abs_sens = np.abs(sensitivity[entry])
    sens_pct = tuple(float(v) for v in np.percentile(abs_sens, [5, 50, 95]))
    fit_values = fit_rms[entry]

    # Object-space extent of the entries at the reference Z (for the report and the default grid).
    kk, ss = np.nonzero(entry & seen_at_ref)
    t_ref = reference_t[kk, ss]
    q_px = np.column_stack([t_ref, ss] if edge_settings.axis == "rows" else [ss, t_ref])
    if len(q_px):
        xy = backproject_to_z(camera_model.camera, q_px, float(z_sorted[j_ref]), inverse=camera_model.inverse)
        extent = (
            float(np.nanmin(xy[:, 0])),
            float(np.nanmax(xy[:, 0])),
            float(np.nanmin(xy[:, 1])),
            float(np.nanmax(xy[:, 1])),
        )
    else:
        extent = (nan, nan, nan, nan)
    qa = ProjectorQA(
        coverage=float(coverage),
        n_entries=int(np.count_nonzero(entry)),
        n_edges=n_k,
        sensitivity_px_per_mm=sens_pct,  # type: ignore[arg-type]
        fit_rms_mm=float(np.sqrt(np.mean(fit_values**2))),
        fit_p95_mm=float(np.percentile(fit_values, 95)),
        n_non_monotonic=n_non_monotonic,
        n_insensitive=n_insensitive,
        max_step_shift_periods=max_step_shift,
        edge_noise_px=noise_px,
        z_range_mm=(float(z_sorted[0]), float(z_sorted[-1])),
        xy_extent_mm=extent,
    )
    return ProjectorCalibration(
        image_shape_hw_px=image_shape_hw_px,
        edges=edge_settings,
        reference_z_mm=float(z_sorted[j_ref]),
        z_mm=z_sorted,
        polarity=polarity,
        lut_t_px=lut,
        reference_t_px=np.where(seen_at_ref, reference_t, nan),
        coefficients=np.where(entry[..., None], coefficients, nan),
        t_centre_px=np.where(entry, centre, nan),
        t_scale_px=np.where(entry, scale, nan),
        t_lo_px=np.where(entry, t_min - margin_px, nan),
        t_hi_px=np.where(entry, t_max + margin_px, nan),
        z_lo_mm=z_lo,
        z_hi_mm=z_hi,
        sensitivity_px_per_mm=np.where(entry, sensitivity, nan),
        fit_rms_mm=np.where(entry, fit_rms, nan),
        qa=qa,
        camera_fingerprint=camera_fingerprint(camera_model.camera),
        provenance=provenance,
    )
