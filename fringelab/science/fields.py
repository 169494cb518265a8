"""Deflection fields from measured edge points: the regular grid, peak and centre, profiles, time histories.

Belongs here: pure array functions on the 3-D points of one frame (gridding by linear interpolation on the
triangles that the edge structure itself defines, so holes are never bridged), on a gridded field (peak,
centre, section profiles along any line, radial profiles) and on a stack of fields (point time histories).
Not here: how the points are measured (`topography.py`) or stored (`fringelab.formats.topography.py`).

Grids: `x_mm` (nx,), `y_mm` (ny,) node coordinates in the object frame; fields are (ny, nx) arrays indexed
[iy, ix], NaN where there is no data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .arrays import checked_array


@dataclass(frozen=True, eq=False)
class Grid:
    """A regular grid in the object frame: node coordinates x_mm (nx,), y_mm (ny,)."""

    x_mm: np.ndarray
    y_mm: np.ndarray

    @property
    def step_mm(self) -> float:
        return float(self.x_mm[1] - self.x_mm[0]) if len(self.x_mm) > 1 else float("nan")

    @property
    def shape(self) -> tuple[int, int]:
        return (len(self.y_mm), len(self.x_mm))


def grid_covering(points_xy_mm: np.ndarray, *, step_mm: float, margin_mm: float) -> Grid:
    """The grid of spacing step_mm, with nodes on multiples of it, covering points (N, 2) plus a margin."""
    xy = checked_array(points_xy_mm, shape=(None, 2), name="points_xy_mm")
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if not step_mm > 0:
        raise ValueError(f"step_mm: expected > 0, got {step_mm}")
    if len(xy) == 0:
        raise ValueError("points_xy_mm: no finite point to cover")
    lo = np.floor((xy.min(axis=0) - margin_mm) / step_mm) * step_mm
    hi = np.ceil((xy.max(axis=0) + margin_mm) / step_mm) * step_mm
    nx = int(round((hi[0] - lo[0]) / step_mm)) + 1
    ny = int(round((hi[1] - lo[1]) / step_mm)) + 1
    return Grid(x_mm=lo[0] + step_mm * np.arange(nx), y_mm=lo[1] + step_mm * np.arange(ny))


def edge_mesh_triangles(x_mm: np.ndarray, y_mm: np.ndarray, *, max_edge_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of the mesh that the edge points span, from their (edge k, line s) structure.

    x_mm, y_mm: (K, S) object coordinates of edge k on scan line s (NaN where not measured). Each cell between
    edges k, k+1 and lines s, s+1 gives two triangles; a triangle is kept when its three corners were measured
    and its sides are at most max_edge_mm long. Neighbouring edges and lines are neighbours on the plate, so the
    mesh follows the data and never spans a hole, a crack or the area outside the plate.

    Returns the corner indices into the flattened (K·S) arrays, shape (T, 3), and a mask (T,) of the kept ones.
    """
    n_k, n_s = x_mm.shape
    k, s = np.meshgrid(np.arange(n_k - 1), np.arange(n_s - 1), indexing="ij")
    a = (k * n_s + s).ravel()
    b = a + n_s  # (k+1, s)
    c = a + n_s + 1  # (k+1, s+1)
    d = a + 1  # (k, s+1)
    triangles = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    x, y = x_mm.ravel(), y_mm.ravel()
    corner_x, corner_y = x[triangles], y[triangles]
    side = np.hypot(corner_x - np.roll(corner_x, -1, axis=1), corner_y - np.roll(corner_y, -1, axis=1))
    with np.errstate(invalid="ignore"):
        keep = np.all(side <= max_edge_mm, axis=1)
    return triangles, keep


