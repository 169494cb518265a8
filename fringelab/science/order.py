"""Fringe order of every edge point of one frame, from the frame itself and the calibration (docs/method.md §5).

Belongs here: the reference that anchors the order (the flat reference frame matched to the projector table, and
the stationary clamped rim found from it), and `order_frame`, a pure function of one frame's edges and that
reference which gives every edge point its order k or the reason it has none. No frame depends on the frames
before it, so frames can be ordered in any order, on any worker, and a frame ordered alone equals the same frame
ordered within its sequence. Not here: locating edges (`fringes.py`), the table (`projector.py`), Z, X, Y and
the frame loop (`topography.py`).

Sources of the order, in the order they are trusted:
1. Relative order: `fringes.order_edges` links the frame's edge curves by counting edges across scan lines
   (consecutive edges of opposite polarity less than 0.8 period apart are neighbours), which fixes every curve's
   place within a connected group; the order is constant along each curve. Only sure links join groups (both
   edges with a small σ for the edge spacing, neither beside a dark area, gaps like their neighbours'), and
   curves are cut at long unsure stretches and wherever they run beside a dark area, so a dim region reached only
   through unsure edges, and an edge kept beside a hole or the clamp, is a group of its own. Edges beside a dark
   area do not vote for an anchor (below) either: they are located but never ordered.
2. Anchor: the clamped rim does not move (w = 0), so there an edge point lies within a fraction of a period of
   where the reference frame had the same edge; each rim point votes for the offset between its group's relative
   count and that edge's order. A group takes the offset a clear majority of its rim votes agree on.
3. Bounds: the projector table says over which positions each (edge, line) can lie within the calibrated Z range;
   a curve whose points lie outside those bounds for the order it was given disagrees with the table.
4. Consistency: neighbouring edges on a scan line are a fraction of a stripe's Z step apart on a smooth surface;
   a wrong order shows as a jump of a whole step. A curve whose neighbours mostly disagree with it is masked.
A group that reaches no rim (a dim region among them) is not guessed: its points are masked as "order unresolved".
Frame-to-frame continuity is no source here; `topography.py` may use it as a cross-check.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numba
import numpy as np

from . import MeasurementError
from .camera import backproject_to_z
from .fringes import FrameEdges, beside_dark_points, order_edges
from .graycode import Decoding
from .projector import TABLE_SENSITIVITY, CameraModel, EdgeLines, ProjectorCalibration, match_to_reference, table_z_at

# Reasons an edge point of a frame has no order (per point, int8).
ORDERED = 0
ORDER_UNRESOLVED = 1  # its group reaches no rim, or the rim votes split: the order cannot be fixed
ORDER_CONFLICT = 2  # its curve disagrees with its neighbours or with the table: masked, never guessed
REASON_NAMES = {ORDERED: "ordered", ORDER_UNRESOLVED: "order unresolved", ORDER_CONFLICT: "order conflict"}


class ReferenceFrameError(MeasurementError):
    """The reference frame cannot anchor the fringe order (not flat, not matching the table, rim not visible)."""


class ReferenceNotFlatError(ReferenceFrameError):
    """The reference (first) test frame does not show the flat, undeformed plate the order is anchored on."""


class RimNotVisibleError(ReferenceFrameError):
    """The clamped rim, where w = 0 anchors the order, is not in view."""


class OrderAgainstTableError(MeasurementError):
    """The rim-anchored order puts a frame's stripes on the wrong side of the projector table: the table's edges
    move the other way with Z than the frame's (a calibration whose Z steps aliased, or a plate beyond the
    calibrated range)."""


@dataclass(frozen=True)
class OrderSettings:
    """Settings of the per-frame order.

    rim_width_mm: width of the band inside the clamp circle taken as stationary (w ≈ 0). The band must lie where
        the deflection moves an edge by less than `anchor_tolerance_fraction` of a period: 15 mm keeps a 60 mm
        membrane deflection under ~2 mm there.
    rim_circle_mm: (X, Y, radius) of the circle where the plate is clamped, in mm; None finds it from the
        outermost points of the reference frame (the clamp ring must be in view). Set it when the rim is not
        visible in the frame, or when a stationary region other than the rim should anchor the order.
    anchor_tolerance_fraction: a rim point votes for the edge of the reference frame nearest to it of the same
        polarity when it lies within this fraction of a period of it (the next such edge is a whole period away).
    min_anchor_points: fewest agreeing rim votes that fix a group's order.
    min_anchor_agreement: share of a group's rim votes that must agree on one offset.
    """

    rim_width_mm: float = 15.0
    rim_circle_mm: tuple[float, float, float] | None = None
    anchor_tolerance_fraction: float = 0.3
    min_anchor_points: int = 20
    min_anchor_agreement: float = 0.8

    def __post_init__(self) -> None:
        if not self.rim_width_mm > 0:
            raise ValueError(f"rim_width_mm: expected > 0, got {self.rim_width_mm}")
        if self.rim_circle_mm is not None and (len(self.rim_circle_mm) != 3 or not self.rim_circle_mm[2] > 0):
            raise ValueError(f"rim_circle_mm: expected (x_mm, y_mm, radius_mm > 0) or None, got {self.rim_circle_mm}")
        if not 0 < self.anchor_tolerance_fraction < 0.5:
            raise ValueError(f"anchor_tolerance_fraction: expected 0 < f < 0.5, got {self.anchor_tolerance_fraction}")
        if self.min_anchor_points < 1:
            raise ValueError(f"min_anchor_points: expected ≥ 1, got {self.min_anchor_points}")
        if not 0.5 < self.min_anchor_agreement <= 1:
            raise ValueError(f"min_anchor_agreement: expected 0.5 < a ≤ 1, got {self.min_anchor_agreement}")


@dataclass(frozen=True, eq=False)
class OrderReference:
    """What anchors the order in every frame of a test.

    reference_t_px: (K, S) positions of the table's edges in the reference frame, NaN where not seen.
    rim: (K, S) bool, the (edge, line) points of the reference frame on the stationary rim band.
    rim_circle_mm: (X, Y, radius) of the clamp circle used; cell_area_mm2: (K, S) area of the plate each
        reference point stands for (edge spacing × line spacing at the reference Z), NaN where not seen.
    code_points, code_compared, code_agreement: where the reference frame's order came from a Gray code at rest
        (`CodedReference`): the points it identified, those the table's match identified too and the share of
        them that agree; 0, 0, NaN when the order came from the table's match alone.
    """

    reference_t_px: np.ndarray
    rim: np.ndarray
    rim_circle_mm: tuple[float, float, float]
    cell_area_mm2: np.ndarray
    code_points: int = 0
    code_compared: int = 0
    code_agreement: float = float("nan")

    @functools.cached_property
    def rim_t_px(self) -> np.ndarray:
        """(K, S) reference positions on the rim band only, NaN elsewhere."""
        return np.where(self.rim, self.reference_t_px, np.nan)

    @functools.cached_property
    def rim_lines(self) -> EdgeLines:
        """The rim positions line by line (`match_to_reference`)."""
        return EdgeLines.from_positions(self.rim_t_px)

    @functools.cached_property
    def seen(self) -> np.ndarray:
        """(K, S) bool, read-only: the reference points with a position and an area (`topography.frame_coverage`),
        the same for every frame of the test."""
        seen = np.isfinite(self.reference_t_px) & np.isfinite(self.cell_area_mm2)
        seen.flags.writeable = False
        return seen

    @functools.cached_property
    def seen_area_mm2(self) -> float:
        """The area (mm²) of the `seen` points, summed as `topography.frame_coverage` sums each frame's."""
        return float(np.sum(self.cell_area_mm2[self.seen]))

    @property
    def visible_area_mm2(self) -> float:
        """Area of the plate the reference frame sees."""
        return float(np.nansum(self.cell_area_mm2))


