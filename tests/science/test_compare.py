"""Mapping a finite-element model onto the plate frame, time alignment and differences, on exact synthetic models.

The models are the virtual plate's true surface (`virtual_test.true_plate_model`); the "measurement" here is the true
deflection on a 2 mm grid, so every difference is the model's own interpolation error (about 0.01 mm, see
`true_plate_model`) unless the mapping is wrong, which gives errors of millimetres.
"""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.science import compare
from fringelab.science.fe_results import FEResults, solid_boundary_faces
from fringelab.science.fields import Grid
from fringelab.science.virtual_test import PlateScene, PlateState, punch_timeline, true_deflection_mm, true_plate_model

SCENE = PlateScene()
TIMELINE = punch_timeline(8)
GRID = Grid(x_mm=np.arange(-246.0, 262.0, 2.0), y_mm=np.arange(-258.0, 250.0, 2.0))
GX, GY = np.meshgrid(GRID.x_mm, GRID.y_mm)
INSIDE = np.hypot(GX - SCENE.centre_xy_mm[0], GY - SCENE.centre_xy_mm[1]) < SCENE.clamp_radius_mm - 2.0
PLATE = compare.PlateFrame(axis_xy_mm=SCENE.centre_xy_mm, data_box_mm=(-242.0, 258.0, -255.0, 245.0))
# The model's linear interpolation of the log-shaped deflection is within ~0.01 mm at 60 mm (true_plate_model);
# a wrong unit, symmetry or origin is off by millimetres.
MODEL_TOLERANCE_MM = 0.03


def as_results(model, *, scale: float = 1.0, unit: str | None = None, source: str = "model") -> FEResults:  # type: ignore[no-untyped-def]
    displacement = scale * model.displacement_mm
    return FEResults(
        source=source, kind="test", node_ids=np.arange(1, len(model.node_xyz_mm) + 1),
        node_xyz=scale * model.node_xyz_mm, shells=np.column_stack([model.triangles, model.triangles[:, 2]]),
        solids=np.zeros((0, 8), np.int64), shell_thickness=None, time=model.time_s,
        displacement=lambda i: displacement[i], length_unit=unit, punch_time=model.time_s,
        punch_displacement=scale * model.punch_displacement_mm,
    )  # fmt: skip


def truth(frame: int) -> np.ndarray:
    w = true_deflection_mm(SCENE, PlateState(TIMELINE.states[frame].w0_mm), GX, GY)
    return np.where(INSIDE, w, np.nan)


def test_full_model_in_plate_coordinates_needs_no_setting() -> None:
    model = compare.map_model(as_results(true_plate_model(SCENE, TIMELINE), unit="mm"), PLATE)
    mapping = model.mapping
    assert (mapping.symmetry, mapping.normal_axis, mapping.w_sign) == ("none", "z", 1)
    # Its own punch axis (the centre of its deflection, already on the measured axis) goes on the measured axis:
    # it does not move, to the centroid's rounding over the model's rings of nodes (0.01 mm is far below the 0.1
    # mm that would show in the differences).
    np.testing.assert_allclose(mapping.origin_xy_mm, (0.0, 0.0), atol=0.01)
    assert mapping.origin_on_axis and any("model's punch axis" in note for note in mapping.notes)
    assert set(mapping.detected) >= {"symmetry", "normal_axis", "w_sign", "origin_xy_mm"}
    w_sim = model.sample(5, GRID)
    diff = w_sim - truth(5)
    assert np.count_nonzero(np.isfinite(diff)) > 0.95 * np.count_nonzero(INSIDE)
    assert np.nanmax(np.abs(diff)) < MODEL_TOLERANCE_MM


def test_quarter_model_unfolded_equals_the_full_model() -> None:
    full = compare.map_model(as_results(true_plate_model(SCENE, TIMELINE)), PLATE)
    quarter = compare.map_model(as_results(true_plate_model(SCENE, TIMELINE, quarter=True)), PLATE)
    assert quarter.mapping.symmetry == "quarter" and "symmetry" in quarter.mapping.detected
    assert quarter.mapping.origin_xy_mm == SCENE.centre_xy_mm  # its symmetry axis goes on the punch axis
    w_full, w_quarter = full.sample(4, GRID), quarter.sample(4, GRID)
    both = np.isfinite(w_full) & np.isfinite(w_quarter)
    assert both.sum() > 0.95 * np.count_nonzero(INSIDE)  # the unfolded quarter covers the whole disc
    assert np.max(np.abs(w_full[both] - w_quarter[both])) < MODEL_TOLERANCE_MM


