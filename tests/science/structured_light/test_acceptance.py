"""Acceptance numbers of docs/method.md §7 on the virtual test, at both presets (sizes in conftest.py).

Noise σ = 2 grey levels, ~10 px per stripe period, camera ~2 m away, peak deflection 60 mm, then perforation.
- RMS error of w below 0.05 mm on the flat plate and below 0.10 mm over the deforming plate, outside 15 mm from
  the punch edge and from the clamp (at the measured points and at the grid nodes);
- no edge identity lost before perforation (no point with a wrong edge index, no track in that region ended);
- after perforation, no point and no grid node inside the hole.
"""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.science.camera import project_points
from fringelab.science.fields import field_peak
from fringelab.science.fringes import UNUSABLE_BLOCK_PX, UNUSABLE_UNEVEN_LIGHT
from fringelab.science.topography import (
    FrameMeasurement,
    grid_for_first_frame,
    grid_measurement,
    track_and_measure,
)
from fringelab.science.virtual_test import true_deflection_mm

from .conftest import RenderedExperiment

FLAT_RMS_LIMIT_MM = 0.05
DEFORMING_RMS_LIMIT_MM = 0.10
EXCLUDED_MM = 15.0
SLIDE_PER_FRAME_MM = 3.0


def evaluation_region(
    experiment: RenderedExperiment, x_mm: np.ndarray, y_mm: np.ndarray, *, margin_mm: float = 0.0
) -> np.ndarray:
    scene = experiment.preset.scene
    r = scene.radius_mm(x_mm, y_mm)
    excluded = EXCLUDED_MM + margin_mm
    return (r > scene.punch_radius_mm + excluded) & (r < scene.clamp_radius_mm - excluded)


def slide_edge_number(experiment: RenderedExperiment, points_obj_mm: np.ndarray, w0_mm: float) -> np.ndarray:
    """Which stripe edge of the projector slide truly lights each measured point (half periods from phase 0)."""
    scene, projector = experiment.preset.scene, experiment.preset.projector
    x, y = points_obj_mm[:, 0], points_obj_mm[:, 1]
    z, _, _ = scene.deflection_mm(x, y, w0_mm)
    xs, _ = projector.slide_mm(x, y, z)
    return np.round((xs - projector.phase_mm) / (0.5 * projector.period_mm)).astype(np.int64)


@pytest.fixture(scope="module", params=["kodak", "phantom"])
def measured(request) -> tuple[RenderedExperiment, list[FrameMeasurement]]:
    experiment = request.getfixturevalue(request.param)
    return experiment, list(track_and_measure(experiment.test_edges, experiment.projector, experiment.camera))


def test_flat_first_frame_is_within_0_05_mm(measured) -> None:
    experiment, measurements = measured
    points = measurements[0].points_obj_mm
    region = evaluation_region(experiment, points[:, 0], points[:, 1])
    rms = np.sqrt(np.mean(points[region, 2] ** 2))
    assert region.sum() > 10_000
    assert rms < FLAT_RMS_LIMIT_MM, f"{experiment.preset.name}: flat RMS {rms:.4f} mm"


def test_deforming_plate_is_within_0_10_mm_at_points_and_grid(measured) -> None:
    experiment, measurements = measured
    scene = experiment.preset.scene
    grid, max_edge_mm = grid_for_first_frame(measurements[0], experiment.projector, _settings())
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    grid_region = evaluation_region(experiment, gx, gy)
    worst_points = worst_grid = 0.0
    for measurement, state in zip(measurements, experiment.timeline.states, strict=True):
        points = measurement.points_obj_mm
        region = evaluation_region(experiment, points[:, 0], points[:, 1])
        error = points[region, 2] - true_deflection_mm(scene, state, points[region, 0], points[region, 1])
        worst_points = max(worst_points, float(np.sqrt(np.mean(error**2))))
        z_grid = grid_measurement(measurement, experiment.projector, grid, max_edge_mm=max_edge_mm)
        grid_error = (z_grid - true_deflection_mm(scene, state, gx, gy))[grid_region]
        # The grid is linear between edges ~7 mm apart: its error adds the curvature of w over that span.
        assert np.count_nonzero(np.isfinite(grid_error)) > 0.95 * grid_region.sum()
        worst_grid = max(worst_grid, float(np.sqrt(np.nanmean(grid_error**2))))
    name = experiment.preset.name
    assert worst_points < DEFORMING_RMS_LIMIT_MM, f"{name}: worst frame RMS at points {worst_points:.4f} mm"
    assert worst_grid < DEFORMING_RMS_LIMIT_MM, f"{name}: worst frame RMS on the grid {worst_grid:.4f} mm"


