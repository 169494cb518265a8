"""The camera–projector pair: the projector as an inverse camera (docs/procam.md §1, §4).

Belongs here: `ProcamModel` (OpenCV pinhole + distortion for both, and the stereo pose R, T taking camera
coordinates to projector coordinates, in mm), projecting camera-frame points into the projector, camera rays,
and triangulation of a camera pixel against a projector column (or row) with the projector's distortion, with the
derivatives that carry σ. Not here: estimating the model (`procam_calibration.py`), decoding (`graycode.py`),
files (`fringelab.formats.procam`).

Frames. Camera frame: OpenCV's (x right, y down, z along the optical axis), mm. Projector frame: the same for the
projector, `p_proj = R · p_cam + T`. Pixels of either: (u, v) = (column, row), (0, 0) the centre of the top-left
pixel. Distortion coefficients in OpenCV's order (k1, k2, p1, p2, k3).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from .arrays import checked_array

CodeAxis = Literal["columns", "rows"]


@dataclass(frozen=True, eq=False)
class ProcamModel:
    """A calibrated camera–projector pair.

    camera_matrix, projector_matrix: K, shape (3, 3). camera_dist, projector_dist: (5,) (k1, k2, p1, p2, k3).
    r_proj_from_cam: (3, 3) rotation; t_proj_from_cam_mm: (3,), so p_proj = R·p_cam + T.
    camera_size_wh_px, projector_size_wh_px: image sizes (width, height).
    camera_rms_px, projector_rms_px: reprojection RMS of the calibration that made the model, NaN when unknown
    (an imported file that does not say); n_observations: the corner coordinates it was fitted to (0: unknown).
    Together they give the model's own σ of a predicted pixel (`camera_sigma_px`, `projector_sigma_px`), which
    enters every point's σ.
    """

    camera_matrix: np.ndarray
    camera_dist: np.ndarray
    camera_size_wh_px: tuple[int, int]
    projector_matrix: np.ndarray
    projector_dist: np.ndarray
    projector_size_wh_px: tuple[int, int]
    r_proj_from_cam: np.ndarray
    t_proj_from_cam_mm: np.ndarray
    camera_rms_px: float = float("nan")
    projector_rms_px: float = float("nan")
    n_observations: int = 0

    def __post_init__(self) -> None:
        for name, shape in (("camera_matrix", (3, 3)), ("projector_matrix", (3, 3)), ("r_proj_from_cam", (3, 3)),
                            ("t_proj_from_cam_mm", (3,))):  # fmt: skip
            object.__setattr__(self, name, checked_array(getattr(self, name), shape=shape, name=name))
        for name in ("camera_dist", "projector_dist"):
            values = np.asarray(getattr(self, name), np.float64).ravel()
            if values.size not in (4, 5, 8, 12, 14):
                raise ValueError(
                    f"{name}: expected 4, 5, 8, 12 or 14 OpenCV distortion coefficients, got {values.size}"
                )
            object.__setattr__(self, name, values)
        rotation = self.r_proj_from_cam
        if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-5) or np.linalg.det(rotation) < 0:
            raise ValueError("r_proj_from_cam: expected a rotation matrix (orthonormal, determinant +1)")
        for name in ("camera_size_wh_px", "projector_size_wh_px"):
            size = tuple(int(v) for v in getattr(self, name))
            if len(size) != 2 or min(size) < 1:
                raise ValueError(f"{name}: expected (width, height) ≥ 1 px, got {getattr(self, name)}")
            object.__setattr__(self, name, size)

    @property
    def camera_sigma_px(self) -> float:
        """σ of a camera pixel the model predicts: RMS·√(p/n) with p = MODEL_PARAMETERS (as a fitted
        polynomial's prediction error); NaN when the calibration's RMS or size is unknown."""
        return _prediction_sigma(self.camera_rms_px, self.n_observations)

    @property
    def projector_sigma_px(self) -> float:
        return _prediction_sigma(self.projector_rms_px, self.n_observations)

    @property
    def projector_centre_cam_mm(self) -> np.ndarray:
        """The projector's centre in the camera frame, shape (3,)."""
        return -self.r_proj_from_cam.T @ self.t_proj_from_cam_mm

    def same_as(self, other: ProcamModel) -> bool:
        """Whether every number agrees exactly (the models carry arrays, so == is not defined)."""
        return all(
            np.array_equal(getattr(self, name), getattr(other, name), equal_nan=True)
            for name in ("camera_matrix", "camera_dist", "projector_matrix", "projector_dist", "r_proj_from_cam",
                         "t_proj_from_cam_mm", "camera_size_wh_px", "projector_size_wh_px", "camera_rms_px",
                         "projector_rms_px", "n_observations")
        )  # fmt: skip


# Parameters of one device in the calibration: fx, fy, cx, cy, k1, k2, p1, p2, and the 6 of the stereo pose.
MODEL_PARAMETERS = 14


def _prediction_sigma(rms_px: float, n_observations: int) -> float:
    if not (np.isfinite(rms_px) and n_observations > MODEL_PARAMETERS):
        return float("nan")
    return float(rms_px * np.sqrt(MODEL_PARAMETERS / n_observations))


def project_to_camera(model: ProcamModel, points_cam_mm: np.ndarray) -> np.ndarray:
    """Camera pixels, shape (N, 2), of camera-frame points, shape (N, 3)."""
    p = checked_array(points_cam_mm, shape=(None, 3), name="points_cam_mm")
    return distorted_pixels(model.camera_matrix, model.camera_dist, p)


def project_to_projector(model: ProcamModel, points_cam_mm: np.ndarray) -> np.ndarray:
    """Projector pixels, shape (N, 2), of camera-frame points, shape (N, 3)."""
    p = checked_array(points_cam_mm, shape=(None, 3), name="points_cam_mm")
    return distorted_pixels(model.projector_matrix, model.projector_dist,
                            rigid_transform(model.r_proj_from_cam, model.t_proj_from_cam_mm, p))  # fmt: skip


def rigid_transform(rotation: np.ndarray, translation: np.ndarray, points: np.ndarray) -> np.ndarray:
    """R·p + t for points (N, 3), written per component: a BLAS matrix product of (N, 3) by (3, 3) is slower than
    this (and far slower on a machine whose cores are all busy, where BLAS threads wait for each other)."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    out = np.empty_like(points, dtype=np.float64)
    for i in range(3):
        out[:, i] = rotation[i, 0] * x + rotation[i, 1] * y + rotation[i, 2] * z + translation[i]
    return out


def distorted_pixels(matrix: np.ndarray, dist: np.ndarray, points_mm: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of points (N, 3) in the device's own frame: OpenCV's model with (k1, k2, p1, p2, k3), as
    cv2.projectPoints computes it (to 1e-12 px) but vectorised over many points; longer coefficient lists (rational,
    thin prism, tilt) go to cv2.projectPoints."""
    if len(dist) > 5:
        q, _ = cv2.projectPoints(points_mm.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), matrix, dist)
        return q.reshape(-1, 2)
    k1, k2, p1, p2, k3 = (list(dist) + [0.0] * 5)[:5]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = points_mm[:, 0] / points_mm[:, 2]
        y = points_mm[:, 1] / points_mm[:, 2]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.column_stack([matrix[0, 0] * xd + matrix[0, 2], matrix[1, 1] * yd + matrix[1, 2]])


