"""Height uncertainty σ_w of measured points and grid nodes (METHOD.md §5–6 error budget).

Belongs here (pure): the standard deviation of a measured height from what the measurement itself knows.
1. Edge location in the test frame: each frame's `noise_px` is the RMS of raw − smoothed edge positions. The
   locator presmooths the image along the stripes (Gaussian σ_p px), which correlates the raw noise of
   neighbouring scan lines as exp(−d²/4σ_p²), then smooths along each edge with fixed weights w; the σ of a
   smoothed position is then noise_px · √(wᵀCw / (e₀−w)ᵀC(e₀−w)) (`smoothing.smoothed_noise_ratio`). Through
   the projector table's sensitivity (px per mm of Z) it is σ_Z,edge = σ_t / |dt/dZ|.
2. The table itself: each (edge, line) polynomial of D + 1 coefficients fitted to J calibration heights with
   residual RMS r has a prediction error of about r·√((D + 1)/J) on average over the fitted range, and
   r·√(h(τ)) at τ in it (the fit's leverage, `leverage_polynomials`: larger toward the range's ends).
3. The camera calibration: its parameter covariance (standard errors and correlations) moves where a pixel's
   ray meets the plane by δX, δY (the forward model's Jacobians); that changes w by ∇w·(δX, δY).
The first two are independent and add in quadrature per point (`point_sigma_z_mm`). A grid node is interpolated
linearly from the three corners of its triangle, which lie on two neighbouring edges (k and k + 1): errors of one
edge on neighbouring lines are nearly fully correlated (the smoothing along the edge, the table fitted to
smoothed calibration edges), errors of different edges independent, so σ_node² = (Σ_k λσ)² + (Σ_k+1 λσ)²
(`grid_sigma_mm`). The camera term is a field over the plate (`camera_sigma_xy_mm`), applied with
the surface's slope (`with_camera_term`). Not here: where the numbers are stored (`fringelab.formats.topography`).
"""

from __future__ import annotations

import functools
from dataclasses import replace
from typing import TYPE_CHECKING

import numba
import numpy as np
from scipy import special

from .camera import Camera, project_points
from .fields import Grid
from .gridding import grid_edge_fields
from .order_statistics import median
from .smoothing import smoothed_noise_ratio

if TYPE_CHECKING:
    from .fringes import EdgeSettings, FrameEdges


def edge_sigma_px(noise_px: float, edges: EdgeSettings) -> float:
    """σ (px) of a smoothed edge position in a frame whose raw − smoothed RMS is noise_px."""
    return float(noise_px) * smoothed_noise_ratio(edges.edge_smoothing_lines, presmooth_px=edges.presmooth_px)


def edge_sigmas_px(frame_edges: FrameEdges, edges: EdgeSettings) -> np.ndarray:
    """σ (px), shape (N,), of each smoothed edge position of a frame: the edge's own (`FrameEdges.sigma_px`), or,
    for edges stored before it existed (or located without smoothing along the edges), the frame's σ from its
    noise_px (`edge_sigma_px`) for every edge."""
    if frame_edges.sigma_px is not None and np.any(np.isfinite(frame_edges.sigma_px)):
        return np.asarray(frame_edges.sigma_px, np.float64)
    return np.full(len(frame_edges), edge_sigma_px(frame_edges.noise_px, edges))