def rasterize_triangles(
    corner_xy_mm: np.ndarray, corner_values: np.ndarray, grid: Grid, *, out: np.ndarray | None = None
) -> np.ndarray:
    """Linear interpolation of values given at triangle corners onto the grid nodes inside the triangles.

    corner_xy_mm: (T, 3, 2); corner_values: (T, 3). Returns (ny, nx), NaN at nodes inside no triangle. Each
    triangle visits only the nodes of its bounding box, so the cost is that of the triangles plus the nodes.
    """
    field = np.full(grid.shape, np.nan) if out is None else out
    if len(corner_xy_mm) == 0:
        return field
    step = grid.step_mm
    gx = (corner_xy_mm[..., 0] - grid.x_mm[0]) / step
    gy = (corner_xy_mm[..., 1] - grid.y_mm[0]) / step
    ix_lo = np.maximum(np.ceil(gx.min(axis=1)), 0).astype(np.int64)
    ix_hi = np.minimum(np.floor(gx.max(axis=1)), len(grid.x_mm) - 1).astype(np.int64)
    iy_lo = np.maximum(np.ceil(gy.min(axis=1)), 0).astype(np.int64)
    iy_hi = np.minimum(np.floor(gy.max(axis=1)), len(grid.y_mm) - 1).astype(np.int64)
    width = np.maximum(ix_hi - ix_lo + 1, 0)
    count = width * np.maximum(iy_hi - iy_lo + 1, 0)
    has = np.flatnonzero(count > 0)
    if len(has) == 0:
        return field
    count_h = count[has]
    tri = np.repeat(has, count_h)
    local = np.arange(int(count_h.sum())) - np.repeat(np.cumsum(count_h) - count_h, count_h)
    ix = ix_lo[tri] + local % width[tri]
    iy = iy_lo[tri] + local // width[tri]
    # Barycentric coordinates in grid units.
    x0, y0 = gx[tri, 0], gy[tri, 0]
    e1x, e1y = gx[tri, 1] - x0, gy[tri, 1] - y0
    e2x, e2y = gx[tri, 2] - x0, gy[tri, 2] - y0
    det = e1x * e2y - e1y * e2x
    px, py = ix - x0, iy - y0
    with np.errstate(divide="ignore", invalid="ignore"):
        l1 = (px * e2y - py * e2x) / det
        l2 = (e1x * py - e1y * px) / det
    eps = 1e-9
    inside = (l1 >= -eps) & (l2 >= -eps) & (l1 + l2 <= 1.0 + eps) & (det != 0)
    values = corner_values[tri]
    interpolated = values[:, 0] + l1 * (values[:, 1] - values[:, 0]) + l2 * (values[:, 2] - values[:, 0])
    # A node on the side two triangles share is inside both: it takes the later triangle's value. Said here, since
    # numpy leaves unspecified which of repeated indices an assignment keeps (a node with one triangle's value in
    # one run and the other's in the next: a NaN or not, where one of them has a corner without data).
    node = iy[inside] * len(grid.x_mm) + ix[inside]
    _, last_reversed = np.unique(node[::-1], return_index=True)
    last = len(node) - 1 - last_reversed
    field[iy[inside][last], ix[inside][last]] = interpolated[inside][last]
    return field


def grid_edge_points(
    x_mm: np.ndarray, y_mm: np.ndarray, z_mm: np.ndarray, grid: Grid, *, max_edge_mm: float
) -> np.ndarray:
    """The gridded field (ny, nx) of edge points given as (K, S) arrays (edge k, scan line s), NaN = missing.

    Linear on the triangles of `edge_mesh_triangles`; nodes outside every triangle are NaN, so the field is
    interpolated only within the data and never across holes. The rule in numpy; frames are gridded by its
    compiled twin, `gridding.grid_edge_fields`, which gives the same numbers to the bit.
    """
    triangles, keep = edge_mesh_triangles(x_mm, y_mm, max_edge_mm=max_edge_mm)
    triangles = triangles[keep]
    corner_xy = np.stack([x_mm.ravel()[triangles], y_mm.ravel()[triangles]], axis=-1)
    return rasterize_triangles(corner_xy, z_mm.ravel()[triangles], grid)


def typical_edge_gap_mm(x_mm: np.ndarray, y_mm: np.ndarray) -> float:
    """Median distance between neighbouring edges (k, k+1) on a line, mm: the scale of the data."""
    gaps = np.hypot(np.diff(x_mm, axis=0), np.diff(y_mm, axis=0))
    finite = gaps[np.isfinite(gaps)]
    return float(np.median(finite)) if len(finite) else float("nan")


@dataclass(frozen=True)
class Peak:
    """Largest deflection of a field and where it is; centre: the centroid of the area above half of it."""

    w_mm: float
    x_mm: float
    y_mm: float
    centre_x_mm: float
    centre_y_mm: float


