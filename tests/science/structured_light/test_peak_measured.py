"""A peak is measured, or the result says it is not (issue 27): soft partial shadows over the dome top.

A virtual test (the kodak set-up, 512 × 480 px) whose frames carry soft-edged partial shadows over the top of the
dome (radius 10–32 mm, 0–12 mm off the punch axis, the stripes at 20–50 % of their brightness), between frames
without one. Whatever the edge location makes of the shaded stripes (points lost, or points moved), a frame's
stored peak must be within 0.5 mm of the true one, or peak/measured must be 0; frames without a shadow keep a
measured peak.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from fringelab.formats.sidecars import FrameTable, frames_csv_text
from fringelab.formats.topography import TopographyResult
from fringelab.pipelines.topography import topography_recording
from fringelab.science.fields import Grid
from fringelab.science.gridding import grid_edge_points
from fringelab.science.peaks import peak_measurement
from fringelab.science.projector import build_projector_calibration, exact_camera_model
from fringelab.science.virtual_test import (
    FringeRenderer,
    Imaging,
    PlateScene,
    PlateState,
    SoftShadow,
    preset,
    scenario,
    true_deflection_mm,
)

from .conftest import MemorySource

# The figure, against the truth as this grid can show it: the true deflection at the frame's own measured
# (X, Y) points, gridded as the measurement is (linear between edges ~5 mm apart, which alone reads the top of
# the dome up to ~0.3 mm low). A shadow's wrong points (the issue saw 1.3–3.5 mm) stand out against it.
PEAK_TOLERANCE_MM = 0.5
# And a measured peak has the dome's true top inside its measured area: the true deflection at the grid nodes
# with data reaches within this of w0 (the nodes are 2 mm apart: the top falls < 0.1 mm within 1.4 mm of the axis).
TOP_TOLERANCE_MM = 0.2
# (w0 mm, shadow: radius mm, offset X mm, offset Y mm from the punch axis, light level) per frame; frame 0 is flat.
FRAMES = [
    (0.0, None),
    (20.0, None),
    (20.0, (18.0, 3.0, -2.0, 0.3)),
    (30.0, (10.0, 0.0, 0.0, 0.2)),
    (30.0, None),
    (40.0, (18.0, 6.0, 3.0, 0.3)),
    (40.0, (32.0, -4.0, 8.0, 0.5)),
    (50.0, (25.0, 10.0, -5.0, 0.4)),
    (50.0, None),
    (55.0, (18.0, 2.0, 1.0, 0.3)),
    (55.0, (32.0, 0.0, 0.0, 0.3)),
    (45.0, (14.0, 12.0, 0.0, 0.25)),
]


@dataclass(frozen=True)
class Shaded:
    path: Path
    scene: PlateScene
    states: list[PlateState]
    n_edges_lines: tuple[int, int]
    max_peak_w_mm: float


@pytest.fixture(scope="module")
def shaded(tmp_path_factory) -> Shaded:
    setup = preset("kodak", imaging=Imaging(supersample=1))
    renderer = FringeRenderer(setup)
    rng = np.random.default_rng(27)
    z_mm = np.arange(0.0, 64.0 + 1e-9, 2.0)
    camera = exact_camera_model(setup.camera)
    projector = build_projector_calibration([renderer.render_flat(z, rng=rng) for z in z_mm], z_mm, camera)
    states = [PlateState(w0) for w0, _ in FRAMES]
    images = []
    for state, (_, shadow) in zip(states, FRAMES, strict=True):
        # The shadow is the scene's (it lies on the plate): a renderer per frame, each with its own.
        shadows = () if shadow is None else (
            SoftShadow(centre_xy_mm=(shadow[1], shadow[2]), semi_axes_mm=(shadow[0], shadow[0]),
                       transmission=shadow[3], rim_mm=6.0),)  # fmt: skip
        shaded_setup = replace(setup, scene=replace(setup.scene, soft_shadows=shadows))
        images.append(FringeRenderer(shaded_setup).render_test(state, rng=rng))
    n = len(states)
    log = FrameTable(frame=np.arange(n), time_s=np.arange(n) * 1e-3, force_kN=np.full(n, np.nan),
                     punch_displacement_mm=np.array([w for w, _ in FRAMES]))  # fmt: skip
    source = MemorySource(images, {"frames.csv": frames_csv_text(log)})
    path = tmp_path_factory.mktemp("shadows") / "result.h5"
    summary = topography_recording(source, camera, projector, out_path=path)
    return Shaded(path, setup.scene, states, (projector.n_edges, projector.n_lines), summary.max_peak_w_mm)


def truth_as_gridded(shaded: Shaded, result: TopographyResult, i: int) -> np.ndarray:
    """The true deflection at frame position i's measured (X, Y) points, gridded as the measurement is."""
    points = result.points(i)
    k, line = result.point_labels(i)
    x, y, w = (np.full(shaded.n_edges_lines, np.nan) for _ in range(3))
    x[k, line], y[k, line] = points[:, 0], points[:, 1]
    w[k, line] = true_deflection_mm(shaded.scene, shaded.states[i], points[:, 0], points[:, 1])
    max_edge_mm = float(result.file.attrs["grid_max_edge_mm"])
    return grid_edge_points(x, y, w, result.grid, max_edge_mm=max_edge_mm)


