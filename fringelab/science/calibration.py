"""Camera calibration from chessboard corners (docs/method.md §3.1): Z-stack (the paper) and free poses (Zhang).

Belongs here: the solver (3-D DLT start, Levenberg–Marquardt, covariance), per-frame statistics, outlier-frame
rejection, the residual map, the verdict, the `CameraCalibration` result, and `calibrate_camera_recording`, the
one entry point the CLI and the Celery task call. Not here: the camera model (`camera.py`), corner detection
(`chessboard.py`), files (`fringelab.formats.recordings.py`, `fringelab.formats.camera.py`).

The Levenberg–Marquardt runs over an equivalent, well-conditioned form of the same model: OpenCV's intrinsics
(fx, fy, cx, cy, k1..p2 on normalised coordinates), a Rodrigues vector and a translation per pose. With D_u, D_v
fixed this is a one-to-one reparametrisation of the 14 Heikkilä parameters (docs/method.md §3), so the minimum is the
same; cv2.projectPoints supplies the analytic Jacobian, the Euler angles' gimbal lock is avoided, and the
covariance is carried over to the Heikkilä parameters with the Jacobian of the exact conversion.
"""

from __future__ import annotations

import contextlib
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, get_args

import cv2
import numpy as np
import scipy.linalg
from scipy.spatial.transform import Rotation

from . import MeasurementError, natural_key
from .arrays import checked_array
from .camera import (
    SCALE_ON_CHOICES,
    Camera,
    InverseModel,
    OpenCVCamera,
    ScaleAxis,
    angles_from_rotation,
    camera_as_opencv,
    camera_from_opencv,
    fit_inverse_model,
)
from .chessboard import Board
from .verdict import VERDICT_LEVELS, YES_NO, Verdict, VerdictCheck, check, verdict_of  # noqa: F401 (re-exported)

CalibrationMode = Literal["zstack", "poses"]  # a Z-stack of one board pose, or free poses
MODES: tuple[str, ...] = get_args(CalibrationMode)

# The 14 estimated Heikkilä parameters, as `Camera` field names, in the order of `correlation`.
CAMERA_PARAMETERS = (
    "su", "f_mm", "u0_px", "v0_px", "k1_per_mm2", "k2_per_mm4", "p1_per_mm", "p2_per_mm",
    "x0_mm", "y0_mm", "z0_mm", "omega_rad", "phi_rad", "kappa_rad",
)  # fmt: skip
OPENCV_PARAMETERS = (
    "fx_px", "fy_px", "cx_px", "cy_px", "k1", "k2", "p1", "p2",
    "rvec_x_rad", "rvec_y_rad", "rvec_z_rad", "tvec_x_mm", "tvec_y_mm", "tvec_z_mm",
)  # fmt: skip

MIN_FRAMES = {"zstack": 3, "poses": 3}
# A frame is an outlier when its RMS exceeds 3 × the median frame RMS and 0.2 px (Heikkilä's residual level),
# so a calibration whose frames are all excellent never loses one to the ratio alone.
OUTLIER_RATIO = 3.0
OUTLIER_FLOOR_PX = 0.2
RESIDUAL_MAP_CELLS = (8, 8)
# Cells with fewer corners say nothing about a local mean.
RESIDUAL_MAP_MIN_COUNT = 3


class CalibrationError(MeasurementError):
    """Calibration cannot be done from what was given: too few usable frames or Z levels, no convergence."""


@dataclass(frozen=True, eq=False)
class CornerView:
    """Corners of one frame: object points, shape (N, 3), and their pixels q_px, shape (N, 2).

    In `zstack` mode all views share one object frame (Z is the stage reading); in `poses` mode each view is in
    its own board frame (Z = 0) and gets its own pose.
    """

    frame: str
    points_obj_mm: np.ndarray
    q_px: np.ndarray
    z_mm: float | None = None

    def __post_init__(self) -> None:
        points = checked_array(self.points_obj_mm, shape=(None, 3), name=f"{self.frame}: points_obj_mm")
        checked_array(self.q_px, shape=(len(points), 2), name=f"{self.frame}: q_px")


@dataclass(frozen=True)
class FrameResult:
    """What happened to one frame: `used`, `skipped` (no board) or `rejected` (outlier), with numbers."""

    frame: str
    status: str
    reason: str = ""
    z_mm: float | None = None
    n_corners: int = 0
    rms_px: float | None = None
    max_px: float | None = None
    r_cam_from_obj_rad: tuple[float, float, float] | None = None
    t_cam_from_obj_mm: tuple[float, float, float] | None = None


@dataclass(frozen=True, eq=False)
class ResidualVectors:
    """Per-corner residuals of the used frames: frame_index (N,) into `frames`, the corner's object point
    points_obj_mm (N, 3) (board frame in poses mode), observed q_px (N, 2), residual_px (N, 2) = observed − model.
    """

    frame_index: np.ndarray
    points_obj_mm: np.ndarray
    q_px: np.ndarray
    residual_px: np.ndarray


