"""Edges under light that changes: soft partial shadows and uneven illumination (issue 29, docs/method.md §5).

The mid-level follows light that changes linearly along a scan line. Where a soft shadow's rim bends the light
within a period, or dims one flank of a stripe, an edge moves (up to 2.9 px here). By default two rules judge an
edge by its neighbours on its line: the last edge of a run before a shadow's dark interior by its departure from
the cubic through its four neighbours (`max_end_departure_px`), and every edge by how the stripe widths either side
of it alternate (`max_width_alternation_px`, `width_alternations_px`): a misplaced edge widens one of its stripes
and narrows the other, where a slope, even where the dome's stripes fold beside the punch, changes them
monotonically. An edge so rejected takes the points of its curve within 2 lines with it
(`fringes.ALTERNATION_ALONG_CURVE_LINES`): the rim crosses the stripes at an angle, and on the next lines moves the
same edge by too little for its widths to alternate, but by 0.4–0.7 px where the deep shadow's rim lies on the
dome's fold at w0 55 mm (1.30 mm without it). By default no point of the eight soft-shadow frames is more than 1 mm
off (0.97 mm; 3.3 mm before the alternation). Two refusals, off by default, also keep every point of them within
1 mm: by the light's bend (`max_uneven_light_shift_px`, 0.08 px: `STRICT_PX`) and by an edge's departure from the
cubic through its neighbours (`max_departure_px`, 0.3 px: `DEPARTURE_PX`; `edge_departures_px`). Neither is the
default: beside
the punch, where the dome's stripes fold (compressed on one side, stretched into the punch's own shadow on the
other), good edges bend the light and depart from a cubic as much as misplaced ones, and a frame's peak would go
unmeasured (docs/method.md §5).
Lean renders: straight stripes of 96 × 256 px, and the virtual Kodak test (512 × 480, one sample per pixel, the
harder imaging of the "dim" scenario) with soft shadows of several sizes, places, strengths (stripes at 20–50 %)
and rims.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import special

from fringelab.science import fringes
from fringelab.science.fringes import (
    UNUSABLE_UNEVEN_LIGHT,
    EdgeSettings,
    FrameEdges,
    edge_departures_px,
    locate_edges,
    width_alternations_px,
)
from fringelab.science.projector import build_projector_calibration, exact_camera_model
from fringelab.science.topography import TopographySettings, reference_for, track_and_measure
from fringelab.science.virtual_test import (
    DOME_SHADOWS,
    FringeRenderer,
    PlateState,
    SoftShadow,
    harder_imaging,
    preset,
    render_straight_stripes,
    true_deflection_mm,
)

PERIOD_PX = 10.0
# The refusal by the light's bend that keeps every soft shadow's points within 1 mm, not the default (method.md §5).
STRICT_PX = 0.08
# The refusal by an edge's departure from its neighbours that does so too, also not the default.
DEPARTURE_PX = 0.3
PHASE_PX = 0.3
RIM_AT_PX = 128.3


def stripes_under(light: np.ndarray, *, seed: int) -> np.ndarray:
    """Vertical stripes (period 10 px, dark at 15 % of bright) under `light` (W,) along the rows, σ = 1 noise."""
    rng = np.random.default_rng(seed)
    stripes = render_straight_stripes(
        (96, 256), period_px=PERIOD_PX, angle_deg=0.0, phase_px=PHASE_PX, rng=rng, noise_grey=0.0, dark_grey=30.0,
        bright_grey=200.0, uneven_illumination=False,
    )  # fmt: skip
    return (stripes * light[None, :] + rng.normal(0.0, 1.0, stripes.shape)).astype(np.float32)


def edge_errors_px(edges: FrameEdges) -> np.ndarray:
    """Each edge's distance from the nearest true edge (edges every half period from the phase)."""
    x = edges.t_px.astype(np.float64) - PHASE_PX
    half = 0.5 * PERIOD_PX
    return (x / half - np.round(x / half)) * half


def soft_rim(width_px: float, *, shadow: float = 0.4) -> np.ndarray:
    """Light along a row: `shadow` left of the rim, full right of it, a 10–90 % rim `width_px` wide."""
    u = np.arange(256.0)
    return shadow + (1.0 - shadow) * special.ndtr((u - RIM_AT_PX) * 2.563 / width_px)