@dataclass(frozen=True, eq=False)
class FrameOrder:
    """The order of every edge point of one frame.

    k: (N,) int64 order (−1 where none); reason: (N,) int8, ORDERED or why not (ORDER_UNRESOLVED, ORDER_CONFLICT);
    n_conflicts: number of disagreements found (curves masked for disagreeing with their neighbours or the
    table, groups whose rim votes split, curves `order_edges` left out).
    """

    k: np.ndarray
    reason: np.ndarray
    n_conflicts: int


def identify_reference(edges: FrameEdges, projector: ProjectorCalibration, *, flat_tolerance_mm: float) -> np.ndarray:
    """Positions (K, S) of the projector's edges in the reference (flat) frame, NaN where not seen.

    Each edge point is matched to the nearest table edge of the same polarity at the reference Z on its line;
    an edge curve takes the index most of its points agree on (≥ 80 %, else it is left out). Raises
    ReferenceNotFlatError when the identified points do not lie at the reference Z, ReferenceFrameError when too
    few are identified.
    """
    k = _table_match(edges, projector)
    identified = k >= 0
    if np.count_nonzero(identified) < max(50, 0.3 * len(edges)):
        raise ReferenceFrameError(
            f"only {np.count_nonzero(identified)} of {len(edges)} edge points of the reference (first) test frame "
            "match the projector calibration's edges: the projector, the camera or the plate moved since the "
            "calibration"
        )
    z, status = projector.z_from_t(k[identified], edges.line[identified], edges.t_px[identified])
    offset = np.abs(z[status == 0] - projector.reference_z_mm)
    if len(offset) == 0 or np.percentile(offset, 90) > flat_tolerance_mm:
        p90 = float(np.percentile(offset, 90)) if len(offset) else float("nan")
        raise ReferenceNotFlatError(
            f"the reference (first) test frame is not the flat plate at Z = {projector.reference_z_mm:g} mm: 10 % of "
            f"its edge points are more than {p90:.1f} mm from it (tolerance {flat_tolerance_mm:g} mm); the fringe "
            "order is anchored on an undeformed reference frame, so start the recording before the punch touches"
        )
    return _positions_of(edges, k, projector)


def _table_match(edges: FrameEdges, projector: ProjectorCalibration) -> np.ndarray:
    """(N,) each edge point's order from the nearest table edge of its polarity at the reference Z, taken by its
    whole curve (`_chain_majority`); −1 where none."""
    k_near, distance = match_to_reference(
        edges.line, edges.t_px, edges.polarity, projector.reference_lines, projector.polarity
    )
    near = (k_near >= 0) & (np.abs(distance) <= 0.5 * projector.period_px)
    return _chain_majority(edges.chain, np.where(near, k_near, -1), projector.n_edges)