@dataclass(frozen=True, eq=False)
class ResidualMap:
    """Residuals binned over the image in cells_v × cells_u cells: count, mean vector, RMS per cell.

    `systematic_px` is the RMS length of the cell mean vectors with the part expected from random noise removed
    (0 for purely random residuals); `coverage` the fraction of cells that hold corners.
    """

    cells_u: int
    cells_v: int
    count: np.ndarray
    mean_px: np.ndarray
    rms_px: np.ndarray
    systematic_px: float
    coverage: float


@dataclass(frozen=True, eq=False)
class CameraCalibration:
    """A calibrated camera with its quality numbers; `read_camera_json` / `write_camera_json` store it."""

    camera: Camera
    inverse: InverseModel
    mode: CalibrationMode
    rms_px: float
    residual_std_px: float
    n_points: int
    standard_errors: dict[str, float]
    opencv_standard_errors: dict[str, float]
    correlation: np.ndarray
    frames: tuple[FrameResult, ...]
    residuals: ResidualVectors
    residual_map: ResidualMap
    verdict: Verdict
    board: Board | None = None
    pixel_pitch_um: tuple[float, float] | None = None
    converged: bool = True
    provenance: dict[str, Any] = field(default_factory=dict)

    @property
    def opencv(self) -> OpenCVCamera:
        return camera_as_opencv(self.camera)


# --------------------------------------------------------------------------------------------------------------
# Initial values


def dlt_camera_matrix(points_obj_mm: np.ndarray, q_px: np.ndarray) -> np.ndarray:
    """The 3 × 4 DLT camera matrix (Abdel-Aziz & Karara) of non-coplanar points, shape (N, 3), and pixels (N, 2).

    Points and pixels are normalised (Hartley) before the SVD so the 11 unknowns are well conditioned.
    """
    points = checked_array(points_obj_mm, shape=(None, 3), name="points_obj_mm")
    q = checked_array(q_px, shape=(len(points), 2), name="q_px")
    if len(points) < 6:
        raise CalibrationError(f"the 3-D DLT needs at least 6 points, got {len(points)}")

    def normaliser(values: np.ndarray) -> np.ndarray:
        centre = values.mean(axis=0)
        scale = np.sqrt(values.shape[1]) / np.mean(np.linalg.norm(values - centre, axis=1))
        transform = np.eye(values.shape[1] + 1)
        transform[:-1, :-1] *= scale
        transform[:-1, -1] = -scale * centre
        return transform

    t_points, t_q = normaliser(points), normaliser(q)
    p_h = np.column_stack([points, np.ones(len(points))]) @ t_points.T
    q_n = (np.column_stack([q, np.ones(len(q))]) @ t_q.T)[:, :2]
    zeros = np.zeros_like(p_h)
    rows_u = np.hstack([p_h, zeros, -q_n[:, :1] * p_h])
    rows_v = np.hstack([zeros, p_h, -q_n[:, 1:] * p_h])
    _, singular, vt = np.linalg.svd(np.vstack([rows_u, rows_v]), full_matrices=False)
    if singular[-2] < 1e-9 * singular[0]:
        raise CalibrationError("the 3-D DLT is degenerate: the points are (nearly) coplanar")
    matrix_n = vt[-1].reshape(3, 4)
    return np.linalg.inv(t_q) @ matrix_n @ t_points