def test_light_that_changes_along_the_lines_moves_no_edge_and_refuses_none() -> None:
    # From 40 % to full light across the frame: the mid-level follows it, so every edge stays where it is (the
    # 0.06 px are the noise's: σ = 1 grey level on a ~50 grey/px slope, smoothed along the edge).
    edges = locate_edges(stripes_under(0.4 + 0.6 * np.arange(256.0) / 255.0, seed=1),
                         EdgeSettings(axis="rows", period_px=PERIOD_PX))  # fmt: skip
    assert np.max(np.abs(edge_errors_px(edges))) < 0.08
    assert not np.any(edges.unusable == UNUSABLE_UNEVEN_LIGHT)
    assert len(edges) == 50 * 90  # every edge of every line (3 lines at either end are the smoothing's margin)


@pytest.mark.parametrize("rim_px", [6.0, 12.0])
def test_a_soft_rim_along_the_stripes_is_refused_as_uneven_light_not_misplaced(rim_px: float) -> None:
    # The hardest case: a shadow's rim running along the stripes dims one side of them, so an edge beside it
    # cannot tell the rim from the stripe. Without the refusal edges there are 0.16-0.36 px off. The edges kept
    # are those whose expected shift is within 0.08 px; the shift estimates an edge's error to within
    # about a factor 2 (errors 0.2-0.9 × |bend| / slope), so they are within 0.15 px (0.13 px seen).
    image = stripes_under(soft_rim(rim_px), seed=2)
    settings = EdgeSettings(axis="rows", period_px=PERIOD_PX, max_uneven_light_shift_px=STRICT_PX)
    unrefused = locate_edges(
        image, replace(settings, max_uneven_light_shift_px=None, max_departure_px=None, max_width_alternation_px=None)
    )
    assert np.max(np.abs(edge_errors_px(unrefused))) > 0.16
    edges = locate_edges(image, settings)
    assert np.max(np.abs(edge_errors_px(edges))) < 0.15
    # What is refused is said, where the rim is (its blocks within 2.5 periods of it) and nowhere else.
    assert len(edges) < len(unrefused)
    blocks = np.nonzero(edges.unusable == UNUSABLE_UNEVEN_LIGHT)[1]
    assert len(blocks) > 0
    assert np.all(np.abs((blocks + 0.5) * 4 - RIM_AT_PX) < 2.5 * PERIOD_PX + 4)


# Soft shadows of the punch and its holder over the dome (from the plate centre): the three
# (`DOME_SHADOWS`: 30, 50, 20 %, rims 8, 20, 5 mm), a long thin one nearly along the stripes (the hardest: 30 %,
# rim 5 mm), a wide deep one with a sharp rim (20 %, 4 mm) and one turned across the stripes (35 %, 6 mm).
SHADOW_SETS = {
    "dome": DOME_SHADOWS,
    "along the stripes": (SoftShadow((0.0, -10.0), (60.0, 8.0), 0.3, 5.0, 80.0),),
    "wide and deep": (SoftShadow((-40.0, -30.0), (45.0, 30.0), 0.2, 4.0, -15.0),),
    "across": (SoftShadow((-20.0, 10.0), (25.0, 18.0), 0.35, 6.0, 60.0),),
}
DEFLECTIONS_MM = (25.0, 55.0)
# The requirement of issue 29: no point kept as measured more than 1 mm from the truth (4.9 mm before the mid-level
# followed the light; 3.9 mm with no edge refused, or the bend's refusal at 0.25 px; 3.3 mm with the run ends' only,
# the former default; 0.67 mm with the bend's at 0.08 px, 0.96 mm with the departure's at 0.3 px).
LIMIT_MM = 1.0
FRAME_NAMES = [f"{name}, w0 {w0:g} mm" for name in SHADOW_SETS for w0 in DEFLECTIONS_MM]


@pytest.fixture(scope="module")
def shadowed() -> dict[str, object]:
    setup = preset("kodak", imaging=harder_imaging(supersample=1))
    setup = replace(setup, scene=replace(setup.scene, room_light=0.03))
    renderer = FringeRenderer(setup)
    rng = np.random.default_rng(29)
    z_mm = np.arange(0.0, 80.0 + 1e-9, 4.0)
    camera = exact_camera_model(setup.camera)
    projector = build_projector_calibration([renderer.render_flat(z, rng=rng) for z in z_mm], z_mm, camera)
    reference = reference_for(locate_edges(renderer.render_test(PlateState(0.0), rng=rng), projector.edges),
                              projector, camera, TopographySettings())  # fmt: skip
    frames = []
    for name, shadows in SHADOW_SETS.items():
        scene = replace(setup.scene, soft_shadows=shadows)
        shaded = FringeRenderer(replace(setup, scene=scene))
        for w0 in DEFLECTIONS_MM:
            frames.append((name, scene, PlateState(w0), shaded.render_test(PlateState(w0), rng=rng)))
    frames.append(("none", setup.scene, PlateState(55.0), renderer.render_test(PlateState(55.0), rng=rng)))
    return {"projector": projector, "camera": camera, "reference": reference, "frames": frames}