def test_pairing_a_quarter_model_with_a_measurement_fits_it_and_pairs_every_frame() -> None:
    """`pair_with_measurement`, the one pairing of the comparison and its preview: a quarter model is detected,
    its symmetry axis put on the punch axis and fitted there (it is already right: the fit must stay within
    0.05 mm), every frame paired at its own state, and w_sim of a frame is the truth within the model's own
    interpolation error. A model moved by 3 mm is fitted back."""
    frames = [truth(i) for i in range(len(TIMELINE.states))]
    peaks = np.array([np.nanmax(w) for w in frames])
    kwargs = dict(grid=GRID, plate=PLATE, measured_w=lambda i: frames[i], frame_time_s=TIMELINE.time_s,
                  frame_punch_mm=TIMELINE.punch_displacement_mm, frame_peak_mm=peaks)  # fmt: skip
    pairing = compare.pair_with_measurement(as_results(true_plate_model(SCENE, TIMELINE, quarter=True)), **kwargs)  # type: ignore[arg-type]
    assert pairing.model.mapping.symmetry == "quarter" and pairing.overlap > 0.9
    assert np.hypot(*np.subtract(pairing.model.mapping.origin_xy_mm, SCENE.centre_xy_mm)) < 0.05
    np.testing.assert_array_equal(pairing.alignment.state_lo[1:] + pairing.alignment.fraction[1:].round(),
                                  np.arange(1, len(frames)))  # fmt: skip
    w_sim = pairing.simulated_w(5)
    assert w_sim is not None and np.nanmax(np.abs(w_sim - frames[5])) < MODEL_TOLERANCE_MM
    off = compare.PlateFrame(axis_xy_mm=(SCENE.centre_xy_mm[0] + 3.0, SCENE.centre_xy_mm[1]),
                                          data_box_mm=PLATE.data_box_mm)  # fmt: skip
    moved = compare.pair_with_measurement(as_results(true_plate_model(SCENE, TIMELINE, quarter=True)),
                                          **{**kwargs, "plate": off})  # type: ignore[arg-type]  # fmt: skip
    assert np.hypot(*np.subtract(moved.model.mapping.origin_xy_mm, SCENE.centre_xy_mm)) < 0.05, moved.model.mapping


def test_half_model_given_explicitly_and_rotated_plate_normal() -> None:
    base = true_plate_model(SCENE, TIMELINE, quarter=True)
    # The same quarter with its normal along the model's y axis and deflecting toward −y: (x, y, z) → (z, −x, y)
    # would be one choice; the model here is written with plate Z along model y and in-plane (x, y) → (z, x).
    xyz = base.node_xyz_mm[:, [1, 2, 0]]  # model (x, y, z) = plate (Y, Z, X): normal along model y
    results = as_results(base)
    moved = FEResults(
        source="rotated", kind="test", node_ids=results.node_ids, node_xyz=xyz, shells=results.shells,
        solids=results.solids, shell_thickness=None, time=results.time,
        displacement=lambda i: -base.displacement_mm[i][:, [1, 2, 0]], punch_time=results.punch_time,
        punch_displacement=results.punch_displacement,
    )  # fmt: skip
    model = compare.map_model(moved, PLATE)
    assert model.mapping.normal_axis == "y" and model.mapping.w_sign == -1
    diff = model.sample(5, GRID) - truth(5)
    assert np.count_nonzero(np.isfinite(diff)) > 0.95 * np.count_nonzero(INSIDE)
    assert np.nanmax(np.abs(diff)) < MODEL_TOLERANCE_MM


def test_model_in_metres_is_detected_and_scaled() -> None:
    model = compare.map_model(as_results(true_plate_model(SCENE, TIMELINE), scale=1e-3), PLATE)
    assert model.mapping.length_unit == "m" and "length_unit" in model.mapping.detected
    assert np.nanmax(np.abs(model.sample(5, GRID) - truth(5))) < MODEL_TOLERANCE_MM
    np.testing.assert_allclose(compare.state_punch_mm(model), TIMELINE.punch_displacement_mm, rtol=1e-12)