def table_sigma_z_mm(*, fit_rms_mm: np.ndarray, n_heights: np.ndarray, n_coefficients: int) -> np.ndarray:
    """σ_Z (mm) of the projector table's prediction, any shape: fit RMS r, J calibration heights used and D + 1
    coefficients give r·√((D + 1)/J) (NaN where the table has no entry)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(fit_rms_mm, np.float64) * np.sqrt(n_coefficients / np.asarray(n_heights, np.float64))


@functools.lru_cache(maxsize=4)
def leverage_polynomials(degree: int, max_heights: int) -> np.ndarray:
    """(max_heights + 1, 2D + 1) coefficients, ascending powers of τ, of h_J(τ)/h̄_J for J = 0 … max_heights: the
    leverage of a degree-D least-squares fit to J heights spread evenly over τ ∈ [−1, 1], against its mean
    (D + 1)/J, the factor by which a prediction's variance at τ exceeds the average `table_sigma_z_mm` assumes
    (for D = 3 and 17 heights: 0.57 in the middle, 2.65 at the ends). Rows for J ≤ D + 1 are the constant 1."""
    out = np.zeros((max_heights + 1, 2 * degree + 1))
    out[:, 0] = 1.0
    for n in range(degree + 2, max_heights + 1):
        powers = np.linspace(-1.0, 1.0, n)[:, None] ** np.arange(degree + 1)
        inverse = np.linalg.inv(powers.T @ powers)
        row = np.zeros(2 * degree + 1)
        for a in range(degree + 1):
            row[a : a + degree + 1] += inverse[a]
        out[n] = row * n / (degree + 1)
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def fit_leverage_ratio(tau: float, polynomials: np.ndarray, n_heights: int) -> float:
    """How much larger than its average over the fitted range (`table_sigma_z_mm`) a polynomial fit's prediction
    σ is at τ (clipped to [−1, 1]) for n_heights heights: √ of that row of `leverage_polynomials` (the last row
    for more heights than it has) at τ."""
    row = min(max(n_heights, 0), polynomials.shape[0] - 1)
    x = min(max(tau, -1.0), 1.0)
    value = 0.0
    for j in range(polynomials.shape[1] - 1, -1, -1):
        value = value * x + polynomials[row, j]
    return float(np.sqrt(max(value, 0.0)))


def _point_sigma_z(sensitivity_px_per_mm: float, table_sigma_z_mm: float, edge_sigma_px: float) -> float:
    """The rule of `point_sigma_z_mm` for one point, compiled twice below (per point and per array). √(a² + b²)
    rather than hypot: the same value within an ulp (no σ here comes near overflow), in a third of the time."""
    edge_sigma_z_mm = edge_sigma_px / abs(sensitivity_px_per_mm)
    return float(np.sqrt(edge_sigma_z_mm * edge_sigma_z_mm + table_sigma_z_mm * table_sigma_z_mm))


# For compiled loops over many points (`topography._looked_up_points`).
point_sigma_z_at = numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")(_point_sigma_z)
_point_sigma_z_ufunc = numba.vectorize(["float64(float64, float64, float64)"], cache=True)(_point_sigma_z)


def point_sigma_z_mm(
    *, sensitivity_px_per_mm: np.ndarray, table_sigma_z_mm: np.ndarray, edge_sigma_px: float | np.ndarray
) -> np.ndarray:
    """σ_Z (N,) of points from the edge noise and the table, given per point the table's sensitivity, its own
    σ (`table_sigma_z_mm`) and the edge's σ (one for all, or (N,)): the two are independent and add in
    quadrature (σ_edge / |sensitivity|, hypot, σ_table; infinite at zero sensitivity)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return _point_sigma_z_ufunc(
            np.asarray(sensitivity_px_per_mm, np.float64), np.asarray(table_sigma_z_mm, np.float64),
            np.asarray(edge_sigma_px, np.float64),
        )  # fmt: skip


# The fourth difference across edges, (1, −4, 6, −4, 1): Σc² = 70 times an edge's variance for independent edges.
_FOURTH_DIFFERENCE = np.array([1.0, -4.0, 6.0, -4.0, 1.0])
# Median of χ² with one degree of freedom: the median of (d/σ_d)² for a normal d.
_CHI2_1_MEDIAN = 0.45494
# Fewer fourth differences than this in a frame do not check its σ (the scale is then 1).
MIN_CROSS_EDGE_CHECKS = 200


def cross_edge_scale(z_mm: np.ndarray, sigma_z_mm: np.ndarray) -> float:
    """How much larger than their σ the frame's errors that differ from edge to edge are, ≥ 1: the factor its
    points' σ_Z are multiplied by (docs/method.md §7, "Error budget").

    z_mm, sigma_z_mm: (K, S) heights and σ of the points by (edge, line), NaN where none. On a scan line, the
    fourth difference of five neighbouring edges' heights, Z_k−2 − 4Z_k−1 + 6Z_k − 4Z_k+1 + Z_k+2, cancels any
    surface of up to third order over the ~4 stripes it spans (a membrane's dome leaves well under its noise) and
    keeps what each edge gets wrong on its own, with the variance Σ c²σ² if the σ are right. The errors along an
    edge that no residual along it shows (a bias that stays along the edge: pixel locking, a mid-level off in
    the test but not in the calibration, a blur another lens makes) appear here, since they differ from edge to
    edge. The factor is √(median of d²/Σc²σ² / 0.455) (the median of χ²₁: robust to the few steps at the punch
    and the hole), never below 1 (σ that errs large is left as it is).
    """
    z = np.asarray(z_mm, np.float64)
    variance = np.asarray(sigma_z_mm, np.float64) ** 2
    if z.shape[0] < 5:
        return 1.0
    n = z.shape[0] - 4
    d4 = sum(c * z[i : i + n] for i, c in enumerate(_FOURTH_DIFFERENCE))
    predicted = sum(c * c * variance[i : i + n] for i, c in enumerate(_FOURTH_DIFFERENCE))
    ok = np.isfinite(d4) & (predicted > 0)
    return scale_from_ratios(d4[ok] ** 2 / predicted[ok])