def measured_errors(shadowed: dict[str, object], settings: EdgeSettings):  # type: ignore[no-untyped-def]
    """Per frame: its name, the true error of every point kept as measured, the light at each, its coverage."""
    projector, camera, reference = shadowed["projector"], shadowed["camera"], shadowed["reference"]
    for name, scene, state, frame in shadowed["frames"]:  # type: ignore[attr-defined]
        edges = locate_edges(frame, settings)
        measurement = next(track_and_measure([edges], projector, camera, reference=reference))  # type: ignore[arg-type]
        points = measurement.points_obj_mm[np.isfinite(measurement.points_obj_mm[:, 2])]
        error = points[:, 2] - true_deflection_mm(scene, state, points[:, 0], points[:, 1])
        light = np.ones(len(points))
        for shadow in scene.soft_shadows:
            light *= shadow.light(points[:, 0] - scene.centre_xy_mm[0], points[:, 1] - scene.centre_xy_mm[1])
        yield f"{name}, w0 {state.w0_mm:g} mm", error, light, measurement.coverage


@pytest.fixture(scope="module")
def by_default(shadowed) -> dict[str, tuple[np.ndarray, np.ndarray, object]]:  # type: ignore[no-untyped-def]
    """Per frame name: the true errors of its points, the light at each and its coverage, with the defaults."""
    return {name: (error, light, coverage) for name, error, light, coverage in
            measured_errors(shadowed, shadowed["projector"].edges)}  # fmt: skip


@pytest.mark.parametrize("name", FRAME_NAMES)
def test_by_default_no_point_of_a_soft_shadow_is_more_than_1_mm_off(by_default, name: str) -> None:  # type: ignore[no-untyped-def]
    error, _, _ = by_default[name]
    assert np.max(np.abs(error)) < LIMIT_MM, f"{name}: a point {np.max(np.abs(error)):.2f} mm off"


def test_by_default_the_rims_are_masked_as_uneven_light_and_the_shadows_measured(by_default) -> None:  # type: ignore[no-untyped-def]
    assert EdgeSettings().max_width_alternation_px is not None
    masked_mm2 = {name: coverage.missing_mm2["uneven_light"] for name, (_, _, coverage) in by_default.items()}
    # 5 843 mm² over the eight frames seen (4 183 with the alternation's rejections alone, without their curves'
    # lines; 92 mm² with the run ends' rule only), none on the shadow-free frame, whose dome folds beside the punch
    # at 55 mm; the stripes inside the shadows are still measured.
    assert 2000.0 < sum(masked_mm2.values()) < 9000.0
    assert masked_mm2["none, w0 55 mm"] == 0.0
    in_shadow = sum(int(np.count_nonzero(light < 0.6)) for _, light, _ in by_default.values())
    assert in_shadow > 500


def test_the_width_alternation_refuses_the_rims_along_the_stripes(shadowed, by_default) -> None:  # type: ignore[no-untyped-def]
    # The case the bend misses (a rim along a stripe's flank): 3.3 and 3.1 mm without the alternation, 0.57 and
    # 0.69 mm with it (seen; 0.94 and 0.69 mm without its curves' lines).
    settings = replace(shadowed["projector"].edges, max_width_alternation_px=None)
    without = {name: float(np.max(np.abs(error))) for name, error, _, _ in measured_errors(shadowed, settings)}
    for name in FRAME_NAMES[2:4]:
        assert name.startswith("along")
        assert without[name] > 3.0 > LIMIT_MM > float(np.max(np.abs(by_default[name][0])))