def test_every_peak_is_within_half_a_mm_of_the_truth_or_said_not_measured(shaded: Shaded) -> None:
    with TopographyResult(shaded.path) as result:
        peaks, measured = result.column("peak/w_mm"), result.peak_measured()
        reasons = [p.reason if p is not None else None for p in result.peak_measurements()]
        gridded_truth = [float(np.nanmax(truth_as_gridded(shaded, result, i))) for i in range(len(FRAMES))]
        gx, gy = np.meshgrid(result.x_mm, result.y_mm)
        top_measured = []
        for i, state in enumerate(shaded.states):
            seen = np.isfinite(result.w_grid(i))
            top_measured.append(float(np.max(true_deflection_mm(shaded.scene, state, gx[seen], gy[seen]))))
    assert set(np.unique(measured)) <= {0.0, 1.0}  # known for every frame of a new file
    for i, (w0, shadow) in enumerate(FRAMES):
        if measured[i]:
            error = peaks[i] - gridded_truth[i]
            assert abs(error) < PEAK_TOLERANCE_MM, f"frame {i} (shadow {shadow}): {peaks[i]:.2f} mm, {error:+.2f} mm"
            assert w0 - top_measured[i] < TOP_TOLERANCE_MM, f"frame {i}: the dome's top was not measured"
            assert reasons[i] == ""
        else:
            assert shadow is not None, f"frame {i} has no shadow but its peak is not measured: {reasons[i]}"
            assert "lower bound" in str(reasons[i])
    unshaded = [i for i, (_, shadow) in enumerate(FRAMES) if shadow is None]
    assert all(measured[unshaded] == 1.0)
    # The shadows this test draws do take data off the dome top: the rule is exercised, not passed by default.
    assert np.count_nonzero(measured == 0.0) >= 4
    # The run's headline peak is the largest measured one, never a lower bound.
    assert shaded.max_peak_w_mm == np.nanmax(np.where(measured == 1.0, peaks, np.nan))


def test_a_maximum_on_the_rim_of_a_gap_is_not_measured() -> None:
    grid = Grid(x_mm=np.arange(-30.0, 30.1, 2.0), y_mm=np.arange(-20.0, 20.1, 2.0))
    measured = np.ones(grid.shape, bool)
    assert peak_measurement(measured, grid, (0.0, 0.0)).measured
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    # A gap 6 mm wide (3 × 3 nodes, 7 of them within 10 mm) 8 mm from the maximum: within the punch radius, so a
    # lower bound.
    gap = (np.abs(gx - 8.0) <= 2.0) & (np.abs(gy) <= 2.0)
    verdict = peak_measurement(measured & ~gap, grid, (0.0, 0.0))
    assert not verdict.measured and verdict.missing_nodes == 7 and "lower bound" in verdict.reason
    # ... 14 mm away it is beyond the radius (its nearest nodes are 12 mm off): measured.
    assert peak_measurement(measured & ~((np.abs(gx - 14.0) <= 2.0) & (np.abs(gy) <= 2.0)), grid, (0.0, 0.0)).measured
    # A streak two nodes wide (a lost edge) is bridged: over 4 mm the plate cannot rise more than 0.2 mm.
    streak = (np.abs(gx - 5.0) <= 1.0) & (np.abs(gy) <= 8.0)
    assert peak_measurement(measured & ~streak, grid, (0.0, 0.0)).measured
    # Nodes that are no plate (the reference frame never saw them) are no gap: a maximum by the view's edge.
    plate = gx < 26.0
    assert peak_measurement(measured & plate, grid, (24.0, 0.0), plate_nodes=plate).measured
    assert not peak_measurement(measured & plate, grid, (24.0, 0.0)).measured
    nothing = peak_measurement(np.zeros(grid.shape, bool), grid, (float("nan"), float("nan")))
    assert not nothing.measured and nothing.missing_nodes == -1


def test_the_demos_quasi_static_test_counts_no_frame_measured_whose_peak_region_lacks_data(tmp_path: Path) -> None:
    """The dashboard demo's default (kodak, 20 frames, the paper's quasi-static test, rendered as `simulate`
    renders it): a frame with more than a tenth of the nodes within the punch radius of the punch axis missing
    (the issue's frame 13 had 27 of 46) never counts as measured."""
    setup, timeline = scenario("quasi-static", preset("kodak"), 20)
    renderer = FringeRenderer(setup)
    rng = np.random.default_rng(0)
    z_mm = np.asarray(setup.calibration_z_mm)
    camera = exact_camera_model(setup.camera)
    projector = build_projector_calibration([renderer.render_flat(z, rng=rng) for z in z_mm], z_mm, camera)
    source = MemorySource([renderer.render_test(state, rng=rng) for state in timeline.states], {})
    path = topography_recording(source, camera, projector, out_path=tmp_path / "demo.h5").path
    cx, cy = setup.scene.centre_xy_mm
    radius = setup.scene.punch_radius_mm
    lacking = []
    with TopographyResult(path) as result:
        measured = result.peak_measured()
        gx, gy = np.meshgrid(result.x_mm, result.y_mm)
        region = np.hypot(gx - cx, gy - cy) <= radius
        for i in range(result.n_frames):
            lacking.append(np.mean(~np.isfinite(result.w_grid(i))[region]) > 0.1)
    assert not np.any(measured[np.array(lacking)]), f"measured: {measured}, lacking: {lacking}"
    # Perforated frames lack the top (a hole): the test does exercise the rule.
    assert all(lacking[timeline.perforation_frame :])
    # and frames with the peak region whole keep their measured peak
    assert all(measured[: min(timeline.perforation_frame, 10)] == 1.0)
