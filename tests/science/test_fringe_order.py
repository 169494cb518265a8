"""Fringe order found in every frame on its own (docs/method.md §5), on hard virtual tests at 512 × 480 (kodak).

- fast: ~5 mm more deflection per frame (edges jump up to ~3 px, more than the old tracking followed near the
  punch), then an 18 mm hole and 6 mm of springback within one frame;
- petals: the same with four radial cracks 15 … 35 mm long and petals lifted by −3 … +5 mm, so w jumps across
  each crack;
- hard: petals, highlight and the punch's shadow at once.
Rendered with one sample per pixel (the stripes' blur and pixel integration are analytic), 16 frames each, the
projector calibration shared (it sees only the flat plate).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from fringelab.science.fields import grid_covering
from fringelab.science.fringes import FrameEdges
from fringelab.science.order import ORDER_UNRESOLVED, ORDERED, OrderSettings, RimNotVisibleError, order_frame
from fringelab.science.projector import (
    ExactCamera,
    ProjectorCalibration,
    build_projector_calibration,
    exact_camera_model,
)
from fringelab.science.topography import (
    FrameMeasurement,
    TemporalCrossCheck,
    TopographySettings,
    grid_measurement,
    locate_test_edges,
    measure_frame,
    reference_for,
    temporal_check,
    track_and_measure,
)
from fringelab.science.virtual_test import (
    FringeRenderer,
    Imaging,
    PlateState,
    Preset,
    PunchTimeline,
    SoftShadow,
    harder_imaging,
    preset,
    scenario,
    true_deflection_mm,
)

N_FRAMES = 16
RMS_LIMIT_MM = 0.05  # docs/method.md §7 asks 0.10 over the deforming plate; the issue keeps today's 0.05 at 512 × 480
EXCLUDED_MM = 15.0


@dataclass(frozen=True, eq=False)
class Case:
    preset: Preset
    camera: ExactCamera
    projector: ProjectorCalibration
    timeline: PunchTimeline
    frames: list[np.ndarray]
    edges: list[FrameEdges]
    measurements: list[FrameMeasurement]


@pytest.fixture(scope="module")
def calibration() -> tuple[ExactCamera, ProjectorCalibration]:
    setup = preset("kodak", imaging=Imaging(supersample=1))
    renderer = FringeRenderer(setup)
    rng = np.random.default_rng(31)
    z_mm = np.arange(0.0, 80.0 + 1e-9, 2.0)
    camera = exact_camera_model(setup.camera)
    return camera, build_projector_calibration([renderer.render_flat(z, rng=rng) for z in z_mm], z_mm, camera)


def render_case(name: str, calibration: tuple[ExactCamera, ProjectorCalibration], seed: int) -> Case:
    camera, projector = calibration
    setup, timeline = scenario(name, preset("kodak", imaging=Imaging(supersample=1)), N_FRAMES)
    renderer = FringeRenderer(setup)
    rng = np.random.default_rng(seed)
    frames = [renderer.render_test(state, rng=rng) for state in timeline.states]
    edges = list(locate_test_edges(frames, projector))
    measurements = list(track_and_measure(edges, projector, camera))
    return Case(setup, camera, projector, timeline, frames, edges, measurements)


@pytest.fixture(scope="module")
def fast(calibration) -> Case:
    return render_case("fast", calibration, seed=32)


@pytest.fixture(scope="module")
def petals(calibration) -> Case:
    return render_case("petals", calibration, seed=33)


def stripe_z_step_mm(projector: ProjectorCalibration) -> float:
    """How far in Z a wrong order puts a point: one period over the edge's sensitivity (the smallest step)."""
    return float(projector.period_px / np.nanpercentile(np.abs(projector.sensitivity_px_per_mm), 95))


def errors(case: Case, measurement: FrameMeasurement) -> tuple[np.ndarray, np.ndarray]:
    """w error of every point and the radius of the point from the punch axis."""
    scene, state = case.preset.scene, case.timeline.states[measurement.frame]
    p = measurement.points_obj_mm
    return p[:, 2] - true_deflection_mm(scene, state, p[:, 0], p[:, 1]), scene.radius_mm(p[:, 0], p[:, 1])


