"""The topography pipeline (docs/method.md §5–6): chunked runs, temporal smoothing, the result file, bad input."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest

from fringelab.formats.edges import read_edges, write_edges
from fringelab.formats.topography import TopographyResult
from fringelab.pipelines.topography import topography_recording
from fringelab.science import Cancelled
from fringelab.science.camera import backproject_to_z, distortion_mm
from fringelab.science.fringes import NoStripesError
from fringelab.science.projector import TABLE_SENSITIVITY, TABLE_SIGMA_Z, CalibrationMismatchError, exact_camera_model
from fringelab.science.topography import (
    FirstFrameNotFlatError,
    TopographySettings,
    check_stripes_against,
    locate_test_edges,
    measure_frame,
    reference_for,
    scan_rays,
    track_and_measure,
)
from fringelab.science.uncertainty import edge_sigma_px, point_sigma_z_mm
from fringelab.science.virtual_test import PlateState, true_deflection_mm

from .conftest import MemorySource, RenderedExperiment, recorded_test

N_FRAMES = 16  # the first 16 frames of the kodak test: flat, then up to ~25 mm of deflection


def source_of(experiment: RenderedExperiment, n: int = N_FRAMES) -> MemorySource:
    return recorded_test(experiment, n)


def read_all(path: Path) -> dict[str, np.ndarray]:
    with TopographyResult(path) as result:
        return {
            "frames": result.frames,
            "grid": np.stack([result.z_grid(i) for i in range(result.n_frames)]),
            "points": np.vstack([result.points(i) for i in range(result.n_frames)]),
            "peak": result.column("peak/w_mm"),
            "time": result.column("frames/time_s"),
            "force": result.column("frames/force_kN"),
        }


def test_chunked_runs_give_identical_results(kodak: RenderedExperiment, tmp_path: Path) -> None:
    source = source_of(kodak)
    whole = topography_recording(source, kodak.camera, kodak.projector, out_path=tmp_path / "whole.h5")
    assert whole.frames == range(N_FRAMES)
    # Edge location in three chunks (as three workers would), stored and read back, then one sequential pass.
    chunks = [range(0, 5), range(5, 11), range(11, N_FRAMES)]
    stored = []
    for i, chunk in enumerate(chunks):
        edges = list(locate_test_edges([source[f] for f in chunk], kodak.projector))
        stored.append(write_edges(tmp_path / f"edges{i}.h5", list(chunk), edges))
    located = []
    for path in stored:
        frames, edges = read_edges(path)
        located.extend(edges)
    part = topography_recording(
        source, kodak.camera, kodak.projector, out_path=tmp_path / "part.h5", frames=range(6, 12), edges=located
    )
    assert part.frames == range(6, 12)
    a, b = read_all(tmp_path / "whole.h5"), read_all(tmp_path / "part.h5")
    np.testing.assert_array_equal(b["frames"], np.arange(6, 12))
    np.testing.assert_array_equal(b["grid"], a["grid"][6:12])
    np.testing.assert_array_equal(b["peak"], a["peak"][6:12])
    with TopographyResult(tmp_path / "whole.h5") as whole_file, TopographyResult(tmp_path / "part.h5") as part_file:
        for i in range(6):
            np.testing.assert_array_equal(part_file.points(i), whole_file.points(i + 6))
            np.testing.assert_array_equal(part_file.point_labels(i)[0], whole_file.point_labels(i + 6)[0])


def test_edges_stored_before_the_per_edge_sigma_read_with_the_frames_sigma(
    kodak: RenderedExperiment, tmp_path: Path
) -> None:
    edges = list(locate_test_edges(kodak.test_frames[3:4], kodak.projector))
    path = write_edges(tmp_path / "edges.h5", [3], edges)
    _, (stored,) = read_edges(path)
    assert stored.sigma_px is not None and stored.contrast_grey is not None
    np.testing.assert_array_equal(stored.sigma_px, edges[0].sigma_px)
    np.testing.assert_array_equal(stored.contrast_grey, edges[0].contrast_grey)
    assert stored.beside_dark is not None and np.any(stored.beside_dark)  # the clamp ring, where it is not black
    np.testing.assert_array_equal(stored.beside_dark, edges[0].beside_dark)
    with h5py.File(path, "a") as file:
        del file["sigma_px"], file["contrast_grey"]
    _, (old,) = read_edges(path)
    assert old.sigma_px is None and old.contrast_grey is None
    reference = reference_for(edges[0], kodak.projector, kodak.camera, TopographySettings())
    new_measured = measure_frame(edges[0], reference, kodak.projector, kodak.camera, frame=3)
    old_measured = measure_frame(old, reference, kodak.projector, kodak.camera, frame=3)
    np.testing.assert_array_equal(old_measured.points_obj_mm, new_measured.points_obj_mm)
    # Old edges: every point's edge term is the frame's σ (`uncertainty.edge_sigma_px`), the local check across
    # edges adds its τ², then the frame's check across edges scales every σ alike.
    frame_sigma = edge_sigma_px(old.noise_px, kodak.projector.edges)
    expected = point_sigma_z_mm(
        sensitivity_px_per_mm=_sensitivities(old_measured, kodak),
        table_sigma_z_mm=_table_sigmas(old_measured, kodak),
        edge_sigma_px=frame_sigma,
    )
    assert old_measured.sigma_scale >= 1.0
    assert old_measured.local_variance_mm2 is not None
    with_local = np.sqrt(expected**2 + old_measured.local_variance_mm2)
    np.testing.assert_allclose(old_measured.sigma_z_mm, with_local * old_measured.sigma_scale, rtol=1e-12)
    assert not np.allclose(new_measured.sigma_z_mm, old_measured.sigma_z_mm)


def test_points_whose_edge_sigma_exceeds_the_setting_are_missing_as_low_contrast(kodak: RenderedExperiment) -> None:
    (edges,) = locate_test_edges(kodak.test_frames[5:6], kodak.projector)
    assert edges.sigma_px is not None
    reference = reference_for(kodak.test_edges[0], kodak.projector, kodak.camera, TopographySettings())
    limit = float(np.quantile(edges.sigma_px, 0.7))  # about the least sure 30 % of the edge points
    kept = measure_frame(edges, reference, kodak.projector, kodak.camera, frame=5)
    settings = TopographySettings(max_edge_sigma_px=limit)
    masked = measure_frame(edges, reference, kodak.projector, kodak.camera, frame=5, settings=settings)
    assert 0.55 * len(kept.k) < len(masked.k) < 0.85 * len(kept.k)
    assert kept.coverage is not None and masked.coverage is not None
    lost_mm2 = kept.coverage.measured_area_mm2 - masked.coverage.measured_area_mm2
    gained_mm2 = masked.coverage.missing_mm2["low_contrast"] - kept.coverage.missing_mm2["low_contrast"]
    assert lost_mm2 > 0 and gained_mm2 == pytest.approx(lost_mm2, rel=0.1)
    unlimited = measure_frame(edges, reference, kodak.projector, kodak.camera, frame=5,
                              settings=TopographySettings(max_edge_sigma_px=None))  # fmt: skip
    assert len(unlimited.k) == len(kept.k)  # the default (0.25 px) masks nothing on these clean frames
    with pytest.raises(ValueError, match="max_edge_sigma_px"):
        TopographySettings(max_edge_sigma_px=0.0)


def _sensitivities(measured, kodak: RenderedExperiment) -> np.ndarray:  # type: ignore[no-untyped-def]
    return kodak.projector.lookup_table[measured.line, measured.k, TABLE_SENSITIVITY]


def _table_sigmas(measured, kodak: RenderedExperiment) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Each point's table σ_Z at its place in the fitted range: the entry's average σ_Z times the fit's leverage
    there (`uncertainty.fit_leverage_ratio`), between 0.75 and 1.9 of it for a cubic fit to ≤ 41 heights."""
    average = kodak.projector.lookup_table[measured.line, measured.k, TABLE_SIGMA_Z]
    ratio = measured.table_sigma_z_mm / average
    assert np.all((ratio > 0.74) & (ratio < 1.9))
    return np.asarray(measured.table_sigma_z_mm)


