"""Topography: fringe order per frame, Z from the projector table, X and Y by back-projection (docs/method.md §5–6).

Belongs here: the frame loop of a test. Every frame is measured on its own from its edges, the calibration and
the reference (first, flat) frame: the order of its edges (`order.py`: anchored on the stationary rim, counted
across scan lines and along edge curves, bounded by the table, checked for consistency), Z from the table, X and
Y by back-projection; optional temporal smoothing of the ordered positions; gridding helpers. The pipeline is
split so that test recordings can be processed in parallel chunks with results identical to one run:

1. `locate_test_edges` / `fringes.locate_edges`: the expensive part, a pure function of one frame. Chunks of
   frames can run on different workers; their `FrameEdges` can be stored (`fringelab.formats.edges`).
2. `measure_frame`: order, Z, X, Y of one frame given the reference (`reference_for` of the first frame's
   edges), a pure function of the frame too. `track_and_measure` runs it over frames in order, with temporal
   smoothing (if on) as a centred window, so it sees the same neighbours whatever the chunking.
3. Gridding of Z and its σ on one mesh (`grid_measurement_with_sigma`), a pure function of one measurement.

`topography_recording` runs all three over a recording and streams the result into an HDF5 file. Not here: the
edge locator (`fringes.py`), the order (`order.py`), the table (`projector.py`), grids and profiles
(`fields.py`), files (`fringelab.formats.topography`).
"""

from __future__ import annotations

import functools
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numba
import numpy as np

from . import MeasurementError
from .camera import Camera, InverseModel, camera_centre_obj_mm, ideal_from_pixels
from .coverage import MISSING_REASONS, FrameCoverage
from .fields import Grid, Peak, grid_covering, typical_edge_gap_mm
from .fringes import (
    UNUSABLE_BLACK,
    UNUSABLE_BLOCK_PX,
    UNUSABLE_DARK,
    UNUSABLE_UNEVEN_LIGHT,
    FrameEdges,
    detect_stripes,
    locate_edges,
)
from .graycode import Decoding
from .gridding import grid_edge_fields, grid_edge_points
from .order import (
    ORDER_CONFLICT,
    ORDER_UNRESOLVED,
    OrderReference,
    OrderSettings,
    ReferenceNotFlatError,
    check_order_against_table,
    clamp_circle,
    identify_reference,
    identify_reference_from_code,
    order_frame,
    order_reference,
)
from .peaks import PUNCH_RADIUS_MM
from .projector import (
    TABLE_SENSITIVITY,
    TABLE_SIGMA_Z,
    CalibrationMismatchError,
    CameraModel,
    ProjectorCalibration,
    camera_fingerprint,
    table_z_tau_at,
)
from .uncertainty import (
    contiguous_index_array,
    edge_sigmas_px,
    fit_leverage_ratio,
    leverage_polynomials,
    local_excess_variance,
    point_sigma_z_at,
    scale_from_ratios,
    sigma_edge_halves,
    sigma_from_halves,
)

# The first test frame is the reference the order is anchored on (kept under its old name).
FirstFrameNotFlatError = ReferenceNotFlatError
__all__ = ["FirstFrameNotFlatError", "clamp_circle"]


class TopographyError(MeasurementError):
    """The topography cannot be computed from this recording (too few edges identified, ...)."""


@dataclass(frozen=True)
class TopographySettings:
    """Settings of the topography.

    max_jump_fraction: kept for settings files written before the order was found per frame; unused.
    order: how the fringe order of every frame is anchored and checked (`order.OrderSettings`).
    temporal_smoothing_frames: half-width h of a centred quadratic (Savitzky–Golay) filter of each tracked edge
        position over 2h + 1 frames; 0 = off. Near the ends of a track the window shrinks symmetrically.
    flat_tolerance_mm: the first (reference) frame is taken as flat when 90 % of its points lie within this of
        the calibration's reference Z.
    grid_step_mm: spacing of the deflection grid.
    grid_max_edge_mm: longest triangle side of the gridding mesh; None = 3 × the median gap between neighbouring
        edges in the first frame (a missing edge between two measured ones is still bridged, a hole is not).
    grid_margin_mm: margin of the grid around the first frame's points.
    punch_radius_mm: radius of the punch; a frame's peak counts as measured only where the surface is measured on
        all sides of the maximum over at least this (`peaks.peak_measurement`).
    max_edge_sigma_px: edge points whose σ (`FrameEdges.sigma_px`, px along the scan line) exceeds this are not
        measured, missing as "low contrast" (faint, blurred or noisy stripes, or uneven light in the window):
        0.25 px is 0.4 mm of Z at the Kodak set-up's 0.6 px/mm. None keeps every point.
    """

    max_jump_fraction: float = 0.3
    temporal_smoothing_frames: int = 0
    flat_tolerance_mm: float = 2.0
    grid_step_mm: float = 2.0
    grid_max_edge_mm: float | None = None
    grid_margin_mm: float = 4.0
    punch_radius_mm: float = PUNCH_RADIUS_MM
    order: OrderSettings = field(default_factory=OrderSettings)
    max_edge_sigma_px: float | None = 0.25

    def __post_init__(self) -> None:
        if not 0 < self.max_jump_fraction < 0.5:
            raise ValueError(f"max_jump_fraction: expected 0 < f < 0.5, got {self.max_jump_fraction}")
        if self.temporal_smoothing_frames < 0:
            raise ValueError(f"temporal_smoothing_frames: expected ≥ 0, got {self.temporal_smoothing_frames}")
        if not self.grid_step_mm > 0:
            raise ValueError(f"grid_step_mm: expected > 0, got {self.grid_step_mm}")
        if not self.punch_radius_mm > 0:
            raise ValueError(f"punch_radius_mm: expected > 0, got {self.punch_radius_mm}")
        if self.max_edge_sigma_px is not None and not self.max_edge_sigma_px > 0:
            raise ValueError(f"max_edge_sigma_px: expected > 0 or None, got {self.max_edge_sigma_px}")
        if self.grid_max_edge_mm is not None and not self.grid_max_edge_mm > 0:
            raise ValueError(f"grid_max_edge_mm: expected > 0 or None, got {self.grid_max_edge_mm}")