def test_the_width_alternation_sees_a_moved_edge_and_not_a_fold() -> None:
    # Edges every half period, stretched smoothly (a cubic in the edge's index): the widths change monotonically and
    # nothing alternates. One edge moved by 0.5 px: 0.5 px there (0.49 with the slope), ≤ 0 elsewhere. A step in the
    # widths (a fold: 4 px, then 6 px) and bright stripes wider than dark ones (the duty) alternate nothing.
    k = np.arange(16.0)
    line = np.zeros(16, np.int64)
    polarity = np.where(k % 2 == 0, 1, -1)
    t = 20.0 + 5.0 * k + 0.05 * k**2 - 0.002 * k**3
    assert np.nanmax(width_alternations_px(line, t, polarity, period_px=10.0)) < 0.0
    moved = t.copy()
    moved[7] += 0.5
    alternation = width_alternations_px(line, moved, polarity, period_px=10.0)
    assert alternation[7] == pytest.approx(0.5, abs=0.02)
    assert np.nanmax(np.delete(alternation, 7)) < 0.05
    # Judged where a stripe lies beyond each of the two either side.
    assert np.isnan(alternation[[0, 1, 14, 15]]).all() and np.isfinite(alternation[2:14]).all()
    for widths in ([4.0] * 8 + [6.0] * 7, [4.6, 3.4] * 7 + [4.6]):
        stepped = np.r_[20.0, 20.0 + np.cumsum(widths)]
        assert np.nanmax(width_alternations_px(line, stepped, polarity, period_px=10.0)) <= 1e-9


STRICT_SETTINGS = {"the light's bend": {"max_uneven_light_shift_px": STRICT_PX},
                   "the departure": {"max_departure_px": DEPARTURE_PX}}  # fmt: skip


def test_with_a_strict_refusal_no_point_of_a_soft_shadow_is_more_than_1_mm_off(shadowed) -> None:  # type: ignore[no-untyped-def]
    uneven_mm2 = {}
    for refusal, values in STRICT_SETTINGS.items():
        uneven_mm2[refusal] = 0.0
        in_shadow = 0
        settings = replace(shadowed["projector"].edges, **values)
        for name, error, light, coverage in measured_errors(shadowed, settings):
            assert np.max(np.abs(error)) < LIMIT_MM, f"{refusal}, {name}: a point {np.max(np.abs(error)):.2f} mm off"
            uneven_mm2[refusal] += coverage.missing_mm2["uneven_light"]
            in_shadow += int(np.count_nonzero(light < 0.6))
        # The rims are masked with their reason, and the stripes inside the shadows are still measured.
        assert uneven_mm2[refusal] > 500.0, refusal
        assert in_shadow > 500, refusal  # 893 seen
    # The departure masks less than half what the bend does (5 661 against 12 198 mm² seen, with the default
    # alternation; the shadow-free frame's 238 and 367 mm² beside the punch included: the fold the defaults keep).
    # Worst points 0.96 and 0.67 mm.
    assert uneven_mm2["the departure"] < 0.6 * uneven_mm2["the light's bend"]


def test_without_a_refusal_the_same_shadows_make_wrong_points(shadowed) -> None:  # type: ignore[no-untyped-def]
    # The frames above are hard enough: with no rule but the run ends' (the former default), or the bend's at
    # 0.25 px, points at the rims are over 1 mm off (3.3 mm seen: edges whose stripe's flank a rim along the stripes
    # dims, 2.4-2.9 px off where the bend predicts 0.2-0.5 px). The shift still enters their σ, but it says too
    # little of it for the σ to mask them.
    assert EdgeSettings().max_uneven_light_shift_px is EdgeSettings().max_departure_px is None
    for limit_px in (None, 0.25):
        settings = replace(shadowed["projector"].edges, max_uneven_light_shift_px=limit_px, max_departure_px=None,
                           max_width_alternation_px=None)  # fmt: skip
        worst = max(float(np.max(np.abs(error))) for _, error, _, _ in measured_errors(shadowed, settings))
        assert worst > LIMIT_MM, limit_px


def test_the_last_edge_before_a_deep_shadow_is_refused_by_default(shadowed) -> None:  # type: ignore[no-untyped-def]
    # The last lit edge before the deep shadow's dark interior: its mid-level is the envelopes' and its neighbours'
    # the means', so its bend is not judged, and it lies 2.1 px short of the truth (3.9 mm). It departs from the
    # cubic through its four neighbours on its line by more than max_end_departure_px; so does no edge where the
    # dome's stripes fold (next test). 0.67 mm is left (1.30 mm without the alternation's curves' lines, 1.73 mm
    # without the alternation: an edge two from the end) against 3.92 mm without the rule.
    def worst_of_deep(settings: EdgeSettings) -> float:
        errors = [error for name, error, _, _ in measured_errors(shadowed, settings) if name.startswith("wide")]
        return max(float(np.max(np.abs(error))) for error in errors)

    edges = shadowed["projector"].edges
    assert edges.max_end_departure_px == EdgeSettings().max_end_departure_px
    assert worst_of_deep(edges) < 2.0 < 3.0 < worst_of_deep(replace(edges, max_end_departure_px=None))


