"""Projector calibration (docs/method.md §4): the look-up table, its checks and QA, lookups, files, bad input."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fringelab.formats.projector import read_projector_calibration, write_projector_calibration
from fringelab.formats.sidecars import z_csv_text
from fringelab.pipelines.projector_calibration import calibrate_projector_recording
from fringelab.science import Cancelled
from fringelab.science.fringes import NoStripesError
from fringelab.science.order import OrderAgainstTableError
from fringelab.science.projector import CalibrationMismatchError, ProjectorCalibrationError, build_projector_calibration
from fringelab.science.topography import locate_test_edges, track_and_measure

from .conftest import MemorySource, RenderedExperiment


def test_table_quality_numbers(kodak: RenderedExperiment) -> None:
    table = kodak.projector
    qa = table.qa
    assert table.axis == "rows" and 9.0 < table.period_px < 11.0
    assert qa.coverage > 0.95
    assert qa.n_non_monotonic == 0 and qa.n_insensitive == 0
    # ~0.6 px per mm of Z for the kodak set-up (projector 30° off the normal, ~0.85 px/mm on the plate).
    assert 0.5 < qa.sensitivity_px_per_mm[1] < 0.75
    # Edge noise ~0.01 px over 0.6 px/mm: a few hundredths of a mm of Z in each fit.
    assert qa.fit_rms_mm < 0.03
    assert qa.z_range_mm == (0.0, 80.0)
    assert qa.max_step_shift_periods < 0.2
    # The table covers the plate (Ø500 mm) at the reference Z.
    x_min, x_max, y_min, y_max = qa.xy_extent_mm
    assert x_min < -250 and x_max > 250 and y_min < -250 and y_max > 250
    # Polarity alternates with the edge index.
    assert np.all(table.polarity[1:] == -table.polarity[:-1])


def test_lookup_returns_the_calibration_heights_and_never_extrapolates(kodak: RenderedExperiment) -> None:
    table = kodak.projector
    k, s = np.nonzero(table.valid)
    pick = np.arange(0, len(k), 97)
    k, s = k[pick], s[pick]
    j = 20  # Z = 40 mm
    t = table.lut_t_px[k, s, j].astype(np.float64)
    seen = np.isfinite(t)
    z, status = table.z_from_t(k[seen], s[seen], t[seen])
    assert np.all(status == 0)
    # The fit averages ~40 samples of ~0.015 mm noise each.
    assert np.sqrt(np.mean((z - 40.0) ** 2)) < 0.03
    # Beyond the sampled range (+ the 0.1 mm noise margin) nothing is looked up.
    beyond = table.t_hi_px[k, s] + 0.01
    z, status = table.z_from_t(k, s, beyond)
    assert np.all(status == 1) and np.all(np.isnan(z))
    z, status = table.z_from_t(np.array([-1, table.n_edges]), np.array([0, 0]), np.array([100.0, 100.0]))
    assert np.all(status == 2) and np.all(np.isnan(z))


def test_table_file_round_trip(kodak: RenderedExperiment, tmp_path: Path) -> None:
    path = write_projector_calibration(kodak.projector, tmp_path / "projector.h5")
    back = read_projector_calibration(path)
    assert back.qa == kodak.projector.qa
    assert back.edges == kodak.projector.edges
    assert back.camera_fingerprint == kodak.projector.camera_fingerprint
    np.testing.assert_array_equal(back.lut_t_px, kodak.projector.lut_t_px)
    np.testing.assert_array_equal(back.coefficients, kodak.projector.coefficients)
    k, s = np.nonzero(kodak.projector.valid)
    t = kodak.projector.reference_t_px[k, s]
    np.testing.assert_array_equal(back.z_from_t(k, s, t)[0], kodak.projector.z_from_t(k, s, t)[0])
    with pytest.raises(ValueError, match="not a fringelab.projector-calibration file"):
        import h5py

        with h5py.File(tmp_path / "other.h5", "w") as other:
            other.attrs["schema"] = "something else"
        read_projector_calibration(tmp_path / "other.h5")


def test_recording_entry_point_reads_z_csv_reports_progress_and_provenance(kodak: RenderedExperiment) -> None:
    frames = kodak.calibration_frames[:8]
    z = kodak.calibration_z_mm[:8]
    seen = []
    table = calibrate_projector_recording(
        MemorySource(frames, {"z.csv": z_csv_text(z)}), kodak.camera,
        progress=lambda done, total, stage: seen.append((done, stage)),
    )  # fmt: skip
    assert seen[-1] == (9, "done") and [d for d, _ in seen[:-1]] == list(range(1, 9))
    assert table.qa.z_range_mm == (0.0, 14.0)
    assert len(table.provenance["input_sha256"]) == 64
    with pytest.raises(ValueError, match="z.csv missing"):
        calibrate_projector_recording(MemorySource(frames, {}), kodak.camera)
    with pytest.raises(Cancelled):
        calibrate_projector_recording(
            MemorySource(frames, {"z.csv": z_csv_text(z)}), kodak.camera, should_cancel=lambda: True
        )


def test_stripes_that_do_not_move_with_z_are_refused(kodak: RenderedExperiment) -> None:
    # Stripes along the camera–projector baseline do not move with Z: the same image at every height.
    frames = [kodak.calibration_frames[0]] * 8
    with pytest.raises(ProjectorCalibrationError, match="hardly move with Z"):
        build_projector_calibration(frames, np.arange(8) * 2.0, kodak.camera)


def test_z_steps_too_coarse_for_the_stripes_are_refused(kodak: RenderedExperiment) -> None:
    # 6 mm steps move kodak's edges ~3.8 px, 0.38 of a stripe period: too close to half a period to be safe.
    # (Steps beyond ~0.6 period alias: every edge looks like its neighbour moved the other way, consistently,
    # which no image can tell; the calibration's Z steps must be chosen for the stripe period, see ProjectorQA.)
    frames = kodak.calibration_frames[::3][:8]
    with pytest.raises(ProjectorCalibrationError, match="finer Z steps"):
        build_projector_calibration(frames, kodak.calibration_z_mm[::3][:8], kodak.camera)


def asked_step_mm(message: str) -> float:
    return float(message.split("Z steps of at most ")[1].split(" mm")[0])


def test_z_steps_that_alias_are_refused_with_the_step_they_need(kodak: RenderedExperiment) -> None:
    # 10 mm steps move kodak's edges ~0.66 period (0.64 px/mm × 10 mm over a ~10 px period): each step reads as
    # the same-polarity neighbour moving 0.34 period back, every edge alike, so the step check passes, but each
    # edge's back-projected positions over Z bend off a straight line by a period's change per step.
    with pytest.raises(ProjectorCalibrationError, match="Z steps \\(10 mm\\) are too coarse") as raised:
        build_projector_calibration(kodak.calibration_frames[::5], kodak.calibration_z_mm[::5], kodak.camera)
    # The step asked for must work: 4 mm steps do (and the 2 mm fixture); the largest true shift per step,
    # ~0.74 px/mm, allows 0.35 × 9.9 / 0.74 ≈ 4.7 mm.
    assert 3.5 <= asked_step_mm(str(raised.value)) <= 4.7
    # 4 mm steps (0.26 period) and 2 mm ones are straight as followed: accepted.
    build_projector_calibration(kodak.calibration_frames[::2], kodak.calibration_z_mm[::2], kodak.camera)


def test_a_table_that_aliased_is_named_by_the_first_deflected_frame(kodak: RenderedExperiment, monkeypatch) -> None:
    # A table built before the calibration refused aliased steps (a file in a lab's database) runs backwards:
    # +0.33 instead of −0.64 px/mm. The first frame of the test whose plate moved (here ~9 mm) shows it: its
    # stripes, ordered from the rim, lie below the table's lowest Z for their order.
    import fringelab.science.projector as projector_module

    monkeypatch.setattr(projector_module, "_refuse_aliased_steps", lambda *args, **kwargs: None)  # the old build
    table = build_projector_calibration(kodak.calibration_frames[::5], kodak.calibration_z_mm[::5], kodak.camera)
    assert np.nanmedian(table.sensitivity_px_per_mm) > 0 > np.nanmedian(kodak.projector.sensitivity_px_per_mm)
    edges = list(locate_test_edges([kodak.test_frames[0], kodak.test_frames[3]], table))
    with pytest.raises(OrderAgainstTableError, match="Z steps \\(10 mm\\) were too coarse") as raised:
        list(track_and_measure(edges, table, kodak.camera))
    assert 3.5 <= asked_step_mm(str(raised.value)) <= 4.7


def test_frames_of_another_camera_and_malformed_input_are_refused(kodak: RenderedExperiment, phantom) -> None:
    with pytest.raises(CalibrationMismatchError, match="512 × 480 px but the camera calibration is for 1024 × 1024"):
        build_projector_calibration(kodak.calibration_frames[:8], kodak.calibration_z_mm[:8], phantom.camera)
    with pytest.raises(ValueError, match="strictly monotonic"):
        build_projector_calibration(kodak.calibration_frames[:8], [0, 2, 4, 4, 8, 10, 12, 14], kodak.camera)
    with pytest.raises(ProjectorCalibrationError, match="at least 6 Z steps"):
        build_projector_calibration(kodak.calibration_frames[:3], [0, 2, 4], kodak.camera)
    blank = [np.full((480, 512), 40, np.uint8)] * 8
    with pytest.raises(NoStripesError):
        build_projector_calibration(blank, np.arange(8) * 2.0, kodak.camera)


def test_reference_height_sets_where_edges_are_counted(kodak: RenderedExperiment) -> None:
    from fringelab.science.projector import ProjectorSettings

    settings = ProjectorSettings(reference_z_mm=10.0, edges=replace(kodak.projector.edges))
    table = build_projector_calibration(
        kodak.calibration_frames[:12], kodak.calibration_z_mm[:12], kodak.camera, settings=settings
    )
    assert table.reference_z_mm == 10.0
    k, s = np.nonzero(table.valid & np.isfinite(table.reference_t_px))
    z, status = table.z_from_t(k, s, table.reference_t_px[k, s])
    assert np.all(status == 0) and abs(np.median(z) - 10.0) < 0.01