def decompose_camera_matrix(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K (3, 3) with positive diagonal, rotation R (3, 3) with det +1 and t (3,) such that matrix ∝ K·[R | t]."""
    p = checked_array(matrix, shape=(3, 4), name="matrix")
    # P and −P are the same projective camera; the sign with det(H) > 0 gives a proper rotation and a positive
    # scale, which puts the points in front of the camera.
    if np.linalg.det(p[:, :3]) < 0:
        p = -p
    k, r = scipy.linalg.rq(p[:, :3])
    signs = np.diag(np.sign(np.diag(k)))
    k, r = k @ signs, signs @ r
    scale = k[2, 2]
    t = np.linalg.solve(k, p[:, 3])
    return k / scale, r, t


def _pose_vector(rotation: np.ndarray, t_mm: np.ndarray) -> np.ndarray:
    rvec, _ = cv2.Rodrigues(rotation)
    return np.concatenate([rvec.ravel(), t_mm])


def _initial_intrinsics(fx: float, fy: float, cx: float, cy: float, *, du: float, dv: float, scale_on: str) -> list:
    # docs/method.md §3.1: the scale factor starts at 1 and the distortion at 0; f comes from the axis without s.
    f_px_per_mm = fy / dv if scale_on == "u" else fx / du
    return [f_px_per_mm * du, f_px_per_mm * dv, cx, cy, 0.0, 0.0, 0.0, 0.0]


def _initial_zstack_dlt(
    views: Sequence[CornerView], image_size_wh_px: tuple[int, int], *, du: float, dv: float, scale_on: str
) -> np.ndarray:
    points = np.vstack([v.points_obj_mm for v in views])
    q = np.vstack([v.q_px for v in views])
    k, r, t = decompose_camera_matrix(dlt_camera_matrix(points, q))
    width, height = image_size_wh_px
    if not (-0.5 <= k[0, 2] <= width - 0.5 and -0.5 <= k[1, 2] <= height - 0.5):
        raise CalibrationError(f"the DLT put the principal point outside the image ({k[0, 2]:.0f}, {k[1, 2]:.0f})")
    intrinsics = _initial_intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], du=du, dv=dv, scale_on=scale_on)
    # The DLT absorbs the focal length change of s = 1 into the pose only weakly; re-solve the pose for the
    # starting intrinsics so LM starts close.
    pose = _solve_pose(points, q, np.array(intrinsics), _pose_vector(r, t))
    return np.concatenate([intrinsics, pose])


def _initial_planar_intrinsics(
    views: Sequence[CornerView], image_size_wh_px: tuple[int, int], *, du: float, dv: float, scale_on: str
) -> list:
    """Zhang-style start: the camera matrix from the homographies of planar views (principal point at the centre)."""
    object_points = [v.points_obj_mm.astype(np.float32) for v in views]
    image_points = [v.q_px.astype(np.float32) for v in views]
    k = cv2.initCameraMatrix2D(object_points, image_points, image_size_wh_px)
    return _initial_intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], du=du, dv=dv, scale_on=scale_on)


def _solve_pose(
    points_obj_mm: np.ndarray,
    q_px: np.ndarray,
    intrinsics: np.ndarray,
    guess: np.ndarray | None,
    *,
    planar: bool = False,
) -> np.ndarray:
    k = np.array([[intrinsics[0], 0, intrinsics[2]], [0, intrinsics[1], intrinsics[3]], [0, 0, 1]])
    dist = np.asarray(intrinsics[4:8], dtype=np.float64)
    if guess is None:
        # IPPE is the closed-form pose of a plane at Z = 0, ten times quicker than the iterative PnP.
        method = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_ITERATIVE
        ok, rvec, tvec = cv2.solvePnP(points_obj_mm, q_px, k, dist, flags=method)
    else:
        ok, rvec, tvec = cv2.solvePnP(
            points_obj_mm, q_px, k, dist, guess[:3].copy(), guess[3:].copy(), True, cv2.SOLVEPNP_ITERATIVE
        )
    if not ok:
        raise CalibrationError("could not find an initial pose (solvePnP failed)")
    return np.concatenate([rvec.ravel(), tvec.ravel()])


# --------------------------------------------------------------------------------------------------------------
# Levenberg–Marquardt


class _Problem:
    """Corner groups sharing the 8 intrinsics; group g has its own pose, parameters 8 + 6g .. 14 + 6g.

    Parameters: fx, fy, cx, cy, k1, k2, p1, p2 (OpenCV's, on normalised coordinates), then per pose a Rodrigues
    vector and a translation. Residuals are model − observed, interleaved u, v.
    """

    def __init__(self, groups: Sequence[tuple[np.ndarray, np.ndarray]]) -> None:
        self.points = [np.ascontiguousarray(p, dtype=np.float64).reshape(-1, 1, 3) for p, _ in groups]
        self.observed = [np.ascontiguousarray(q, dtype=np.float64).reshape(-1) for _, q in groups]
        sizes = [len(o) for o in self.observed]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)])
        self.n_params = 8 + 6 * len(groups)

    def _project(self, x: np.ndarray):
        """Per group: its index, residual (2n,) and projectPoints' Jacobian (2n, 14), whose columns are
        rvec(3), tvec(3), fx, fy, cx, cy, k1, k2, p1, p2."""
        k = np.array([[x[0], 0.0, x[2]], [0.0, x[1], x[3]], [0.0, 0.0, 1.0]])
        dist = x[4:8]
        for g, (points, observed) in enumerate(zip(self.points, self.observed, strict=True)):
            pose = x[8 + 6 * g : 14 + 6 * g]
            projected, jac = cv2.projectPoints(points, pose[:3], pose[3:], k, dist)
            yield g, projected.reshape(-1) - observed, jac

    def normal_equations(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residual (2N,), JᵀJ (P, P) and Jᵀr (P,), assembled per group: J is block-sparse across poses."""
        residual = np.empty(self.offsets[-1])
        normal = np.zeros((self.n_params, self.n_params))
        gradient = np.zeros(self.n_params)
        for g, r, jac in self._project(x):
            residual[self.offsets[g] : self.offsets[g + 1]] = r
            block, jr = jac.T @ jac, jac.T @ r
            pose = slice(8 + 6 * g, 14 + 6 * g)
            normal[:8, :8] += block[6:, 6:]
            normal[:8, pose] = block[6:, :6]
            normal[pose, :8] = block[:6, 6:]
            normal[pose, pose] = block[:6, :6]
            gradient[:8] += jr[6:]
            gradient[pose] = jr[:6]
        return residual, normal, gradient

    def residual(self, x: np.ndarray) -> np.ndarray:
        return np.concatenate([r for _, r, _ in self._project(x)])

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """The dense Jacobian (2N, P); the solver itself only needs the normal equations."""
        jacobian = np.zeros((self.offsets[-1], self.n_params))
        for g, _, jac in self._project(x):
            rows = slice(self.offsets[g], self.offsets[g + 1])
            jacobian[rows, :8] = jac[:, 6:]
            jacobian[rows, 8 + 6 * g : 14 + 6 * g] = jac[:, :6]
        return jacobian


# Convergence: the cosine between the residual vector and any Jacobian column (MINPACK's gtol), or a relative
# cost decrease (ftol) or scaled step (xtol) at round-off level.
LM_GTOL = 1e-10
LM_FTOL = 1e-10
LM_XTOL = 1e-12
LM_MAX_ITERATIONS = 200
# Relative to the diagonal of JᵀJ; small because the starts are close to the minimum.
LM_INITIAL_DAMPING = 1e-6


def _levenberg_marquardt(problem: _Problem, x0: np.ndarray) -> tuple[np.ndarray, bool]:
    """Levenberg–Marquardt on the normal equations: Marquardt's diagonal scaling (as MINPACK) and Nielsen's
    damping update. Returns the parameters and whether a convergence test was met.

    Written out rather than scipy.optimize.least_squares because the poses problem is block-sparse: JᵀJ
    assembled per view costs a few 14 × 14 products, where MINPACK's dense QR of the whole Jacobian made the
    solver 3 × slower than cv2.calibrateCamera. `test_calibration_solver` checks it reaches least_squares' minimum.
    """
    x = np.array(x0, dtype=np.float64)
    residual, normal, gradient = problem.normal_equations(x)
    cost = float(residual @ residual)
    scale = np.zeros(len(x))
    damping, growth = LM_INITIAL_DAMPING, 2.0
    for _ in range(LM_MAX_ITERATIONS):
        scale = np.maximum(scale, np.sqrt(np.diag(normal)))
        scale[scale == 0] = 1.0
        if np.max(np.abs(gradient) / scale) <= LM_GTOL * np.sqrt(max(cost, 1e-300)):
            return x, True
        try:
            factor = scipy.linalg.cho_factor(normal + damping * np.diag(scale**2))
            step = -scipy.linalg.cho_solve(factor, gradient)
        except np.linalg.LinAlgError:
            damping, growth = damping * growth, growth * 2
            continue
        predicted = -float(2 * step @ gradient + step @ normal @ step)
        candidate = problem.normal_equations(x + step)
        new_cost = float(candidate[0] @ candidate[0])
        actual = cost - new_cost
        if np.isfinite(new_cost) and actual > 0:
            rho = actual / predicted if predicted > 0 else 1.0
            x = x + step
            residual, normal, gradient = candidate
            cost = new_cost
            damping *= max(1 / 3, 1 - (2 * rho - 1) ** 3)
            growth = 2.0
            small_decrease = actual <= LM_FTOL * cost and predicted <= LM_FTOL * cost
            if small_decrease or np.linalg.norm(scale * step) <= LM_XTOL * np.linalg.norm(scale * x):
                return x, True
        else:
            if np.linalg.norm(scale * step) <= LM_XTOL * np.linalg.norm(scale * x):
                return x, True
            damping, growth = damping * growth, growth * 2
    return x, False


# --------------------------------------------------------------------------------------------------------------
# Statistics


def _covariance(normal: np.ndarray, sigma2: float) -> np.ndarray:
    """σ²·(JᵀJ)⁻¹ from the normal matrix, equilibrated first: fx (~1e3 px) and k2 (~1e-1) differ by decades."""
    norms = np.sqrt(np.diag(normal))
    norms[norms == 0] = 1.0
    scaled = normal / np.outer(norms, norms)
    try:
        inverse = np.linalg.inv(scaled)
    except np.linalg.LinAlgError:
        inverse = np.linalg.pinv(scaled)
    return sigma2 * inverse / np.outer(norms, norms)


def _opencv_camera_from_vector(x: np.ndarray, image_size_wh_px: tuple[int, int]) -> OpenCVCamera:
    return OpenCVCamera(
        image_width_px=image_size_wh_px[0], image_height_px=image_size_wh_px[1],
        fx_px=float(x[0]), fy_px=float(x[1]), cx_px=float(x[2]), cy_px=float(x[3]),
        k1=float(x[4]), k2=float(x[5]), p1=float(x[6]), p2=float(x[7]),
        r_cam_from_obj_rad=(float(x[8]), float(x[9]), float(x[10])),
        t_cam_from_obj_mm=(float(x[11]), float(x[12]), float(x[13])),
    )  # fmt: skip


def _heikkila_intrinsics(o: np.ndarray, *, du: float, dv: float, scale_on: str) -> np.ndarray:
    """(s, f, u0, v0, k1, k2, p1, p2) from OpenCV's (fx, fy, cx, cy, k1, k2, p1, p2), shape (..., 8): the formulas
    of `camera_from_opencv`, vectorised for the differences below."""
    fx, fy, cx, cy, k1, k2, p1, p2 = np.moveaxis(o, -1, 0)
    f = fy / dv if scale_on == "u" else fx / du
    s = fx / (f * du) if scale_on == "u" else fy / (f * dv)
    return np.stack([s, f, cx, cy, k1 / f**2, k2 / f**4, p1 / f, p2 / f], axis=-1)


def _heikkila_from_opencv_jacobian(x14: np.ndarray, *, du: float, dv: float, scale_on: str) -> np.ndarray:
    """∂(Heikkilä 14)/∂(OpenCV 14), block-diagonal: intrinsics from intrinsics, angles from the Rodrigues vector,
    translation unchanged. Central differences of the exact conversions: smooth, so relative steps of 1e-6 are
    accurate to ~1e-10, far below what a standard error needs."""
    jacobian = np.zeros((14, 14))
    steps = 1e-6 * np.maximum(np.abs(x14), 1e-3)
    offsets = np.diag(steps[:8])
    intrinsics = x14[:8]
    differences = _heikkila_intrinsics(intrinsics + offsets, du=du, dv=dv, scale_on=scale_on) - _heikkila_intrinsics(
        intrinsics - offsets, du=du, dv=dv, scale_on=scale_on
    )
    jacobian[:8, :8] = differences.T / (2 * steps[:8])
    for j in range(3):
        plus, minus = x14[8:11].copy(), x14[8:11].copy()
        plus[j] += steps[8 + j]
        minus[j] -= steps[8 + j]
        angles_plus = np.array(angles_from_rotation(Rotation.from_rotvec(plus).as_matrix()))
        angles_minus = np.array(angles_from_rotation(Rotation.from_rotvec(minus).as_matrix()))
        # Angles may wrap by 2π between the two sides; their true difference is tiny.
        difference = (angles_plus - angles_minus + np.pi) % (2 * np.pi) - np.pi
        jacobian[11:14, 8 + j] = difference / (2 * steps[8 + j])
    jacobian[8:11, 11:14] = np.eye(3)
    return jacobian


def residual_map(q_px: np.ndarray, residual_px: np.ndarray, image_size_wh_px: tuple[int, int], *, sigma_px: float,
                 cells: tuple[int, int] = RESIDUAL_MAP_CELLS) -> ResidualMap:  # fmt: skip
    """Bin residuals, shape (N, 2), at pixels q_px, shape (N, 2), into cells_u × cells_v cells over the image.

    sigma_px: the per-coordinate residual standard deviation, to remove the noise part from `systematic_px`.
    """
    cells_u, cells_v = cells
    width, height = image_size_wh_px
    cu = np.clip(((q_px[:, 0] + 0.5) * cells_u / width).astype(int), 0, cells_u - 1)
    cv_ = np.clip(((q_px[:, 1] + 0.5) * cells_v / height).astype(int), 0, cells_v - 1)
    flat = cv_ * cells_u + cu
    n_cells = cells_u * cells_v
    count = np.bincount(flat, minlength=n_cells)
    sums = np.stack([np.bincount(flat, weights=residual_px[:, i], minlength=n_cells) for i in range(2)], axis=1)
    sum_sq = np.bincount(flat, weights=np.sum(residual_px**2, axis=1), minlength=n_cells)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = sums / count[:, None]
        rms = np.sqrt(sum_sq / count)
    usable = count >= RESIDUAL_MAP_MIN_COUNT
    if np.any(usable):
        # E|mean|² = |bias|² + 2σ²/n for random residuals: subtract the noise part.
        excess = np.sum(mean[usable] ** 2, axis=1) - 2 * sigma_px**2 / count[usable]
        systematic = float(np.sqrt(max(0.0, np.sum(count[usable] * excess) / np.sum(count[usable]))))
    else:
        systematic = float("nan")
    return ResidualMap(
        cells_u=cells_u, cells_v=cells_v, count=count.reshape(cells_v, cells_u),
        mean_px=mean.reshape(cells_v, cells_u, 2), rms_px=rms.reshape(cells_v, cells_u),
        systematic_px=systematic, coverage=float(np.mean(count > 0)),
    )  # fmt: skip


# --------------------------------------------------------------------------------------------------------------
# Verdict


def _check(name: str, value: float, unit: str, *, good: float, bad: float, higher_is_better: bool = False,
           what: str) -> VerdictCheck:  # fmt: skip
    return check(name, value, unit, good=good, bad=bad, higher_is_better=higher_is_better, what=what)


def judge_calibration(
    *, residual_std_px: float, frames: Sequence[FrameResult], residual_map: ResidualMap, inverse: InverseModel,
    f_relative_error: float, converged: bool,
) -> Verdict:  # fmt: skip
    """The plain verdict: every rule with its value and thresholds; the level is the worst of them."""
    used = [f for f in frames if f.status == "used" and f.rms_px is not None]
    frame_rms = np.array([f.rms_px for f in used], dtype=np.float64)
    median_rms = float(np.median(frame_rms))
    worst = used[int(np.argmax(frame_rms))]
    lost = sum(f.status != "used" for f in frames) / len(frames)
    worst_rms = float(frame_rms.max())
    worst_ratio = worst_rms / median_rms if worst_rms > OUTLIER_FLOOR_PX else 1.0
    checks = [
        _check("solver", 1.0 if converged else 0.0, YES_NO, good=1.0, bad=1.0, higher_is_better=True,
               what="Levenberg–Marquardt converged (no: it stopped at its iteration limit)"),
        _check("residual_std", residual_std_px, "px", good=0.2, bad=0.5,
               what="residual standard deviation per coordinate (Heikkilä: below 0.2 px)"),
        # A frame far worse than the others is a detection or Z error in that frame; below 0.2 px it is harmless.
        _check("worst_frame", worst_ratio, "× median", good=2.0, bad=4.0,
               what=f"worst frame {worst.frame} RMS {worst.rms_px:.3f} px relative to the median frame RMS "
               f"{median_rms:.3f} px (ignored below {OUTLIER_FLOOR_PX} px)"),
        _check("systematic_residual", residual_map.systematic_px, "px", good=0.05, bad=0.2,
               what=f"systematic residual over {residual_map.cells_u} × {residual_map.cells_v} image cells "
               "(noise part removed)"),
        _check("coverage", residual_map.coverage, "of image cells", good=0.5, bad=0.2, higher_is_better=True,
               what="image area holding corners (distortion is extrapolated outside)"),
        _check("inverse_model", inverse.residual_px, "px", good=0.001, bad=0.01,
               what="inverse model residual after refinement"),
        _check("focal_length_precision", 100.0 * f_relative_error, "%", good=0.5, bad=2.0,
               what="standard error of f relative to f (more Z range or tilt tightens it)"),
        _check("frames_lost", 100.0 * lost, "%", good=20.0, bad=50.0,
               what="frames skipped (no board) or rejected (outliers)"),
    ]  # fmt: skip
    return verdict_of(checks)


# --------------------------------------------------------------------------------------------------------------
# The solver on corners


ProgressCallback = Callable[[int, int, str], None]


def calibrate_from_views(
    views: Sequence[CornerView],
    *,
    image_size_wh_px: tuple[int, int],
    mode: CalibrationMode,
    du_px_per_mm: float,
    dv_px_per_mm: float,
    scale_on: ScaleAxis = "u",
    reject_outliers: bool = False,
    skipped: Sequence[FrameResult] = (),
    board: Board | None = None,
    pixel_pitch_um: tuple[float, float] | None = None,
    provenance: dict[str, Any] | None = None,
) -> CameraCalibration:
    """Calibrate a camera from corners: 3-D DLT (zstack) or Zhang (poses) start, then Levenberg–Marquardt.

    image_size_wh_px: (width, height). In `poses` mode the returned camera carries the pose of the first used view.
    `skipped` frames (board not found) are listed in the result. Raises CalibrationError when fewer views than
    the mode needs remain.
    """
    if mode not in MODES:
        raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
    if scale_on not in SCALE_ON_CHOICES:
        raise ValueError(f"scale_on: expected one of {SCALE_ON_CHOICES}, got {scale_on!r}")
    if not (du_px_per_mm > 0 and dv_px_per_mm > 0):
        raise ValueError(f"D_u, D_v must be positive px/mm, got {du_px_per_mm}, {dv_px_per_mm}")
    views = list(views)
    _require_enough(views, mode=mode, skipped=skipped)
    du, dv = du_px_per_mm, dv_px_per_mm

    active = list(range(len(views)))
    rejected: dict[int, str] = {}
    candidates = _initial_candidates(views, image_size_wh_px, mode=mode, du=du, dv=dv, scale_on=scale_on)
    problem = _build_problem(views, mode=mode)
    fits = [(name, *_levenberg_marquardt(problem, start)) for name, start in candidates]
    costs = [float(np.sum(problem.residual(x) ** 2)) for _, x, _ in fits]
    start_name, x, converged = fits[int(np.argmin(costs))]
    while True:
        problem = _build_problem([views[i] for i in active], mode=mode)
        if len(active) < len(views):
            x, converged = _levenberg_marquardt(problem, x)
        residual, normal, _ = problem.normal_equations(x)
        frame_rms = np.array([_view_rms(residual, problem, views, active, k, mode) for k in range(len(active))])
        if not reject_outliers or len(active) <= MIN_FRAMES[mode]:
            break
        threshold = max(OUTLIER_RATIO * float(np.median(frame_rms)), OUTLIER_FLOOR_PX)
        worst = int(np.argmax(frame_rms))
        if frame_rms[worst] <= threshold:
            break
        rejected[active[worst]] = (
            f"outlier: RMS {frame_rms[worst]:.3f} px > {threshold:.3f} px "
            f"(the larger of {OUTLIER_RATIO:g} × median frame RMS and {OUTLIER_FLOOR_PX} px)"
        )
        del active[worst]
        if mode == "poses":
            x = np.delete(x, np.s_[8 + 6 * worst : 14 + 6 * worst])

    n_points = len(residual) // 2
    n_params = len(x)
    dof = max(len(residual) - n_params, 1)
    sigma2 = float(residual @ residual) / dof
    covariance_o = _covariance(normal, sigma2)
    reference = np.r_[0:14]
    x14 = x[reference]
    opencv_camera = _opencv_camera_from_vector(x14, image_size_wh_px)
    camera = camera_from_opencv(opencv_camera, du_px_per_mm=du, dv_px_per_mm=dv, scale_on=scale_on)
    cov14 = covariance_o[np.ix_(reference, reference)]
    conversion = _heikkila_from_opencv_jacobian(x14, du=du, dv=dv, scale_on=scale_on)
    cov_h = conversion @ cov14 @ conversion.T
    se_h = np.sqrt(np.clip(np.diag(cov_h), 0, None))
    se_o = np.sqrt(np.clip(np.diag(cov14), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = cov_h / np.outer(se_h, se_h)

    frames, residual_vectors = _frame_results(views, active, rejected, skipped, problem, x, residual, mode)
    rms_px = float(np.sqrt(residual @ residual / n_points))
    residual_std_px = float(np.sqrt(sigma2))
    rmap = residual_map(residual_vectors.q_px, residual_vectors.residual_px, image_size_wh_px, sigma_px=residual_std_px)
    inverse = fit_inverse_model(camera)
    verdict = judge_calibration(
        residual_std_px=residual_std_px, frames=frames, residual_map=rmap, inverse=inverse,
        f_relative_error=float(se_h[1] / camera.f_mm), converged=converged,
    )  # fmt: skip
    return CameraCalibration(
        camera=camera,
        inverse=inverse,
        mode=mode,
        rms_px=rms_px,
        residual_std_px=residual_std_px,
        n_points=n_points,
        standard_errors={name: float(se) for name, se in zip(CAMERA_PARAMETERS, se_h, strict=True)},
        opencv_standard_errors={name: float(se) for name, se in zip(OPENCV_PARAMETERS, se_o, strict=True)},
        correlation=correlation,
        frames=frames,
        residuals=residual_vectors,
        residual_map=rmap,
        verdict=verdict,
        board=board,
        pixel_pitch_um=pixel_pitch_um,
        converged=converged,
        provenance={**(provenance or {}), "initialisation": start_name},
    )


def _require_enough(views: Sequence[CornerView], *, mode: str, skipped: Sequence[FrameResult]) -> None:
    need = MIN_FRAMES[mode]
    if len(views) < need:
        # One short sentence: why frames were skipped, each reason once (a reason names its frame first).
        reasons = Counter(f.reason.split(": ", 1)[-1] for f in skipped)
        lost = "; ".join(f"{n} × {reason}" for reason, n in reasons.most_common(3))
        raise CalibrationError(
            f"{mode} calibration needs at least {need} frames with the board, got {len(views)}"
            + (f" ({len(skipped)} skipped: {lost})" if lost else "")
        )
    if mode == "zstack":
        levels = {v.z_mm for v in views}
        if len(levels) < 2:
            raise CalibrationError(
                f"zstack calibration needs at least 2 distinct Z levels among the frames with the board, got {levels}"
            )


def _initial_candidates(views, image_size_wh_px, *, mode, du, dv, scale_on) -> list[tuple[str, np.ndarray]]:
    """Starting points for LM, each named. poses: Zhang's (initCameraMatrix2D, then PnP per view). zstack: the
    paper's 3-D DLT and a planar start (initCameraMatrix2D on the Z levels, then PnP on all points).

    A shallow stack (Z range ~5 % of the distance, as in the paper) with strong distortion leaves the DLT's
    principal point hundreds of pixels off, and from there LM can end in a local minimum. A DLT start whose
    principal point lies outside the image is therefore dropped; when both remain, LM runs from both and the
    lower cost wins.
    """
    planar_views = [
        CornerView(v.frame, np.column_stack([v.points_obj_mm[:, :2], np.zeros(len(v.q_px))]), v.q_px) for v in views
    ]
    intrinsics = _initial_planar_intrinsics(planar_views, image_size_wh_px, du=du, dv=dv, scale_on=scale_on)
    if mode == "poses":
        poses = [_solve_pose(v.points_obj_mm, v.q_px, np.array(intrinsics), None, planar=True) for v in views]
        return [("zhang", np.concatenate([intrinsics, *poses]))]
    points = np.vstack([v.points_obj_mm for v in views])
    q = np.vstack([v.q_px for v in views])
    candidates = [("planar", np.concatenate([intrinsics, _solve_pose(points, q, np.array(intrinsics), None)]))]
    # A degenerate DLT (nearly coplanar points) leaves the planar start alone.
    with contextlib.suppress(CalibrationError, cv2.error, np.linalg.LinAlgError):
        candidates.insert(0, ("dlt", _initial_zstack_dlt(views, image_size_wh_px, du=du, dv=dv, scale_on=scale_on)))
    return candidates


def _build_problem(views: Sequence[CornerView], *, mode: str) -> _Problem:
    if mode == "zstack":
        return _Problem([(np.vstack([v.points_obj_mm for v in views]), np.vstack([v.q_px for v in views]))])
    return _Problem([(v.points_obj_mm, v.q_px) for v in views])


def _view_rows(problem: _Problem, views, active, k: int, mode: str) -> slice:
    if mode == "poses":
        return slice(problem.offsets[k], problem.offsets[k + 1])
    start = 2 * sum(len(views[i].q_px) for i in active[:k])
    return slice(start, start + 2 * len(views[active[k]].q_px))


def _view_rms(residual, problem, views, active, k, mode) -> float:
    r = residual[_view_rows(problem, views, active, k, mode)]
    return float(np.sqrt(np.mean(r.reshape(-1, 2) ** 2) * 2))


def _frame_results(views, active, rejected, skipped, problem, x, residual, mode):
    by_view: dict[int, FrameResult] = {}
    frame_index, p_list, q_list, r_list = [], [], [], []
    for k, i in enumerate(active):
        view = views[i]
        r = -residual[_view_rows(problem, views, active, k, mode)].reshape(-1, 2)  # observed − model
        distance = np.hypot(r[:, 0], r[:, 1])
        pose = x[8 + 6 * k : 14 + 6 * k] if mode == "poses" else None
        by_view[i] = FrameResult(
            frame=view.frame, status="used", z_mm=view.z_mm, n_corners=len(view.q_px),
            rms_px=float(np.sqrt(np.mean(distance**2))), max_px=float(np.max(distance)),
            r_cam_from_obj_rad=None if pose is None else (float(pose[0]), float(pose[1]), float(pose[2])),
            t_cam_from_obj_mm=None if pose is None else (float(pose[3]), float(pose[4]), float(pose[5])),
        )  # fmt: skip
        p_list.append(view.points_obj_mm)
        q_list.append(view.q_px)
        r_list.append(r)
    for i, reason in rejected.items():
        by_view[i] = FrameResult(frame=views[i].frame, status="rejected", reason=reason, z_mm=views[i].z_mm,
                                 n_corners=len(views[i].q_px))  # fmt: skip
    # Frames in recording order (natural name order, as the readers list them).
    frames = sorted([by_view[i] for i in range(len(views))] + list(skipped), key=lambda f: natural_key(f.frame))
    order = {f.frame: n for n, f in enumerate(frames)}
    for i in active:
        frame_index.append(np.full(len(views[i].q_px), order[views[i].frame]))
    residuals = ResidualVectors(
        frame_index=np.concatenate(frame_index),
        points_obj_mm=np.vstack(p_list),
        q_px=np.vstack(q_list),
        residual_px=np.vstack(r_list),
    )
    return tuple(frames), residuals


# --------------------------------------------------------------------------------------------------------------
# The entry point for a recording


def zstack_heights_mm(z_by_frame: dict[int, float], n_frames: int, *, name: str = "z.csv") -> list[float]:
    """Z of each frame in recording order from `read_z_csv` rows; frames are numbered 0..n−1 or 1..n.

    Raises ValueError naming the file and the frames for a different count, gaps, repeated or non-monotonic Z,
    or a degenerate stack (all frames at one Z).
    """
    numbers = sorted(z_by_frame)
    if len(numbers) != n_frames:
        raise ValueError(f"{name}: {len(numbers)} rows, but the recording has {n_frames} frames")
    if numbers[0] not in (0, 1) or numbers[-1] - numbers[0] + 1 != n_frames:
        raise ValueError(
            f"{name}: frames must be numbered 0..{n_frames - 1} or 1..{n_frames} without gaps, "
            f"got {numbers[0]}..{numbers[-1]}"
        )
    z = [z_by_frame[n] for n in numbers]
    if len(set(z)) == 1:
        raise ValueError(f"{name}: all {n_frames} frames are at Z = {z[0]} mm; a Z-stack needs the board moved along Z")
    steps = np.diff(z)
    for k, step in enumerate(steps):
        if step == 0:
            raise ValueError(f"{name}: frames {numbers[k]} and {numbers[k + 1]} repeat Z = {z[k]} mm")
    direction = np.sign(steps[0])
    for k, step in enumerate(steps):
        if np.sign(step) != direction:
            raise ValueError(
                f"{name}: Z is not monotonic: frame {numbers[k + 1]} ({z[k + 1]} mm) "
                f"after frame {numbers[k]} ({z[k]} mm)"
            )
    return z