def test_temporal_smoothing_is_chunk_safe_and_reduces_noise(kodak: RenderedExperiment, tmp_path: Path) -> None:
    settings = TopographySettings(temporal_smoothing_frames=2)
    source = source_of(kodak)
    topography_recording(source, kodak.camera, kodak.projector, out_path=tmp_path / "a.h5", settings=settings)
    topography_recording(
        source, kodak.camera, kodak.projector, out_path=tmp_path / "b.h5", settings=settings, frames=range(4, 9)
    )
    a, b = read_all(tmp_path / "a.h5"), read_all(tmp_path / "b.h5")
    np.testing.assert_array_equal(b["grid"], a["grid"][4:9])
    # Against the truth, smoothing over 5 frames lowers the noise of w (the deflection is smooth in time).
    raw = list(track_and_measure(kodak.test_edges[:N_FRAMES], kodak.projector, kodak.camera))
    smooth = list(track_and_measure(kodak.test_edges[:N_FRAMES], kodak.projector, kodak.camera, settings=settings))
    assert [m.frame for m in smooth] == list(range(N_FRAMES))

    def rms(measurement) -> float:
        state = kodak.timeline.states[measurement.frame]
        p = measurement.points_obj_mm
        r = kodak.preset.scene.radius_mm(p[:, 0], p[:, 1])
        keep = (r > 25) & (r < 235)
        error = p[keep, 2] - true_deflection_mm(kodak.preset.scene, state, p[keep, 0], p[keep, 1])
        return float(np.sqrt(np.mean(error**2)))

    middle = range(3, N_FRAMES - 3)
    assert np.mean([rms(smooth[i]) for i in middle]) < 0.9 * np.mean([rms(raw[i]) for i in middle])