def scale_from_ratios(ratios: np.ndarray) -> float:
    """`cross_edge_scale` from its ratios d²/Σc²σ² (one per fourth difference, any order): √(median / 0.455),
    at least 1, and 1 for fewer than MIN_CROSS_EDGE_CHECKS of them."""
    if len(ratios) < MIN_CROSS_EDGE_CHECKS:
        return 1.0
    return max(1.0, float(np.sqrt(median(np.asarray(ratios)) / _CHI2_1_MEDIAN)))


# The local check's tiles of check centres: 5 edges (the five a check spans) by 24 scan lines, interpolated
# between their centres; fewer than LOCAL_MIN_CHECKS checks (interpolated) leave the point without the local term.
# A check's d² is clipped at LOCAL_CLIP_RATIO times its predicted variance, so the rim of a hole adds a bounded
# amount.
LOCAL_TILE_EDGES = 5
LOCAL_TILE_LINES = 24
LOCAL_MIN_CHECKS = 20
LOCAL_CLIP_RATIO = 16.0
# E[min(χ²₁, c)] = (2Φ(a) − 1) − 2aφ(a) + c·2(1 − Φ(a)), a = √c: the clipped d²/predicted when σ is right.
_A = float(np.sqrt(LOCAL_CLIP_RATIO))
_CLIPPED_CHI2_MEAN = (
    float(special.erf(_A / np.sqrt(2.0)))
    - 2.0 * _A * float(np.exp(-0.5 * _A * _A) / np.sqrt(2.0 * np.pi))
    + LOCAL_CLIP_RATIO * float(special.erfc(_A / np.sqrt(2.0)))
)
# Σc² of the fourth difference: an error τ that each edge has on its own adds 70·τ² to E[d²].
_FOURTH_DIFFERENCE_NORM = float(np.sum(_FOURTH_DIFFERENCE**2))


def local_excess_variance(
    k_centre: np.ndarray,
    line_centre: np.ndarray,
    d2: np.ndarray,
    predicted: np.ndarray,
    shape: tuple[int, int],
    *,
    k: np.ndarray,
    line: np.ndarray,
) -> np.ndarray:
    """The variance τ² (mm², (N,)) that the errors of points (k, line) (N,) each have beyond their σ, from the
    fourth differences across edges (`cross_edge_scale`) around them; shape (K, S): edges and lines.

    k_centre, line_centre: (M,) the middle edge and the line of each check (each pair once); d2, predicted: (M,)
    its d² and Σc²σ². Each check's excess min(d², 16·Σc²σ²) − E[min(χ²₁, 16)]·Σc²σ² is zero on average where σ is
    right and 70·τ² where every edge has an extra error of variance τ² of its own (a bias along an edge near the
    punch, a floor the edges' σ do not reach); averaged in tiles of LOCAL_TILE_EDGES × LOCAL_TILE_LINES,
    interpolated between the tiles' centres, never below 0, and 0 where fewer than LOCAL_MIN_CHECKS checks count.
    Added, not a factor: the points with a small σ gain most from it, the ranking by σ improves (docs/method.md
    §7, "Error budget").
    """
    return _local_excess_at(
        contiguous_index_array(k_centre), contiguous_index_array(line_centre), np.ascontiguousarray(d2, np.float64),
        np.ascontiguousarray(predicted, np.float64), int(shape[0]), int(shape[1]), contiguous_index_array(k),
        contiguous_index_array(line),
    )  # fmt: skip


def contiguous_index_array(values: np.ndarray) -> np.ndarray:
    """values (indices: edges, lines) as a contiguous int32 or int64 array for compiled kernels, which take either
    (the measurement keeps int32): copied only when it is neither or not contiguous."""
    values = np.asarray(values)
    return np.ascontiguousarray(values, values.dtype if values.dtype in (np.int32, np.int64) else np.int64)


