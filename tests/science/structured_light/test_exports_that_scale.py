"""Exports past the limits of the tools users open them with: MAT v7.3 (HDF5) past v5's 2 GB per variable, a
points CSV past a spreadsheet's rows. Read back with scipy and h5py, as MATLAB's users and scripts would."""

from __future__ import annotations

import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
from scipy.io import loadmat
from scipy.io.matlab import matfile_version

from fringelab.formats import exports
from fringelab.formats.exports import SpreadsheetLimitWarning, export_result, read_points_csv
from fringelab.formats.topography import TopographyResult
from fringelab.pipelines.topography import topography_recording

from .conftest import RenderedExperiment, recorded_test


@pytest.fixture(scope="module")
def result_path(kodak: RenderedExperiment, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("result") / "result.h5"
    topography_recording(recorded_test(kodak, 3), kodak.camera, kodak.projector, out_path=path)
    return path


def test_mat_v73_is_a_mat_file_with_every_variable_as_matlab_sees_it(result_path: Path, tmp_path: Path) -> None:
    path = export_result(result_path, "mat", tmp_path / "result.mat", mat_version="7.3")
    assert matfile_version(str(path)) == (2, 0)  # scipy recognises MATLAB's v7.3 header
    with h5py.File(path, "r") as mat, TopographyResult(result_path) as result:
        assert mat["z_mm"].attrs["MATLAB_class"] == b"single"
        # HDF5 holds MATLAB's column-major arrays with dimensions reversed: z_mm is nx × ny × frames on disk
        assert mat["z_mm"].shape == (*result.grid.shape[::-1], result.n_frames)
        for i in range(result.n_frames):
            np.testing.assert_array_equal(mat["z_mm"][:, :, i].T, result.file["grid/z_mm"][i])  # exact: float32
            np.testing.assert_array_equal(mat["sigma_w_mm"][:, :, i].T, result.file["grid/sigma_w_mm"][i])
            w = result.file["grid/z_mm"][i] - np.float32(result.z_flat_mm)
            np.testing.assert_array_equal(mat["w_mm"][:, :, i].T, w)  # w itself, as float32 arithmetic gives it
        np.testing.assert_array_equal(mat["x_mm"][:, 0], result.grid.x_mm)
        np.testing.assert_array_equal(mat["time_s"][:, 0], result.column("frames/time_s"))
        np.testing.assert_array_equal(mat["camera_frames"][:, 0], result.camera_frames)
        assert mat["z_flat_mm"].shape == (1, 1) and mat["z_flat_mm"][0, 0] == result.z_flat_mm
        points = mat["points"][()].T
        assert points.shape == (int(result.offsets[-1]), 6)  # frame, x_mm, y_mm, z_mm, w_mm, sigma_w_mm
        np.testing.assert_array_equal(points[: len(result.points(0)), 1:4], result.points(0))
        length = mat["units/length"][()].ravel().astype(np.uint16).tobytes().decode("utf-16-le")
        assert length == "mm" and mat["units"].attrs["MATLAB_class"] == b"struct"


def test_auto_switches_to_v73_only_past_the_v5_limit(result_path: Path, tmp_path: Path, monkeypatch) -> None:
    small = export_result(result_path, "mat", tmp_path / "small.mat")
    assert matfile_version(str(small)) == (1, 0)
    data = loadmat(small)
    with TopographyResult(result_path) as result:
        assert data["z_mm"].dtype == np.float32  # float32 as stored: nothing measurable is lost
        np.testing.assert_array_equal(data["z_mm"][1], result.file["grid/z_mm"][1])
        grid_bytes = result.n_frames * result.grid.shape[0] * result.grid.shape[1] * 4
    # The real limit (2 GB) is too large to cross in a test: lower it to just under this grid's size
    monkeypatch.setattr(exports, "MAT_V5_MAX_VARIABLE_BYTES", grid_bytes - 1)
    large = export_result(result_path, "mat", tmp_path / "large.mat")
    assert matfile_version(str(large)) == (2, 0)


def test_points_csv_past_spreadsheet_rows_warns_or_splits(result_path: Path, tmp_path: Path, monkeypatch) -> None:
    with TopographyResult(result_path) as result:
        n_rows = int(result.offsets[-1]) + 1
        frames = list(result.frames)
        total = [result.points(i) for i in range(result.n_frames)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        export_result(result_path, "points-csv", tmp_path / "fits.csv")  # under the limit: no warning
    monkeypatch.setattr(exports, "SPREADSHEET_MAX_ROWS", n_rows - 1)
    with pytest.warns(SpreadsheetLimitWarning, match=f"{n_rows} rows.*--per-frame"):
        whole = export_result(result_path, "points-csv", tmp_path / "all.csv")
    assert len(read_points_csv(whole)) == n_rows - 1  # written whole all the same
    folder = export_result(result_path, "points-csv", tmp_path / "per_frame", per_frame=True)
    files = sorted(folder.glob("frame_*.csv"))
    assert [int(f.stem.split("_")[1]) for f in files] == frames
    for f, points in zip(files, total, strict=True):
        np.testing.assert_allclose(read_points_csv(f)[:, 1:4], points, atol=6e-5)  # 4 decimals of float32 mm


def test_every_export_reports_progress_per_frame(result_path: Path, tmp_path: Path) -> None:
    from fringelab.formats import EXPORT_FORMATS

    with TopographyResult(result_path) as result:
        n = result.n_frames
    for fmt in EXPORT_FORMATS:
        calls: list[tuple[int, int, str]] = []
        suffix = {"vtk": ".pvd", "grid-npz": ".npz", "mat": ".mat"}.get(fmt, ".csv")
        export_result(result_path, fmt, tmp_path / f"out{suffix}", progress=lambda *a, c=calls: c.append(a))
        assert calls and calls[-1][:2] == (n, n), (fmt, calls)
        assert [done for done, _, _ in calls] == sorted(done for done, _, _ in calls)  # never backwards