def test_result_file_holds_log_quality_and_provenance(kodak: RenderedExperiment, tmp_path: Path) -> None:
    source = source_of(kodak)
    summary = topography_recording(source, kodak.camera, kodak.projector, out_path=tmp_path / "r.h5")
    with TopographyResult(summary.path) as result:
        np.testing.assert_allclose(result.column("frames/time_s"), kodak.timeline.time_s[:N_FRAMES])
        np.testing.assert_allclose(result.column("frames/force_kN"), kodak.timeline.force_kN[:N_FRAMES])
        assert result.file["grid/z_mm"].chunks == (1, *result.grid.shape)
        assert result.file["grid/z_mm"].attrs["unit"] == "mm"
        assert "projector_json" in result.file["calibration"].attrs
        assert np.all(result.column("qa/n_points") > 20_000)
        assert abs(result.z_flat_mm) < 0.01
        # A point history at 100 mm from the centre follows the truth.
        x, y = kodak.preset.scene.centre_xy_mm[0] + 100.0, kodak.preset.scene.centre_xy_mm[1]
        truth = [true_deflection_mm(kodak.preset.scene, s, np.array([x]), np.array([y]))[0]
                 for s in kodak.timeline.states[:N_FRAMES]]  # fmt: skip
        np.testing.assert_allclose(result.history(x, y), truth, atol=0.05)
        summary_attrs = result.summary()
    # The clamp circle is found from the rim of the data, ~7 mm inside the clamp (edges within half a stripe of
    # the dark ring are rejected), centred on the plate to ~1 mm.
    np.testing.assert_allclose(summary.clamp_centre_xy_mm, kodak.preset.scene.centre_xy_mm, atol=1.5)
    assert 235 < summary_attrs["clamp_radius_mm"] < 250
    assert summary.flat_rms_mm < 0.05


