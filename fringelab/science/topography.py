"""Topography: edge identity through a test, Z from the projector table, X and Y by back-projection
(docs/method.md §5–6).

Belongs here: identifying the edges of the first (flat) test frame against the projector calibration, tracking
every (edge, scan line) point frame to frame and ending tracks that break, optional temporal smoothing, and
turning tracked positions into 3-D points. The pipeline is split so that test recordings can be processed in
parallel chunks with results identical to one run:

1. `locate_test_edges` / `fringes.locate_edges`: the expensive part, a pure function of one frame. Chunks of
   frames can run on different workers; their `FrameEdges` can be stored (`fringelab.formats.topography.write_edges`).
2. `track_and_measure`: a cheap sequential pass over the located edges in frame order, always from the first
   frame (identity is fixed there), yielding one `FrameMeasurement` per frame. Temporal smoothing, if on, is a
   centred window inside this pass, so it sees the same neighbours whatever the chunking.
3. Gridding (`fields.grid_edge_points`), a pure function of one measurement.

`topography_recording` runs all three over a recording and streams the result into an HDF5 file. Not here: the
edge locator (`fringes.py`), the table (`projector.py`), grids and profiles (`fields.py`), files
(`fringelab.formats.topography.py`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import MeasurementError
from .camera import backproject_to_z
from .fields import Grid, Peak, grid_covering, grid_edge_points, typical_edge_gap_mm
from .fringes import FrameEdges, detect_stripes, locate_edges
from .projector import (
    CalibrationMismatchError,
    CameraModel,
    ProjectorCalibration,
    camera_fingerprint,
    match_to_reference,
)
from .uncertainty import edge_sigma_px, point_sigma_z_mm


class FirstFrameNotFlatError(MeasurementError):
    """The first test frame does not show the flat, undeformed plate the edge identity is fixed on."""


class TopographyError(MeasurementError):
    """The topography cannot be computed from this recording (too few edges identified, ...)."""


@dataclass(frozen=True)
class TopographySettings:
    """Settings of the topography.

    max_jump_fraction: a tracked edge may move at most this fraction of the stripe period from where its last
        motion predicts it, or its track ends (never guessed across a gap); 0.3 period is well under the half
        period at which it could take its neighbour's place.
    temporal_smoothing_frames: half-width h of a centred quadratic (Savitzky–Golay) filter of each tracked edge
        position over 2h + 1 frames; 0 = off. Near the ends of a track the window shrinks symmetrically.
    flat_tolerance_mm: the first frame is taken as flat when 90 % of its points lie within this of the
        calibration's reference Z.
    grid_step_mm: spacing of the deflection grid.
    grid_max_edge_mm: longest triangle side of the gridding mesh; None = 3 × the median gap between neighbouring
        edges in the first frame (a missing edge between two measured ones is still bridged, a hole is not).
    grid_margin_mm: margin of the grid around the first frame's points.
    """

    max_jump_fraction: float = 0.3
    temporal_smoothing_frames: int = 0
    flat_tolerance_mm: float = 2.0
    grid_step_mm: float = 2.0
    grid_max_edge_mm: float | None = None
    grid_margin_mm: float = 4.0

    def __post_init__(self) -> None:
        if not 0 < self.max_jump_fraction < 0.5:
            raise ValueError(f"max_jump_fraction: expected 0 < f < 0.5, got {self.max_jump_fraction}")
        if self.temporal_smoothing_frames < 0:
            raise ValueError(f"temporal_smoothing_frames: expected ≥ 0, got {self.temporal_smoothing_frames}")
        if not self.grid_step_mm > 0:
            raise ValueError(f"grid_step_mm: expected > 0, got {self.grid_step_mm}")
        if self.grid_max_edge_mm is not None and not self.grid_max_edge_mm > 0:
            raise ValueError(f"grid_max_edge_mm: expected > 0 or None, got {self.grid_max_edge_mm}")


@dataclass(frozen=True, eq=False)
class FrameMeasurement:
    """The 3-D points of one frame and how many of the tracked points made it.

    frame: index of the frame in the recording. k, line: (N,) edge index and scan line of each point;
    points_obj_mm: (N, 3). n_tracks: tracked (edge, line) points in this frame (with or without Z); n_ended:
    tracks that ended at this frame; n_out_of_range: tracked points outside the calibrated Z range of their
    table entry (masked, never extrapolated); n_unmatched: edge points of the frame that belong to no track;
    edge_noise_px: the frame's edge-location noise estimate. sigma_z_mm: (N,) σ of each point's Z from the edge
    noise and the projector table (`uncertainty.point_sigma_z_mm`), None where not computed.
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
    sigma_z_mm: np.ndarray | None = None

    def dense(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """X, Y, Z as (K, S) arrays over (edge, line), NaN where not measured."""
        out = [np.full(shape, np.nan) for _ in range(3)]
        for axis in range(3):
            out[axis][self.k, self.line] = self.points_obj_mm[:, axis]
        return out[0], out[1], out[2]


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
# Identity and tracking


def identify_first_frame(edges: FrameEdges, projector: ProjectorCalibration, *, flat_tolerance_mm: float) -> np.ndarray:
    """Positions (K, S) of the projector's edges in the first (flat) test frame, NaN where not seen.

    Each edge point is matched to the nearest table edge of the same polarity at the reference Z on its line;
    an edge curve takes the index most of its points agree on (≥ 80 %, else it is left out). Raises
    FirstFrameNotFlatError when the identified points do not lie at the reference Z, TopographyError when too
    few are identified.
    """
    k_near, distance = match_to_reference(
        edges.line, edges.t_px, edges.polarity, projector.reference_t_px, projector.polarity,
        n_samples=edges.n_samples,
    )  # fmt: skip
    near = (k_near >= 0) & (np.abs(distance) <= 0.5 * projector.period_px)
    n_chains = int(edges.chain.max()) + 1 if len(edges) else 0
    k = np.full(len(edges), -1, np.int64)
    if n_chains:
        codes, counts = np.unique(edges.chain[near].astype(np.int64) * (projector.n_edges + 1) + k_near[near],
                                  return_counts=True)  # fmt: skip
        chain_of, k_of = codes // (projector.n_edges + 1), codes % (projector.n_edges + 1)
        best = np.zeros(n_chains, np.int64)
        best_k = np.full(n_chains, -1, np.int64)
        order = np.argsort(counts, kind="stable")  # ascending, so the largest count per chain is written last
        best[chain_of[order]] = counts[order]
        best_k[chain_of[order]] = k_of[order]
        length = np.bincount(edges.chain, minlength=n_chains)
        chain_ok = best >= 0.8 * length
        k = np.where(chain_ok[edges.chain], best_k[edges.chain], -1)
    identified = k >= 0
    if np.count_nonzero(identified) < max(50, 0.3 * len(edges)):
        raise TopographyError(
            f"only {np.count_nonzero(identified)} of {len(edges)} edge points of the first test frame match the "
            "projector calibration's edges: the projector, the camera or the plate moved since the calibration"
        )
    z, status = projector.z_from_t(k[identified], edges.line[identified], edges.t_px[identified])
    offset = np.abs(z[status == 0] - projector.reference_z_mm)
    if len(offset) == 0 or np.percentile(offset, 90) > flat_tolerance_mm:
        p90 = float(np.percentile(offset, 90)) if len(offset) else float("nan")
        raise FirstFrameNotFlatError(
            f"the first test frame is not the flat plate at Z = {projector.reference_z_mm:g} mm: 10 % of its edge "
            f"points are more than {p90:.1f} mm from it (tolerance {flat_tolerance_mm:g} mm); the topography "
            "fixes edge identity on an undeformed first frame, so start the recording before the punch touches"
        )
    positions = np.full((projector.n_edges, projector.n_lines), np.nan)
    kk, ll = k[identified], edges.line[identified].astype(np.int64)
    flat = kk * projector.n_lines + ll
    counts = np.bincount(flat, minlength=positions.size)
    single = counts[flat] == 1
    positions.ravel()[flat[single]] = edges.t_px[identified][single]
    # Without a table entry a track can never give Z.
    positions[~projector.valid] = np.nan
    return positions


@dataclass
class EdgeTracker:
    """Tracks every (edge k, scan line s) point from frame to frame (docs/method.md §5).

    positions: (K, S) current positions (NaN = no track); velocity: (K, S) last motion per frame.
    A track follows the nearest edge point of its polarity on its line to where its last motion predicts it,
    if that point is within max_jump_px, if the next point of that polarity is at least 1/ambiguity_ratio times
    farther (unambiguous), and if the point's own nearest track is this one (mutual). Then an edge curve of the
    frame may serve one edge only, and the order of the edges along each line must be kept. A track that fails
    any of this ends for good: it is never guessed.
    """

    positions: np.ndarray
    polarity: np.ndarray
    max_jump_px: float
    ambiguity_ratio: float = 0.5
    velocity: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.velocity = np.zeros_like(self.positions)

    def step(self, edges: FrameEdges) -> tuple[np.ndarray, int, int]:
        """Advance to the next frame. Returns the new positions (K, S), the number of tracks ended and the number
        of edge points of the frame that no track took."""
        kk, ss = np.nonzero(np.isfinite(self.positions))
        predicted = self.positions[kk, ss] + self.velocity[kk, ss]
        predicted_table = np.full_like(self.positions, np.nan)
        predicted_table[kk, ss] = predicted
        n_samples = edges.n_samples
        # Each edge point's nearest track (for the mutual check).
        k_near, _ = match_to_reference(
            edges.line, edges.t_px, edges.polarity, predicted_table, self.polarity, n_samples=n_samples
        )
        # Each track's nearest and second-nearest edge point of its polarity on its line.
        stride = float(n_samples + 1000.0)
        taken = np.full(len(kk), -1, np.int64)
        for sign in (1, -1):
            members = np.flatnonzero(edges.polarity == sign)
            tracks = np.flatnonzero(self.polarity[kk] == sign)
            if len(members) < 2 or len(tracks) == 0:
                continue
            keys = edges.line[members].astype(np.float64) * stride + edges.t_px[members]
            query = ss[tracks].astype(np.float64) * stride + predicted[tracks]
            pos = np.searchsorted(keys, query)
            last = len(keys) - 1
            lo, hi = np.clip(pos - 1, 0, last), np.minimum(pos, last)
            d_lo, d_hi = np.abs(query - keys[lo]), np.abs(keys[hi] - query)
            lower_nearer = d_lo <= d_hi
            nearest = np.where(lower_nearer, lo, hi)
            d1 = np.minimum(d_lo, d_hi)
            # The runner-up is the other of the pair, or the next one out on the nearer side.
            outer = np.where(lower_nearer, np.maximum(lo - 1, 0), np.minimum(hi + 1, last))
            d_outer = np.abs(keys[outer] - query)
            d_outer[outer == nearest] = np.inf
            d_other = np.where(lower_nearer, d_hi, d_lo)
            d_other[(lo == hi)] = np.inf
            d2 = np.minimum(d_other, d_outer)
            point = members[nearest]
            ok = (d1 <= self.max_jump_px) & (d1 <= self.ambiguity_ratio * d2) & (k_near[point] == kk[tracks])
            taken[tracks[ok]] = point[ok]
        keep = taken >= 0
        kk_t, ss_t, point_t = kk[keep], ss[keep], taken[keep]
        keep_curve = self._one_edge_per_curve(kk_t, edges.chain[point_t], self.positions.shape[0])
        kk_t, ss_t, point_t = kk_t[keep_curve], ss_t[keep_curve], point_t[keep_curve]
        positions = np.full_like(self.positions, np.nan)
        positions[kk_t, ss_t] = edges.t_px[point_t]
        positions = self._keep_order(positions)
        moved = np.isfinite(positions)
        n_alive_before = len(kk)
        self.velocity = np.where(moved, positions - self.positions, 0.0)
        self.positions = positions
        n_taken = int(np.count_nonzero(moved))
        return positions, n_alive_before - n_taken, len(edges) - n_taken

    @staticmethod
    def _one_edge_per_curve(k: np.ndarray, chain: np.ndarray, n_edges: int) -> np.ndarray:
        """Mask (N,) of the points to keep: an edge curve of the frame is one stripe edge, so where tracks of
        different edges took points of the same curve, only the edge that took clearly most of them keeps its
        points there (a tie keeps none). This catches a track that, its own edge gone (at a new hole), took up a
        neighbouring edge that other tracks follow elsewhere along its length."""
        if len(k) == 0:
            return np.zeros(0, bool)
        n_chains = int(chain.max()) + 1
        counts = np.bincount(chain.astype(np.int64) * n_edges + k, minlength=n_chains * n_edges).reshape(
            n_chains, n_edges
        )
        best = np.argmax(counts, axis=1)
        best_count = counts[np.arange(n_chains), best]
        counts[np.arange(n_chains), best] = 0
        clear = best_count > counts.max(axis=1)
        owner = np.where(clear, best, -1)
        return owner[chain] == k

    @staticmethod
    def _keep_order(positions: np.ndarray) -> np.ndarray:
        """End both tracks of any pair of consecutive tracked edges on a line that swapped order."""
        valid = np.isfinite(positions)
        index = np.where(valid, np.arange(positions.shape[0])[:, None], -1)
        # The previous tracked edge on the same line, for every (k, s).
        previous = np.maximum.accumulate(index, axis=0)
        previous = np.vstack([np.full((1, positions.shape[1]), -1), previous[:-1]])
        has_previous = valid & (previous >= 0)
        kk, ss = np.nonzero(has_previous)
        pk = previous[kk, ss]
        swapped = positions[kk, ss] <= positions[pk, ss]
        if not np.any(swapped):
            return positions
        out = positions.copy()
        out[kk[swapped], ss[swapped]] = np.nan
        out[pk[swapped], ss[swapped]] = np.nan
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
) -> Iterator[FrameMeasurement]:
    """The sequential pass: identity, tracking, Z from the table, X and Y by back-projection (docs/method.md §5–6).

    edges: the located edges of consecutive frames in frame order, starting with the flat first frame of the
    test (`first_frame` is its index in the recording). Yields one FrameMeasurement per frame, in order (with
    temporal smoothing, h frames after their edges came in). Cheap next to edge location: it can be rerun over
    stored edges, and a chunked run that feeds it the same edges gives identical results.
    """
    settings = TopographySettings() if settings is None else settings
    iterator = iter(edges)
    try:
        first = next(iterator)
    except StopIteration:
        return
    positions = identify_first_frame(first, projector, flat_tolerance_mm=settings.flat_tolerance_mm)
    tracker = EdgeTracker(
        positions=positions, polarity=projector.polarity, max_jump_px=settings.max_jump_fraction * projector.period_px
    )
    smoother = _TemporalSmoother(settings.temporal_smoothing_frames)
    n_first_unmatched = len(first) - int(np.count_nonzero(np.isfinite(positions)))
    pending = ((first_frame, 0, n_first_unmatched, first.noise_px), positions)
    for emitted in smoother.push(*pending):
        yield _measure(emitted, projector, camera_model)
    for offset, frame_edges in enumerate(iterator, start=1):
        positions, n_ended, n_unmatched = tracker.step(frame_edges)
        for emitted in smoother.push((first_frame + offset, n_ended, n_unmatched, frame_edges.noise_px), positions):
            yield _measure(emitted, projector, camera_model)
    for emitted in smoother.flush():
        yield _measure(emitted, projector, camera_model)


