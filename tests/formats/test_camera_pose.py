"""The calibration document states the pose both ways, each named for what it is: x0, y0, z0 are the plate's
origin in the camera frame, and the camera's projection centre in the plate frame is derived from them."""

from __future__ import annotations

import json

import numpy as np

from fringelab.formats.camera import write_camera_json
from fringelab.science.camera import project_points
from fringelab.science.virtual_test import preset, true_camera_calibration


def test_pose_both_ways(tmp_path):
    camera = preset("kodak").camera
    document = json.loads(write_camera_json(true_camera_calibration(camera), tmp_path / "camera.json").read_text())
    pose = document["pose"]
    origin_cam = np.array(pose["object_origin_in_camera_mm"])
    centre_obj = np.array(pose["camera_centre_in_object_mm"])
    np.testing.assert_allclose(origin_cam, [camera.x0_mm, camera.y0_mm, camera.z0_mm], atol=1e-9)
    # Truth: the projection centre maps to the camera frame's origin, M·C + t = 0 (1e-6 mm: float64 round-off
    # on a 2 m scale).
    np.testing.assert_allclose(camera.rotation @ centre_obj + origin_cam, 0.0, atol=1e-6)
    # And every point on the line through C and a plate point projects to the same pixel as that point (to
    # 1e-6 px): C is where the rays meet, not the translation.
    point = np.array([[30.0, -20.0, 0.0]])
    towards = centre_obj + 0.5 * (point[0] - centre_obj)
    np.testing.assert_allclose(project_points(camera, towards[None, :]), project_points(camera, point), atol=1e-6)
    assert np.linalg.norm(centre_obj - origin_cam) > 1.0  # the two are not the same numbers
