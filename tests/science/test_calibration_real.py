"""Real images: OpenCV's left01..left14 chessboard photographs in poses mode, against OpenCV's own result.

The data live beside the checkout in ../shared/data/opencv_left (not on a user's machine): skipped when absent.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fringelab.formats.recordings import open_recording
from fringelab.pipelines.camera_calibration import calibrate_camera_recording
from fringelab.science.calibration import CornerView, calibrate_from_views
from fringelab.science.camera import project_points
from fringelab.science.chessboard import Board

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "opencv_left"
BOARD = Board(cols=9, rows=6, square_mm=25.0)
IMAGE_SIZE = (640, 480)

if not (DATA / "reference_opencv.json").is_file():
    print(f"skipping real-image calibration tests: {DATA.resolve()} not found (it ships only beside the repo)")
    pytestmark = pytest.mark.skip(reason=f"{DATA} not found")


@pytest.fixture(scope="module")
def reference() -> dict:
    return json.loads((DATA / "reference_opencv.json").read_text())


def intrinsics(calibration) -> dict[str, float]:
    o = calibration.opencv
    return {"fx": o.fx_px, "fy": o.fy_px, "cx": o.cx_px, "cy": o.cy_px}


def test_default_pipeline_matches_opencv(reference):
    # f in pixels: the pixel pitch of these images is unknown, so D_u = D_v = 1 px/mm.
    calibration = calibrate_camera_recording(
        open_recording(DATA), board=BOARD, mode="poses", du_px_per_mm=1.0, dv_px_per_mm=1.0
    )
    print(f"default corners: RMS {calibration.rms_px:.4f} px (OpenCV {reference['rms_reprojection_error_px']:.4f})")
    for name, value in intrinsics(calibration).items():
        print(f"  {name} {value:.3f} (OpenCV {reference[name]:.3f})")
        assert value == pytest.approx(reference[name], rel=0.01)  # docs/method.md §7: 1 %
    # Our corner window is sized to the squares; OpenCV's fixed 23 × 23 px window reaches the neighbouring
    # corners on left02's small squares (its 1.22 px outlier). So our RMS is lower, never higher.
    assert calibration.rms_px < reference["rms_reprojection_error_px"] * 1.05
    assert [f.frame for f in calibration.frames] == reference["images_found"]
    assert all(f.status == "used" for f in calibration.frames)


def test_opencv_procedure_reproduces_opencv(reference):
    # The sample's procedure: findChessboardCorners, cornerSubPix with an 11 px half-window.
    calibration = calibrate_camera_recording(
        open_recording(DATA), board=BOARD, mode="poses", du_px_per_mm=1.0, dv_px_per_mm=1.0, detector="classic",
        subpix_half_window_px=11,
    )  # fmt: skip
    # The brief asks 5 %; the same detector, window and model reach the same minimum, so it agrees to 1e-6.
    assert calibration.rms_px == pytest.approx(reference["rms_reprojection_error_px"], rel=1e-6)
    for name, value in intrinsics(calibration).items():
        assert value == pytest.approx(reference[name], rel=0.01)
    left02 = next(f for f in calibration.frames if f.frame == "left02.jpg")
    assert left02.rms_px == pytest.approx(1.2207, rel=0.05)
    cleaned = calibrate_camera_recording(
        open_recording(DATA), board=BOARD, mode="poses", du_px_per_mm=1.0, dv_px_per_mm=1.0, detector="classic",
        subpix_half_window_px=11, reject_outliers=True,
    )  # fmt: skip
    assert [f.frame for f in cleaned.frames if f.status == "rejected"] == ["left02.jpg"]


def test_reference_corners_give_opencvs_camera(reference):
    # OpenCV's own sub-pixel corners given to our solver: the same model at the same minimum.
    cols, rows = reference["pattern_inner_corners_cols_rows"]
    square = reference["square_size"]
    j_index, i_index = np.mgrid[0:rows, 0:cols]
    board_points = np.column_stack([i_index.ravel() * square, j_index.ravel() * square, np.zeros(cols * rows)])
    views = [
        CornerView(name, board_points, np.array(reference["corners_subpix_px"][name], dtype=np.float64).reshape(-1, 2))
        for name in reference["images_found"]
    ]
    calibration = calibrate_from_views(
        views, image_size_wh_px=IMAGE_SIZE, mode="poses", du_px_per_mm=1.0, dv_px_per_mm=1.0
    )
    k = np.array([[reference["fx"], 0, reference["cx"]], [0, reference["fy"], reference["cy"]], [0, 0, 1]])
    dist = np.array([reference[name] for name in ("k1", "k2", "p1", "p2", "k3")])
    worst_px = 0.0
    for frame, per_image in zip(calibration.frames, reference["per_image"], strict=True):
        ours = calibration.camera.__class__(
            **{**calibration.camera.__dict__, **_pose_fields(frame.r_cam_from_obj_rad, frame.t_cam_from_obj_mm)}
        )
        theirs, _ = cv2.projectPoints(board_points, np.array(per_image["rvec"]), np.array(per_image["tvec"]), k, dist)
        worst_px = max(worst_px, float(np.max(np.abs(project_points(ours, board_points) - theirs.reshape(-1, 2)))))
    print(f"reference corners: RMS {calibration.rms_px:.6f} px, worst model difference {worst_px:.2e} px")
    assert worst_px < 1e-3  # the brief: agreement to 1e-3 px
    # The stored corners are rounded to 1e-4 px, which moves the RMS by ~2e-6 relative.
    assert calibration.rms_px == pytest.approx(reference["rms_reprojection_error_px"], rel=2e-5)


def _pose_fields(r_cam_from_obj_rad, t_cam_from_obj_mm) -> dict[str, float]:
    from fringelab.science.camera import angles_from_rotation

    omega, phi, kappa = angles_from_rotation(Rotation.from_rotvec(r_cam_from_obj_rad).as_matrix())
    x0, y0, z0 = t_cam_from_obj_mm
    return {"omega_rad": omega, "phi_rad": phi, "kappa_rad": kappa, "x0_mm": x0, "y0_mm": y0, "z0_mm": z0}