def test_shell_thickness_offsets_the_surface_toward_the_cameras() -> None:
    """The face toward the cameras lies t/2 along the normal from the mid-surface: with the mid-surface's slope s
    it is t/2 · s/√(1+s²) inward in the plane and t/2 · (1/√(1+s²) − 1) lower than the mid-surface's point.
    Nodal normals average the neighbouring triangles, hence 0.05 mm (the slope reaches 0.93 at the punch edge)."""
    results = as_results(true_plate_model(SCENE, TIMELINE))
    mid = compare.map_model(results, PLATE, compare.MappingSettings(surface="mid"))
    face = compare.map_model(results, PLATE, compare.MappingSettings(shell_thickness_mm=4.0))
    assert face.mapping.shell_thickness_mm == pytest.approx(4.0)
    xy_mid, w_mid = mid.surface_w(5)
    xy_face, w_face = face.surface_w(5)
    _, slope_x, slope_y = SCENE.deflection_mm(xy_mid[:, 0], xy_mid[:, 1], TIMELINE.states[5].w0_mm)
    slope = np.hypot(slope_x, slope_y)
    inner = SCENE.radius_mm(xy_mid[:, 0], xy_mid[:, 1]) < SCENE.clamp_radius_mm - 1.0  # the rim's slope jumps to 0
    moved = np.hypot(*(xy_face - xy_mid).T)
    np.testing.assert_allclose(moved[inner], 2.0 * slope[inner] / np.sqrt(1 + slope[inner] ** 2), atol=0.05)
    np.testing.assert_allclose((w_face - w_mid)[inner], 2.0 * (1 / np.sqrt(1 + slope[inner] ** 2) - 1), atol=0.05)
    assert np.max(np.hypot(*(xy_face - xy_mid).T)) > 1.0


def test_solid_model_compares_its_face_toward_the_cameras() -> None:
    # Two layers of nodes 4 mm apart, joined as wedges (6 nodes) under each triangle.
    base = true_plate_model(SCENE, TIMELINE, resolution=0.08)
    n = len(base.node_xyz_mm)
    xyz = np.concatenate([base.node_xyz_mm - [0, 0, 4.0], base.node_xyz_mm])
    wedges = np.column_stack([base.triangles, base.triangles + n])
    faces = solid_boundary_faces(wedges)
    assert len(faces) > 2 * len(base.triangles)  # both caps and the rim
    displacement = np.concatenate([base.displacement_mm, base.displacement_mm], axis=1)
    results = FEResults(
        source="solid", kind="test", node_ids=np.arange(1, 2 * n + 1), node_xyz=xyz, shells=np.zeros((0, 4), np.int64),
        solids=wedges, shell_thickness=None, time=base.time_s, displacement=lambda i: displacement[i],
        length_unit="mm",
    )  # fmt: skip
    model = compare.map_model(results, PLATE)
    assert model.surface.origin == "solid boundary"
    assert np.all(model.reference_mm[:, 2] == 0.0)  # the upper layer, toward the cameras
    assert np.nanmax(np.abs(model.sample(5, GRID) - truth(5))) < 0.1


def test_alignment_by_displacement_between_states() -> None:
    frames = TIMELINE.punch_displacement_mm
    states = np.array([0.0, 5.0, 15.0, 25.0, 40.0, 55.0, 70.0])
    alignment = compare.align_by_values("punch displacement", frames, states, unit="mm")
    for value, lo, fraction in zip(frames, alignment.state_lo, alignment.fraction, strict=True):
        assert states[lo] <= value <= states[lo + 1]
        assert states[lo] + fraction * (states[lo + 1] - states[lo]) == pytest.approx(value)
    # States after the punch's largest travel are not used; frames beyond the states' range say why.
    alignment = compare.align_by_values(
        "punch displacement", np.array([10.0, 80.0, np.nan]), np.array([0.0, 20.0, 60.0, 30.0]), unit="mm"
    )
    assert alignment.state_lo.tolist() == [0, -1, -1]
    assert "outside the simulation's 0–60 mm" in alignment.reason[1] and "no punch displacement" in alignment.reason[2]