def _chain_majority(chain: np.ndarray, k_point: np.ndarray, n_edges: int, *, share: float = 0.8) -> np.ndarray:
    """(N,) the order k each edge curve takes: the one at least `share` of its points (k_point ≥ 0, −1: no vote)
    agree on; −1 for every point of a curve without such a majority."""
    n_chains = int(chain.max()) + 1 if len(chain) else 0
    if n_chains == 0:
        return np.full(len(chain), -1, np.int64)
    voted = k_point >= 0
    codes, counts = np.unique(chain[voted].astype(np.int64) * (n_edges + 1) + k_point[voted], return_counts=True)
    chain_of, k_of = codes // (n_edges + 1), codes % (n_edges + 1)
    best = np.zeros(n_chains, np.int64)
    best_k = np.full(n_chains, -1, np.int64)
    order = np.argsort(counts, kind="stable")  # ascending, so the largest count per chain is written last
    best[chain_of[order]] = counts[order]
    best_k[chain_of[order]] = k_of[order]
    length = np.bincount(chain, minlength=n_chains)
    chain_ok = best >= share * length
    return np.where(chain_ok[chain], best_k[chain], -1)


def _positions_of(edges: FrameEdges, k: np.ndarray, projector: ProjectorCalibration) -> np.ndarray:
    """(K, S) positions of the identified points (k ≥ 0), NaN where none or where two points claim one cell."""
    identified = k >= 0
    positions = np.full((projector.n_edges, projector.n_lines), np.nan)
    kk, ll = k[identified], edges.line[identified].astype(np.int64)
    flat = kk * projector.n_lines + ll
    counts = np.bincount(flat, minlength=positions.size)
    single = counts[flat] == 1
    positions.ravel()[flat[single]] = edges.t_px[identified][single]
    # Without a table entry a point can never give Z.
    positions[~projector.valid] = np.nan
    return positions


class ReferenceCodeError(ReferenceFrameError):
    """The Gray code recorded at rest cannot give the reference frame's order (no decoded pixels at its stripe
    edges, a code along the other projector axis, a table that does not know its projector edges), or it
    disagrees with the order the projector table's match gives."""


@dataclass(frozen=True, eq=False)
class CodedReference:
    """The reference frame's order from a Gray code recorded with the plate at rest (`identify_reference_from_code`).

    positions: (K, S) as `identify_reference` gives them. rest_z_mm: median Z of the plate at rest (from the table
    at the coded order). n_points: edge points the code identified (whole curves). n_compared / agreement: edge
    points the projector table's match at the reference Z (`identify_reference`'s route) identified too, and the
    share of them given the same order; 0 and NaN when the table's match finds no flat plate at its reference Z
    (the plate rests elsewhere).
    """

    positions: np.ndarray
    rest_z_mm: float
    n_points: int
    n_compared: int
    agreement: float


# A code whose two sides of an edge are further than this from it names no edge (px along the scan line, at most
# the decoder's undecided band beside a code edge plus the stripe edge's own blur).
CODE_SIDE_REACH_PX = 4
# Fewest points of the reference the code must identify (as `identify_reference` asks of the table's match), and
# the share of the points both routes identify that must agree.
MIN_CODE_AGREEMENT = 0.99