# Undistortion iterates until the distorted point is reproduced to far below any tolerance used here.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


def normalised_from_pixels(matrix: np.ndarray, dist: np.ndarray, q_px: np.ndarray) -> np.ndarray:
    """Undistorted normalised coordinates (x/z, y/z), shape (N, 2), of pixels q_px, shape (N, 2)."""
    q = checked_array(q_px, shape=(None, 2), name="q_px")
    if len(q) == 0:
        return np.zeros((0, 2))
    out = cv2.undistortPointsIter(
        q.reshape(-1, 1, 2),
        matrix,
        dist,
        None,
        None,
        _UNDISTORT_CRITERIA,  # type: ignore[call-overload]
    )
    return out.reshape(-1, 2).astype(np.float64)


def camera_rays(model: ProcamModel, q_px: np.ndarray) -> np.ndarray:
    """Directions (x/z, y/z, 1), shape (N, 3), of camera pixels q_px, shape (N, 2), in the camera frame."""
    xy = normalised_from_pixels(model.camera_matrix, model.camera_dist, q_px)
    return np.column_stack([xy, np.ones(len(xy))])


def _projector_coordinate(model: ProcamModel, points_cam_mm: np.ndarray, index: int) -> np.ndarray:
    return project_to_projector(model, points_cam_mm)[:, index]


