"""Z-stack calibration of rendered chessboard recordings against the known camera (docs/method.md §7)."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.science.calibration import CAMERA_PARAMETERS
from fringelab.science.camera import backproject_to_z, project_points

SIZES = ("512x480", "1024x1024")


@pytest.mark.parametrize("size", SIZES)
def test_reprojection_rms_is_the_noise_level(size, calibrations, zstack_recordings):
    calibration, truth = calibrations[size], zstack_recordings[size].camera
    residuals = calibration.residuals
    # The noise the images put on the corners: detected minus true corner pixels.
    corner_error_px = residuals.q_px - project_points(truth, residuals.points_obj_mm)
    n_obs, n_params = 2 * calibration.n_points, 14
    implied_rms_px = np.sqrt(np.mean(np.sum(corner_error_px**2, axis=1)) * (n_obs - n_params) / n_obs)
    print(f"{size}: RMS {calibration.rms_px:.4f} px, implied by the corner noise {implied_rms_px:.4f} px")
    # 10 %: the brief's acceptance; corner errors are not purely random (blur, aliasing), so the fit may absorb
    # a little more than the Gaussian degrees-of-freedom factor says.
    assert calibration.rms_px == pytest.approx(implied_rms_px, rel=0.10)
    assert calibration.verdict.level == "good", calibration.verdict.reasons


@pytest.mark.parametrize("size", SIZES)
def test_corners_backprojected_at_true_z(size, calibrations, zstack_recordings):
    calibration, truth = calibrations[size], zstack_recordings[size].camera
    points_obj_mm = calibration.residuals.points_obj_mm
    q_true_px = project_points(truth, points_obj_mm)
    back = backproject_to_z(calibration.camera, q_true_px, points_obj_mm[:, 2], inverse=calibration.inverse)
    rms_mm = np.sqrt(np.mean(np.sum((back - points_obj_mm) ** 2, axis=1)))
    print(f"{size}: back-projection RMS {rms_mm:.5f} mm")
    assert rms_mm < 0.02  # docs/method.md §7: 0.02 mm at 2 m


@pytest.mark.parametrize("size", SIZES)
def test_parameters_within_their_standard_errors(size, calibrations, zstack_recordings):
    calibration, truth = calibrations[size], zstack_recordings[size].camera
    z_scores = {
        name: (getattr(calibration.camera, name) - getattr(truth, name)) / calibration.standard_errors[name]
        for name in CAMERA_PARAMETERS
    }
    # Honest standard errors: every parameter within 5 σ of the truth (corner errors are not exactly Gaussian,
    # so a 3 σ bound would be too tight for 14 correlated parameters at both sizes).
    assert max(abs(z) for z in z_scores.values()) < 5, z_scores


@pytest.mark.parametrize("size", SIZES)
def test_inverse_model_and_result_contents(size, calibrations, zstack_recordings):
    calibration = calibrations[size]
    assert calibration.inverse.residual_px < 1e-3
    assert [f.status for f in calibration.frames] == ["used"] * len(zstack_recordings[size].z_mm)
    np.testing.assert_allclose([f.z_mm for f in calibration.frames], zstack_recordings[size].z_mm)
    assert calibration.provenance["input_sha256"]
    assert calibration.residual_map.coverage > 0.5