def identify_reference_from_code(
    edges: FrameEdges, decoding: Decoding, projector: ProjectorCalibration, *, flat_tolerance_mm: float
) -> CodedReference:
    """The reference frame's order from a Gray code recorded with the plate at rest (docs/procam.md §5).

    The stripe pattern's edges are code boundaries of the projector (`projector.pattern_edges`: the projector
    coordinate of each table edge). At each reference edge point, the first decoded pixels within
    CODE_SIDE_REACH_PX on either side along its scan line name the projector coordinate there: the boundary between
    their codes when they are neighbours, else the middle of their bands; the point votes for the table edge of
    its polarity nearest to it, within 0.4 of the edges' spacing. An edge curve takes the edge at least 80 %
    of its points vote for (`_chain_majority`). No table match at the reference Z is needed, so the plate may rest
    anywhere in the table's Z range; it must be flat (90 % of its points within flat_tolerance_mm of their median Z).
    Where the table's match (`identify_reference`'s route) finds the plate flat at the table's reference Z, it must
    give the same edges to ≥ 99 % of the points both name, else ReferenceCodeError naming both; where it does not
    (the plate rests elsewhere in the table's range), the code alone says.
    """
    pattern_edges = projector.pattern_edges
    if pattern_edges is None:
        raise ReferenceCodeError(
            "the projector table does not say which projector stripe each of its edges is (a Z-stack's table, or one "
            "written before tables recorded it): a Gray code at rest needs the table generated from the "
            "camera–projector calibration (`fringelab projector-table`)"
        )
    sequence = decoding.sequence
    if sequence.axis != pattern_edges.axis:
        raise ReferenceCodeError(
            f'the Gray code at rest runs along projector {sequence.axis} (patterns.json "axis") but the test\'s '
            f"stripes along projector {pattern_edges.axis}: record the code along {pattern_edges.axis}"
        )
    if tuple(decoding.code.shape) != tuple(projector.image_shape_hw_px):
        h, w = decoding.code.shape
        raise ReferenceCodeError(
            f"the Gray code at rest is {w} × {h} px but the test frames are {projector.image_shape_hw_px[1]} × "
            f"{projector.image_shape_hw_px[0]} px: record it with the test's camera"
        )
    x_px = _projector_coordinate_at_edges(edges, decoding, projector.axis)
    edge_x = np.asarray(pattern_edges.projector_px, np.float64)
    spacing = float(np.median(np.abs(np.diff(edge_x)))) if len(edge_x) > 1 else float("inf")
    finite = np.isfinite(x_px)
    k_vote = np.full(len(edges), -1, np.int64)
    if len(edge_x) and np.any(finite):
        ascending = np.argsort(edge_x)
        where = np.clip(np.searchsorted(edge_x[ascending], x_px[finite]), 1, max(len(edge_x) - 1, 1))
        lower, upper = ascending[where - 1], ascending[np.minimum(where, len(edge_x) - 1)]
        nearest = np.where(np.abs(edge_x[lower] - x_px[finite]) <= np.abs(edge_x[upper] - x_px[finite]), lower, upper)
        close = np.abs(edge_x[nearest] - x_px[finite]) <= 0.4 * spacing
        same_polarity = projector.polarity[nearest] == edges.polarity[finite]
        k_vote[finite] = np.where(close & same_polarity, nearest, -1)
    k = _chain_majority(edges.chain, k_vote, projector.n_edges)
    identified = k >= 0
    if np.count_nonzero(identified) < max(50, 0.3 * len(edges)):
        raise ReferenceCodeError(
            f"the Gray code at rest names only {np.count_nonzero(identified)} of the reference frame's "
            f"{len(edges)} stripe-edge points ({np.count_nonzero(finite)} had decoded pixels on both sides): check "
            "that it was recorded with the plate at rest, by the test's camera, and that its patterns.json "
            '("band_px", "projector_size_px", the frames) describes what the projector showed'
        )
    z, status = projector.z_from_t(k[identified], edges.line[identified], edges.t_px[identified])
    z_ok = z[status == 0]
    if len(z_ok) == 0:
        raise ReferenceCodeError(
            "the stripe edges the Gray code names lie outside the projector table's Z range everywhere: the plate "
            "rests outside the range the table was made for, or the code, the table and the test are not of one "
            "set-up (the projector's pattern or the camera moved)"
        )
    rest_z = float(np.median(z_ok))
    p90 = float(np.percentile(np.abs(z_ok - rest_z), 90))
    if p90 > flat_tolerance_mm:
        raise ReferenceNotFlatError(
            f"the plate at rest is not flat: 10 % of the reference frame's edge points are more than {p90:.1f} mm "
            f"from their median Z = {rest_z:.1f} mm (tolerance {flat_tolerance_mm:g} mm); the fringe order is "
            "anchored on an undeformed reference frame, so start the recording before the punch touches"
        )
    # The table's match takes the edge nearest where the table has it at its reference Z; where it finds a flat plate
    # there (its own check), it is an answer of its own, and the two must agree.
    n_compared, agreement = 0, float("nan")
    k_table = _table_match(edges, projector)
    both = identified & (k_table >= 0)
    if np.count_nonzero(both) >= max(50, 0.3 * len(edges)):
        z_table, status_table = projector.z_from_t(k_table[both], edges.line[both], edges.t_px[both])
        off = np.abs(z_table[status_table == 0] - projector.reference_z_mm)
        if len(off) and np.percentile(off, 90) <= flat_tolerance_mm:
            n_compared = int(np.count_nonzero(both))
            agreement = float(np.mean(k_table[both] == k[both]))
    if agreement < MIN_CODE_AGREEMENT:
        shift = int(np.median(k_table[both] - k[both]))
        raise ReferenceCodeError(
            "the Gray code at rest and the projector table disagree on the reference frame's stripe order: "
            f"{1 - agreement:.1%} of the {n_compared} edge points both name are given different edges (typically "
            f"{shift:+d}, {abs(shift) / 2:g} stripe periods); the code puts the plate at rest at Z = {rest_z:.1f} mm, "
            f"the table's match at its reference Z = {projector.reference_z_mm:g} mm. Either the plate rests a whole "
            "stripe step from the table's reference Z (make the table with reference_z_mm where the plate rests), or "
            "the code, the table and the test are not of one set-up (the projector's pattern or the camera moved)"
        )
    return CodedReference(
        positions=_positions_of(edges, k, projector), rest_z_mm=rest_z, n_points=int(np.count_nonzero(identified)),
        n_compared=n_compared, agreement=agreement,
    )  # fmt: skip