def test_cancel_removes_the_partial_file(kodak: RenderedExperiment, tmp_path: Path) -> None:
    calls = []

    def should_cancel() -> bool:
        calls.append(1)
        return len(calls) > 3

    with pytest.raises(Cancelled):
        topography_recording(
            source_of(kodak), kodak.camera, kodak.projector, out_path=tmp_path / "c.h5", should_cancel=should_cancel
        )
    assert list(tmp_path.iterdir()) == []


def test_progress_reports_every_frame(kodak: RenderedExperiment, tmp_path: Path) -> None:
    seen = []
    topography_recording(
        source_of(kodak, 5), kodak.camera, kodak.projector, out_path=tmp_path / "p.h5",
        progress=lambda done, total, stage: seen.append((done, total, stage)),
    )  # fmt: skip
    assert seen == [(i, 5, "frames") for i in range(1, 6)]


def test_first_frame_that_is_not_flat_is_refused(kodak: RenderedExperiment) -> None:
    deflected = kodak.test_edges[12:16]  # starts at ~20 mm of deflection
    with pytest.raises(FirstFrameNotFlatError, match="not the flat plate"):
        list(track_and_measure(deflected, kodak.projector, kodak.camera))


def test_recordings_of_another_size_or_camera_are_refused(kodak: RenderedExperiment, phantom, tmp_path) -> None:
    with pytest.raises(CalibrationMismatchError, match="1024 × 1024 px but the projector calibration is for 512 × 480"):
        topography_recording(source_of(phantom, 2), kodak.camera, kodak.projector, out_path=tmp_path / "x.h5")
    with pytest.raises(CalibrationMismatchError, match="different cameras"):
        topography_recording(source_of(kodak, 2), phantom.camera, kodak.projector, out_path=tmp_path / "x.h5")
    other = exact_camera_model(replace(kodak.camera.camera, f_mm=kodak.camera.camera.f_mm * 1.01))
    with pytest.raises(CalibrationMismatchError, match="made with another camera calibration"):
        topography_recording(source_of(kodak, 2), other, kodak.projector, out_path=tmp_path / "x.h5")


def test_stripes_in_another_direction_are_refused(kodak: RenderedExperiment) -> None:
    turned = replace(kodak.projector, edges=replace(kodak.projector.edges, axis="cols"))
    with pytest.raises(CalibrationMismatchError, match="stripes of the test run roughly vertical"):
        check_stripes_against(kodak.test_frames[0], turned)


def test_frames_without_stripes_are_refused(kodak: RenderedExperiment, tmp_path: Path) -> None:
    blank = MemorySource([np.full((480, 512), 30, np.uint8)] * 2, {})
    with pytest.raises(NoStripesError, match="no stripes found"):
        topography_recording(blank, kodak.camera, kodak.projector, out_path=tmp_path / "x.h5")


def test_deflection_beyond_the_calibrated_range_is_masked_and_counted(kodak: RenderedExperiment) -> None:
    # The same test against a table that only reaches 20 mm: points higher up are masked, never extrapolated.
    from fringelab.science.projector import build_projector_calibration

    keep = kodak.calibration_z_mm <= 20.0
    short = build_projector_calibration(
        [f for f, k in zip(kodak.calibration_frames, keep, strict=True) if k],
        kodak.calibration_z_mm[keep],
        kodak.camera,
    )
    frame = 20  # w0 ≈ 31 mm: w > 20 mm within r ≈ 29 mm of the axis, some 800 edge points
    measurement = list(track_and_measure(kodak.test_edges[: frame + 1], short, kodak.camera))[-1]
    assert measurement.n_out_of_range > 300
    assert np.max(measurement.points_obj_mm[:, 2]) <= 20.0 + 0.1 + 0.05  # range + noise margin + noise
    state: PlateState = kodak.timeline.states[frame]
    p = measurement.points_obj_mm
    error = p[:, 2] - true_deflection_mm(kodak.preset.scene, state, p[:, 0], p[:, 1])
    r = kodak.preset.scene.radius_mm(p[:, 0], p[:, 1])
    assert np.sqrt(np.mean(error[r < 235] ** 2)) < 0.1