def _measure(
    emitted: tuple[Any, np.ndarray], projector: ProjectorCalibration, camera_model: CameraModel
) -> FrameMeasurement:
    (frame, n_ended, n_unmatched, noise_px), positions = emitted
    kk, ll = np.nonzero(np.isfinite(positions))
    t = positions[kk, ll]
    z, status = projector.z_from_t(kk, ll, t)
    ok = status == 0
    kk, ll, t, z = kk[ok], ll[ok], t[ok], z[ok]
    q_px = np.column_stack([t, ll] if projector.axis == "rows" else [ll, t]).astype(np.float64)
    points = backproject_to_z(camera_model.camera, q_px, z, inverse=camera_model.inverse)
    sigma_z = point_sigma_z_mm(
        sensitivity_px_per_mm=projector.sensitivity_px_per_mm[kk, ll], fit_rms_mm=projector.fit_rms_mm[kk, ll],
        n_heights=np.count_nonzero(np.isfinite(projector.lut_t_px[kk, ll]), axis=-1),
        n_coefficients=projector.coefficients.shape[-1], edge_sigma_px=edge_sigma_px(noise_px, projector.edges),
    )  # fmt: skip
    return FrameMeasurement(
        frame=int(frame),
        k=kk.astype(np.int32),
        line=ll.astype(np.int32),
        points_obj_mm=points,
        n_tracks=int(len(status)),
        n_ended=int(n_ended),
        n_out_of_range=int(np.count_nonzero(status == 1)),
        n_unmatched=int(n_unmatched),
        edge_noise_px=float(noise_px),
        sigma_z_mm=sigma_z,
    )


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