def _projector_coordinate_at_edges(edges: FrameEdges, decoding: Decoding, axis: str) -> np.ndarray:
    """(N,) projector coordinate along the code's axis at each edge point from the decoded pixels either side
    (`identify_reference_from_code`), NaN where either side has none within CODE_SIDE_REACH_PX."""
    code = decoding.code if axis == "rows" else decoding.code.T  # (S, T): scan lines × positions along them
    n_samples = code.shape[1]
    line = edges.line.astype(np.int64)
    t = edges.t_px.astype(np.float64)
    sides = []
    for start, step in ((np.floor(t).astype(np.int64), -1), (np.floor(t).astype(np.int64) + 1, 1)):
        found = np.full(len(t), -1, np.int64)
        for d in range(CODE_SIDE_REACH_PX):
            at = start + step * d
            inside = (at >= 0) & (at < n_samples) & (found < 0)
            value = np.full(len(t), -1, np.int64)
            value[inside] = code[line[inside], at[inside]]
            found = np.where(inside & (value >= 0), value, found)
        sides.append(found)
    left, right = sides
    sequence = decoding.sequence
    both = (left >= 0) & (right >= 0)
    neighbours = both & (np.abs(right - left) == 1)
    x = np.full(len(t), np.nan)
    x[neighbours] = sequence.boundary_px(np.maximum(left, right)[neighbours])
    apart = both & ~neighbours
    x[apart] = 0.5 * (sequence.band_centre_px(left[apart]) + sequence.band_centre_px(right[apart]))
    return x


def order_reference(
    positions: np.ndarray,
    projector: ProjectorCalibration,
    camera_model: CameraModel,
    *,
    settings: OrderSettings | None = None,
    rest_z_mm: float | None = None,
) -> OrderReference:
    """The anchor of a test from its identified reference frame (`identify_reference` or
    `identify_reference_from_code`), shape (K, S). rest_z_mm: the plate's Z at rest (the points are back-projected
    there to find the rim); None: the table's reference Z.

    Raises RimNotVisibleError when no clamp circle is given and the reference frame's points do not end at a
    clamp ring inside the image (they run into the image border instead).
    """
    settings = OrderSettings() if settings is None else settings
    kk, ss = np.nonzero(np.isfinite(positions))
    t = positions[kk, ss]
    q_px = np.column_stack([t, ss] if projector.axis == "rows" else [ss, t]).astype(np.float64)
    z_rest = projector.reference_z_mm if rest_z_mm is None else float(rest_z_mm)
    xy = backproject_to_z(camera_model.camera, q_px, z_rest, inverse=camera_model.inverse)[:, :2]
    if settings.rim_circle_mm is not None:
        cx, cy, radius = (float(v) for v in settings.rim_circle_mm)
    else:
        _require_rim_in_view(t, ss, projector)
        cx, cy, radius = clamp_circle(xy)
        if not np.isfinite(radius):
            raise RimNotVisibleError(
                "the clamped rim of the plate could not be found in the reference frame (too few points): set "
                "rim_circle_mm (X, Y, radius of the clamp in mm) in the topography settings to anchor the order"
            )
    r = np.hypot(xy[:, 0] - cx, xy[:, 1] - cy)
    rim = np.zeros(positions.shape, bool)
    rim[kk, ss] = (r > radius - settings.rim_width_mm) & (r <= radius + 1.0)
    if np.count_nonzero(rim) < 10 * settings.min_anchor_points:
        raise RimNotVisibleError(
            f"only {np.count_nonzero(rim)} edge points of the reference frame lie on the rim band "
            f"({settings.rim_width_mm:g} mm inside the clamp circle of radius {radius:.0f} mm): the order cannot be "
            "anchored; set rim_circle_mm (X, Y, radius of the clamp in mm) or widen rim_width_mm"
        )
    area = np.full(positions.shape, np.nan)
    area[kk, ss] = _cell_area_mm2(positions, kk, ss, xy, projector, camera_model, z_rest)
    return OrderReference(reference_t_px=positions, rim=rim, rim_circle_mm=(cx, cy, radius), cell_area_mm2=area)


def _require_rim_in_view(t: np.ndarray, line: np.ndarray, projector: ProjectorCalibration) -> None:
    """RimNotVisibleError when the reference points reach the image border on most lines (no clamp in view)."""
    if len(t) == 0:
        raise RimNotVisibleError("the reference frame has no identified edge points")
    margin = projector.period_px
    n_samples = projector.image_shape_hw_px[1] if projector.axis == "rows" else projector.image_shape_hw_px[0]
    lowest = np.full(projector.n_lines, np.inf)
    highest = np.full(projector.n_lines, -np.inf)
    np.minimum.at(lowest, line, t)
    np.maximum.at(highest, line, t)
    seen = np.isfinite(lowest)
    at_border = seen & ((lowest < margin) | (highest > n_samples - 1 - margin))
    if np.count_nonzero(at_border) > 0.5 * np.count_nonzero(seen):
        raise RimNotVisibleError(
            f"the plate runs into the image border on {np.count_nonzero(at_border)} of {np.count_nonzero(seen)} scan "
            "lines of the reference frame, so the clamped rim (w = 0) that anchors the fringe order is not in view: "
            "frame the camera to show the clamp ring, or set rim_circle_mm (X, Y, radius in mm of a region that "
            "stays still) in the topography settings"
        )