def test_states_between_frames_reproduce_the_frames() -> None:
    """States at punch displacements between the frames: the deflection is linear in w0, and w0 in the punch
    travel up to perforation, so blending the two neighbouring states gives each frame's surface to the model's
    interpolation error."""
    frames = TIMELINE.punch_displacement_mm[:6]
    states = np.concatenate([[0.0], 0.5 * (frames[1:] + frames[:-1]), [frames[-1]]])
    model = compare.map_model(as_results(true_plate_model(SCENE, TIMELINE, state_punch_mm=states)), PLATE)
    alignment = compare.align_frames(model, "displacement", frame_time_s=TIMELINE.time_s[:6], frame_punch_mm=frames,
                                     frame_peak_mm=np.full(6, np.nan))  # fmt: skip
    assert alignment.state_lo.tolist() == [0, 1, 2, 3, 4, 5]  # frame i lies between states i and i + 1
    sampler = compare.StateSampler(model, GRID)
    for frame in range(1, 6):
        w_sim = sampler.at(int(alignment.state_lo[frame]), float(alignment.fraction[frame]))
        assert np.nanmax(np.abs(w_sim - truth(frame))) < MODEL_TOLERANCE_MM, frame


def test_difference_statistics() -> None:
    measured = np.array([[1.0, 2.0], [np.nan, 4.0]])
    simulated = np.array([[1.5, 1.0], [3.0, np.nan]])
    diff, stats = compare.frame_difference(measured, simulated, sigma_w_mm=np.array([[0.1, 1.0], [1.0, 1.0]]))
    assert np.isnan(diff[1]).all() and stats.n_nodes == 2
    assert stats.rms_diff_mm == pytest.approx(np.sqrt((0.25 + 1.0) / 2))
    assert stats.max_diff_mm == 1.0 and stats.fraction_beyond_2sigma == 0.5


# ------------------------------------------------------------------------------------------------- bad input


def test_no_plate_like_surface_names_the_setting() -> None:
    rng = np.random.default_rng(0)
    cube = rng.uniform(0, 100, (200, 3))
    results = FEResults(
        source="cube.csv", kind="csv", node_ids=np.arange(200), node_xyz=cube, shells=np.zeros((0, 4), np.int64),
        solids=np.zeros((0, 8), np.int64), shell_thickness=None, time=np.zeros(1), displacement=lambda i: cube * 0,
    )  # fmt: skip
    with pytest.raises(compare.ComparisonError, match=r"no plate-like surface.*--normal-axis"):
        compare.map_model(results, PLATE)


def test_units_that_cannot_be_decided() -> None:
    results = as_results(true_plate_model(SCENE, TIMELINE, resolution=0.2), scale=0.04)  # 20 units across
    with pytest.raises(compare.ComparisonError, match=r"units cannot be decided.*--units mm\|m"):
        compare.map_model(results, PLATE)


def test_model_larger_than_the_plate() -> None:
    results = as_results(true_plate_model(SCENE, TIMELINE, resolution=0.2), scale=4.0, unit="mm")
    with pytest.raises(compare.ComparisonError, match=r"larger than the measured plate.*--units"):
        compare.map_model(results, PLATE)


def test_a_wrong_unit_that_was_given_is_refused_not_compared() -> None:
    """A model in metres declared (or set) as mm is a speck on the plate: compared as it is, every difference
    would be the whole deflection. It is refused, naming the setting, in the CLI's and in the form's terms."""
    in_metres = as_results(true_plate_model(SCENE, TIMELINE, resolution=0.2), scale=1e-3, unit="mm")
    with pytest.raises(compare.ComparisonError, match=r"far smaller than the measured plate.*--units mm\|m") as caught:
        compare.map_model(in_metres, PLATE)
    form = compare.in_form_terms(str(caught.value))
    assert "“Units” mm or m" in form and "--" not in form
    set_wrong = as_results(true_plate_model(SCENE, TIMELINE, resolution=0.2), scale=1e-3)
    with pytest.raises(compare.ComparisonError, match=r"in mm as set"):
        compare.map_model(set_wrong, PLATE, compare.MappingSettings(length_unit="mm"))
    assert compare.map_model(set_wrong, PLATE, compare.MappingSettings(length_unit="m")).mapping.length_unit == "m"