def test_no_edge_identity_lost_before_perforation(measured) -> None:
    experiment, measurements = measured
    perforation = experiment.timeline.perforation_frame
    first = measurements[0]
    offsets = []
    for measurement, state in zip(measurements, experiment.timeline.states, strict=True):
        number = slide_edge_number(experiment, measurement.points_obj_mm, state.w0_mm)
        offsets.append(np.stack([number - measurement.k, number + measurement.k]))
    # The table counts edges along the scan line, the slide along its x axis: one of k ± number is constant.
    sense = int(np.argmax([np.mean(offsets[0][i] == np.median(offsets[0][i])) for i in (0, 1)]))
    reference = int(np.median(offsets[0][sense]))
    for frame, offset in enumerate(offsets):
        wrong = np.count_nonzero(offset[sense] != reference)
        assert wrong == 0, f"{experiment.preset.name}: frame {frame}: {wrong} points with a wrong edge index"
    # No track ends inside the evaluation region before perforation. Edge points slide over the plate as it
    # deflects (the light sheets are oblique, up to ~2 mm per frame near the punch), so a track is judged by
    # where it was in the frame before it ended, with that slide as margin.
    for frame in range(1, perforation):
        previous, current = measurements[frame - 1], measurements[frame]
        inside = _in_region(experiment, previous, margin_mm=SLIDE_PER_FRAME_MM)
        was = set(zip(previous.k[inside].tolist(), previous.line[inside].tolist(), strict=True))
        now = set(zip(current.k.tolist(), current.line.tolist(), strict=True))
        lost = was - now - _refused_for_uneven_light(experiment, previous, frame, was - now)
        assert not lost, f"{experiment.preset.name}: frame {frame}: {len(lost)} tracks ended in the evaluation region"
    assert len(first.k) > 10_000


def test_no_points_in_the_hole_after_perforation(measured) -> None:
    experiment, measurements = measured
    scene = experiment.preset.scene
    grid, max_edge_mm = grid_for_first_frame(measurements[0], experiment.projector, _settings())
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    perforated = range(experiment.timeline.perforation_frame, len(measurements))
    assert len(perforated) >= 4
    for frame in perforated:
        measurement, state = measurements[frame], experiment.timeline.states[frame]
        points = measurement.points_obj_mm
        r = scene.radius_mm(points[:, 0], points[:, 1])
        # 0.5 mm: a point on the rim of the hole may be placed that far in by the error in its X, Y.
        assert np.count_nonzero(r < state.hole_radius_mm - 0.5) == 0, f"frame {frame}"
        z_grid = grid_measurement(measurement, experiment.projector, grid, max_edge_mm=max_edge_mm)
        inside = scene.radius_mm(gx, gy) < state.hole_radius_mm
        assert not np.any(np.isfinite(z_grid[inside])), f"frame {frame}: grid nodes with data inside the hole"


def test_peak_deflection_follows_the_punch(measured) -> None:
    experiment, measurements = measured
    grid, max_edge_mm = grid_for_first_frame(measurements[0], experiment.projector, _settings())
    peaks = []
    for measurement in measurements[: experiment.timeline.perforation_frame]:
        z_grid = grid_measurement(measurement, experiment.projector, grid, max_edge_mm=max_edge_mm)
        peaks.append(field_peak(z_grid, grid))
    states = experiment.timeline.states[: len(peaks)]
    scene = experiment.preset.scene
    for peak, state in zip(peaks, states, strict=True):
        # The highest measured point is next to the punch (the steep rim right at it is not measured) and its
        # height is right for where it is, up to the linear interpolation across the dome's cap between edges
        # ~7 mm apart (within 15 mm of the punch, where no accuracy is promised: ~1.5 % of the deflection).
        truth = true_deflection_mm(scene, state, np.array([peak.x_mm]), np.array([peak.y_mm]))[0]
        assert abs(peak.w_mm - truth) < 0.1 + 0.03 * state.w0_mm
        if state.w0_mm > 5.0:
            assert scene.radius_mm(peak.x_mm, peak.y_mm) < scene.punch_radius_mm + 20.0
            assert peak.w_mm > 0.9 * state.w0_mm
    centre = np.array([(p.centre_x_mm, p.centre_y_mm) for p in peaks if p.w_mm > 5.0])
    # The centroid of the dome finds the punch axis to a fraction of a mm.
    np.testing.assert_allclose(np.median(centre, axis=0), experiment.preset.scene.centre_xy_mm, atol=0.3)