def test_fast_motion_and_springback_keep_the_surface(fast: Case) -> None:
    scene, projector = fast.preset.scene, fast.projector
    perforation = fast.timeline.perforation_frame
    hole_radius = fast.timeline.states[perforation].hole_radius_mm
    assert hole_radius == 9.0 and fast.timeline.states[perforation].w0_mm == 54.0  # 18 mm hole, 6 mm springback
    # The measured area, on a 2 mm grid outside the hole and a 15 mm margin and inside the clamp.
    grid = grid_covering(fast.measurements[0].points_obj_mm[:, :2], step_mm=2.0, margin_mm=4.0)
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    r = scene.radius_mm(gx, gy)
    region = (r > hole_radius + EXCLUDED_MM) & (r < scene.clamp_radius_mm - EXCLUDED_MM)

    def measured_nodes(frame: int) -> int:
        z = grid_measurement(fast.measurements[frame], projector, grid, max_edge_mm=21.0)
        return int(np.count_nonzero(np.isfinite(z[region])))

    before = measured_nodes(perforation - 1)
    assert before > 0.95 * region.sum()
    for frame in range(perforation, N_FRAMES):
        assert measured_nodes(frame) >= 0.95 * before, f"frame {frame}: the measured area fell"
    step = stripe_z_step_mm(projector)
    for measurement in fast.measurements:
        error, radius = errors(fast, measurement)
        state = fast.timeline.states[measurement.frame]
        # No wrong order anywhere: a wrong order is off by a whole stripe's Z step (~17 mm here).
        assert np.all(np.abs(error[np.isfinite(error)]) < 0.25 * step), f"frame {measurement.frame}"
        inside = (radius > max(scene.punch_radius_mm, state.hole_radius_mm) + EXCLUDED_MM) & (
            radius < scene.clamp_radius_mm - EXCLUDED_MM
        )
        rms = float(np.sqrt(np.mean(error[inside] ** 2)))
        assert rms <= RMS_LIMIT_MM, f"frame {measurement.frame}: RMS {rms:.4f} mm"
        assert measurement.n_order_conflicts == 0
        # Unresolved only where edges are kept beside a dark area (the clamp ring, the hole), which are never
        # ordered (docs/method.md §5), and the odd piece of a curve of fewer than 3 lines between two stretches of
        # them (too short for a sure link): at most a tenth more.
        beside = fast.edges[measurement.frame].beside_dark
        assert beside is not None and measurement.n_order_unresolved <= 1.1 * np.count_nonzero(beside)


def test_a_frame_measured_alone_equals_the_same_frame_in_the_sequence(fast: Case) -> None:
    reference = reference_for(fast.edges[0], fast.projector, fast.camera, TopographySettings())
    for frame in (fast.timeline.perforation_frame, 7):
        alone = measure_frame(fast.edges[frame], reference, fast.projector, fast.camera, frame=frame)
        within = fast.measurements[frame]
        np.testing.assert_array_equal(alone.k, within.k)
        np.testing.assert_array_equal(alone.line, within.line)
        np.testing.assert_array_equal(alone.points_obj_mm, within.points_obj_mm)
    # And a sequence that starts after the first frame, given the reference, gives the same frames.
    late = list(track_and_measure(fast.edges[10:], fast.projector, fast.camera, first_frame=10, reference=reference))
    for measurement in late:
        np.testing.assert_array_equal(measurement.points_obj_mm, fast.measurements[measurement.frame].points_obj_mm)