def triangulate(
    model: ProcamModel, q_px: np.ndarray, projector_px: np.ndarray, *, axis: CodeAxis
) -> tuple[np.ndarray, np.ndarray]:
    """Where each camera pixel's ray meets the projector's column (axis "columns") or row surface at
    projector_px, distortion included.

    q_px: (N, 2) camera pixels; projector_px: (N,) projector x (columns) or y (rows).
    Returns points_cam_mm (N, 3) (NaN where the ray does not meet the surface in front of both) and
    dz_dprojector (N,): the depth's rate along the ray per projector pixel, ∂|p|/∂x_p in mm/px, for σ.

    The surface of one projector column is a plane through the projector's centre when the projector has no
    distortion; with it, it bends. The depth λ along the ray (p = λ·d, d = (x/z, y/z, 1)) solves
    x_p(λ·d) = projector_px; it starts from the plane of the undistorted column at the point's projector row and
    then Newton's steps on the distorted projection, with a numerical derivative, converge in a few steps.
    """
    q = checked_array(q_px, shape=(None, 2), name="q_px")
    target = checked_array(projector_px, shape=(len(q),), name="projector_px")
    index = 0 if axis == "columns" else 1
    d = camera_rays(model, q)
    centre = model.projector_centre_cam_mm
    r = model.r_proj_from_cam
    # Start: the plane through the projector centre of the undistorted column (row) at the projector's middle row
    # (column), refined once with the row (column) that start point has.
    other = np.full(len(q), 0.5 * (model.projector_size_wh_px[1 - index] - 1))
    lam = np.full(len(q), np.nan)
    for _ in range(2):
        q_proj = np.column_stack([target, other] if index == 0 else [other, target])
        n_proj = np.column_stack(
            [normalised_from_pixels(model.projector_matrix, model.projector_dist, q_proj), np.ones(len(q))]
        )
        # Plane through the projector centre containing the ray n_proj and the projector's other axis.
        along = np.zeros(3)
        along[1 - index] = 1.0
        normal_proj = np.cross(n_proj, along)
        normal_cam = normal_proj @ r  # (Rᵀ·n)ᵀ
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = np.sum(normal_cam * centre, axis=1) / np.sum(normal_cam * d, axis=1)
        points = lam[:, None] * d
        good = np.isfinite(lam) & (lam > 0)
        if np.any(good):
            other = np.where(good, project_to_projector(model, np.where(good[:, None], points, 1.0))[:, 1 - index],
                             other)  # fmt: skip
    derivative = np.full(len(q), np.nan)
    for _ in range(8):
        points = lam[:, None] * d
        ok = np.isfinite(lam) & (lam > 0)
        safe = np.where(ok[:, None], points, 1.0)
        value = _projector_coordinate(model, safe, index)
        step_lam = 1e-6 * np.where(ok, lam, 1.0)
        value_2 = _projector_coordinate(model, safe + step_lam[:, None] * d, index)
        derivative = (value_2 - value) / step_lam
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = (value - target) / derivative
        lam = np.where(ok, lam - delta, np.nan)
        if np.nanmax(np.abs(delta), initial=0.0) < 1e-10 * max(float(np.nanmax(np.abs(lam), initial=1.0)), 1.0):
            break
    ok = np.isfinite(lam) & (lam > 0)
    points = np.where(ok[:, None], lam[:, None] * d, np.nan)
    in_front = ok.copy()
    in_front[ok] = rigid_transform(r, model.t_proj_from_cam_mm, points[ok])[:, 2] > 0
    points[~in_front] = np.nan
    norm_d = np.linalg.norm(d, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.where(in_front, norm_d / np.abs(derivative), np.nan)
    return points, rate


def point_sigma_mm(
    model: ProcamModel,
    q_px: np.ndarray,
    projector_px: np.ndarray,
    *,
    axis: CodeAxis,
    sigma_projector_px: np.ndarray,
    sigma_camera_px: np.ndarray,
    scan_axis: Literal["rows", "cols"],
) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) and their σ (N,) in mm along the ray (the one direction a structured-light point is uncertain
    in, to first order).

    sigma_projector_px: (N,) σ of the projector coordinate (a band's width for a code point, the calibration's
    projector RMS for an edge); sigma_camera_px: (N,) σ of the camera position along the scan line (the edge's σ
    and the calibration's camera RMS). The camera term moves the pixel along the scan line by one pixel and
    triangulates again (the derivative), the projector term uses ∂depth/∂x_p of `triangulate`.
    """
    q = checked_array(q_px, shape=(None, 2), name="q_px")
    points, rate = triangulate(model, q, projector_px, axis=axis)
    shift = np.array([1.0, 0.0]) if scan_axis == "rows" else np.array([0.0, 1.0])
    moved, _ = triangulate(model, q + shift, projector_px, axis=axis)
    per_px = np.linalg.norm(moved - points, axis=1)
    sigma = np.sqrt((rate * np.asarray(sigma_projector_px)) ** 2 + (per_px * np.asarray(sigma_camera_px)) ** 2)
    return points, sigma


def reprojection_of_truth_px(
    model: ProcamModel, truth: ProcamModel, points_cam_mm: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """How well a recovered model reproduces the true camera and projector pixels of points (N, 3) given in the
    TRUE camera frame: each model's camera frame is its own (a calibration fixes it only through the camera's
    intrinsics, so a principal point off by a pixel is the same camera turned by a milliradian), so the points
    are first moved by the rigid motion that fits the model best to the true pixels of both devices, then
    projected. Returns the distances (N,) in px of the camera and of the projector."""
    from scipy.optimize import least_squares

    p = checked_array(points_cam_mm, shape=(None, 3), name="points_cam_mm")
    q_cam, q_proj = project_to_camera(truth, p), project_to_projector(truth, p)

    def moved(x: np.ndarray) -> np.ndarray:
        return p @ cv2.Rodrigues(x[:3])[0].T + x[3:]

    def residual(x: np.ndarray) -> np.ndarray:
        m = moved(x)
        return np.concatenate([(project_to_camera(model, m) - q_cam).ravel(),
                               (project_to_projector(model, m) - q_proj).ravel()])  # fmt: skip

    fit = least_squares(residual, np.zeros(6), x_scale=np.array([1e-3, 1e-3, 1e-3, 1.0, 1.0, 1.0]), xtol=1e-14,
                        ftol=1e-14, gtol=1e-14)  # fmt: skip
    m = moved(fit.x)
    camera = np.linalg.norm(project_to_camera(model, m) - q_cam, axis=1)
    projector = np.linalg.norm(project_to_projector(model, m) - q_proj, axis=1)
    return camera, projector
