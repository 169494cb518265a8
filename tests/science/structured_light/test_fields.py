"""Gridding on the edge mesh, holes, peak and centre, profiles (fields.py), and edge ordering (fringes.order_edges)."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.science.fields import (
    Grid,
    field_peak,
    grid_covering,
    grid_edge_points,
    line_profile,
    radial_profile,
    sample_field,
)
from fringelab.science.fringes import locate_edges, order_edges
from fringelab.science.virtual_test import render_straight_stripes


def edge_grid(n_k: int = 40, n_s: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """(K, S) coordinates of edges 6 mm apart, lines 1.2 mm apart, slightly sheared like a camera view."""
    k, s = np.meshgrid(np.arange(n_k), np.arange(n_s), indexing="ij")
    x = -120.0 + 6.0 * k + 0.05 * s
    y = -70.0 + 1.2 * s
    return x, y


def test_planes_are_gridded_exactly_and_only_within_the_data() -> None:
    x, y = edge_grid()
    z = 3.0 + 0.02 * x - 0.01 * y
    grid = grid_covering(np.column_stack([x.ravel(), y.ravel()]), step_mm=2.0, margin_mm=4.0)
    field = grid_edge_points(x, y, z, grid, max_edge_mm=20.0)
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    finite = np.isfinite(field)
    # Linear interpolation reproduces a plane to rounding.
    np.testing.assert_allclose(field[finite], (3.0 + 0.02 * gx - 0.01 * gy)[finite], atol=1e-9)
    # Nodes outside the data's hull are empty; inside it (a margin of one grid step in) all are filled.
    inside = (gx > x.min() + 8) & (gx < x.max() - 8) & (gy > y.min() + 2) & (gy < y.max() - 2)
    assert np.all(finite[inside])
    assert not np.any(finite[(gx < x.min() - 1e-6) | (gy > y.max() + 1e-6)])


def test_holes_in_the_data_are_never_bridged() -> None:
    x, y = edge_grid()
    z = np.zeros_like(x)
    hole = np.hypot(x - 0.0, y - 0.0) < 15.0
    x, y, z = (np.where(hole, np.nan, a) for a in (x, y, z))
    grid = Grid(x_mm=np.arange(-100.0, 100.0, 2.0), y_mm=np.arange(-60.0, 60.0, 2.0))
    field = grid_edge_points(x, y, z, grid, max_edge_mm=20.0)
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    # Nothing within the hole, less one edge spacing (6 mm) for the triangles that touch its rim.
    assert not np.any(np.isfinite(field[np.hypot(gx, gy) < 15.0 - 6.0]))
    around = (np.hypot(gx, gy) > 15.0 + 7.0) & (np.abs(gx) < 90) & (np.abs(gy) < 58)
    assert np.all(np.isfinite(field[around]))


def test_a_missing_edge_is_bridged_but_a_wide_gap_is_not() -> None:
    x, y = edge_grid()
    z = np.ones_like(x)
    for k in (10, 20, 21, 22):
        x[k], y[k], z[k] = np.nan, np.nan, np.nan
    # The mesh joins neighbours in (k, s): a missing edge removes its triangles either way ...
    grid = Grid(x_mm=np.arange(-100.0, 100.0, 1.0), y_mm=np.arange(-40.0, 40.0, 1.0))
    field = grid_edge_points(x, y, z, grid, max_edge_mm=20.0)
    row = field[40]
    column_x = grid.x_mm
    gap_10 = (column_x > -120 + 6 * 9 + 4) & (column_x < -120 + 6 * 11)
    assert not np.any(np.isfinite(row[gap_10]))
    assert np.all(np.isfinite(row[(column_x > -120 + 6 * 12 + 4) & (column_x < -120 + 6 * 19)]))


def test_peak_centre_and_profiles_of_a_dome() -> None:
    grid = Grid(x_mm=np.arange(-100.0, 101.0, 2.0), y_mm=np.arange(-80.0, 81.0, 2.0))
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    centre = (12.0, -6.0)
    w = 40.0 * np.exp(-((gx - centre[0]) ** 2 + (gy - centre[1]) ** 2) / (2 * 30.0**2))
    peak = field_peak(w, grid)
    assert peak.w_mm == pytest.approx(40.0, abs=0.1)
    assert (peak.x_mm, peak.y_mm) == (12.0, -6.0)
    np.testing.assert_allclose((peak.centre_x_mm, peak.centre_y_mm), centre, atol=0.05)
    profile = line_profile(w, grid, (-90.0, -6.0), (90.0, -6.0), step_mm=1.0)
    assert profile.s_mm[-1] == pytest.approx(180.0)
    expected = 40.0 * np.exp(-((profile.x_mm - centre[0]) ** 2) / (2 * 30.0**2))
    # Bilinear interpolation of a smooth dome on a 2 mm grid: error ≲ curvature × h²/8 ≈ 0.02 mm.
    np.testing.assert_allclose(profile.values, expected, atol=0.03)
    r, mean, count = radial_profile(w, grid, centre)
    at = (r > 20) & (r < 60) & (count > 0)
    np.testing.assert_allclose(mean[at], 40.0 * np.exp(-(r[at] ** 2) / (2 * 30.0**2)), atol=0.6)
    stack = np.stack([w, 2 * w])
    np.testing.assert_allclose(sample_field(stack, grid, np.array([12.0]), np.array([-6.0]))[:, 0], [40.0, 80.0])
    assert np.isnan(sample_field(w, grid, np.array([500.0]), np.array([0.0]))[0])


def test_order_edges_counts_stripes_consistently_across_a_hole() -> None:
    rng = np.random.default_rng(11)
    image = render_straight_stripes((160, 200), period_px=10.0, angle_deg=8.0, phase_px=2.0, rng=rng)
    rows, cols = np.mgrid[0:160, 0:200]
    image[np.hypot(cols - 100, rows - 80) < 18] = 6
    edges = locate_edges(image)
    order = order_edges(edges)
    index = order.crossing_index(edges)
    assert order.conflicts == 0
    assert np.all(order.crossing_component(edges) == 0)
    # The index counts edges along +t: it is a function of the true edge number m (x = m·P/2 along the normal).
    x = edges.q_px() @ np.array([np.cos(np.deg2rad(8.0)), np.sin(np.deg2rad(8.0))]) - 2.0
    m = np.round(x / 5.0).astype(int)
    assert len(np.unique(index - m)) == 1


def test_the_compiled_gridding_gives_the_numpy_rule_to_the_bit_for_every_field_on_one_mesh() -> None:
    """`gridding.grid_edge_fields` (what frames are gridded with) against `fields.grid_edge_points` (the rule in
    numpy): a noisy sheared mesh with a hole, missing points and a wide gap, nodes on shared triangle sides, and
    three fields at once (as Z and the two σ halves are gridded); equal to the bit, NaN where NaN."""
    from fringelab.science.gridding import grid_edge_fields

    rng = np.random.default_rng(12)
    x, y = edge_grid()
    x, y = x + rng.normal(0.0, 0.3, x.shape), y + rng.normal(0.0, 0.05, y.shape)
    gone = (np.hypot(x, y) < 15.0) | (rng.uniform(size=x.shape) < 0.02)
    gone[25:28] = True
    x, y = np.where(gone, np.nan, x), np.where(gone, np.nan, y)
    fields = rng.normal(0.0, 1.0, (3, *x.shape))
    fields[1, ::2] = 0.0  # the σ halves' zeros, and a NaN σ where a point has no σ
    fields[2, 5, 7] = np.nan
    grid = Grid(x_mm=np.arange(-130.0, 130.0, 1.0), y_mm=np.arange(-80.0, 80.0, 0.6))
    compiled = grid_edge_fields(x, y, fields, grid, max_edge_mm=8.0)
    for field, gridded in zip(fields, compiled, strict=True):
        expected = grid_edge_points(x, y, field, grid, max_edge_mm=8.0)
        assert np.count_nonzero(np.isfinite(expected)) > 1000
        np.testing.assert_array_equal(gridded, expected)
