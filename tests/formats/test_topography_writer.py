"""The topography result writer stores what it is given, whoever packed it: points spanning several stored chunks
(whole chunks written directly, the rest through HDF5), grids packed by the caller (as the worker's chunks do) or by
the writer's threads, or in the calling thread, read back to the bit."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from fringelab.formats.topography import POINTS_CHUNK_ROWS, TopographyResult, TopographyWriter, pack_grids
from fringelab.science.coverage import MISSING_REASONS, FrameCoverage
from fringelab.science.fields import Grid, Peak
from fringelab.science.topography import FrameMeasurement

GRID = Grid(x_mm=np.linspace(-20.0, 20.0, 21), y_mm=np.linspace(-10.0, 10.0, 11))


def frame(i: int, n_points: int) -> tuple[FrameMeasurement, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(i)
    coverage = FrameCoverage(visible_area_mm2=100.0, measured_area_mm2=90.0,
                             missing_mm2=dict.fromkeys(MISSING_REASONS, 1.0), n_order_conflicts=0)  # fmt: skip
    measurement = FrameMeasurement(
        frame=i,
        k=rng.integers(0, 200, n_points).astype(np.int32),
        line=rng.integers(0, 480, n_points).astype(np.int32),
        points_obj_mm=rng.normal(0.0, 50.0, (n_points, 3)),
        n_tracks=n_points,
        n_ended=0,
        n_out_of_range=0,
        n_unmatched=0,
        edge_noise_px=0.05,
        coverage=coverage,
        sigma_z_mm=rng.uniform(0.01, 0.1, n_points),
    )
    z = rng.normal(0.0, 1.0, GRID.shape)
    z[rng.uniform(size=GRID.shape) < 0.2] = np.nan
    sigma = np.where(np.isfinite(z), 0.02, np.nan)
    return measurement, z, sigma


@pytest.mark.parametrize(("threads", "packed"), [(0, False), (2, False), (2, True)])
def test_what_is_written_reads_back_to_the_bit(tmp_path: Path, threads: int, packed: bool) -> None:
    sizes = [POINTS_CHUNK_ROWS // 2 + 7, POINTS_CHUNK_ROWS + 3, 0, 11]  # chunks filled across frames, and a tail
    frames = [frame(i, n) for i, n in enumerate(sizes)]
    peak = Peak(w_mm=1.0, x_mm=0.0, y_mm=0.0, centre_x_mm=0.0, centre_y_mm=0.0)
    path = tmp_path / "result.h5"
    with TopographyWriter(path, grid=GRID, max_edge_mm=6.0, z_flat_mm=0.0, axis="rows", attrs={},
                          calibration_attrs={}, threads=threads) as writer:  # fmt: skip
        for measurement, z, sigma in frames:
            if packed:
                writer.append(measurement, None, peak, log=(0.0, 0.0, 0.0), packed=pack_grids(z, sigma))
            else:
                writer.append(measurement, z, peak, log=(0.0, 0.0, 0.0), sigma_grid_mm=sigma)
        writer.close({})
    with TopographyResult(path) as result:
        assert result.n_frames == len(frames)
        np.testing.assert_array_equal(result.offsets, np.concatenate([[0], np.cumsum(sizes)]))
        for i, (measurement, z, sigma) in enumerate(frames):
            np.testing.assert_array_equal(result.points(i), measurement.points_obj_mm.astype(np.float32))
            edge, line = result.point_labels(i)
            np.testing.assert_array_equal(edge, measurement.k)
            np.testing.assert_array_equal(line, measurement.line)
            np.testing.assert_array_equal(result.sigma_points(i), measurement.sigma_z_mm.astype(np.float32))
            np.testing.assert_array_equal(result.z_grid(i), z.astype(np.float32))
            np.testing.assert_array_equal(result.sigma_grid(i), sigma.astype(np.float32))
        grid_coverage = result.column("qa/grid_coverage")
    expected = [np.count_nonzero(np.isfinite(z)) / np.count_nonzero(np.isfinite(frames[0][1])) for _, z, _ in frames]
    np.testing.assert_array_equal(grid_coverage, expected)
    with h5py.File(path) as file:  # stored compressed, the grids one chunk per frame
        assert file["grid/z_mm"].compression == "gzip" and file["grid/z_mm"].chunks == (1, *GRID.shape)
        assert file["points/x_mm"].compression == "gzip"