@numba.njit(cache=True, nogil=True)
def _local_excess_at(
    k_centre: np.ndarray,
    line_centre: np.ndarray,
    d2: np.ndarray,
    predicted: np.ndarray,
    n_edges: int,
    n_lines: int,
    k: np.ndarray,
    line: np.ndarray,
) -> np.ndarray:
    """`local_excess_variance`: the checks' excess and count summed in tiles of LOCAL_TILE_EDGES ×
    LOCAL_TILE_LINES, both interpolated bilinearly between the tiles' centres at each point (a window of about
    twice a tile, tapering), so a frame costs one pass over its checks and one over its points."""
    n_tl, n_tk = n_lines // LOCAL_TILE_LINES + 2, n_edges // LOCAL_TILE_EDGES + 2
    total = np.zeros((n_tl, n_tk))
    count = np.zeros((n_tl, n_tk))
    for i in range(len(d2)):
        p = predicted[i]
        a, b = line_centre[i] // LOCAL_TILE_LINES, k_centre[i] // LOCAL_TILE_EDGES
        total[a, b] += min(d2[i], LOCAL_CLIP_RATIO * p) - _CLIPPED_CHI2_MEAN * p
        count[a, b] += 1.0
    return _tiles_at(total, count, k, line)


@numba.njit(cache=True, nogil=True)
def _tiles_at(total: np.ndarray, count: np.ndarray, k: np.ndarray, line: np.ndarray) -> np.ndarray:
    """τ² at (k, line) from the tiles of `_local_excess_at`."""
    n_tl, n_tk = total.shape
    # The tile and the fraction along the lines depend on the line only, across the edges on the edge only: both
    # tabulated once, not worked out per point.
    a_of, fu_of = _tile_coordinates(line, LOCAL_TILE_LINES, n_tl)
    b_of, fv_of = _tile_coordinates(k, LOCAL_TILE_EDGES, n_tk)
    out = np.zeros(len(k))
    for i in range(len(k)):
        a0, b0, fu, fv = a_of[line[i]], b_of[k[i]], fu_of[line[i]], fv_of[k[i]]
        w00, w01, w10, w11 = (1 - fu) * (1 - fv), (1 - fu) * fv, fu * (1 - fv), fu * fv
        n = w00 * count[a0, b0] + w01 * count[a0, b0 + 1] + w10 * count[a0 + 1, b0] + w11 * count[a0 + 1, b0 + 1]
        if n >= LOCAL_MIN_CHECKS:
            excess = (w00 * total[a0, b0] + w01 * total[a0, b0 + 1] + w10 * total[a0 + 1, b0]
                      + w11 * total[a0 + 1, b0 + 1])  # fmt: skip
            out[i] = max(excess / n / _FOURTH_DIFFERENCE_NORM, 0.0)
    return out


@numba.njit(cache=True, nogil=True)
def _tile_coordinates(index: np.ndarray, tile: int, n_tiles: int) -> tuple[np.ndarray, np.ndarray]:
    """For every index 0 … max(index) (lines or edges), the first of the two tiles `_tiles_at` interpolates between
    and the fraction of the way to the second (0 … 1), clipped to the tiles there are."""
    size = index.max() + 1 if len(index) else 0
    first, fraction = np.empty(size, np.int64), np.empty(size)
    for x in range(size):
        u = (x + 0.5) / tile - 0.5
        first[x] = min(max(int(np.floor(u)), 0), n_tiles - 2)
        fraction[x] = min(max(u - first[x], 0.0), 1.0)
    return first, fraction


def budget_shares(
    sigma_z_mm: np.ndarray,
    table_sigma_z_mm: np.ndarray,
    sigma_scale: float,
    local_variance_mm2: np.ndarray | None = None,
) -> dict[str, float]:
    """Each term's share of a frame's mean σ_Z² (points (N,), the final σ and the table's): "edge" (the edges' own
    σ through the sensitivity), "table" (the table's fit), "local" (the local check's τ², `local_excess_variance`,
    (N,) or None for none) and "across edges" (what the frame's check across edges added, 1 − 1/scale²); they sum
    to 1."""
    total = np.asarray(sigma_z_mm, np.float64) ** 2
    table = (np.asarray(table_sigma_z_mm, np.float64) * sigma_scale) ** 2
    local = np.zeros_like(total) if local_variance_mm2 is None else np.asarray(local_variance_mm2) * sigma_scale**2
    ok = np.isfinite(total) & np.isfinite(table) & np.isfinite(local)
    if not np.any(ok) or not np.sum(total[ok]) > 0:
        return {"edge": float("nan"), "table": float("nan"), "local": float("nan"), "across edges": float("nan")}
    table_share = float(np.sum(table[ok]) / np.sum(total[ok]))
    local_share = float(np.sum(local[ok]) / np.sum(total[ok]))
    across = 1.0 - 1.0 / sigma_scale**2
    edge = 1.0 - across - table_share - local_share
    return {"edge": edge, "table": table_share, "local": local_share, "across edges": across}