def field_peak(w_mm: np.ndarray, grid: Grid, *, min_peak_mm: float = 1.0) -> Peak:
    """Peak of a deflection field (ny, nx) and the centroid of the region where w ≥ half the peak.

    The centroid locates the punch axis once the plate has deflected (it averages over the whole dome, so it is
    steadier than the position of the single highest node); below min_peak_mm it is NaN.
    """
    if not np.any(np.isfinite(w_mm)):
        nan = float("nan")
        return Peak(nan, nan, nan, nan, nan)
    iy, ix = np.unravel_index(int(np.nanargmax(w_mm)), w_mm.shape)
    peak = float(w_mm[iy, ix])
    centre_x = centre_y = float("nan")
    if peak >= min_peak_mm:
        with np.errstate(invalid="ignore"):
            weight = np.where(w_mm >= 0.5 * peak, w_mm - 0.5 * peak, 0.0)
        weight = np.nan_to_num(weight)
        total = weight.sum()
        centre_x = float((weight.sum(axis=0) * grid.x_mm).sum() / total)
        centre_y = float((weight.sum(axis=1) * grid.y_mm).sum() / total)
    return Peak(peak, float(grid.x_mm[ix]), float(grid.y_mm[iy]), centre_x, centre_y)


def sample_field(field: np.ndarray, grid: Grid, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of fields at points; NaN where any of the four surrounding nodes is NaN or outside.

    field: (..., ny, nx) (a stack of frames is sampled at once); x_mm, y_mm: (M,). Returns (..., M).
    """
    x = np.asarray(x_mm, np.float64)
    y = np.asarray(y_mm, np.float64)
    step = grid.step_mm
    fx = (x - grid.x_mm[0]) / step
    fy = (y - grid.y_mm[0]) / step
    ix = np.floor(fx).astype(np.int64)
    iy = np.floor(fy).astype(np.int64)
    nx, ny = len(grid.x_mm), len(grid.y_mm)
    # A point exactly on the last node belongs to the last cell.
    ix = np.where(ix == nx - 1, nx - 2, ix)
    iy = np.where(iy == ny - 1, ny - 2, iy)
    inside = (ix >= 0) & (ix < nx - 1) & (iy >= 0) & (iy < ny - 1) & np.isfinite(fx) & np.isfinite(fy)
    ixc, iyc = np.where(inside, ix, 0), np.where(inside, iy, 0)
    ax, ay = fx - ixc, fy - iyc
    f00 = field[..., iyc, ixc]
    f01 = field[..., iyc, ixc + 1]
    f10 = field[..., iyc + 1, ixc]
    f11 = field[..., iyc + 1, ixc + 1]
    value = (f00 * (1 - ax) + f01 * ax) * (1 - ay) + (f10 * (1 - ax) + f11 * ax) * ay
    return np.where(inside, value, np.nan)


@dataclass(frozen=True, eq=False)
class Profile:
    """A section profile: distance along the line s_mm (M,), the points x_mm, y_mm (M,), values (..., M)."""

    s_mm: np.ndarray
    x_mm: np.ndarray
    y_mm: np.ndarray
    values: np.ndarray


def line_profile(
    field: np.ndarray, grid: Grid, start_xy_mm: tuple[float, float], end_xy_mm: tuple[float, float], *,
    step_mm: float | None = None,
) -> Profile:  # fmt: skip
    """Values of a field (or a stack (..., ny, nx)) along the straight line from start to end, every step_mm
    (default: half the grid step); NaN where the field has no data."""
    start = np.asarray(start_xy_mm, np.float64)
    end = np.asarray(end_xy_mm, np.float64)
    length = float(np.hypot(*(end - start)))
    if not length > 0:
        raise ValueError(f"line: start and end must differ, got {tuple(start)} and {tuple(end)}")
    step = 0.5 * grid.step_mm if step_mm is None else step_mm
    s = np.linspace(0.0, length, int(np.floor(length / step)) + 1)
    x = start[0] + (end[0] - start[0]) * s / length
    y = start[1] + (end[1] - start[1]) * s / length
    return Profile(s_mm=s, x_mm=x, y_mm=y, values=sample_field(field, grid, x, y))


def radial_profile(
    field: np.ndarray, grid: Grid, centre_xy_mm: tuple[float, float], *, bin_mm: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Azimuthal mean of a field (ny, nx) around a centre: radii r_mm (M,) of the bin centres, mean (M,), and the
    number of nodes per bin (M,) (a bin with none is NaN)."""
    step = grid.step_mm if bin_mm is None else bin_mm
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    r = np.hypot(gx - centre_xy_mm[0], gy - centre_xy_mm[1])
    finite = np.isfinite(field)
    n_bins = int(np.ceil(r.max() / step)) + 1
    bins = np.minimum((r / step).astype(np.int64), n_bins - 1)
    count = np.bincount(bins[finite], minlength=n_bins)
    total = np.bincount(bins[finite], weights=field[finite], minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
    return (np.arange(n_bins) + 0.5) * step, mean, count