def _cell_area_mm2(
    positions: np.ndarray,
    kk: np.ndarray,
    ss: np.ndarray,
    xy: np.ndarray,
    projector: ProjectorCalibration,
    camera_model: CameraModel,
    z_mm: float,
) -> np.ndarray:
    """Plate area (mm²) each reference point stands for: half the distance to its neighbours along the line on
    each side, times the line spacing, both at the plate's rest height z_mm (one period's worth at the ends of a
    run)."""
    t = positions[kk, ss]
    n_k = positions.shape[0]
    before = positions[np.maximum(kk - 1, 0), ss]
    after = positions[np.minimum(kk + 1, n_k - 1), ss]
    half = 0.5 * projector.period_px
    gap_before = np.where(np.isfinite(before) & (kk > 0), t - before, half)
    gap_after = np.where(np.isfinite(after) & (kk < n_k - 1), after - t, half)
    along_px = np.clip(0.5 * (np.abs(gap_before) + np.abs(gap_after)), 0.0, projector.period_px)
    # mm per px along the line and across it, from back-projecting the neighbouring pixel.
    step = np.array([1.0, 0.0]) if projector.axis == "rows" else np.array([0.0, 1.0])
    q_px = np.column_stack([t, ss] if projector.axis == "rows" else [ss, t]).astype(np.float64)
    along = backproject_to_z(camera_model.camera, q_px + step, z_mm, inverse=camera_model.inverse)
    across = backproject_to_z(camera_model.camera, q_px + step[::-1], z_mm, inverse=camera_model.inverse)
    mm_along = np.hypot(along[:, 0] - xy[:, 0], along[:, 1] - xy[:, 1])
    mm_across = np.hypot(across[:, 0] - xy[:, 0], across[:, 1] - xy[:, 1])
    return along_px * mm_along * mm_across


def order_frame(
    edges: FrameEdges,
    reference: OrderReference,
    projector: ProjectorCalibration,
    *,
    settings: OrderSettings | None = None,
) -> FrameOrder:
    """The order k of every edge point of one frame, or the reason it has none (see the module docstring)."""
    settings = OrderSettings() if settings is None else settings
    n = len(edges)
    k = np.full(n, -1, np.int64)
    reason = np.full(n, ORDER_UNRESOLVED, np.int8)
    if n == 0:
        return FrameOrder(k=k, reason=reason, n_conflicts=0)
    order = order_edges(edges)
    relative = order.crossing_index(edges)
    component = order.crossing_component(edges)
    reason[relative < 0] = ORDER_CONFLICT
    n_conflicts = int(np.count_nonzero(order.part_index < 0))
    # Rim votes: the nearest reference edge of the same polarity on the stationary band, if close. (Edges of one
    # polarity are a period apart, so a point within a third of a period of a rim edge has no nearer one.)
    k_near, distance = match_to_reference(
        edges.line, edges.t_px, edges.polarity, reference.rim_lines, projector.polarity
    )
    # Edges beside a dark area are no anchor either: they are cut off from their curves and neighbours
    # (`order_edges`), so a stretch of them would be anchored by its own rim votes alone, and their places are
    # not sure enough for that (their mid-level is set from one side: beside the clamp ring 1.8 mm off in w under
    # a soft shadow, docs/method.md §5). They stay "order unresolved".
    n_groups = int(order.part_component.max()) + 1 if np.any(order.part_component >= 0) else 0
    if n_groups:
        anchored, split, best_offset = _rim_anchors(
            k_near, distance, relative, component, beside_dark_points(edges),
            settings.anchor_tolerance_fraction * projector.period_px, n_groups, settings.min_anchor_points,
            settings.min_anchor_agreement,
        )  # fmt: skip
        # A group whose rim votes split (a miscount somewhere in it) is a conflict, not a guess.
        n_conflicts += int(np.count_nonzero(split))
        bad = _anchored_order(
            relative, component, anchored, split, best_offset, np.ascontiguousarray(projector.polarity, np.int8),
            np.ascontiguousarray(edges.polarity, np.int8), k, reason,
        )  # fmt: skip
    else:
        bad = np.zeros(n, bool)
    if np.any(bad):
        bad_chains = np.unique(edges.chain[bad])
        n_conflicts += len(bad_chains)
        drop = np.isin(edges.chain, bad_chains)
        k[drop] = -1
        reason[drop] = ORDER_CONFLICT
    masked_chains = _inconsistent_chains(edges, k, projector)
    if len(masked_chains):
        n_conflicts += len(masked_chains)
        drop = np.isin(edges.chain, masked_chains)
        k[drop] = -1
        reason[drop] = ORDER_CONFLICT
    return FrameOrder(k=k, reason=reason, n_conflicts=n_conflicts)


