"""A .cine without frames.csv: the result's time axis and frame numbers come from the file, as the camera wrote them."""

from __future__ import annotations

import numpy as np

from fringelab.formats.recordings import open_recording
from fringelab.formats.topography import TopographyResult
from fringelab.pipelines.topography import topography_recording
from tests.formats.recording_files import write_cine

from .conftest import RenderedExperiment


def test_cine_time_stamps_and_trigger_numbers_reach_the_result(kodak: RenderedExperiment, tmp_path) -> None:
    frames = list(kodak.test_frames[:4])
    path = write_cine(tmp_path / "test.cine", frames, fps=20000, first_image_no=-1, jitter_s=2e-7)
    with open_recording(path) as source:
        summary = topography_recording(source, kodak.camera, kodak.projector, out_path=tmp_path / "result.h5")
        stamps_s = source.frame_times_s
    with TopographyResult(summary.path) as result:
        np.testing.assert_array_equal(result.camera_frames, [-1, 0, 1, 2])
        np.testing.assert_array_equal(result.frames, [0, 1, 2, 3])
        expected = (np.arange(4) - 1) / 20000 + 2e-7 * (np.arange(4) % 3 - 1)
        # 1 ns: TIME64 resolves 0.23 ns; the jitter (200 ns) shows the stamps were used, not the rate
        np.testing.assert_allclose(result.column("frames/time_s"), expected, atol=1e-9)
        np.testing.assert_array_equal(result.column("frames/time_s"), stamps_s)
        assert "time stamps" in result.time_source
        assert np.isnan(result.column("frames/force_kN")).all()  # not logged: NaN, not zero


def test_frames_csv_time_wins_over_the_container(kodak: RenderedExperiment, tmp_path) -> None:
    frames = list(kodak.test_frames[:2])
    path = write_cine(tmp_path / "test.cine", frames, fps=20000)
    (tmp_path / "frames.csv").write_text("frame,time_s\n0,1.5\n1,2.5\n")
    with open_recording(path) as source:
        summary = topography_recording(source, kodak.camera, kodak.projector, out_path=tmp_path / "result.h5")
    with TopographyResult(summary.path) as result:
        np.testing.assert_array_equal(result.column("frames/time_s"), [1.5, 2.5])
        assert result.time_source == "frames.csv"


def test_result_has_dimension_scales_and_an_xdmf_sidecar_meshio_reads(kodak: RenderedExperiment, tmp_path) -> None:
    import h5py
    import meshio

    path = write_cine(tmp_path / "test.cine", list(kodak.test_frames[:3]), fps=1000)
    with open_recording(path) as source:
        summary = topography_recording(source, kodak.camera, kodak.projector, out_path=tmp_path / "result.h5")
    xdmf = summary.path.with_suffix(".xdmf")
    assert xdmf.is_file()
    with h5py.File(summary.path, "r") as file:
        z = file["grid/z_mm"]
        assert [z.dims[i].label for i in range(3)] == ["frame", "y_mm", "x_mm"]
        np.testing.assert_array_equal(z.dims[2][0][()], file["grid/x_mm"][()])
        np.testing.assert_array_equal(z.dims[0][0][()], [0, 1, 2])
    with TopographyResult(summary.path) as result, meshio.xdmf.TimeSeriesReader(xdmf) as reader:
        points, cells = reader.read_points_cells()
        gx, gy = np.meshgrid(result.grid.x_mm, result.grid.y_mm)
        np.testing.assert_array_equal(points, np.column_stack([gx.ravel(), gy.ravel()]))
        assert cells[0].type == "quad" and len(cells[0].data) == (gx.shape[0] - 1) * (gx.shape[1] - 1)
        assert reader.num_steps == 3
        for k in range(3):
            t, point_data, _ = reader.read_data(k)
            assert t == result.column("frames/time_s")[k]  # the .cine's times, exactly as in the result
            # the per-frame views are the stored float32 grid, bit for bit (NaN where no data)
            np.testing.assert_array_equal(np.ravel(point_data["z_mm"]), result.z_grid(k).ravel().astype(np.float32))