def test_no_point_bridges_a_crack_and_both_sides_keep_their_order(petals: Case) -> None:
    scene = petals.preset.scene
    step = stripe_z_step_mm(petals.projector)
    perforated = range(petals.timeline.perforation_frame, N_FRAMES)
    for frame in perforated:
        measurement, state = petals.measurements[frame], petals.timeline.states[frame]
        p = measurement.points_obj_mm
        error, radius = errors(petals, measurement)
        # Nothing inside a crack or the hole (the truth there is NaN). 0.5 mm of X, Y error allowed at the rims,
        # and 2 mm at a crack's tip, where it narrows to nothing within the blur of a pixel (~1 mm here).
        near = scene.in_crack(p[:, 0], p[:, 1], state)
        narrower = replace(scene, crack_width_mm=scene.crack_width_mm - 1.0)
        shorter = replace(state, crack_length_mm=state.crack_length_mm - 2.0)
        inside = narrower.in_crack(p[:, 0], p[:, 1], shorter)
        assert np.count_nonzero(inside) == 0, f"frame {frame}: points in a crack"
        assert np.count_nonzero(radius < state.hole_radius_mm - 0.5) == 0
        finite = np.isfinite(error)
        assert np.all(np.abs(error[finite]) < 0.25 * step), f"frame {frame}: a wrong order"
        # Both sides of every crack are measured, each at its own height: points near the cracks on every petal,
        # whose w differs from petal to petal by up to 8 mm at the hole's rim.
        petal = scene.petal_index(p[:, 0], p[:, 1])
        reach = state.hole_radius_mm + state.crack_length_mm + 10.0
        beside = finite & ~near & (radius > state.hole_radius_mm + 3.0) & (radius < reach)
        for index in range(scene.crack_count):
            on_petal = beside & (petal == index)
            assert np.count_nonzero(on_petal) > 20, f"frame {frame}: petal {index} not measured"
            # Within 15 mm of the punch the surface is steep and the grid of edges coarse for it: 0.5 mm median
            # error there, far below the ~17 mm of an order error or the petals' own offsets.
            assert np.median(np.abs(error[on_petal])) < 0.5, f"frame {frame}: petal {index}"


def test_hard_case_masks_rather_than_guesses(calibration) -> None:
    case = render_case("hard", calibration, seed=34)
    step = stripe_z_step_mm(case.projector)
    for measurement in case.measurements:
        error, _ = errors(case, measurement)
        assert np.all(np.abs(error[np.isfinite(error)]) < 0.25 * step), f"frame {measurement.frame}"
    last = case.measurements[-1]
    assert len(last.k) > 0.9 * len(case.measurements[0].k)


def test_stripes_that_cannot_be_ordered_are_masked_with_the_reason(fast: Case) -> None:
    # Frames whose rim is hidden (a dark ring over the outer 60 mm of the plate): no anchor, nothing measured.
    camera = fast.camera.camera
    from fringelab.science.camera import project_points

    scene = fast.preset.scene
    centre = project_points(camera, np.array([[*scene.centre_xy_mm, 0.0]]))[0]
    edge = project_points(camera, np.array([[scene.centre_xy_mm[0] + 190.0, scene.centre_xy_mm[1], 0.0]]))[0]
    v, u = np.mgrid[0:480, 0:512]
    hidden = np.hypot(u - centre[0], v - centre[1]) > np.hypot(*(edge - centre))
    frame = fast.frames[8].copy()
    frame[hidden] = 5
    edges = next(iter(locate_test_edges([frame], fast.projector)))
    reference = reference_for(fast.edges[0], fast.projector, fast.camera, TopographySettings())
    measurement = measure_frame(edges, reference, fast.projector, fast.camera, frame=8)
    assert len(measurement.k) == 0
    assert measurement.n_order_unresolved > 10_000
    assert measurement.n_unmatched == len(edges)


def test_a_rim_out_of_view_is_refused_with_how_to_set_the_anchor(fast: Case) -> None:
    # A camera zoomed in on the middle of the plate (focal length 34 mm instead of 17): no clamp ring in view.
    setup = preset("kodak", imaging=Imaging(supersample=1))
    setup = replace(setup, camera=replace(setup.camera, f_mm=34.0))
    renderer = FringeRenderer(setup)
    rng = np.random.default_rng(35)
    z_mm = np.arange(0.0, 20.0 + 1e-9, 2.0)
    camera = exact_camera_model(setup.camera)
    projector = build_projector_calibration([renderer.render_flat(z, rng=rng) for z in z_mm], z_mm, camera)
    flat = renderer.render_test(fast.timeline.states[0], rng=rng)
    edges = next(iter(locate_test_edges([flat], projector)))
    settings = TopographySettings()
    with pytest.raises(RimNotVisibleError, match="rim_circle_mm"):
        reference_for(edges, projector, camera, settings)
    # Naming a region that stays still (here: the outer part of what is in view) anchors the order again.
    scene = setup.scene
    named = replace(settings, order=OrderSettings(rim_circle_mm=(*scene.centre_xy_mm, 130.0), rim_width_mm=30.0))
    reference = reference_for(edges, projector, camera, named)
    assert np.count_nonzero(reference.rim) > 1000