def test_an_edge_whose_widths_alternate_takes_its_curve_within_two_lines_with_it(shadowed, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # The deep shadow at w0 55 mm, whose rim lies on the dome's fold: the same edge on the lines beside a rejected
    # one is 0.4-0.7 px off, its widths changing monotonically still. Without its curve's lines 1.30 mm is kept, with
    # them 0.67 mm (seen; the same with 1, 3 or 4 lines).
    def worst_of_deep() -> float:
        errors = measured_errors(shadowed, shadowed["projector"].edges)
        return next(float(np.max(np.abs(error))) for name, error, _, _ in errors if name == "wide and deep, w0 55 mm")

    assert fringes.ALTERNATION_ALONG_CURVE_LINES == 2
    assert worst_of_deep() < LIMIT_MM
    monkeypatch.setattr(fringes, "ALTERNATION_ALONG_CURVE_LINES", 0)
    assert worst_of_deep() > LIMIT_MM


def test_the_departure_refuses_good_edges_where_the_domes_stripes_fold(shadowed) -> None:  # type: ignore[no-untyped-def]
    # Why the departure is not the default: without any shadow, beside the punch at 55 mm the stripes fold
    # (compressed on the dome's near flank, stretched into the punch's own shadow) and good edges depart from the
    # cubic through their neighbours by up to 1.5-2.7 px (w0 50-60 mm); the refusal masks them next to the peak
    # (in tests/science/structured_light/test_peak_measured.py a shadow-free frame's peak then goes unmeasured).
    name, scene, state, frame = shadowed["frames"][-1]
    assert name == "none"
    # By default (the run's ends only) none of them is refused.
    assert not np.any(locate_edges(frame, shadowed["projector"].edges).unusable == UNUSABLE_UNEVEN_LIGHT)
    settings = replace(shadowed["projector"].edges, max_departure_px=DEPARTURE_PX)
    edges = locate_edges(frame, settings)
    refused = np.argwhere(edges.unusable == UNUSABLE_UNEVEN_LIGHT)
    assert len(refused) > 0
    # ... and the points there are good without it: this frame's worst is well within the bound.
    kept = replace(settings, max_departure_px=None)
    worst = next(float(np.max(np.abs(e))) for n, e, _, _ in measured_errors(shadowed, kept) if n.startswith("none"))
    assert worst < 0.5 * LIMIT_MM


def test_an_edge_is_judged_by_the_cubic_through_its_neighbours_on_its_line() -> None:
    # Edges of one line every half period (5 px) on a stripe pattern stretched smoothly (a cubic in the edge's
    # index: a slope stretches stripes): no departure, to rounding. One edge moved by 0.5 px departs by exactly
    # 0.5 px; its neighbours, whose cubics it bends, by 4/6 of it (centred) and less.
    k = np.arange(12.0)
    t = 20.0 + 5.0 * k + 0.05 * k**2 - 0.002 * k**3
    line = np.zeros(12, np.int64)
    polarity = np.where(k % 2 == 0, 1, -1)
    smooth = edge_departures_px(line, t, polarity, period_px=10.0)
    assert np.max(np.abs(smooth[:, 0])) < 1e-9
    # Where each edge lies in its run: at its ends (2), next to them (1), centred (0).
    assert smooth[:, 1].tolist() == [2, 1] + [0] * 8 + [1, 2]
    moved = t.copy()
    moved[5] += 0.5
    departure = edge_departures_px(line, moved, polarity, period_px=10.0)[:, 0]
    assert departure[5] == pytest.approx(0.5)
    assert departure[[4, 6]] == pytest.approx([-4.0 / 6.0 * 0.5] * 2)
    # An edge alone on its line (no neighbour within 0.2–1.5 periods of opposite polarity) is judged as such.
    alone = edge_departures_px(np.array([0, 1]), np.array([10.0, 10.0]), np.array([1, 1]), period_px=10.0)
    assert alone[:, 1].tolist() == [3, 3]


def test_files_with_the_former_uneven_light_setting_are_read_with_the_new_default() -> None:
    # max_uneven_light_fraction (a share of the contrast, 0 = off) has no meaning as a shift in px: dropped.
    settings = EdgeSettings.from_dict({"max_uneven_light_fraction": 0.05, "min_contrast": 25.0})
    assert settings.max_uneven_light_shift_px is EdgeSettings().max_uneven_light_shift_px is None
    assert settings.min_contrast_grey == 25.0
    with pytest.raises(ValueError, match="max_uneven_light_shift_px"):
        EdgeSettings(max_uneven_light_shift_px=0.0)