@dataclass(frozen=True, eq=False)
class FrameMeasurement:
    """The 3-D points of one frame and what its order left out.

    frame: index of the frame in the recording. k, line: (N,) edge order and scan line of each point, sorted by
    (line, k);
    points_obj_mm: (N, 3). n_tracks: ordered (edge, line) points in this frame (with or without Z); n_ended: 0
    (the order is found per frame; kept for the worker's stored chunks); n_out_of_range: ordered points outside
    the calibrated Z range of their table entry (masked, never extrapolated); n_unmatched: edge points of the
    frame without an order; edge_noise_px: the frame's edge-location noise estimate; n_order_unresolved: edge
    points whose group no anchor reaches; n_order_conflict_points: edge points masked for a conflict of sources;
    n_order_conflicts: conflicts found (curves or groups); coverage: what of the plate was measured and what
    is missing by reason (None for measurements stored without it). sigma_z_mm: (N,) σ of each
    point's Z from the edge noise and the projector table (`uncertainty.point_sigma_z_mm`), None where not
    computed. temporal: the cross-check against the frame before (`TemporalCrossCheck`), None where not made.
    sigma_scale: the factor (≥ 1) the frame's check across edges multiplied sigma_z_mm by
    (`uncertainty.cross_edge_scale`); 1 where not checked. local_variance_mm2: (N,) the local check's τ² added to
    each point's σ_Z² before that factor (`uncertainty.local_excess_variance`), None where not computed.
    table_sigma_z_mm: (N,) the projector table's term of each point's σ_Z at its place in the fitted range
    (before the frame's factor), None where not computed.
    """

    frame: int
    k: np.ndarray
    line: np.ndarray
    points_obj_mm: np.ndarray
    n_tracks: int
    n_ended: int
    n_out_of_range: int
    n_unmatched: int
    edge_noise_px: float
    n_order_unresolved: int = 0
    n_order_conflict_points: int = 0
    n_order_conflicts: int = 0
    coverage: FrameCoverage | None = None
    sigma_z_mm: np.ndarray | None = None
    temporal: TemporalCheck | None = None
    sigma_scale: float = 1.0
    local_variance_mm2: np.ndarray | None = None
    table_sigma_z_mm: np.ndarray | None = None

    def dense(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """X, Y, Z as (K, S) arrays over (edge, line), NaN where not measured."""
        out = [np.full(shape, np.nan) for _ in range(3)]
        for axis in range(3):
            out[axis][self.k, self.line] = self.points_obj_mm[:, axis]
        return out[0], out[1], out[2]


@dataclass(frozen=True)
class TemporalCheck:
    """The order of a frame cross-checked against the frame before it (docs/method.md §5).

    n_checked: points measured on the same (edge, line) in both frames whose neighbouring edges on the line
    (k − 1, k + 1) were too; n_jumps: those whose change of Z between the frames differs from the mean change of
    those two neighbours by more than TEMPORAL_JUMP_STEPS of a stripe's Z step (the Z a point moves when its edge
    moves one period). The motion between frames is smooth across edges however fast it is, so the change of a
    point follows its neighbours'; an order one edge pair off adds a whole step to the point (and half a step to
    its neighbours' mean, so they are not counted with it).
    """

    n_checked: int
    n_jumps: int


TEMPORAL_JUMP_STEPS = 0.75


def temporal_check(
    previous: FrameMeasurement, current: FrameMeasurement, projector: ProjectorCalibration
) -> TemporalCheck:
    """Cross-check of `current`'s order against `previous` (`TemporalCheck`): a report, never a correction, so a
    frame measured alone stays equal to the same frame measured within its sequence."""
    return _temporal_check(previous, current, _stripe_step_mm(projector))


def _stripe_step_mm(projector: ProjectorCalibration) -> np.ndarray:
    """(K, S) the Z step of one stripe period at each table entry (mm)."""
    return np.ascontiguousarray(projector.period_px / np.maximum(np.abs(projector.sensitivity_px_per_mm), 1e-6))


def _temporal_check(previous: FrameMeasurement, current: FrameMeasurement, step_mm: np.ndarray) -> TemporalCheck:
    n_checked, n_jumps = _temporal_check_kernel(
        np.ascontiguousarray(previous.k, np.int64), np.ascontiguousarray(previous.line, np.int64),
        np.ascontiguousarray(previous.points_obj_mm[:, 2], np.float64),
        np.ascontiguousarray(current.k, np.int64), np.ascontiguousarray(current.line, np.int64),
        np.ascontiguousarray(current.points_obj_mm[:, 2], np.float64), step_mm, TEMPORAL_JUMP_STEPS,
    )  # fmt: skip
    return TemporalCheck(n_checked=int(n_checked), n_jumps=int(n_jumps))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _temporal_check_kernel(
    k_before: np.ndarray,
    line_before: np.ndarray,
    z_before: np.ndarray,
    k: np.ndarray,
    line: np.ndarray,
    z: np.ndarray,
    step_mm: np.ndarray,
    jump_steps: float,
) -> tuple[int, int]:
    """Each point's change of Z between the frames (NaN unless measured in both) against the mean change of its
    neighbouring edges on the line (k − 1, k + 1), in stripe steps: (points checked, points beyond jump_steps)."""
    n_edges, n_lines = step_mm.shape
    change = np.full((n_edges, n_lines), np.nan)
    before = np.full((n_edges, n_lines), np.nan)
    for i in range(len(z)):
        change[k[i], line[i]] = z[i]
    for i in range(len(z_before)):
        before[k_before[i], line_before[i]] = z_before[i]
    for e in range(n_edges):
        for s in range(n_lines):
            change[e, s] -= before[e, s]
    n_checked = n_jumps = 0
    for e in range(1, n_edges - 1):
        for s in range(n_lines):
            neighbours = 0.5 * (change[e - 1, s] + change[e + 1, s])
            departure = np.abs(change[e, s] - neighbours) / step_mm[e, s]
            if np.isfinite(departure):
                n_checked += 1
                if departure > jump_steps:
                    n_jumps += 1
    return n_checked, n_jumps


class TemporalCrossCheck:
    """The frames of a test in frame order, each cross-checked against the one before it (`temporal_check`) by
    whoever writes them in order, whatever chunks measured them: the first frame, and a frame after a gap, have
    none."""

    def __init__(self, projector: ProjectorCalibration) -> None:
        self._step_mm = _stripe_step_mm(projector)
        self._previous: FrameMeasurement | None = None

    def checked(self, measurement: FrameMeasurement) -> FrameMeasurement:
        """The measurement with its `temporal` cross-check."""
        previous, self._previous = self._previous, measurement
        if previous is None or measurement.frame != previous.frame + 1:
            return measurement
        return replace(measurement, temporal=_temporal_check(previous, measurement, self._step_mm))


def check_recording_against(
    image_shape_hw_px: tuple[int, int], projector: ProjectorCalibration, camera_model: CameraModel
) -> None:
    """Raise CalibrationMismatchError when a recording's frames, the camera and the projector table disagree."""
    camera = camera_model.camera
    camera_shape = (camera.image_height_px, camera.image_width_px)
    table_h, table_w = projector.image_shape_hw_px
    if tuple(image_shape_hw_px) != (table_h, table_w):
        raise CalibrationMismatchError(
            f"the test frames are {image_shape_hw_px[1]} × {image_shape_hw_px[0]} px but the projector calibration is "
            f"for {table_w} × {table_h} px: use the calibrations of this camera"
        )
    if camera_shape != (table_h, table_w):
        raise CalibrationMismatchError(
            f"the camera calibration is for {camera_shape[1]} × {camera_shape[0]} px but the projector calibration "
            f"for {table_w} × {table_h} px: they come from different cameras"
        )
    if camera_fingerprint(camera) != projector.camera_fingerprint:
        raise CalibrationMismatchError(
            "the projector calibration was made with another camera calibration (fingerprint "
            f"{projector.camera_fingerprint}, this one {camera_fingerprint(camera)}): use the camera calibration it "
            "was made with, or calibrate the projector again with this one"
        )


def check_stripes_against(first_frame: np.ndarray, projector: ProjectorCalibration) -> None:
    """Raise CalibrationMismatchError when the test's stripes run another way than the calibration's."""
    geometry = detect_stripes(first_frame, axis="auto")
    if geometry.axis != projector.axis:
        direction = {"rows": "roughly vertical", "cols": "roughly horizontal"}
        raise CalibrationMismatchError(
            f"the stripes of the test run {direction[geometry.axis]} ({geometry.angle_deg:.0f}°) but those of the "
            f"projector calibration {direction[projector.axis]}: the projector or the camera moved between them"
        )


def locate_test_edges(frames: Iterable[np.ndarray], projector: ProjectorCalibration) -> Iterator[FrameEdges]:
    """`fringes.locate_edges` with the projector calibration's edge settings, frame by frame (lazy)."""
    for image in frames:
        if tuple(np.shape(image)[:2]) != tuple(projector.image_shape_hw_px):
            shape = np.shape(image)
            raise CalibrationMismatchError(
                f"a test frame is {shape[1]} × {shape[0]} px but the projector calibration is for "
                f"{projector.image_shape_hw_px[1]} × {projector.image_shape_hw_px[0]} px"
            )
        yield locate_edges(image, projector.edges)


# --------------------------------------------------------------------------------------------------------------
# Order and measurement, frame by frame


def reference_for(
    first: FrameEdges,
    projector: ProjectorCalibration,
    camera_model: CameraModel,
    settings: TopographySettings,
    *,
    code: Decoding | None = None,
) -> OrderReference:
    """The anchor of a test's fringe order from its reference (first, flat) frame's edges. code: a Gray code
    recorded with the plate at rest (decoded), which then gives the reference frame's order
    (`order.identify_reference_from_code`, checked against the table's match where that can be made)."""
    if code is None:
        positions = identify_reference(first, projector, flat_tolerance_mm=settings.flat_tolerance_mm)
        return order_reference(positions, projector, camera_model, settings=settings.order)
    coded = identify_reference_from_code(first, code, projector, flat_tolerance_mm=settings.flat_tolerance_mm)
    reference = order_reference(
        coded.positions, projector, camera_model, settings=settings.order, rest_z_mm=coded.rest_z_mm
    )
    return replace(
        reference, code_points=coded.n_points, code_compared=coded.n_compared, code_agreement=coded.agreement
    )


def identify_first_frame(edges: FrameEdges, projector: ProjectorCalibration, *, flat_tolerance_mm: float) -> np.ndarray:
    """Positions (K, S) of the projector's edges in the first (flat) test frame (`order.identify_reference`)."""
    return identify_reference(edges, projector, flat_tolerance_mm=flat_tolerance_mm)


@dataclass(frozen=True, eq=False)
class OrderedFrame:
    """One frame's edge positions by order, and what the order left out.

    positions: (K, S) position of every ordered (edge, line) point, NaN where none; sigma_px: (K, S) the σ of each
    (`uncertainty.edge_sigmas_px`); counts: per-frame numbers
    (n_tracks: ordered points, n_order_unresolved, n_order_conflict_points, n_order_conflicts, n_unmatched:
    edge points without an order).
    """

    positions: np.ndarray
    counts: dict[str, int]
    coverage: FrameCoverage
    sigma_px: np.ndarray


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _scatter_with_sigma(
    k: np.ndarray,
    line: np.ndarray,
    t_px: np.ndarray,
    sigma_px: np.ndarray,
    valid: np.ndarray,
    max_sigma_px: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Dense (K, S) float64 arrays of the positions and of their σ of the points with 0 ≤ k < K; (k, line) pairs
    that occur twice in a frame are dropped (NaN in both), as `projector._scatter` does. Positions where the
    table has no entry (`valid` (K, S) False) or whose σ exceeds max_sigma_px are NaN too (their σ is kept); with
    the number of positions left."""
    n_edges, n_lines = valid.shape
    out = np.full((n_edges, n_lines), np.nan)
    out_sigma = np.full((n_edges, n_lines), np.nan)
    seen = np.zeros((n_edges, n_lines), np.uint8)
    for i in range(len(k)):
        if 0 <= k[i] < n_edges and 0 <= line[i] < n_lines:
            seen[k[i], line[i]] = min(seen[k[i], line[i]] + 1, 2)
            if seen[k[i], line[i]] == 1:
                out[k[i], line[i]] = float(t_px[i])
                out_sigma[k[i], line[i]] = float(sigma_px[i])
            else:
                out[k[i], line[i]] = out_sigma[k[i], line[i]] = np.nan
    n_left = 0
    for e in range(n_edges):
        for s in range(n_lines):
            if not valid[e, s] or out_sigma[e, s] > max_sigma_px:
                out[e, s] = np.nan
            elif np.isfinite(out[e, s]):
                n_left += 1
    return out, out_sigma, n_left


def order_positions(
    edges: FrameEdges, reference: OrderReference, projector: ProjectorCalibration, settings: TopographySettings
) -> OrderedFrame:
    """The positions (K, S) of one frame's edges by their order (`order.order_frame`): a pure function of the
    frame and the reference, so a frame ordered alone equals the same frame ordered within its sequence."""
    frame_order = order_frame(edges, reference, projector, settings=settings.order)
    n_conflict_points = int(np.count_nonzero(frame_order.reason == ORDER_CONFLICT))
    if n_conflict_points > 0.5 * len(edges):
        # Mostly conflicts: say so when it is the table that disagrees with the whole frame.
        check_order_against_table(edges, reference, projector, settings=settings.order)
    # The ordered points (k ≥ 0) and their σ, in one pass (`projector._scatter`'s rule for duplicates).
    # Without a table entry a point can never give Z. Too unsure to measure (σ above max_edge_sigma_px): missing,
    # and `frame_coverage` counts it as low contrast (no reason of its own).
    max_sigma_px = np.inf if settings.max_edge_sigma_px is None else float(settings.max_edge_sigma_px)
    positions, sigma_px, n_ordered = _scatter_with_sigma(
        np.ascontiguousarray(frame_order.k, np.int64), np.ascontiguousarray(edges.line),
        np.ascontiguousarray(edges.t_px), np.ascontiguousarray(edge_sigmas_px(edges, projector.edges)),
        projector.valid, max_sigma_px,
    )  # fmt: skip
    counts = {
        "n_tracks": n_ordered,
        "n_order_unresolved": int(np.count_nonzero(frame_order.reason == ORDER_UNRESOLVED)),
        "n_order_conflict_points": n_conflict_points,
        "n_order_conflicts": int(frame_order.n_conflicts),
        "n_unmatched": len(edges) - n_ordered,
    }
    coverage = frame_coverage(edges, frame_order.k, frame_order.reason, positions, reference, projector)
    coverage = FrameCoverage(
        visible_area_mm2=coverage.visible_area_mm2, measured_area_mm2=coverage.measured_area_mm2,
        missing_mm2=coverage.missing_mm2, n_order_conflicts=frame_order.n_conflicts,
    )  # fmt: skip
    return OrderedFrame(positions=positions, counts=counts, coverage=coverage, sigma_px=sigma_px)


def frame_coverage(
    edges: FrameEdges,
    k: np.ndarray,
    reason: np.ndarray,
    positions: np.ndarray,
    reference: OrderReference,
    projector: ProjectorCalibration,
) -> FrameCoverage:
    """The measured and missing areas of one frame (`FrameCoverage`).

    k, reason: (N,) order and reason of the frame's edge points (`order.order_frame`); positions: (K, S) the
    ordered positions. Each reference point missing in the frame is placed where the frame's own measured
    neighbours on its line say its edge now is (their displacement from the reference, interpolated in k along
    the line); an unordered edge point found there lends it its reason, else the frame's `unusable` map there
    does (a block with nothing wrong counts as low contrast: no edge was located).
    """
    area = reference.cell_area_mm2
    # The table's bounds, as `z_from_t` applies them (positions only exist where the table has an entry).
    measured_mm2, beyond_mm2, rk, rs = _split_seen(
        positions, projector.t_lo_px, projector.t_hi_px, reference.seen, area
    )
    missing = {name: 0.0 for name in MISSING_REASONS}
    missing["out_of_range"] = float(np.sum(beyond_mm2))
    if len(rk):
        t_now = _displaced_reference(positions, reference.reference_t_px, rk, rs)
        # Unordered edge points lend their reason to the missing point nearest them on their line, found in the
        # missing points' (line, t) order (np.argsort's, as the ties fall).
        stride = float(edges.n_samples + 1000.0)
        keys = rs.astype(np.float64) * stride + t_now
        unusable = np.zeros((0, 0), np.uint8) if edges.unusable is None else edges.unusable
        areas, starts = _missing_areas(
            rk, rs, t_now, keys, np.argsort(keys), stride, np.ascontiguousarray(k, np.int64),
            np.ascontiguousarray(edges.line), np.ascontiguousarray(edges.t_px), np.ascontiguousarray(reason),
            0.25 * float(projector.period_px), unusable, edges.unusable is not None, area,
        )  # fmt: skip
        for index, name in enumerate(MISSING_REASONS):
            if name == "out_of_range":
                continue
            missing[name] = float(np.sum(areas[starts[index] : starts[index + 1]]))
    return FrameCoverage(
        visible_area_mm2=reference.seen_area_mm2,
        measured_area_mm2=float(np.sum(measured_mm2)),
        missing_mm2=missing,
        n_order_conflicts=0,
    )


_UNEVEN_LIGHT_INDEX = MISSING_REASONS.index("uneven_light")
_N_MISSING_REASONS = len(MISSING_REASONS)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _missing_areas(
    rk: np.ndarray,
    rs: np.ndarray,
    t_now: np.ndarray,
    keys: np.ndarray,
    order: np.ndarray,
    stride: float,
    k: np.ndarray,
    line: np.ndarray,
    t_px: np.ndarray,
    reason: np.ndarray,
    max_distance_px: float,
    unusable: np.ndarray,
    has_unusable: bool,
    area_mm2: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """`frame_coverage`'s reasons for the missing reference points (rk, rs) (M,), now at t_now (M,): an unordered
    edge point (k < 0 of the frame's (N,)) within max_distance_px of the nearest of them on its line (keys (M,)
    line × stride + t, sorted by order (M,)) lends its reason (the last such point wins), else the `unusable`
    block there does (has_unusable; low contrast without). Returns their areas grouped by reason (M,) (each group
    in the points' order, as `area[mask]` gives them) and where each MISSING_REASONS index's group starts (R + 1,).
    One pass over the edge points, one over the missing points; numpy took 0.16 ms a 512 × 480 frame in calls."""
    m = len(rk)
    code = np.full(m, -1, np.int64)
    if m > 0:
        for i in range(len(k)):
            if k[i] >= 0:
                continue
            query = np.float64(line[i]) * stride + np.float64(t_px[i])
            lo, hi = 0, m  # np.searchsorted(keys[order], query): the first sorted key ≥ query
            while lo < hi:
                mid = (lo + hi) // 2
                if keys[order[mid]] < query:
                    lo = mid + 1
                else:
                    hi = mid
            pos = min(max(lo, 1), m - 1) if m > 1 else 0
            below, above = order[max(pos - 1, 0)], order[pos]
            nearest = below if abs(keys[below] - query) <= abs(keys[above] - query) else above
            if abs(keys[nearest] - query) <= max_distance_px:
                code[nearest] = 4 if reason[i] == ORDER_CONFLICT else 3
    n_reasons = _N_MISSING_REASONS
    counts = np.zeros(n_reasons + 1, np.int64)
    for j in range(m):
        if code[j] < 0:
            image_code = 2
            if has_unusable:
                row = min(max(rs[j] // UNUSABLE_BLOCK_PX, 0), unusable.shape[0] - 1)
                rounded = 0  # as np.round(t).astype(np.int64): half to even; what a NaN gives clipped to 0
                if np.isfinite(t_now[j]):
                    rounded = int(np.floor(t_now[j]))
                    fraction = t_now[j] - rounded
                    if fraction > 0.5 or (fraction == 0.5 and rounded % 2 != 0):
                        rounded += 1
                col = min(max(rounded // UNUSABLE_BLOCK_PX, 0), unusable.shape[1] - 1)
                block = unusable[row, col]
                if block == UNUSABLE_BLACK:
                    image_code = 0
                elif block == UNUSABLE_DARK:
                    image_code = 1
                elif block == UNUSABLE_UNEVEN_LIGHT:
                    image_code = _UNEVEN_LIGHT_INDEX
            code[j] = image_code
        counts[code[j] + 1] += 1
    for r in range(n_reasons):
        counts[r + 1] += counts[r]
    starts = counts.copy()
    areas = np.empty(m)
    for j in range(m):
        areas[counts[code[j]]] = area_mm2[rk[j], rs[j]]
        counts[code[j]] += 1
    return areas, starts


SEEN_MEASURED, SEEN_BEYOND, SEEN_UNPLACED = 0, 1, 2  # `_seen_kind`; -1: not seen


@numba.njit(cache=True, nogil=True, inline="always")
def _seen_kind(seen: bool, t: float, t_lo: float, t_hi: float) -> int:
    """A reference point's kind in a frame: -1 not seen, else measured (a position within the table's bounds),
    placed beyond the bounds, or with no position."""
    if not seen:
        return -1
    if not np.isfinite(t):
        return SEEN_UNPLACED
    return SEEN_MEASURED if t_lo <= t <= t_hi else SEEN_BEYOND


@numba.njit(cache=True, nogil=True)
def _split_seen(
    positions: np.ndarray, t_lo_px: np.ndarray, t_hi_px: np.ndarray, seen: np.ndarray, area_mm2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The seen reference points (K, S) of a frame split (`_seen_kind`): the areas of those measured and of those
    placed beyond the bounds, each in the order `area[mask]` gives them (so np.sum adds them as it adds that), and
    the (k, line) of those with no position (`np.nonzero`'s order). Two passes, counting then filling, so nothing
    is allocated for every (edge, line)."""
    n_edges, n_lines = positions.shape
    counts = np.zeros(3, np.int64)
    for e in range(n_edges):
        for s in range(n_lines):
            kind = _seen_kind(seen[e, s], positions[e, s], t_lo_px[e, s], t_hi_px[e, s])
            if kind >= 0:
                counts[kind] += 1
    measured, beyond = np.empty(counts[SEEN_MEASURED]), np.empty(counts[SEEN_BEYOND])
    rk, rs = np.empty(counts[SEEN_UNPLACED], np.int64), np.empty(counts[SEEN_UNPLACED], np.int64)
    counts[:] = 0
    for e in range(n_edges):
        for s in range(n_lines):
            kind = _seen_kind(seen[e, s], positions[e, s], t_lo_px[e, s], t_hi_px[e, s])
            if kind == SEEN_MEASURED:
                measured[counts[kind]] = area_mm2[e, s]
            elif kind == SEEN_BEYOND:
                beyond[counts[kind]] = area_mm2[e, s]
            elif kind == SEEN_UNPLACED:
                rk[counts[kind]], rs[counts[kind]] = e, s
            if kind >= 0:
                counts[kind] += 1
    return measured, beyond, rk, rs


def _displaced_reference(
    positions: np.ndarray, reference_t_px: np.ndarray, kk: np.ndarray, ss: np.ndarray
) -> np.ndarray:
    """Where edges (kk, ss) are now: their reference position plus the displacement of the measured edges on
    their line, interpolated linearly in k (held constant beyond the last one; zero on a line with none)."""
    return _displaced_reference_kernel(
        np.ascontiguousarray(positions, np.float64), np.ascontiguousarray(reference_t_px, np.float64),
        np.ascontiguousarray(kk, np.int64), np.ascontiguousarray(ss, np.int64),
    )  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _displaced_reference_kernel(
    positions: np.ndarray, reference_t_px: np.ndarray, kk: np.ndarray, ss: np.ndarray
) -> np.ndarray:
    n_edges = positions.shape[0]
    out = np.empty(len(kk))
    for i in range(len(kk)):
        k, s = kk[i], ss[i]
        below = k - 1
        while below >= 0 and not np.isfinite(positions[below, s] - reference_t_px[below, s]):
            below -= 1
        above = k + 1
        while above < n_edges and not np.isfinite(positions[above, s] - reference_t_px[above, s]):
            above += 1
        if below >= 0 and above < n_edges:
            d_below = positions[below, s] - reference_t_px[below, s]
            d_above = positions[above, s] - reference_t_px[above, s]
            shift = d_below + (d_above - d_below) * (k - below) / (above - below)
        elif below >= 0:
            shift = positions[below, s] - reference_t_px[below, s]
        elif above < n_edges:
            shift = positions[above, s] - reference_t_px[above, s]
        else:
            shift = 0.0
        out[i] = reference_t_px[k, s] + shift
    return out


def savitzky_golay_centre_weights(half_width: int) -> np.ndarray:
    """Weights (2h + 1,) of a centred quadratic least-squares fit evaluated at its centre."""
    offsets = np.arange(-half_width, half_width + 1, dtype=np.float64)
    design = np.vander(offsets, 3, increasing=True)
    return np.linalg.pinv(design)[0]


class _TemporalSmoother:
    """Centred quadratic smoothing of tracked positions over 2h + 1 frames, streaming with a delay of h frames.

    A (k, s) position is smoothed over the widest symmetric window, up to h frames either way, in which it was
    tracked in every frame; at the first and last frames of a run the window shrinks symmetrically. Only the
    last 2h + 1 frames are held.
    """

    def __init__(self, half_width: int) -> None:
        self.half_width = half_width
        self.weights = [savitzky_golay_centre_weights(h) for h in range(half_width + 1)]
        self.buffer: deque[tuple[Any, np.ndarray]] = deque()
        self.next = 0  # buffer index of the next frame to emit

    def push(self, item: Any, positions: np.ndarray) -> Iterator[tuple[Any, np.ndarray]]:
        self.buffer.append((item, positions))
        while self.next + self.half_width < len(self.buffer):
            yield self._emit_next(after=self.half_width)

    def flush(self) -> Iterator[tuple[Any, np.ndarray]]:
        while self.next < len(self.buffer):
            yield self._emit_next(after=len(self.buffer) - 1 - self.next)

    def _emit_next(self, *, after: int) -> tuple[Any, np.ndarray]:
        centre = self.next
        item, positions = self.buffer[centre]
        reach = min(centre, after, self.half_width)
        out = positions
        if reach > 0:
            stack = np.stack([self.buffer[i][1] for i in range(centre - reach, centre + reach + 1)])
            out = positions.copy()
            tracked = np.isfinite(positions)
            for h in range(1, reach + 1):
                window = stack[reach - h : reach + h + 1]
                tracked = tracked & np.isfinite(window[0]) & np.isfinite(window[-1])
                if not np.any(tracked):
                    break
                smoothed = np.tensordot(self.weights[h], np.nan_to_num(window), axes=1)
                out = np.where(tracked, smoothed, out)
        self.next += 1
        while self.next > self.half_width:
            self.buffer.popleft()
            self.next -= 1
        return item, out


def track_and_measure(
    edges: Iterable[FrameEdges],
    projector: ProjectorCalibration,
    camera_model: CameraModel,
    *,
    settings: TopographySettings | None = None,
    first_frame: int = 0,
    reference: OrderReference | None = None,
) -> Iterator[FrameMeasurement]:
    """Order, Z from the table, X and Y by back-projection of consecutive frames (docs/method.md §5–6).

    edges: the located edges of consecutive frames in frame order (`first_frame` is the index of the first in
    the recording). reference: the anchor of the test's order (`reference_for` of its flat first frame); None
    takes the first frame given as the reference. Every frame is ordered on its own (`order_positions`), so the
    frames given may start anywhere when the reference is given; only temporal smoothing, if on, looks at the
    neighbouring frames. Yields one FrameMeasurement per frame, in order (with temporal smoothing, h frames after
    their edges came in).
    """
    settings = TopographySettings() if settings is None else settings
    iterator = iter(edges)
    smoother = _TemporalSmoother(settings.temporal_smoothing_frames)
    for offset, frame_edges in enumerate(iterator):
        if reference is None:
            reference = reference_for(frame_edges, projector, camera_model, settings)
        ordered = order_positions(frame_edges, reference, projector, settings)
        item = (first_frame + offset, ordered.counts, frame_edges.noise_px, ordered.coverage, ordered.sigma_px)
        for emitted in smoother.push(item, ordered.positions):
            yield _measure(emitted, projector, camera_model)
    for emitted in smoother.flush():
        yield _measure(emitted, projector, camera_model)


def measure_frame(
    edges: FrameEdges,
    reference: OrderReference,
    projector: ProjectorCalibration,
    camera_model: CameraModel,
    *,
    frame: int,
    settings: TopographySettings | None = None,
) -> FrameMeasurement:
    """One frame measured alone (no temporal smoothing): equal to the same frame measured within its test."""
    settings = TopographySettings() if settings is None else settings
    ordered = order_positions(edges, reference, projector, settings)
    item = (frame, ordered.counts, edges.noise_px, ordered.coverage, ordered.sigma_px)
    return _measure((item, ordered.positions), projector, camera_model)


@dataclass(frozen=True, eq=False)
class ScanRays:
    """The ideal sensor coordinates of every pixel, laid out along scan lines, for back-projecting many sub-pixel
    points that lie on scan lines (edge points: an integer line, a sub-pixel position t along it).

    ut_mm, vt_mm: shape (S, T), (ũ, ṽ) of pixel (line, t) (NaN where the pixel cannot be undistorted); axis
    "rows": a line is an image row and t its column; "cols": a line is a column and t its row.
    Between two pixels of a line (ũ, ṽ) is interpolated linearly: the distortion bends over hundreds of pixels,
    so the chord departs from the exact undistortion by less than 1e-4 px (6e-5 px on the virtual Kodak camera,
    whose corners move 9 px; tests/science/test_topography.py), a hundredth of the edges' noise.
    """

    camera: Camera
    axis: Literal["rows", "cols"]
    ut_mm: np.ndarray
    vt_mm: np.ndarray

    def backproject_to_z(self, line: np.ndarray, t_px: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
        """Object points (N, 3) where the rays of points (line, t_px), each shape (N,), meet the planes Z = z_mm
        (N,); as `backproject_to_z` of the same pixels."""
        centre = camera_centre_obj_mm(self.camera)
        direction_from_ideal = self.camera.rotation.T * np.array([1.0, 1.0, self.camera.f_mm])  # d = Mᵀ·[ũ, ṽ, f]
        return _scan_rays_to_z(
            self.ut_mm, self.vt_mm, contiguous_index_array(line), np.ascontiguousarray(t_px, np.float64),
            np.ascontiguousarray(z_mm, np.float64), direction_from_ideal, centre,
        )  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _scan_rays_to_z(
    ut_mm: np.ndarray,
    vt_mm: np.ndarray,
    line: np.ndarray,
    t_px: np.ndarray,
    z_mm: np.ndarray,
    direction_from_ideal: np.ndarray,
    centre: np.ndarray,
) -> np.ndarray:
    n_samples = ut_mm.shape[1]
    m = direction_from_ideal
    out = np.empty((len(t_px), 3))
    for i in range(len(t_px)):
        left = min(max(int(t_px[i]), 0), n_samples - 2)
        frac = t_px[i] - left
        s = line[i]
        ut = ut_mm[s, left] + frac * (ut_mm[s, left + 1] - ut_mm[s, left])
        vt = vt_mm[s, left] + frac * (vt_mm[s, left + 1] - vt_mm[s, left])
        dx = m[0, 0] * ut + m[0, 1] * vt + m[0, 2]
        dy = m[1, 0] * ut + m[1, 1] * vt + m[1, 2]
        dz = m[2, 0] * ut + m[2, 1] * vt + m[2, 2]
        lam = (z_mm[i] - centre[2]) / dz
        if np.isfinite(lam):
            out[i, 0] = centre[0] + lam * dx
            out[i, 1] = centre[1] + lam * dy
            out[i, 2] = z_mm[i]
        else:
            out[i, 0] = out[i, 1] = out[i, 2] = np.nan
    return out


def scan_rays(camera_model: CameraModel, axis: Literal["rows", "cols"]) -> ScanRays:
    """The camera's `ScanRays` along the projector's scan lines (exact undistortion at each pixel), built once
    per process and camera."""
    return _scan_rays(camera_model.camera, camera_model.inverse, axis)


@functools.lru_cache(maxsize=2)
def _scan_rays(camera: Camera, inverse: InverseModel, axis: Literal["rows", "cols"]) -> ScanRays:
    height, width = camera.image_height_px, camera.image_width_px
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    ut, vt = ideal_from_pixels(camera, np.column_stack([u.ravel(), v.ravel()]), inverse=inverse)
    ut, vt = ut.reshape(height, width), vt.reshape(height, width)
    if axis == "cols":
        ut, vt = np.ascontiguousarray(ut.T), np.ascontiguousarray(vt.T)
    return ScanRays(camera=camera, axis=axis, ut_mm=ut, vt_mm=vt)


def _measure(
    emitted: tuple[Any, np.ndarray], projector: ProjectorCalibration, camera_model: CameraModel
) -> FrameMeasurement:
    (frame, counts, noise_px, coverage, sigma_px), positions = emitted
    # Each point's σ_Z from its edge σ as located (temporal smoothing, if on, would reduce it: left out, so σ errs
    # large) and the table's (`uncertainty.point_sigma_z_mm`).
    kk, ll, t, z, table_sigma_z, sigma_z, n_placed, n_out_of_range = _looked_up_points(
        positions, sigma_px, projector.lookup_table, projector.n_heights_by_line, _leverage(projector)
    )
    points = scan_rays(camera_model, projector.axis).backproject_to_z(ll, t, z)
    # The local check across neighbouring edges adds what the errors have beyond σ near each point
    # (`uncertainty.local_excess_variance`); the frame's own check (`uncertainty.cross_edge_scale`) then scales.
    centre, k_centre, line_centre, d2, predicted = _fourth_difference_checks(kk, ll, z, sigma_z)
    shape = (int(positions.shape[0]), int(positions.shape[1]))
    local_variance = local_excess_variance(k_centre, line_centre, d2, predicted, shape, k=kk, line=ll)
    sigma_scale = scale_from_ratios(_check_ratios(local_variance, centre, d2, predicted))
    _with_local_variance(sigma_z, local_variance, sigma_scale)  # in place: the array is this frame's own
    return FrameMeasurement(
        frame=int(frame),
        k=kk,
        line=ll,
        points_obj_mm=points,
        n_tracks=n_placed,
        n_ended=0,
        n_out_of_range=n_out_of_range,
        n_unmatched=int(counts["n_unmatched"]),
        edge_noise_px=float(noise_px),
        n_order_unresolved=int(counts["n_order_unresolved"]),
        n_order_conflict_points=int(counts["n_order_conflict_points"]),
        n_order_conflicts=int(counts["n_order_conflicts"]),
        coverage=coverage,
        sigma_z_mm=sigma_z,
        sigma_scale=sigma_scale,
        local_variance_mm2=local_variance,
        table_sigma_z_mm=table_sigma_z,
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _fourth_difference_checks(
    kk: np.ndarray, ll: np.ndarray, z: np.ndarray, sigma: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every fourth difference of five neighbouring edges (k … k + 4) on a scan line (`uncertainty.cross_edge_scale`),
    from the points (N,) sorted by (line, k) as `_looked_up_points` gives them: the index of its middle point, that
    point's k and line (kk's and ll's type), d² and its predicted variance Σc²σ² (M,) each."""
    n = len(kk)
    size = max(n - 4, 0)
    centre = np.empty(size, np.int64)
    k_centre, line_centre = np.empty(size, kk.dtype), np.empty(size, ll.dtype)
    d2, predicted = np.empty(size), np.empty(size)
    m = 0
    for i in range(n - 4):
        if ll[i + 4] != ll[i] or kk[i + 4] - kk[i] != 4:
            continue  # not five consecutive edges of one line
        d = z[i] - 4.0 * z[i + 1] + 6.0 * z[i + 2] - 4.0 * z[i + 3] + z[i + 4]
        p = (sigma[i] ** 2 + 16.0 * sigma[i + 1] ** 2 + 36.0 * sigma[i + 2] ** 2 + 16.0 * sigma[i + 3] ** 2
             + sigma[i + 4] ** 2)  # fmt: skip
        if np.isfinite(d) and p > 0:
            centre[m], d2[m], predicted[m] = i + 2, d * d, p
            k_centre[m], line_centre[m] = kk[i + 2], ll[i + 2]
            m += 1
    return centre[:m], k_centre[:m], line_centre[:m], d2[:m], predicted[:m]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _check_ratios(local_variance: np.ndarray, centre: np.ndarray, d2: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Each check's (M,) d² over its variance with the local check's τ² (N,) counted, for the frame's check
    (`uncertainty.scale_from_ratios`): τ² varies little over the five edges of a check, so its middle's (centre
    (M,)) stands for them (Σc² = 70)."""
    ratios = np.empty(len(d2))
    for m in range(len(d2)):
        ratios[m] = d2[m] / (predicted[m] + 70.0 * local_variance[centre[m]])
    return ratios


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _with_local_variance(sigma_z: np.ndarray, local_variance: np.ndarray, sigma_scale: float) -> None:
    """The points' σ_Z (N,), in place, with the local check's τ² (N,) added in quadrature, then times the frame's
    scale: one pass, no temporaries."""
    for i in range(len(sigma_z)):
        sigma_z[i] = np.sqrt(sigma_z[i] * sigma_z[i] + local_variance[i]) * sigma_scale


def _leverage(projector: ProjectorCalibration) -> np.ndarray:
    """The table's `uncertainty.leverage_polynomials` (its degree, up to its number of heights)."""
    return leverage_polynomials(projector.coefficients.shape[-1] - 1, projector.lut_t_px.shape[-1])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _looked_up_points(
    positions: np.ndarray, edge_sigma_px: np.ndarray, table: np.ndarray, n_heights: np.ndarray, leverage: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int]:
    """The points of positions (K, S) with Z from the table, line by line (the order the table and the rays are
    laid out in): k, line, t, z (N,), the table's σ_Z at each point's place in the fitted range (the entry's σ_Z
    times its leverage there, `uncertainty.fit_leverage_ratio` of the row of `leverage` for the entry's
    n_heights (S, K)) (N,), its σ_Z from that, the entry's sensitivity and its edge's σ (`edge_sigma_px` (K, S);
    `uncertainty.point_sigma_z_mm`) (N,), and how many positions there were and how many lay outside the
    calibrated range."""
    n_edges, n_lines = positions.shape
    # Sized by a first pass over the positions, not K × S: writing into outputs of every (edge, line) and copying
    # the points out cost more than the look-ups (0.3 ms of 1.5 on a Kodak frame).
    capacity = 0
    for k in range(n_edges):
        for s in range(n_lines):
            if np.isfinite(positions[k, s]):
                capacity += 1
    kk, ll = np.empty(capacity, np.int32), np.empty(capacity, np.int32)  # as FrameMeasurement keeps them
    t, z, sigma_z, table_sigma_z = np.empty(capacity), np.empty(capacity), np.empty(capacity), np.empty(capacity)
    m = n_placed = n_out_of_range = 0
    for s in range(n_lines):
        for k in range(n_edges):
            if not np.isfinite(positions[k, s]):
                continue
            n_placed += 1
            value, status, tau = table_z_tau_at(table, k, s, positions[k, s])
            if status == 1:
                n_out_of_range += 1
            if status != 0:
                continue
            kk[m], ll[m], t[m], z[m] = k, s, positions[k, s], value
            spread = fit_leverage_ratio(tau, leverage, n_heights[s, k])
            table_sigma_z[m] = table[s, k, TABLE_SIGMA_Z] * spread
            sigma_z[m] = point_sigma_z_at(table[s, k, TABLE_SENSITIVITY], table_sigma_z[m], edge_sigma_px[k, s])
            m += 1
    if m == capacity:  # no point outside the table
        return kk, ll, t, z, table_sigma_z, sigma_z, n_placed, n_out_of_range
    return (kk[:m].copy(), ll[:m].copy(), t[:m].copy(), z[:m].copy(), table_sigma_z[:m].copy(), sigma_z[:m].copy(),
            n_placed, n_out_of_range)  # fmt: skip


# --------------------------------------------------------------------------------------------------------------
# Gridding helpers used by the recording pipeline


def grid_for_first_frame(
    measurement: FrameMeasurement, projector: ProjectorCalibration, settings: TopographySettings
) -> tuple[Grid, float]:
    """The grid of a test (from its first frame's points) and the mesh's longest triangle side (mm)."""
    grid = grid_covering(
        measurement.points_obj_mm[:, :2], step_mm=settings.grid_step_mm, margin_mm=settings.grid_margin_mm
    )
    if settings.grid_max_edge_mm is not None:
        return grid, settings.grid_max_edge_mm
    x, y, _ = measurement.dense((projector.n_edges, projector.n_lines))
    return grid, 3.0 * typical_edge_gap_mm(x, y)


def grid_measurement(
    measurement: FrameMeasurement, projector: ProjectorCalibration, grid: Grid, *, max_edge_mm: float
) -> np.ndarray:
    """The gridded Z (ny, nx) of one frame's points, NaN outside the data."""
    x, y, z = measurement.dense((projector.n_edges, projector.n_lines))
    return grid_edge_points(x, y, z, grid, max_edge_mm=max_edge_mm)


def grid_measurement_with_sigma(
    measurement: FrameMeasurement, projector: ProjectorCalibration, grid: Grid, *, max_edge_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """The gridded Z and its σ (`uncertainty.grid_sigma_mm`), each (ny, nx) and NaN outside the data, on one
    mesh: the Z of `grid_measurement`, and σ NaN everywhere for a measurement without σ."""
    shape = (projector.n_edges, projector.n_lines)
    x, y, z = measurement.dense(shape)
    sigma = np.full(shape, np.nan)
    if measurement.sigma_z_mm is not None:
        sigma[measurement.k, measurement.line] = measurement.sigma_z_mm
    fields = grid_edge_fields(x, y, np.concatenate([z[None], sigma_edge_halves(sigma)]), grid, max_edge_mm=max_edge_mm)
    return fields[0], sigma_from_halves(fields[1:])


def frame_range(frames: Sequence[int] | range | None, n_frames: int) -> range:
    """The frames to output as a range within 0..n_frames − 1; ValueError for an empty, gapped or out-of-bounds
    selection."""
    if frames is None:
        return range(n_frames)
    if isinstance(frames, range):
        chosen = frames
    else:
        values = sorted({int(f) for f in frames})
        if values and values != list(range(values[0], values[-1] + 1)):
            raise ValueError(f"frames: expected a contiguous range, got {frames}")
        chosen = range(values[0], values[-1] + 1) if values else range(0)
    if len(chosen) == 0 or chosen.step != 1 or chosen.start < 0 or chosen.stop > n_frames:
        raise ValueError(f"frames: expected a non-empty contiguous range within 0..{n_frames - 1}, got {frames}")
    return chosen


PUNCH_AXIS_MIN_PEAK_MM = 5.0  # frames whose peak is at least this deep locate the punch axis (shallower: noise)


@dataclass
class SummaryTally:
    """The headline numbers of a topography run (its /summary), tallied frame by frame in frame order: the one
    rule for the command line's sequential run and the worker's parallel job."""

    peaks_w_mm: list[float] = field(default_factory=list)
    centres_xy_mm: list[tuple[float, float]] = field(default_factory=list)
    n_out_of_range: int = 0
    n_after_first: int = 0
    n_ordered_after_first: int = 0
    n_unresolved_after_first: int = 0
    n_conflict_after_first: int = 0

    def add(self, peak: Peak, *, n_out_of_range: int, measurement: FrameMeasurement | None = None) -> None:
        self.peaks_w_mm.append(peak.w_mm)
        if np.isfinite(peak.centre_x_mm) and peak.w_mm >= PUNCH_AXIS_MIN_PEAK_MM:
            self.centres_xy_mm.append((peak.centre_x_mm, peak.centre_y_mm))
        self.n_out_of_range += n_out_of_range
        if measurement is not None and measurement.frame > 0:
            self.n_after_first += 1
            self.n_ordered_after_first += len(measurement.k)
            self.n_unresolved_after_first += measurement.n_order_unresolved
            self.n_conflict_after_first += measurement.n_order_conflict_points

    def require_ordered(self, where: str) -> None:
        """TopographyError when no frame after the reference could be ordered anywhere: a result with nothing
        measured after its first frame would look like a plate that vanished. The message names the reason most
        of the frames' edge points had: no anchor (the rim) or a conflict (neighbours or the projector table)."""
        if self.n_after_first == 0 or self.n_ordered_after_first > 0:
            return
        counts = (f"{self.n_after_first} frames; {self.n_unresolved_after_first} edge points with no anchor, "
                  f"{self.n_conflict_after_first} masked for an order conflict")  # fmt: skip
        if self.n_conflict_after_first > self.n_unresolved_after_first:
            raise TopographyError(
                f"{where}: the stripes could not be ordered in any frame after the first ({counts}): their order, "
                "counted from the clamped rim, disagrees with the projector table or between neighbouring stripes; "
                "check that the projector calibration belongs to this setup and covers the test's Z range"
            )
        raise TopographyError(
            f"{where}: the stripes could not be ordered in any frame after the first ({counts}): the clamped rim, "
            "which anchors the fringe order, shows no stripes in them; check that the rim stays lit and in view, "
            "or set rim_circle_mm to a region that stays still"
        )

    @property
    def punch_axis_xy_mm(self) -> tuple[float, float]:
        """Median of the peak centres of the deep frames; NaN before the plate is deep enough anywhere."""
        if not self.centres_xy_mm:
            return float("nan"), float("nan")
        x, y = np.median(np.array(self.centres_xy_mm), axis=0)
        return float(x), float(y)

    @property
    def max_peak_w_mm(self) -> float:
        finite = [w for w in self.peaks_w_mm if np.isfinite(w)]
        return max(finite) if finite else float("nan")

    def attrs(self, *, flat_rms_mm: float, n_tracks_first_frame: int, clamp: Sequence[float]) -> dict[str, Any]:
        """The /summary attributes of the result file."""
        axis_x, axis_y = self.punch_axis_xy_mm
        return {
            "flat_rms_mm": flat_rms_mm, "n_tracks_first_frame": n_tracks_first_frame,
            "clamp_centre_x_mm": clamp[0], "clamp_centre_y_mm": clamp[1], "clamp_radius_mm": clamp[2],
            "punch_axis_x_mm": axis_x, "punch_axis_y_mm": axis_y, "n_out_of_range_total": self.n_out_of_range,
        }  # fmt: skip
