"""The calibration solver on exact corners with Gaussian noise: DLT, LM, covariance, outliers, verdict, inputs."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fringelab.science.calibration import (
    CalibrationError,
    CornerView,
    calibrate_from_views,
    decompose_camera_matrix,
    dlt_camera_matrix,
    zstack_heights_mm,
)
from fringelab.science.camera import Camera, camera_as_opencv, project_points
from fringelab.science.synthetic import board_corner_points_mm, reference_camera, zstack_board

SIGMA_PX = 0.05  # per coordinate: what a good corner detector achieves on a sharp 8-bit image


def zstack_views(camera: Camera, *, rng: np.random.Generator, sigma_px: float, n_frames: int = 12) -> list[CornerView]:
    board_xy = board_corner_points_mm(zstack_board(camera))
    views = []
    for k, z in enumerate(np.linspace(-20, 100, n_frames)):
        points = np.column_stack([board_xy, np.full(len(board_xy), z)])
        q_px = project_points(camera, points) + rng.normal(0, sigma_px, (len(points), 2))
        views.append(CornerView(f"frame{k:02d}.png", points, q_px, float(z)))
    return views


def pose_views(camera: Camera, *, rng: np.random.Generator, sigma_px: float, n_views: int = 10) -> list[CornerView]:
    """Free views of a board tilted up to ±30° about random axes, 1.6–2.2 m from the camera."""
    board_xy = board_corner_points_mm(zstack_board(camera))
    board_points = np.column_stack([board_xy, np.zeros(len(board_xy))])
    views = []
    for k in range(n_views):
        tilt = Rotation.from_rotvec(rng.uniform(-0.5, 0.5, 3) * np.array([1, 1, 0.3])).as_matrix()
        rotation = camera.rotation @ tilt
        translation = np.array([rng.uniform(-60, 60), rng.uniform(-60, 60), rng.uniform(1700, 2200)])
        pose_camera = dataclasses.replace(camera, x0_mm=translation[0], y0_mm=translation[1], z0_mm=translation[2])
        pose_camera = _with_rotation(pose_camera, rotation)
        q_px = project_points(pose_camera, board_points) + rng.normal(0, sigma_px, (len(board_points), 2))
        inside = np.all((q_px > 0) & (q_px < [camera.image_width_px - 1, camera.image_height_px - 1]), axis=1)
        views.append(CornerView(f"view{k:02d}.png", board_points[inside], q_px[inside]))
    return views


def _with_rotation(camera: Camera, rotation: np.ndarray) -> Camera:
    from fringelab.science.camera import angles_from_rotation

    omega, phi, kappa = angles_from_rotation(rotation)
    return dataclasses.replace(camera, omega_rad=omega, phi_rad=phi, kappa_rad=kappa)


def calibrate(views, camera, **options):
    return calibrate_from_views(
        views, image_size_wh_px=(camera.image_width_px, camera.image_height_px), du_px_per_mm=camera.du_px_per_mm,
        dv_px_per_mm=camera.dv_px_per_mm, scale_on=camera.scale_on, **options,
    )  # fmt: skip


def test_dlt_recovers_a_pinhole_camera_exactly():
    camera = dataclasses.replace(reference_camera("1024x1024"), k1_per_mm2=0, k2_per_mm4=0, p1_per_mm=0, p2_per_mm=0)
    rng = np.random.default_rng(5)
    points = np.column_stack([rng.uniform(-200, 200, 60), rng.uniform(-200, 200, 60), rng.uniform(-20, 100, 60)])
    k, r, t = decompose_camera_matrix(dlt_camera_matrix(points, project_points(camera, points)))
    opencv = camera_as_opencv(camera)
    # Noise-free points: agreement to round-off amplified by the conditioning of a 2 m, ±200 mm geometry.
    np.testing.assert_allclose(k, opencv.camera_matrix, rtol=1e-7, atol=1e-5)
    np.testing.assert_allclose(r, camera.rotation, atol=1e-9)
    np.testing.assert_allclose(t, camera.translation_mm, rtol=1e-8)


def test_dlt_refuses_coplanar_points():
    camera = reference_camera()
    points = np.column_stack([np.random.default_rng(0).uniform(-100, 100, (30, 2)), np.zeros(30)])
    with pytest.raises(CalibrationError, match="coplanar"):
        dlt_camera_matrix(points, project_points(camera, points))


@pytest.mark.parametrize("size", ["512x480", "1024x1024"])
def test_zstack_recovers_truth_at_noise_level(size):
    camera = reference_camera(size)
    views = zstack_views(camera, rng=np.random.default_rng(21), sigma_px=SIGMA_PX)
    result = calibrate(views, camera, mode="zstack")
    n_obs = 2 * result.n_points
    expected_rms_px = SIGMA_PX * np.sqrt(2 * (n_obs - 14) / n_obs)
    # 3 %: with ~2000 corners the sample RMS of Gaussian noise scatters by ~1 %.
    assert result.rms_px == pytest.approx(expected_rms_px, rel=0.03)
    assert result.residual_std_px == pytest.approx(SIGMA_PX, rel=0.03)
    for name, error in result.standard_errors.items():
        # 4.5 σ: 14 parameters × 2 sizes, a false alarm below 1e-4 for honest standard errors.
        assert abs(getattr(result.camera, name) - getattr(camera, name)) < 4.5 * error, name
    assert result.verdict.level == "good", result.verdict.reasons


def test_poses_mode_agrees_with_opencv_on_the_same_corners():
    camera = reference_camera("1024x1024")
    # OpenCV takes float32 corners: round them first so both solvers see the same data.
    views = [
        CornerView(v.frame, v.points_obj_mm.astype(np.float32).astype(float), v.q_px.astype(np.float32).astype(float))
        for v in pose_views(camera, rng=np.random.default_rng(22), sigma_px=SIGMA_PX)
    ]
    result = calibrate(views, camera, mode="poses")
    object_points = [v.points_obj_mm.astype(np.float32) for v in views]
    image_points = [v.q_px.astype(np.float32) for v in views]
    rms, k, dist, _, _ = cv2.calibrateCamera(
        object_points, image_points, (1024, 1024), None, None, flags=cv2.CALIB_FIX_K3,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-15),
    )  # fmt: skip
    opencv = result.opencv
    # Same model, same data, both at the least-squares minimum: agreement far below the standard errors.
    assert result.rms_px == pytest.approx(rms, rel=1e-6)
    np.testing.assert_allclose([opencv.fx_px, opencv.fy_px, opencv.cx_px, opencv.cy_px],
                               [k[0, 0], k[1, 1], k[0, 2], k[1, 2]], rtol=1e-5)  # fmt: skip
    np.testing.assert_allclose(opencv.dist_coeffs[:4], dist.ravel()[:4], rtol=1e-3, atol=1e-6)
    truth = camera_as_opencv(camera)
    for name in ("fx_px", "fy_px", "cx_px", "cy_px"):
        assert abs(getattr(opencv, name) - getattr(truth, name)) < 4.5 * result.opencv_standard_errors[name], name


def test_outlier_frame_is_rejected_with_its_reason():
    camera = reference_camera("512x480")
    views = zstack_views(camera, rng=np.random.default_rng(23), sigma_px=SIGMA_PX)
    bad = views[4]
    # A frame whose stage reading is 3 mm off: its corners sit ~1.5 px from where the others put them.
    views[4] = CornerView(bad.frame, bad.points_obj_mm + [0, 0, 3.0], bad.q_px, bad.z_mm)
    kept = calibrate(views, camera, mode="zstack")
    assert kept.verdict.level != "good"
    cleaned = calibrate(views, camera, mode="zstack", reject_outliers=True)
    statuses = {f.frame: f.status for f in cleaned.frames}
    assert statuses.pop(bad.frame) == "rejected"
    assert set(statuses.values()) == {"used"}
    assert "outlier" in next(f.reason for f in cleaned.frames if f.status == "rejected")
    assert cleaned.rms_px == pytest.approx(SIGMA_PX * np.sqrt(2), rel=0.05)


def test_systematic_residuals_are_flagged():
    camera = reference_camera("512x480")
    views = zstack_views(camera, rng=np.random.default_rng(24), sigma_px=SIGMA_PX)
    # A 0.3 px ripple with two periods across the image (a lens or sensor flaw): no smooth distortion term can
    # absorb it, so it stays in the residuals as a pattern.
    width, height = camera.image_width_px, camera.image_height_px
    warped = []
    for v in views:
        ripple = 0.3 * np.column_stack(
            [np.cos(4 * np.pi * v.q_px[:, 1] / height), np.sin(4 * np.pi * v.q_px[:, 0] / width)]
        )
        warped.append(CornerView(v.frame, v.points_obj_mm, v.q_px + ripple, v.z_mm))
    result = calibrate(warped, camera, mode="zstack")
    check = next(c for c in result.verdict.checks if c.name == "systematic_residual")
    assert check.level != "good"
    assert check.message in result.verdict.reasons


def test_too_few_frames_or_levels():
    camera = reference_camera("512x480")
    views = zstack_views(camera, rng=np.random.default_rng(25), sigma_px=SIGMA_PX, n_frames=4)
    with pytest.raises(CalibrationError, match="at least 3 frames"):
        calibrate(views[:2], camera, mode="zstack")
    same_z = [CornerView(v.frame, v.points_obj_mm * [1, 1, 0], v.q_px, 0.0) for v in views]
    with pytest.raises(CalibrationError, match="2 distinct Z"):
        calibrate(same_z, camera, mode="zstack")


@pytest.mark.parametrize(
    ("rows", "n_frames", "message"),
    [
        ({0: 0.0, 1: 1.0}, 3, "2 rows, but the recording has 3 frames"),
        ({0: 0.0, 2: 1.0, 3: 2.0}, 3, "without gaps"),
        ({0: 5.0, 1: 5.0, 2: 5.0}, 3, "all 3 frames are at Z = 5.0 mm"),
        ({1: 0.0, 2: 1.0, 3: 1.0}, 3, "frames 2 and 3 repeat Z = 1.0 mm"),
        ({0: 0.0, 1: 2.0, 2: 1.0}, 3, r"not monotonic: frame 2 \(1.0 mm\) after frame 1 \(2.0 mm\)"),
    ],
)
def test_z_csv_rows_are_validated(rows, n_frames, message):
    with pytest.raises(ValueError, match=message):
        zstack_heights_mm(rows, n_frames)


def test_z_heights_in_frame_order():
    assert zstack_heights_mm({1: 3.0, 2: 2.0, 3: -1.0}, 3) == [3.0, 2.0, -1.0]


def test_levenberg_marquardt_reaches_scipys_minimum():
    # Our LM on the block-sparse normal equations against scipy's MINPACK on the dense Jacobian, same start.
    from scipy.optimize import least_squares

    from fringelab.science.calibration import _build_problem, _initial_candidates, _levenberg_marquardt

    camera = reference_camera("512x480")
    views = pose_views(camera, rng=np.random.default_rng(26), sigma_px=SIGMA_PX, n_views=6)
    (_, start), *_ = _initial_candidates(views, (512, 480), mode="poses", du=96.0, dv=96.0, scale_on="v")
    problem = _build_problem(views, mode="poses")
    ours, converged = _levenberg_marquardt(problem, start)
    reference = least_squares(problem.residual, start, jac=problem.jacobian, method="lm", x_scale="jac",
                              xtol=1e-12, ftol=1e-12, gtol=1e-12)  # fmt: skip
    assert converged and reference.status > 0
    cost_ours, cost_scipy = (float(np.sum(problem.residual(x) ** 2)) for x in (ours, reference.x))
    assert cost_ours <= cost_scipy * (1 + 1e-9)  # the same minimum, to round-off in the cost
    np.testing.assert_allclose(ours[:4], reference.x[:4], rtol=1e-6)  # fx, fy, cx, cy


@pytest.mark.parametrize("scale_on", ["u", "v"])
def test_covariance_conversion_jacobian(scale_on):
    # The block-diagonal Jacobian used to carry the covariance over, against differences of the whole conversion.
    from fringelab.science.calibration import CAMERA_PARAMETERS, _heikkila_from_opencv_jacobian
    from fringelab.science.camera import OpenCVCamera, camera_from_opencv

    o = camera_as_opencv(dataclasses.replace(reference_camera("1024x1024"), scale_on=scale_on))
    x14 = np.array(
        [o.fx_px, o.fy_px, o.cx_px, o.cy_px, o.k1, o.k2, o.p1, o.p2, *o.r_cam_from_obj_rad, *o.t_cam_from_obj_mm]
    )

    def heikkila(x):
        camera = camera_from_opencv(
            OpenCVCamera(1024, 1024, *x[:8], r_cam_from_obj_rad=tuple(x[8:11]), t_cam_from_obj_mm=tuple(x[11:])),
            du_px_per_mm=212.59, dv_px_per_mm=212.59, scale_on=scale_on,
        )  # fmt: skip
        return np.array([getattr(camera, name) for name in CAMERA_PARAMETERS])

    expected = np.empty((14, 14))
    for j in range(14):
        step = np.zeros(14)
        step[j] = 1e-6 * max(abs(x14[j]), 1e-3)
        expected[:, j] = (heikkila(x14 + step) - heikkila(x14 - step)) / (2 * step[j])
    jacobian = _heikkila_from_opencv_jacobian(x14, du=212.59, dv=212.59, scale_on=scale_on)
    # Both are central differences of smooth maps: agreement to ~1e-8 of each entry's scale.
    np.testing.assert_allclose(jacobian, expected, rtol=1e-6, atol=1e-8 * np.max(np.abs(expected)))