def grid_sigma_mm(
    x_mm: np.ndarray, y_mm: np.ndarray, sigma_mm: np.ndarray, grid: Grid, *, max_edge_mm: float
) -> np.ndarray:
    """σ (ny, nx) of the gridded heights from the points' σ, all (K, S) over (edge, line) (NaN = not measured):
    the interpolation weights summed per edge, edges independent (see the module docstring)."""
    halves = grid_edge_fields(x_mm, y_mm, sigma_edge_halves(sigma_mm), grid, max_edge_mm=max_edge_mm)
    return sigma_from_halves(halves)


def sigma_edge_halves(sigma_mm: np.ndarray) -> np.ndarray:
    """The points' σ (K, S) split in two fields (2, K, S), the even edges' and the odd edges' (0 on the others):
    gridded on the heights' triangles (`fields.grid_edge_fields`), each is the sum of one edge's weighted σ at a
    node, since a triangle's corners lie on two neighbouring edges."""
    sigma = np.asarray(sigma_mm, np.float64)
    even = (np.arange(sigma.shape[0]) % 2 == 0)[:, None]
    return np.stack([np.where(even, sigma, 0.0), np.where(even, 0.0, sigma)])


def sigma_from_halves(halves: np.ndarray) -> np.ndarray:
    """σ (ny, nx) of the grid from its two gridded halves (2, ny, nx) (`sigma_edge_halves`): independent edges
    add in quadrature."""
    return np.hypot(halves[0], halves[1])


def camera_sigma_xy_mm(
    camera: Camera,
    points_obj_mm: np.ndarray,
    *,
    standard_errors: dict[str, float],
    correlation: np.ndarray,
    parameters: tuple[str, ...],
) -> np.ndarray:
    """Covariance (N, 2, 2) of where the camera's rays meet the planes Z of points (N, 3), from the camera
    parameters' covariance (standard errors by name, correlation in `parameters` order).

    A parameter change δp moves the image point by J_p δp; the object point that keeps the pixel moves by
    δX = −A⁻¹ J_p δp on its plane, A = ∂q/∂(X, Y) (2 × 2). Both Jacobians by central differences.
    """
    points = np.asarray(points_obj_mm, np.float64)
    n = len(points)
    se = np.array([float(standard_errors.get(name, 0.0)) for name in parameters])
    if n == 0 or not np.any(se > 0):
        return np.zeros((n, 2, 2))
    covariance = np.asarray(correlation, np.float64) * np.outer(se, se)
    step_mm = 0.5
    a = np.empty((n, 2, 2))
    for axis in range(2):
        delta = np.zeros(3)
        delta[axis] = step_mm
        a[:, :, axis] = (project_points(camera, points + delta) - project_points(camera, points - delta)) / (
            2 * step_mm
        )
    moves = np.empty((len(parameters), n, 2))
    for j, name in enumerate(parameters):
        h = se[j] if se[j] > 0 else 1e-6
        plus = project_points(replace(camera, **{name: getattr(camera, name) + h}), points)
        minus = project_points(replace(camera, **{name: getattr(camera, name) - h}), points)
        dq = (plus - minus) / (2 * h)
        moves[j] = -np.linalg.solve(a, dq[..., None])[..., 0]
    per_point = moves.transpose(1, 2, 0)  # (N, 2, P)
    return np.asarray(per_point @ covariance @ per_point.transpose(0, 2, 1))


def with_camera_term(sigma_w_mm: np.ndarray, slope_xy: np.ndarray, covariance_xy_mm2: np.ndarray) -> np.ndarray:
    """σ_w with the camera term added in quadrature: sigma_w (...,), slopes (..., 2) of w, covariance (..., 2, 2)."""
    variance = np.einsum("...a,...ab,...b->...", slope_xy, covariance_xy_mm2, slope_xy)
    return np.sqrt(np.asarray(sigma_w_mm, np.float64) ** 2 + np.maximum(variance, 0.0))