def test_the_result_file_says_what_is_missing_and_refuses_a_recording_ordered_nowhere(fast: Case, tmp_path) -> None:
    from fringelab.formats.topography import TopographyResult
    from fringelab.pipelines.topography import topography_recording
    from fringelab.science.topography import TopographyError

    from .structured_light.conftest import MemorySource

    perforation = fast.timeline.perforation_frame
    frames = fast.frames[perforation - 2 : perforation + 2]
    source = MemorySource([fast.frames[0], *frames], {})
    summary = topography_recording(source, fast.camera, fast.projector, out_path=tmp_path / "r.h5")
    with TopographyResult(summary.path) as result:
        coverage = result.coverage()
    fraction = coverage["measured_fraction"]
    assert fraction[0] > 0.99 and np.all(fraction > 0.95)
    # Before the hole nothing is dark; after it the hole (and the rejected band around it) is, by its reason.
    hole = coverage["missing_hole_mm2"]
    assert hole[3] > 300.0 > hole[2]  # the 18 mm hole is 254 mm², its rim loses half a stripe more
    assert np.all(coverage["n_order_conflicts"] == 0)
    # Unresolved only the edges kept beside the clamp ring (and the hole), which are never ordered: 1050–1150 mm²
    # here, 0.6 % of the plate.
    assert np.all(coverage["missing_order_unresolved_mm2"] < 0.01 * coverage["visible_area_mm2"])
    jumps = coverage["n_temporal_jumps"]  # the cross-check against the frame before: none before the first
    assert np.isnan(jumps[0]) and np.all(jumps[1:] == 0)
    total = coverage["measured_area_mm2"] + sum(coverage[k] for k in coverage if k.startswith("missing_"))
    np.testing.assert_allclose(total, coverage["visible_area_mm2"], rtol=1e-9)  # every bit of the plate accounted

    # The rim hidden in every frame after the first: the order is anchored nowhere, so nothing is written.
    camera, scene = fast.camera.camera, fast.preset.scene
    from fringelab.science.camera import project_points

    centre = project_points(camera, np.array([[*scene.centre_xy_mm, 0.0]]))[0]
    v, u = np.mgrid[0:480, 0:512]
    hidden = np.hypot(u - centre[0], v - centre[1]) > 150.0
    dimmed = [np.where(hidden, 5, frame).astype(np.uint8) for frame in frames]
    with pytest.raises(TopographyError, match="could not be ordered in any frame"):
        topography_recording(
            MemorySource([fast.frames[0], *dimmed], {}), fast.camera, fast.projector, out_path=tmp_path / "x.h5"
        )
    assert not (tmp_path / "x.h5").exists()


def test_temporal_continuity_cross_checks_the_order(fast: Case) -> None:
    """The frame before is a cross-check, never a source: on the fast test (~5 mm more deflection per frame, the
    hole and the springback within one frame) no pair of frames shows a jump, there being no wrong order; a wrong
    order put in by hand (one edge's points moved by their stripe's Z step, as a miscount by one edge pair moves
    them) is counted point by point, and its neighbours (half a step off in the mean) are not."""
    step_mm = fast.projector.period_px / np.abs(fast.projector.sensitivity_px_per_mm)
    cross_check = TemporalCrossCheck(fast.projector)
    checked = [cross_check.checked(m) for m in fast.measurements[:3] + fast.measurements[4:]]
    assert checked[0].temporal is None and checked[3].temporal is None  # the first frame, and frame 4 after a gap
    for before, after in zip(fast.measurements, fast.measurements[1:], strict=False):
        check = temporal_check(before, after, fast.projector)
        assert check.n_jumps == 0 and check.n_checked > 0.9 * len(after.k)
    assert checked[1].temporal == temporal_check(fast.measurements[0], fast.measurements[1], fast.projector)

    before = fast.measurements[2]
    assert temporal_check(before, before, fast.projector).n_jumps == 0
    edge = int(np.median(before.k))
    wrong = np.flatnonzero(before.k == edge)
    points = before.points_obj_mm.copy()
    points[wrong, 2] += step_mm[before.k[wrong], before.line[wrong]]
    check = temporal_check(before, replace(before, points_obj_mm=points), fast.projector)
    measured = np.zeros((fast.projector.n_edges, fast.projector.n_lines), bool)
    measured[before.k, before.line] = True
    with_both_neighbours = measured[edge - 1, before.line[wrong]] & measured[edge + 1, before.line[wrong]]
    assert check.n_jumps == np.count_nonzero(with_both_neighbours) > 50