def test_the_last_state_keeps_its_punch_travel_when_the_history_was_printed_rounded() -> None:
    """nodout and rcforc print times with 6 to 8 digits, d3plot holds them as float32: the last state's time can
    lie a hair after the history's last, and its punch travel (and with it the state) must not be lost."""
    model = true_plate_model(SCENE, TIMELINE, resolution=0.2)
    printed = np.array([float(f"{t:.5E}") for t in model.time_s])  # as rcforc prints: up to 5e-6 relative off
    state_time = model.time_s.astype(np.float32).astype(np.float64) * (1 + 2e-6)  # a hair later than printed
    results = FEResults(**{**as_results(model).__dict__, "time": state_time, "punch_time": printed})
    mapped = compare.map_model(results, PLATE)
    travel = compare.state_punch_mm(mapped)
    assert travel is not None and np.all(np.isfinite(travel))
    np.testing.assert_allclose(travel[-1], model.punch_displacement_mm[-1], rtol=1e-3)
    # beyond round-off the history does not reach: no travel there
    outside = compare.interpolate_history(np.array([2.0 * printed[-1]]), printed, model.punch_displacement_mm)
    assert np.isnan(outside[0])


def test_model_offset_from_the_plate() -> None:
    results = as_results(true_plate_model(SCENE, TIMELINE, resolution=0.2))
    model = compare.map_model(results, PLATE, compare.MappingSettings(origin_xy_mm=(400.0, 0.0)))
    with pytest.raises(compare.ComparisonError, match=r"overlap on \d+ % of the model.*--origin X,Y"):
        compare.check_overlap(model, GRID, model.sample(0, GRID), truth(0))


def test_no_overlap_in_displacement() -> None:
    model = compare.map_model(as_results(true_plate_model(SCENE, TIMELINE, resolution=0.2)), PLATE)
    with pytest.raises(compare.ComparisonError, match=r"no test frame lies within.*--align"):
        compare.align_frames(model, "displacement", frame_time_s=np.zeros(2), frame_punch_mm=np.array([100.0, 120.0]),
                             frame_peak_mm=np.zeros(2))  # fmt: skip
    bare = FEResults(**{**as_results(true_plate_model(SCENE, TIMELINE, resolution=0.2)).__dict__,
                        "punch_time": None, "punch_displacement": None})  # fmt: skip
    model = compare.map_model(bare, PLATE)
    with pytest.raises(compare.ComparisonError, match=r"no punch displacement.*--punch-node ID"):
        compare.align_frames(model, "displacement", frame_time_s=np.zeros(2), frame_punch_mm=np.zeros(2),
                             frame_peak_mm=np.zeros(2))  # fmt: skip


def test_camera_covariance_moves_the_points_as_a_parameter_change_does() -> None:
    """One parameter with a standard error: the covariance of X, Y is the square of the move that a change of
    that size makes (central differences over ±se are exact to second order: 1e-3 relative here)."""
    from dataclasses import replace

    from fringelab.science.uncertainty import camera_sigma_xy_mm, with_camera_term
    from fringelab.science.virtual_test import preset

    camera = preset("kodak").camera
    points = np.array([[0.0, 0.0, 10.0], [150.0, -100.0, 40.0]])
    names = ("f_mm", "z0_mm")
    covariance = camera_sigma_xy_mm(camera, points, standard_errors={"f_mm": 0.01, "z0_mm": 0.0},
                                    correlation=np.eye(2), parameters=names)  # fmt: skip
    from fringelab.science.camera import backproject_to_z, project_points

    q = project_points(camera, points)
    moved = backproject_to_z(replace(camera, f_mm=camera.f_mm + 0.01), q, points[:, 2])[:, :2] - points[:, :2]
    np.testing.assert_allclose(covariance, moved[:, :, None] * moved[:, None, :], rtol=2e-2, atol=1e-10)
    slope = np.array([[0.5, 0.0], [0.0, 0.0]])
    sigma = with_camera_term(np.array([0.01, 0.01]), slope, covariance)
    assert sigma[1] == 0.01 and sigma[0] == pytest.approx(np.hypot(0.01, 0.5 * abs(moved[0, 0])), rel=2e-2)
