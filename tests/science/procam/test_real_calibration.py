"""The real rig's calibration (../shared/data/real_structured_light_sphere/calibration.yml) tested against the
matched circle-grid centres it was made from (calibration_original/: 12 poses of an asymmetric grid of 21 columns
of 7 circles, camera and projector pixels of each): which conventions the file holds (docs/procam.md §8).

The grid: columns 10 mm apart, circles 20 mm apart within a column, every other column shifted by 10 mm (OpenCV's
asymmetric circle grid). The 10 mm is not given anywhere: it is what makes OpenCV's stereo fit of these centres
reproduce the file's T, and it comes out a round 10.000 mm.

The data live beside the checkout (not on a user's machine): skipped when absent.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from fringelab.formats.procam import read_procam_calibration
from fringelab.science.procam import ProcamModel, normalised_from_pixels, project_to_camera, project_to_projector

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "real_structured_light_sphere"
if not DATA.is_dir():
    print(f"skipping real calibration tests: {DATA.resolve()} not found (it ships only beside the repo)")
    pytestmark = pytest.mark.skip(reason=f"{DATA} not found")

N_POSES, PER_POSE = 12, 147
GRID_MM = np.array([[10.0 * j, 10.0 * (2 * i + j % 2), 0.0] for j in range(21) for i in range(7)])


@pytest.fixture(scope="module")
def model() -> ProcamModel:
    return read_procam_calibration(DATA / "calibration.yml")


@pytest.fixture(scope="module")
def centres() -> tuple[np.ndarray, np.ndarray]:
    """Camera and projector pixels of the circle centres, each (12, 147, 2)."""
    original = DATA / "calibration_original"
    camera = np.loadtxt(original / "cameraCirclePointsRight.txt").reshape(N_POSES, PER_POSE, 2)
    projector = np.loadtxt(original / "projectorCirclePoints.txt").reshape(N_POSES, PER_POSE, 2)
    return camera, projector


def _stereo_fit(model: ProcamModel, camera: np.ndarray, projector: np.ndarray, camera_matrix: np.ndarray,
                camera_dist: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:  # fmt: skip
    """OpenCV's stereo fit of the centres with both devices' intrinsics fixed: RMS (px), R, T."""
    rms, *_, rotation, translation, _, _ = cv2.stereoCalibrate(
        [GRID_MM.astype(np.float32)] * N_POSES, [c.astype(np.float32).reshape(-1, 1, 2) for c in camera],
        [p.astype(np.float32).reshape(-1, 1, 2) for p in projector], camera_matrix, camera_dist,
        model.projector_matrix, model.projector_dist, model.camera_size_wh_px, flags=cv2.CALIB_FIX_INTRINSIC,
    )  # fmt: skip
    return float(rms), rotation, translation.ravel()


def test_the_file_is_opencvs_stereo_fit_of_its_own_circle_centres(model: ProcamModel, centres) -> None:
    """R and T are what cv2.stereoCalibrate returns for (camera, projector) with the file's intrinsics: they take
    camera coordinates to projector coordinates, in mm (a round 10 mm grid), and the projector's pixels are
    those of projectorCirclePoints.txt (912 columns; rows in square pixels: see test_real_scan.py)."""
    rms, rotation, translation = _stereo_fit(model, *centres, model.camera_matrix, model.camera_dist)
    angle_deg = np.degrees(np.linalg.norm(cv2.Rodrigues(rotation @ model.r_proj_from_cam.T)[0]))
    assert angle_deg < 0.001, angle_deg  # measured 0.0000°
    assert np.max(np.abs(translation - model.t_proj_from_cam_mm)) < 0.01, translation  # measured < 0.001 mm
    assert 1.1 < rms < 1.3, rms  # measured 1.206 px (see the next two tests)


def _reprojection_rms(model: ProcamModel, camera_q: np.ndarray, projector_q: np.ndarray) -> tuple[float, float]:
    """Each matched pair triangulated with `model` (undistorted rays, linear triangulation), then projected back
    into both devices: RMS (px) of the camera's and of the projector's residuals."""
    rays_cam = normalised_from_pixels(model.camera_matrix, model.camera_dist, camera_q)
    rays_proj = normalised_from_pixels(model.projector_matrix, model.projector_dist, projector_q)
    pose = np.column_stack([model.r_proj_from_cam, model.t_proj_from_cam_mm])
    homogeneous = cv2.triangulatePoints(np.eye(3, 4), pose, rays_cam.T, rays_proj.T)
    points = (homogeneous[:3] / homogeneous[3]).T
    camera = np.linalg.norm(project_to_camera(model, points) - camera_q, axis=1)
    projector = np.linalg.norm(project_to_projector(model, points) - projector_q, axis=1)
    return float(np.sqrt(np.mean(camera**2))), float(np.sqrt(np.mean(projector**2)))


def _variant(model: ProcamModel, **changes) -> ProcamModel:
    names = ("camera_matrix", "camera_dist", "camera_size_wh_px", "projector_matrix", "projector_dist",
             "projector_size_wh_px", "r_proj_from_cam", "t_proj_from_cam_mm")  # fmt: skip
    fields = {name: getattr(model, name) for name in names}
    fields.update(changes)
    return ProcamModel(**fields)


def test_the_imported_conventions_reproject_the_centres_and_no_other_does(model: ProcamModel, centres) -> None:
    camera, projector = (a.reshape(-1, 2) for a in centres)
    r, t = model.r_proj_from_cam, model.t_proj_from_cam_mm
    camera_rms, projector_rms = _reprojection_rms(model, camera, projector)
    # As imported (fringelab's triangulation and projection): measured 1.765 px camera, 0.713 px projector.
    assert camera_rms < 2.0 and projector_rms < 0.8, (camera_rms, projector_rms)
    wrong = {
        "R transposed": (_variant(model, r_proj_from_cam=r.T), projector),
        "projector to camera (R, T inverted)": (_variant(model, r_proj_from_cam=r.T, t_proj_from_cam_mm=-r.T @ t),
                                                projector),
        "projector rows ×2 (1140 rows)": (model, projector * [1.0, 2.0]),
        "projector rows ×½": (model, projector * [1.0, 0.5]),
        "projector columns ×2 (1824 columns)": (model, projector * [2.0, 1.0]),
        "pixel centres at ½ in the projector only": (model, projector + 0.5),
    }  # fmt: skip
    for name, (variant, q_projector) in wrong.items():
        other_camera, other_projector = _reprojection_rms(variant, camera, q_projector)
        if name.startswith("pixel centres"):
            # Half a pixel is near what this calibration holds, yet it fits worse: measured 1.869 px camera.
            assert other_camera > camera_rms + 0.05, name
            continue
        # measured ≥ 35 px camera and ≥ 12 px projector for each
        assert other_camera > 10 * camera_rms and other_projector > 10 * projector_rms, (name, other_camera)


def test_the_files_camera_intrinsics_are_not_those_of_its_circle_centres(model: ProcamModel, centres) -> None:
    """The camera reproduces its own centres to 0.3 px with the file's K (a pose each), yet the pair reprojects
    them to 1.2 px: refitting the camera to these centres alone gives f = 2618 px (a 12 mm lens on 4.54 µm
    pixels is 2643 px; the file's is 2130 px) and the pair then to 0.52 px with another T (z 14 mm instead of
    83 mm). The file's camera K came from elsewhere; a scan with it inherits the difference (docs/procam.md §8)."""
    camera, projector = centres
    per_pose = []
    for q in camera:
        _, rvec, tvec = cv2.solvePnP(GRID_MM, q, model.camera_matrix, model.camera_dist)
        predicted = cv2.projectPoints(GRID_MM, rvec, tvec, model.camera_matrix, model.camera_dist)[0].reshape(-1, 2)
        per_pose.append(np.sqrt(np.mean(np.sum((predicted - q) ** 2, axis=1))))
    assert max(per_pose) < 0.4, per_pose  # measured 0.26–0.37 px
    own_rms, own_matrix, own_dist, _, _ = cv2.calibrateCamera(
        [GRID_MM.astype(np.float32)] * N_POSES, [c.astype(np.float32).reshape(-1, 1, 2) for c in camera],
        model.camera_size_wh_px, None, None,
    )  # fmt: skip
    assert own_rms < 0.35  # measured 0.300 px
    assert 2500 < own_matrix[0, 0] < 2750, own_matrix[0, 0]  # measured 2618 px against the file's 2130 px
    rms, _, translation = _stereo_fit(model, camera, projector, own_matrix, own_dist)
    assert rms < 0.6, rms  # measured 0.520 px, against 1.206 px with the file's camera
    assert abs(translation[2] - model.t_proj_from_cam_mm[2]) > 50  # measured z 13.6 mm against the file's 82.8 mm