@numba.njit(cache=True, nogil=True)
def _rim_anchors(
    k_near: np.ndarray,
    distance: np.ndarray,
    relative: np.ndarray,
    component: np.ndarray,
    beside_dark: np.ndarray,
    max_distance_px: float,
    n_groups: int,
    min_anchor_points: int,
    min_anchor_agreement: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`order_frame`'s rim votes (N,) counted by group (n_groups,): a point votes when it is near a rim edge
    (k_near ≥ 0, |distance| ≤ max_distance_px), has a relative order and is not beside a dark area, for the offset
    k_near − relative of its group (component). Per group: anchored (the most common offset has at least
    min_anchor_points votes and min_anchor_agreement of them), split (as many votes, not anchored) and that offset
    (the larger of those tied). Votes sorted by group in a counting pass, then each group's offsets sorted."""
    n = len(relative)
    start = np.zeros(n_groups + 1, np.int64)
    for i in range(n):
        if k_near[i] >= 0 and abs(distance[i]) <= max_distance_px and relative[i] >= 0 and not beside_dark[i]:
            start[component[i] + 1] += 1
    for g in range(n_groups):
        start[g + 1] += start[g]
    offsets = np.empty(start[n_groups], np.int64)
    filled = start[:-1].copy()
    for i in range(n):
        if k_near[i] >= 0 and abs(distance[i]) <= max_distance_px and relative[i] >= 0 and not beside_dark[i]:
            offsets[filled[component[i]]] = k_near[i] - relative[i]
            filled[component[i]] += 1
    anchored = np.zeros(n_groups, np.bool_)
    split = np.zeros(n_groups, np.bool_)
    best_offset = np.zeros(n_groups, np.int64)
    for g in range(n_groups):
        votes = np.sort(offsets[start[g] : start[g + 1]])
        best = 0
        run = 0
        for j in range(len(votes)):
            run = run + 1 if j > 0 and votes[j] == votes[j - 1] else 1
            # At the end of each run; ties go to the larger offset, as the stable order of the counts left them.
            if (j + 1 == len(votes) or votes[j + 1] != votes[j]) and run >= best:
                best, best_offset[g] = run, votes[j]
        total = float(len(votes))
        anchored[g] = best >= min_anchor_points and best >= min_anchor_agreement * total
        split[g] = total >= min_anchor_points and not anchored[g]
    return anchored, split, best_offset


@numba.njit(cache=True, nogil=True)
def _anchored_order(
    relative: np.ndarray,
    component: np.ndarray,
    anchored: np.ndarray,
    split: np.ndarray,
    best_offset: np.ndarray,
    table_polarity: np.ndarray,
    polarity: np.ndarray,
    k: np.ndarray,
    reason: np.ndarray,
) -> np.ndarray:
    """`order_frame`'s order of the points (N,) of anchored groups, written into k and reason (ORDERED; the
    points of groups whose rim votes split ORDER_CONFLICT), in one pass: the points (N,) whose order lies outside
    the table or has the wrong polarity (a miscount)."""
    n_edges = len(table_polarity)
    bad = np.zeros(len(relative), np.bool_)
    for i in range(len(relative)):
        if relative[i] < 0:
            continue
        group = component[i]
        if anchored[group]:
            order = relative[i] + best_offset[group]
            k[i] = order
            reason[i] = ORDERED
            bad[i] = order < 0 or order >= n_edges or table_polarity[order] != polarity[i]
        elif split[group]:
            reason[i] = ORDER_CONFLICT
    return bad


def _inconsistent_chains(edges: FrameEdges, k: np.ndarray, projector: ProjectorCalibration) -> np.ndarray:
    """Curves that disagree with the table or their neighbours (labels, sorted).

    Table: a curve most of whose points lie outside the table's bounds for their order while both neighbouring
    orders would put them inside disagrees with the table (a curve genuinely beyond the calibrated Z range lies
    outside for its neighbours' orders too, on one side). Neighbours: consecutive ordered points on a scan line
    of orders k and k + 1 lie less than half a stripe's Z step apart on a smooth surface; each pair votes for or
    against both its curves, and a curve with more votes against than for is masked.
    """
    if not np.any(k >= 0):
        return np.zeros(0, np.int64)
    against = _against_table_or_neighbours(
        np.ascontiguousarray(edges.chain), np.ascontiguousarray(edges.line), np.ascontiguousarray(edges.t_px),
        np.ascontiguousarray(k, np.int64), projector.lookup_table, float(projector.period_px),
        int(edges.chain.max()) + 1,
    )  # fmt: skip
    return np.flatnonzero(against)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _against_table_or_neighbours(
    chain: np.ndarray,
    line: np.ndarray,
    t: np.ndarray,
    k: np.ndarray,
    table: np.ndarray,
    period_px: float,
    n_chains: int,
) -> np.ndarray:
    # One pass: each ordered point's Z is looked up once and voted with the ordered point before it on its line
    # (ordered points follow each other along a line in (line, t) order); t is widened to float64 as it is read.
    length = np.zeros(n_chains)
    table_against = np.zeros(n_chains)
    votes_for = np.zeros(n_chains)
    votes_against = np.zeros(n_chains)
    previous = -1
    z_p, status_p = np.nan, 2
    for i in range(len(t)):
        if k[i] < 0:
            continue
        t_i = np.float64(t[i])
        z_i, status_i = table_z_at(table, k[i], line[i], t_i)
        length[chain[i]] += 1.0
        if status_i == 1:
            for step in (-2, 2):
                if table_z_at(table, k[i] + step, line[i], t_i)[1] == 0:
                    table_against[chain[i]] += 1.0
                    break
        p = previous
        z_prev, status_prev = z_p, status_p
        previous, z_p, status_p = i, z_i, status_i
        if p < 0 or line[p] != line[i] or abs(k[i] - k[p]) != 1 or status_prev != 0 or status_i != 0:
            continue
        if chain[p] == chain[i]:
            continue
        step_mm = period_px / max(abs(table[line[p], k[p], TABLE_SENSITIVITY]), 1e-6)
        if abs(z_i - z_prev) < 0.5 * step_mm:
            votes_for[chain[p]] += 1.0
            votes_for[chain[i]] += 1.0
        else:
            votes_against[chain[p]] += 1.0
            votes_against[chain[i]] += 1.0
    against = np.empty(n_chains, np.bool_)
    for c in range(n_chains):
        against[c] = table_against[c] > 0.5 * max(length[c], 1.0) or votes_against[c] > votes_for[c]
    return against


def check_order_against_table(
    edges: FrameEdges,
    reference: OrderReference,
    projector: ProjectorCalibration,
    *,
    settings: OrderSettings | None = None,
    max_step_fraction: float = 0.35,
) -> None:
    """Raise OrderAgainstTableError when most of a frame's rim-anchored stripes lie below the table's lowest Z.

    Meant for a frame `order_frame` masked mostly as conflicts: its stripes, counted from the stationary rim,
    moved the way the table calls "below the lowest calibrated Z", while the order one stripe over (k ± 2, same
    polarity) would put them inside. That is the mark of a projector calibration whose Z steps moved the stripes
    more than half a period each: edge identity is carried between steps by the nearest edge of the same
    polarity, so a shift of (1 − a) periods reads as a shift of a periods the other way, the same for every
    edge. `projector.build_projector_calibration` refuses such a stack now; tables built before it did are caught
    here, by a frame of the test whose plate moved by less than a step. A plate that moved below the calibrated
    range looks the same, so the message names both.
    max_step_fraction: the calibration's largest safe shift per step in periods (`ProjectorSettings`), for the
    Z step the message asks for.
    """
    settings = OrderSettings() if settings is None else settings
    if len(edges) == 0:
        return
    order = order_edges(edges)
    relative = order.crossing_index(edges)
    component = order.crossing_component(edges)
    k_near, distance = match_to_reference(
        edges.line, edges.t_px, edges.polarity, reference.rim_lines, projector.polarity
    )
    on_rim = (k_near >= 0) & (np.abs(distance) <= settings.anchor_tolerance_fraction * projector.period_px)
    on_rim &= (relative >= 0) & ~beside_dark_points(edges)
    if np.count_nonzero(on_rim) < settings.min_anchor_points:
        return
    # The offset most rim votes of each group agree on (as `order_frame` anchors it, without the checks).
    votes = k_near[on_rim] - relative[on_rim]
    lowest = int(votes.min())
    span = int(votes.max()) - lowest + 1
    codes, counts = np.unique(component[on_rim] * span + (votes - lowest), return_counts=True)
    n_groups = int(order.part_component.max()) + 1
    best_count = np.zeros(n_groups, np.int64)
    best_offset = np.zeros(n_groups, np.int64)
    ascending = np.argsort(counts, kind="stable")
    best_count[codes[ascending] // span] = counts[ascending]
    best_offset[codes[ascending] // span] = codes[ascending] % span + lowest
    anchored = relative >= 0
    anchored[anchored] = best_count[component[anchored]] >= settings.min_anchor_points
    k = relative[anchored] + best_offset[component[anchored]]
    line, t = edges.line[anchored], edges.t_px[anchored]
    in_table = (k >= 0) & (k < projector.n_edges)
    k, line, t = k[in_table], line[in_table], t[in_table]
    _z, status = projector.z_from_t(k, line, t)
    has_entry = status != 2
    if np.count_nonzero(has_entry) < settings.min_anchor_points:
        return
    sensitivity = projector.sensitivity_px_per_mm[k, line]
    with np.errstate(invalid="ignore"):
        below = (status == 1) & np.where(
            sensitivity > 0, t < projector.t_lo_px[k, line], t > projector.t_hi_px[k, line]
        )
    neighbour_fits = np.zeros(len(k), bool)
    for step in (-2, 2):
        neighbour_fits |= projector.z_from_t(k + step, line, t)[1] == 0
    share = np.count_nonzero(below & neighbour_fits) / np.count_nonzero(has_entry)
    if share < 0.5:
        return
    z_lowest = float(projector.z_mm[0])
    dz_mm = float(np.median(np.diff(projector.z_mm)))
    abs_sensitivity = np.abs(projector.sensitivity_px_per_mm[projector.valid])
    shift = float(np.median(abs_sensitivity)) * dz_mm / projector.period_px
    # Were the table aliased by one period per step, an edge's true rate would be period/dz − |apparent rate|,
    # largest where the apparent rate is smallest.
    true_rate = projector.period_px / dz_mm - float(np.percentile(abs_sensitivity, 5))
    safe_step_mm = max_step_fraction * projector.period_px / true_rate if true_rate > 0 else float("nan")
    raise OrderAgainstTableError(
        f"{share:.0%} of the frame's stripes, ordered from the clamped rim, lie below the lowest calibrated Z "
        f"({z_lowest:g} mm) for their order while the next stripe's order would put them inside the projector "
        "table: the stripes moved against the direction in which the table says Z grows. Most likely the projector "
        f"calibration's Z steps ({dz_mm:g} mm) were too coarse: its edges move {shift:.2f} stripe periods per step "
        f"in the table, which reads the same as {1 - shift:.2f} periods the other way (edges are followed from "
        "step to step by the nearest edge of the same polarity, so a shift of more than half a period is taken "
        "for the neighbouring edge moving back); record the projector calibration again with Z steps of at most "
        f"{safe_step_mm:.1f} mm (each step must move the stripes less than {max_step_fraction:g} period). "
        f"Otherwise the plate moved below Z = {z_lowest:g} mm, outside the calibrated range: calibrate that side "
        "too."
    )


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