def _refused_for_uneven_light(
    experiment: RenderedExperiment, previous: FrameMeasurement, frame: int, ended: set[tuple[int, int]]
) -> set[tuple[int, int]]:
    """The ended tracks whose edge the frame refused, saying why: uneven light (`UNUSABLE_UNEVEN_LIGHT` within a
    block of where the track was). At high deflection the punch's own shadow has a blurred rim beside the region
    (edges there were up to 1 mm off before the refusal, issue 29); a refused edge is a point not measured, with its
    reason, not an identity lost."""
    edges = experiment.test_edges[frame]
    if not ended or edges.unusable is None:
        return set()
    keys = list(zip(previous.k.tolist(), previous.line.tolist(), strict=True))
    where = {key: i for i, key in enumerate(keys) if key in ended}
    q_px = project_points(experiment.preset.camera, previous.points_obj_mm[list(where.values())])
    refused = set()
    for key, (u, v) in zip(where, q_px, strict=True):
        line, t = (v, u) if edges.axis == "rows" else (u, v)
        rows = slice(max(int(line) // UNUSABLE_BLOCK_PX - 1, 0), int(line) // UNUSABLE_BLOCK_PX + 2)
        cols = slice(max(int(t) // UNUSABLE_BLOCK_PX - 1, 0), int(t) // UNUSABLE_BLOCK_PX + 2)
        if np.any(edges.unusable[rows, cols] == UNUSABLE_UNEVEN_LIGHT):
            refused.add(key)
    return refused


def _in_region(experiment: RenderedExperiment, measurement: FrameMeasurement, *, margin_mm: float = 0.0) -> np.ndarray:
    return evaluation_region(
        experiment, measurement.points_obj_mm[:, 0], measurement.points_obj_mm[:, 1], margin_mm=margin_mm
    )


def _settings():
    from fringelab.science.topography import TopographySettings

    return TopographySettings()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["kodak_full", "phantom_full"])
def test_full_size_experiments_meet_the_acceptance_numbers(name: str, request) -> None:
    experiment = request.getfixturevalue(name)
    measurements = list(track_and_measure(experiment.test_edges, experiment.projector, experiment.camera))
    scene = experiment.preset.scene
    for measurement, state in zip(measurements, experiment.timeline.states, strict=True):
        points = measurement.points_obj_mm
        region = evaluation_region(experiment, points[:, 0], points[:, 1])
        error = points[region, 2] - true_deflection_mm(scene, state, points[region, 0], points[region, 1])
        limit = FLAT_RMS_LIMIT_MM if measurement.frame == 0 else DEFORMING_RMS_LIMIT_MM
        assert np.sqrt(np.mean(error**2)) < limit
        if measurement.frame >= experiment.timeline.perforation_frame:
            r = scene.radius_mm(points[:, 0], points[:, 1])
            assert np.count_nonzero(r < state.hole_radius_mm - 0.5) == 0


DIM_FRAMES = 6


def test_the_dim_scenario_end_to_end_keeps_no_point_with_a_wrong_order(tmp_path) -> None:
    """The `dim` virtual test (a third of the 8-bit range, photon and fixed-pattern noise, vignetting, soft shadows
    at 20, 30 and 50 % over the dome top, a soft-rimmed highlight) as `fringelab virtual-test --scenario dim`
    writes it (one sample per pixel, 6 frames up to 61 mm), its projector calibrated from its own frames, then the
    topography: no point is kept with a wrong order (a whole stripe's Z step off, ~13 mm), what is left out is
    said by reason, and most of the plate is measured. (Points within the shadows' rims may still be a few mm off:
    the mid-level there is issue 29's "mid-level that follows the light", not the order.)"""
    from fringelab.formats.camera import read_camera_json
    from fringelab.formats.recordings import open_recording
    from fringelab.formats.topography import TopographyResult
    from fringelab.pipelines.projector_calibration import calibrate_projector_recording
    from fringelab.pipelines.topography import topography_recording
    from fringelab.pipelines.virtual_test import write_virtual_test
    from fringelab.science.virtual_test import Imaging, calibration_heights_mm, preset, scenario

    experiment = write_virtual_test(
        tmp_path / "dim", "kodak", n_test_frames=DIM_FRAMES, calibration_z_mm=calibration_heights_mm(4.0),
        camera_z_mm=(-20.0, 40.0, 100.0), imaging=Imaging(supersample=1), scenario="dim", seed=29,
    )  # fmt: skip
    camera = read_camera_json(experiment.camera_json)
    projector = calibrate_projector_recording(open_recording(experiment.projector_calibration), camera)
    summary = topography_recording(open_recording(experiment.test), camera, projector, out_path=tmp_path / "r.h5")
    setup, timeline = scenario("dim", preset("kodak", imaging=Imaging(supersample=1)), DIM_FRAMES)
    step_mm = float(projector.period_px / np.nanpercentile(np.abs(projector.sensitivity_px_per_mm), 95))
    with TopographyResult(summary.path) as result:
        coverage = result.coverage()
        for i, state in enumerate(timeline.states):
            points = result.points(i)
            error = points[:, 2] - result.z_flat_mm - true_deflection_mm(setup.scene, state, points[:, 0], points[:, 1])
            assert np.all(np.abs(error[np.isfinite(error)]) < 0.25 * step_mm), f"frame {i}: a wrong order kept"
    assert np.all(coverage["measured_fraction"] > 0.8)
    # The plate at rest lies inside the calibrated range (its Z-stack starts 2 steps below it): none of frame 0's
    # points is outside it (4.0–4.3 % were, from a stack starting at the rest height).
    assert coverage["missing_out_of_range_mm2"][0] == 0.0
    total = coverage["measured_area_mm2"] + sum(coverage[k] for k in coverage if k.startswith("missing_"))
    np.testing.assert_allclose(total, coverage["visible_area_mm2"], rtol=1e-9)