# Order through dim regions (issue 29): a region joined to the rest only through unsure links is a group of its
# own, never ordered through them. Edge curves written by hand: vertical stripes, an edge every 5 px (period 10 px),
# one curve per edge.
ISLAND_LINES = range(40, 80)


def hand_edges(spurious: bool, *, sigma_px: float | None = None, band_sigma_px: float | None = None) -> FrameEdges:
    """Edges m = 0..9 on all 120 lines (the main region), m = 10..13 on lines 40..79 only (a band) and m = 14..29
    on those lines beyond it (an island that reaches the rest only across the band); with `spurious`, a stripe of
    the band (between edges 11 and 12) is split in three by an invented pair of edges, as noise in a dim band can.
    True edge number per point: the returned edges' `chain` is not it; `hand_edge_number` is."""
    rows = []  # (line, t, polarity, m); m = −1 for the invented edges
    for line in range(120):
        for m in range(30):
            if m >= 10 and line not in ISLAND_LINES:
                continue
            rows.append((line, 20.0 + 5.0 * m, 1 if m % 2 == 0 else -1, m))
            if spurious and m == 11 and line in ISLAND_LINES:
                rows.append((line, 20.0 + 5.0 * m + 5.0 / 3.0, 1, -1))
                rows.append((line, 20.0 + 5.0 * m + 10.0 / 3.0, -1, -2))
    rows.sort()
    line = np.array([r[0] for r in rows], np.int32)
    t = np.array([r[1] for r in rows], np.float32)
    polarity = np.array([r[2] for r in rows], np.int8)
    m = np.array([r[3] for r in rows])
    chain = np.unique(m, return_inverse=True)[1].astype(np.int32)  # one curve per edge
    extra = {}
    if sigma_px is not None:
        sigma = np.full(len(line), sigma_px, np.float32)
        band = (m >= 10) & (m <= 13) | (m < 0)
        sigma[band] = sigma_px if band_sigma_px is None else band_sigma_px
        extra["sigma_px"] = sigma
    edges = FrameEdges(axis="rows", period_px=10.0, image_shape_hw_px=(120, 200), line=line, t_px=t,
                       polarity=polarity, chain=chain, noise_px=0.02, saturated_fraction=0.0, dark_fraction=0.0,
                       **extra)  # fmt: skip
    object.__setattr__(edges, "true_m", m)  # the truth, beside the edges
    return edges


def test_an_island_reached_only_across_an_invented_stripe_is_not_ordered_through_it() -> None:
    from fringelab.science.fringes import order_edges

    edges = hand_edges(spurious=True)
    m = edges.true_m  # type: ignore[attr-defined]
    order = order_edges(edges)
    index, component = order.crossing_index(edges), order.crossing_component(edges)
    main = component == 0
    # Every point ordered with the main region is at its true place; the invented pair splits a stripe into gaps a
    # third of their neighbours', so the links into and out of it are unsure and the island (m ≥ 12, beyond it)
    # is a group of its own. (Counted through the invented pair, the island would be two places off: one stripe.)
    assert len(np.unique(index[main] - m[main])) == 1
    assert np.all(m[main] <= 11) and np.count_nonzero(main) >= 10 * 120
    island = m >= 12
    assert np.all(component[island] != 0)
    assert len(np.unique(component[m >= 13])) == 1  # edge 12 has an unsure gap beside it too: alone
    assert order.n_unsure_links >= 2


def test_an_island_reached_across_a_clean_band_keeps_its_order() -> None:
    from fringelab.science.fringes import order_edges

    edges = hand_edges(spurious=False)
    m = edges.true_m  # type: ignore[attr-defined]
    order = order_edges(edges)
    index, component = order.crossing_index(edges), order.crossing_component(edges)
    assert np.all(component == 0)
    np.testing.assert_array_equal(index, m)
    assert order.n_unsure_links == 0