def clamp_circle(points_xy_mm: np.ndarray, *, n_sectors: int = 72) -> tuple[float, float, float]:
    """Centre (x, y) and radius (mm) of the circle through the outermost points of the flat first frame.

    The points end where the clamp ring hides the plate; the outermost point of each angular sector around
    their centroid lies on that circle (a little inside it: edges within half a stripe of the ring are
    rejected), so a least-squares (Kåsa) circle through them, refitted once without points more than 3 mm off,
    gives the plate centre from the clamp (docs/method.md §2).
    """
    xy = points_xy_mm[np.all(np.isfinite(points_xy_mm), axis=1)]
    if len(xy) < 3 * n_sectors:
        return float("nan"), float("nan"), float("nan")
    centroid = xy.mean(axis=0)
    rel = xy - centroid
    angle = np.arctan2(rel[:, 1], rel[:, 0])
    radius = np.hypot(rel[:, 0], rel[:, 1])
    sector = np.minimum(((angle + np.pi) / (2 * np.pi) * n_sectors).astype(np.int64), n_sectors - 1)
    order = np.lexsort((radius, sector))
    last = np.r_[sector[order][1:] != sector[order][:-1], True]
    rim = xy[order[last]]
    keep = np.ones(len(rim), bool)
    cx = cy = r = float("nan")
    for _ in range(2):
        x, y = rim[keep, 0], rim[keep, 1]
        design = np.column_stack([2 * x, 2 * y, np.ones(len(x))])
        (cx, cy, c), *_ = np.linalg.lstsq(design, x * x + y * y, rcond=None)
        r = float(np.sqrt(c + cx * cx + cy * cy))
        keep = np.abs(np.hypot(rim[:, 0] - cx, rim[:, 1] - cy) - r) < 3.0
        if np.count_nonzero(keep) < 8:
            break
    return float(cx), float(cy), r


PUNCH_AXIS_MIN_PEAK_MM = 5.0  # frames whose peak is at least this deep locate the punch axis (shallower: noise)


@dataclass
class SummaryTally:
    """The headline numbers of a topography run (its /summary), tallied frame by frame in frame order: the one
    rule for the command line's sequential run and the worker's parallel job."""

    peaks_w_mm: list[float] = field(default_factory=list)
    centres_xy_mm: list[tuple[float, float]] = field(default_factory=list)
    n_out_of_range: int = 0

    def add(self, peak: Peak, *, n_out_of_range: int) -> None:
        self.peaks_w_mm.append(peak.w_mm)
        if np.isfinite(peak.centre_x_mm) and peak.w_mm >= PUNCH_AXIS_MIN_PEAK_MM:
            self.centres_xy_mm.append((peak.centre_x_mm, peak.centre_y_mm))
        self.n_out_of_range += n_out_of_range

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