def test_frame_ranges_are_checked(kodak: RenderedExperiment, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="non-empty contiguous range"):
        topography_recording(source_of(kodak, 4), kodak.camera, kodak.projector, out_path=tmp_path / "x.h5",
                             frames=range(2, 9))  # fmt: skip


@pytest.mark.parametrize("axis", ["rows", "cols"])
def test_scan_rays_back_project_as_the_exact_camera_does(kodak: RenderedExperiment, axis: str) -> None:
    """The per-pixel ray table, interpolated along the lines, against exact undistortion at every point.

    Tolerance 1e-4 px (as an image distance, via mm per px at the plate): a hundredth of the edges' noise
    (~0.01 px), so the table cannot change a measured height; it is ~6e-5 px on this camera, whose distortion moves
    the image corners by several px, so a wrong interpolation (nearest pixel: up to 0.5 px) fails by far.
    """
    camera = kodak.camera
    rays = scan_rays(camera, axis)  # type: ignore[arg-type]
    rng = np.random.default_rng(7)
    n_lines, n_samples = rays.ut_mm.shape
    line = rng.integers(0, n_lines, 5000)
    t_px = rng.uniform(0.0, n_samples - 1.0, 5000)
    z_mm = rng.uniform(-5.0, 70.0, 5000)
    q_px = np.column_stack([t_px, line] if axis == "rows" else [line, t_px]).astype(np.float64)
    exact = backproject_to_z(camera.camera, q_px, z_mm, inverse=camera.inverse)
    table = rays.backproject_to_z(line, t_px, z_mm)
    mm_per_px = np.linalg.norm(backproject_to_z(camera.camera, q_px + [1.0, 0.0], z_mm, inverse=camera.inverse)
                               - exact, axis=1)  # fmt: skip
    error_px = np.linalg.norm(table - exact, axis=1) / mm_per_px
    assert np.max(error_px) < 1e-4
    distortion_px = np.hypot(*distortion_mm(rays.ut_mm[[0, -1], [0, -1]], rays.vt_mm[[0, -1], [0, -1]],
                                            camera.camera)) * camera.camera.pixels_per_mm[0]  # fmt: skip
    assert np.min(distortion_px) > 2.0  # the test is about a real lens, not a pinhole


def test_a_recording_ordered_nowhere_is_refused_with_the_reason_its_points_had() -> None:
    from fringelab.science.fields import Peak
    from fringelab.science.topography import FrameMeasurement, SummaryTally, TopographyError

    def frame(index: int, *, unresolved: int, conflict: int) -> FrameMeasurement:
        empty = np.zeros(0, np.int32)
        return FrameMeasurement(
            frame=index, k=empty, line=empty, points_obj_mm=np.zeros((0, 3)), n_tracks=0, n_ended=0,
            n_out_of_range=0, n_unmatched=unresolved + conflict, edge_noise_px=0.01,
            n_order_unresolved=unresolved, n_order_conflict_points=conflict,
        )  # fmt: skip

    peak = Peak(w_mm=float("nan"), x_mm=0.0, y_mm=0.0, centre_x_mm=float("nan"), centre_y_mm=float("nan"))
    for (unresolved, conflict), says in {(900, 100): "rim", (100, 900): "disagrees with the projector table"}.items():
        tally = SummaryTally()
        for index in (1, 2):
            tally.add(peak, n_out_of_range=0, measurement=frame(index, unresolved=unresolved, conflict=conflict))
        with pytest.raises(TopographyError, match=says):
            tally.require_ordered("test")