def crossed_edges(unsure_m: range, unsure_lines: range = range(40, 50), *, beside_dark: bool = False) -> FrameEdges:
    """Edges m = 0..29 on all 120 lines, one curve each, sure (σ 0.03 px) but for edges `unsure_m` on
    `unsure_lines`, a dim band across the stripes (σ 0.3 px: more than a thirtieth of the 5 px edge spacing), or,
    with `beside_dark`, edges kept beside a dark area there (σ 0.03 px, `FrameEdges.beside_dark`)."""
    line, m = (a.ravel() for a in np.meshgrid(np.arange(120), np.arange(30), indexing="ij"))
    there = np.isin(m, unsure_m) & np.isin(line, unsure_lines)
    sigma = np.where(there & (not beside_dark), 0.3, 0.03).astype(np.float32)
    return FrameEdges(axis="rows", period_px=10.0, image_shape_hw_px=(120, 200), line=line.astype(np.int32),
                      t_px=(20.0 + 5.0 * m).astype(np.float32), polarity=np.where(m % 2 == 0, 1, -1).astype(np.int8),
                      chain=m.astype(np.int32), noise_px=0.02, saturated_fraction=0.0, dark_fraction=0.0,
                      sigma_px=sigma, beside_dark=there & beside_dark)  # fmt: skip


def test_the_order_does_not_run_along_curves_through_a_band_of_unsure_edges() -> None:
    from fringelab.science.fringes import order_edges

    # The band crosses every stripe: the plate beyond it (lines 50..119) reaches the rest only through unsure edges,
    # along the curves as well as across them, so it is a group of its own, and the band's own stretches too.
    edges = crossed_edges(range(30))
    order = order_edges(edges)
    component = order.crossing_component(edges)
    line = edges.line
    assert len(np.unique(component[line < 40])) == 1 and len(np.unique(component[line >= 50])) == 1
    assert component[line < 40][0] != component[line >= 50][0]
    band = (line >= 40) & (line < 50)
    assert not np.any(np.isin(component[band], component[~band]))


def test_an_unsure_stretch_takes_its_curve_order_where_sure_links_go_round_it() -> None:
    from fringelab.science.fringes import order_edges

    # The band covers edges 5..9 only: edges 0..4 and 10..29 carry the order past it, so the curves' pieces
    # beyond the band are at their places, and the stretches within it, between two pieces of their curve at one
    # place, take that place.
    edges = crossed_edges(range(5, 10))
    order = order_edges(edges)
    index, component = order.crossing_index(edges), order.crossing_component(edges)
    assert np.all(component == 0)
    np.testing.assert_array_equal(index, (edges.t_px - 20.0) / 5.0)
    # Unsure ends of the curves (σ grows there, the smoothing being one-sided): up to 10 lines keep their curves'
    # places, nothing lying beyond them; 20 lines are a region of their own.
    edges = crossed_edges(range(30), range(112, 120))
    order = order_edges(edges)
    assert np.all(order.crossing_component(edges) == 0)
    np.testing.assert_array_equal(order.crossing_index(edges), (edges.t_px - 20.0) / 5.0)
    edges = crossed_edges(range(30), range(100, 120))
    component = order_edges(edges).crossing_component(edges)
    assert np.all(component[edges.line < 100] == 0) and not np.any(component[edges.line >= 100] == 0)


def test_edges_beside_a_dark_area_carry_no_order_and_take_none_from_their_curve() -> None:
    from fringelab.science.fringes import order_edges

    # Edges 5..9 run beside a dark area on lines 40..49 (sure by their σ): a rim that cut a stripe looks the same
    # from one side, and a curve may follow a hole's rim for a few lines and back. So, unlike a dim band's
    # stretches (test above), they are not linked to the rest nor given their curves' places; the rest keeps its.
    edges = crossed_edges(range(5, 10), beside_dark=True)
    order = order_edges(edges)
    index, component = order.crossing_index(edges), order.crossing_component(edges)
    beside = edges.beside_dark
    assert np.all(component[~beside] == 0)
    np.testing.assert_array_equal(index[~beside], (edges.t_px[~beside] - 20.0) / 5.0)
    assert not np.any(component[beside] == 0)
    # However short: one line beside the dark area at a curve's end is cut off too.
    edges = crossed_edges(range(30), range(119, 120), beside_dark=True)
    component = order_edges(edges).crossing_component(edges)
    assert np.all(component[edges.line < 119] == 0) and not np.any(component[edges.line == 119] == 0)


