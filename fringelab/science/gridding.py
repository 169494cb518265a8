"""Gridding of edge points on the mesh their (edge, line) structure spans, compiled (docs/method.md §6).

Belongs here: `grid_edge_fields`, the one compiled pass that `fields.grid_edge_points` (a height) and
`uncertainty.grid_sigma_mm` (its σ) run on; the rule (which triangles, which nodes, what value) is that of
`fields.edge_mesh_triangles` and `fields.rasterize_triangles`, which say it in numpy. A module of its own so that
what reads grids (the API) never imports the compiler. Not here: grids, peaks and profiles (`fields.py`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .fields import Grid


def grid_edge_points(
    x_mm: np.ndarray, y_mm: np.ndarray, z_mm: np.ndarray, grid: Grid, *, max_edge_mm: float
) -> np.ndarray:
    """`fields.grid_edge_points`, compiled: the same field (ny, nx) to the bit."""
    return grid_edge_fields(x_mm, y_mm, np.asarray(z_mm, np.float64)[None], grid, max_edge_mm=max_edge_mm)[0]


def grid_edge_fields(
    x_mm: np.ndarray, y_mm: np.ndarray, values: np.ndarray, grid: Grid, *, max_edge_mm: float
) -> np.ndarray:
    """Several fields (F, ny, nx) of the same edge points gridded on one mesh: x_mm, y_mm (K, S), values
    (F, K, S), NaN = missing. Each field is what `grid_edge_points` gives for it.

    One compiled pass over the triangles of `edge_mesh_triangles` in the same order as `rasterize_triangles`
    visits them (a node on the side two triangles share takes the later one's value), so the mesh, each
    triangle's grid nodes and their barycentric weights are found once for all the fields.
    """
    x = np.ascontiguousarray(x_mm, np.float64)
    y = np.ascontiguousarray(y_mm, np.float64)
    fields = np.ascontiguousarray(values, np.float64)
    if fields.ndim != 3 or fields.shape[1:] != x.shape or x.shape != y.shape:
        raise ValueError(f"values: expected shape (F, {x.shape[0]}, {x.shape[1]}), got {fields.shape}")
    out = np.full((fields.shape[0], *grid.shape), np.nan)
    if x.shape[0] < 2 or x.shape[1] < 2 or len(grid.x_mm) < 1 or len(grid.y_mm) < 1:
        return out
    _grid_edge_fields_kernel(
        x, y, fields, float(grid.x_mm[0]), float(grid.y_mm[0]), grid.step_mm, float(max_edge_mm), out
    )
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _grid_edge_fields_kernel(
    x: np.ndarray,
    y: np.ndarray,
    values: np.ndarray,
    x0_mm: float,
    y0_mm: float,
    step_mm: float,
    max_edge_mm: float,
    out: np.ndarray,
) -> None:
    """`grid_edge_fields` in place: every triangle (kept by `edge_mesh_triangles`' rule) with the arithmetic of
    `rasterize_triangles`, first the (k, s), (k+1, s), (k+1, s+1) triangles, then the (k, s), (k+1, s+1),
    (k, s+1) ones, each in (k, s) order."""
    n_k, n_s = x.shape
    n_fields, ny, nx = out.shape
    eps = 1e-9
    ck = np.empty(3, np.int64)
    cs = np.empty(3, np.int64)
    gx = np.empty(3)
    gy = np.empty(3)
    for kind in range(2):
        for k in range(n_k - 1):
            for s in range(n_s - 1):
                ck[0], cs[0] = k, s
                if kind == 0:
                    ck[1], cs[1], ck[2], cs[2] = k + 1, s, k + 1, s + 1
                else:
                    ck[1], cs[1], ck[2], cs[2] = k + 1, s + 1, k, s + 1
                kept = True
                for c in range(3):
                    d = (c + 1) % 3
                    side = math.hypot(x[ck[c], cs[c]] - x[ck[d], cs[d]], y[ck[c], cs[c]] - y[ck[d], cs[d]])
                    if not side <= max_edge_mm:  # NaN (a corner not measured) is not kept either
                        kept = False
                        break
                if not kept:
                    continue
                for c in range(3):
                    gx[c] = (x[ck[c], cs[c]] - x0_mm) / step_mm
                    gy[c] = (y[ck[c], cs[c]] - y0_mm) / step_mm
                ix_lo = max(int(math.ceil(min(gx[0], gx[1], gx[2]))), 0)
                ix_hi = min(int(math.floor(max(gx[0], gx[1], gx[2]))), nx - 1)
                iy_lo = max(int(math.ceil(min(gy[0], gy[1], gy[2]))), 0)
                iy_hi = min(int(math.floor(max(gy[0], gy[1], gy[2]))), ny - 1)
                if ix_hi < ix_lo or iy_hi < iy_lo:
                    continue
                e1x, e1y = gx[1] - gx[0], gy[1] - gy[0]
                e2x, e2y = gx[2] - gx[0], gy[2] - gy[0]
                det = e1x * e2y - e1y * e2x
                if det == 0:
                    continue
                for iy in range(iy_lo, iy_hi + 1):
                    py = float(iy) - gy[0]
                    for ix in range(ix_lo, ix_hi + 1):
                        px = float(ix) - gx[0]
                        l1 = (px * e2y - py * e2x) / det
                        l2 = (e1x * py - e1y * px) / det
                        if l1 >= -eps and l2 >= -eps and l1 + l2 <= 1.0 + eps:
                            for f in range(n_fields):
                                v0 = values[f, ck[0], cs[0]]
                                v1 = values[f, ck[1], cs[1]]
                                v2 = values[f, ck[2], cs[2]]
                                out[f, iy, ix] = v0 + l1 * (v1 - v0) + l2 * (v2 - v0)