def ringed_frame(
    calibration: tuple[ExactCamera, ProjectorCalibration], band_transmission: float, *, seed: int
) -> tuple[np.ndarray, np.ndarray, Preset]:
    """A dim test frame (`harder_imaging`: a third of the 8-bit range, photon noise) of the plate 40 mm deep whose
    dome top (a disc of 45 mm radius, stripes at 50 % of their light) reaches the rest of the plate only through a
    ring 25 mm wide at `band_transmission` of it, both with soft rims (6 mm); and where each pixel sees the dome
    top, away from the ring's soft rim."""
    setup = preset("kodak", imaging=Imaging(supersample=1))
    island = SoftShadow(centre_xy_mm=(0.0, 0.0), semi_axes_mm=(75.0, 75.0), transmission=0.5, rim_mm=6.0)
    ring = SoftShadow(centre_xy_mm=(0.0, 0.0), semi_axes_mm=(75.0, 75.0), transmission=band_transmission / 0.5,
                      rim_mm=6.0, inner_semi_axes_mm=(50.0, 50.0))  # fmt: skip
    scene = replace(setup.scene, soft_shadows=(island, ring))
    setup = replace(setup, scene=scene, imaging=harder_imaging(supersample=1))
    renderer = FringeRenderer(setup)
    frame = renderer.render_test(RINGED_STATE, rng=np.random.default_rng(seed))
    x, y = renderer.surface_block(slice(0, frame.shape[0]), flat_z_mm=None, state=RINGED_STATE)[:2]
    dx, dy = x - setup.scene.centre_xy_mm[0], y - setup.scene.centre_xy_mm[1]
    return frame, np.hypot(dx, dy) < 45.0, setup


RINGED_STATE = PlateState(40.0)


@pytest.mark.parametrize("band_transmission", [0.25, 0.45])
def test_a_dim_region_keeps_its_order_only_through_sure_edges(calibration, band_transmission: float) -> None:
    """The dome top at 50 % of the light reaches the rest only through a ring at 25 % (stripes of ~15 grey levels
    against σ ≈ 1.5, edges located only in part, σ of the located ones ~0.2 px) or at 45 % (~23 grey levels: sure).
    Through the dim ring the dome top is masked "order unresolved"; through the brighter one it keeps its order.
    Either way no point is kept with a wrong order (a whole stripe's Z step off, ~14 mm here)."""
    camera, projector = calibration
    frame, dome_top, setup = ringed_frame(calibration, band_transmission, seed=41)
    flat = FringeRenderer(replace(setup, scene=replace(setup.scene, soft_shadows=()))).render_test(
        PlateState(0.0), rng=np.random.default_rng(42)
    )
    reference = reference_for(next(iter(locate_test_edges([flat], projector))), projector, camera, TopographySettings())
    edges = next(iter(locate_test_edges([frame], projector)))
    frame_order = order_frame(edges, reference, projector)
    q = np.round(edges.q_px()).astype(np.int64)
    on_island = dome_top[q[:, 1], q[:, 0]]
    assert np.count_nonzero(on_island) > 500  # its edges are located: it is dim, not dark
    measurement = measure_frame(edges, reference, projector, camera, frame=1)
    error = measurement.points_obj_mm[:, 2] - true_deflection_mm(
        setup.scene, RINGED_STATE, measurement.points_obj_mm[:, 0], measurement.points_obj_mm[:, 1]
    )
    assert np.all(np.abs(error) < 0.25 * stripe_z_step_mm(projector))
    if band_transmission < 0.3:
        assert np.all(frame_order.reason[on_island] == ORDER_UNRESOLVED)
    else:
        assert np.all(frame_order.reason[on_island] == ORDERED)
    assert np.count_nonzero(frame_order.reason == ORDERED) > 0.9 * len(edges)  # the rest of the plate
