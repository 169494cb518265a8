"""Heikkilä camera model (docs/method.md §3): forward projection, inverse model, back-projection, OpenCV interop.

Belongs here: the `Camera`, `InverseModel` and `OpenCVCamera` dataclasses and pure functions on them.
Not here: estimating a camera from corners (`calibration.py`), finding corners (`chessboard.py`), files
(`fringelab.formats.camera.py`).

Conventions (docs/method.md §2-3): object frame X, Y in the plate plane, +Z toward the camera, mm. The camera frame
has z along the optical axis. `M = Rz(κ)·Ry(φ)·Rx(ω)` takes object to camera coordinates and
`[x0, y0, z0]` is the object origin seen from the camera. Ideal sensor coordinates (ũ, ṽ) are in mm; pixels
(u, v) = (column, row) with (0, 0) the centre of the top-left pixel. The scale factor `su` multiplies u
(Heikkilä, `scale_on="u"`) or v (the paper's sV, `scale_on="v"`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
from scipy.spatial.transform import Rotation

from .arrays import checked_array

ScaleAxis = Literal["u", "v"]  # the image axis whose pixel pitch fixes the scale (the other is fitted)
SCALE_ON_CHOICES: tuple[str, ...] = get_args(ScaleAxis)

# The inverse model is fitted on a 45 × 45 grid covering 110 % of the image (docs/method.md §3.2).
INVERSE_GRID_POINTS = 45
INVERSE_GRID_COVERAGE = 1.10
# Newton refinement stops when the forward model reproduces the input pixel to this; the acceptance number is
# 0.001 px, so 1e-7 px leaves four orders of margin and costs one extra iteration at most.
INVERSE_TOLERANCE_PX = 1e-7
INVERSE_MAX_ITERATIONS = 12


@dataclass(frozen=True)
class Camera:
    """A calibrated camera: fixed sensor constants D_u, D_v and the 14 Heikkilä parameters."""

    image_width_px: int
    image_height_px: int
    du_px_per_mm: float
    dv_px_per_mm: float
    su: float
    f_mm: float
    u0_px: float
    v0_px: float
    k1_per_mm2: float
    k2_per_mm4: float
    p1_per_mm: float
    p2_per_mm: float
    x0_mm: float
    y0_mm: float
    z0_mm: float
    omega_rad: float
    phi_rad: float
    kappa_rad: float
    scale_on: ScaleAxis = "u"

    def __post_init__(self) -> None:
        if self.scale_on not in SCALE_ON_CHOICES:
            raise ValueError(f"scale_on: expected one of {SCALE_ON_CHOICES}, got {self.scale_on!r}")
        if not (self.du_px_per_mm > 0 and self.dv_px_per_mm > 0):
            raise ValueError(f"D_u, D_v must be positive px/mm, got {self.du_px_per_mm}, {self.dv_px_per_mm}")
        if self.image_width_px <= 0 or self.image_height_px <= 0:
            raise ValueError(f"image size must be positive, got {self.image_width_px} × {self.image_height_px}")

    @property
    def rotation(self) -> np.ndarray:
        """M, shape (3, 3): object → camera frame."""
        return rotation_from_angles(self.omega_rad, self.phi_rad, self.kappa_rad)

    @property
    def translation_mm(self) -> np.ndarray:
        """[x0, y0, z0], shape (3,): the object origin in the camera frame."""
        return np.array([self.x0_mm, self.y0_mm, self.z0_mm])

    @property
    def pixels_per_mm(self) -> tuple[float, float]:
        """(D_u·s_u, D_v) or (D_u, D_v·s_v): the sensor-mm → pixel factors on u and v."""
        if self.scale_on == "u":
            return self.du_px_per_mm * self.su, self.dv_px_per_mm
        return self.du_px_per_mm, self.dv_px_per_mm * self.su


@dataclass(frozen=True)
class InverseModel:
    """Heikkilä's 8-parameter inverse model (pixels → ideal sensor mm), docs/method.md §3.2.

    `approximation_residual_px` is the largest error of the 8-parameter model alone over the fitting grid;
    `residual_px` the largest error after Newton refinement on the forward model (the QA number).
    """

    a1: float
    a2: float
    a3: float
    a4: float
    a5: float
    a6: float
    a7: float
    a8: float
    residual_px: float
    approximation_residual_px: float

    @property
    def coefficients(self) -> tuple[float, ...]:
        return (self.a1, self.a2, self.a3, self.a4, self.a5, self.a6, self.a7, self.a8)


@dataclass(frozen=True)
class OpenCVCamera:
    """The same camera in OpenCV's form: K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], (k1, k2, p1, p2, k3), rvec, tvec.

    Distortion acts on normalised coordinates (x/z, y/z); rvec is the Rodrigues vector of M, tvec = [x0, y0, z0].
    """

    image_width_px: int
    image_height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    k1: float
    k2: float
    p1: float
    p2: float
    r_cam_from_obj_rad: tuple[float, float, float]  # OpenCV rvec: rotation vector, plate (object) -> camera
    t_cam_from_obj_mm: tuple[float, float, float]  # OpenCV tvec: the plate origin in camera coordinates
    k3: float = 0.0

    @property
    def camera_matrix(self) -> np.ndarray:
        """K, shape (3, 3)."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """(k1, k2, p1, p2, k3), shape (5,), in the order cv2 functions take."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])


def rotation_from_angles(omega_rad: float, phi_rad: float, kappa_rad: float) -> np.ndarray:
    """M = Rz(κ)·Ry(φ)·Rx(ω), shape (3, 3) (right-handed, active rotations)."""
    so, co = np.sin(omega_rad), np.cos(omega_rad)
    sp, cp = np.sin(phi_rad), np.cos(phi_rad)
    sk, ck = np.sin(kappa_rad), np.cos(kappa_rad)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, co, -so], [0.0, so, co]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[ck, -sk, 0.0], [sk, ck, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def angles_from_rotation(rotation: np.ndarray) -> tuple[float, float, float]:
    """(ω, φ, κ) in radians with φ in [-π/2, π/2] from M = Rz(κ)·Ry(φ)·Rx(ω), shape (3, 3)."""
    m = checked_array(rotation, shape=(3, 3), name="rotation")
    omega = float(np.arctan2(m[2, 1], m[2, 2]))
    phi = float(np.arctan2(-m[2, 0], np.hypot(m[0, 0], m[1, 0])))
    kappa = float(np.arctan2(m[1, 0], m[0, 0]))
    return omega, phi, kappa


def distortion_mm(ut_mm: np.ndarray, vt_mm: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(δu, δv) in mm of ideal sensor points (ũ, ṽ), each shape (N,): radial k1, k2 and decentring p1, p2."""
    r2 = ut_mm * ut_mm + vt_mm * vt_mm
    radial = r2 * (camera.k1_per_mm2 + camera.k2_per_mm4 * r2)
    uv = ut_mm * vt_mm
    du = ut_mm * radial + 2.0 * camera.p1_per_mm * uv + camera.p2_per_mm * (r2 + 2.0 * ut_mm * ut_mm)
    dv = vt_mm * radial + camera.p1_per_mm * (r2 + 2.0 * vt_mm * vt_mm) + 2.0 * camera.p2_per_mm * uv
    return du, dv


def project_points(camera: Camera, points_obj_mm: np.ndarray) -> np.ndarray:
    """Pixels q_px, shape (N, 2), of object points, shape (N, 3). Points at or behind the camera give NaN."""
    points = checked_array(points_obj_mm, shape=(None, 3), name="points_obj_mm")
    xyz = points @ camera.rotation.T + camera.translation_mm
    z = xyz[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(z > 0, camera.f_mm / z, np.nan)
    ut = xyz[:, 0] * scale
    vt = xyz[:, 1] * scale
    du, dv = distortion_mm(ut, vt, camera)
    sx, sy = camera.pixels_per_mm
    return np.column_stack([sx * (ut + du) + camera.u0_px, sy * (vt + dv) + camera.v0_px])


def _distorted_mm_from_pixels(camera: Camera, q_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    sx, sy = camera.pixels_per_mm
    return (q_px[:, 0] - camera.u0_px) / sx, (q_px[:, 1] - camera.v0_px) / sy


def _apply_inverse_approximation(
    inverse: InverseModel, ub_mm: np.ndarray, vb_mm: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    a1, a2, a3, a4, a5, a6, a7, a8 = inverse.coefficients
    r2 = ub_mm * ub_mm + vb_mm * vb_mm
    radial = 1.0 + r2 * (a1 + a2 * r2)
    uv2 = 2.0 * ub_mm * vb_mm
    g = (a5 * r2 + a6 * ub_mm + a7 * vb_mm + a8) * r2 + 1.0
    ut = (ub_mm * radial + a3 * uv2 + a4 * (r2 + 2.0 * ub_mm * ub_mm)) / g
    vt = (vb_mm * radial + a3 * (r2 + 2.0 * vb_mm * vb_mm) + a4 * uv2) / g
    return ut, vt


def _refine_ideal(
    camera: Camera, ub_mm: np.ndarray, vb_mm: np.ndarray, ut: np.ndarray, vt: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Newton on the forward distortion: solve (ũ + δu, ṽ + δv) = (ŭ, v̆). Returns ũ, ṽ and the residual in px."""
    k1, k2, p1, p2 = camera.k1_per_mm2, camera.k2_per_mm4, camera.p1_per_mm, camera.p2_per_mm
    sx, sy = camera.pixels_per_mm
    for iteration in range(INVERSE_MAX_ITERATIONS + 1):
        r2 = ut * ut + vt * vt
        g = r2 * (k1 + k2 * r2)
        h = 2.0 * (k1 + 2.0 * k2 * r2)
        uv = ut * vt
        fu = ut * (1.0 + g) + 2.0 * p1 * uv + p2 * (r2 + 2.0 * ut * ut) - ub_mm
        fv = vt * (1.0 + g) + p1 * (r2 + 2.0 * vt * vt) + 2.0 * p2 * uv - vb_mm
        residual_px = np.hypot(fu * sx, fv * sy)
        if iteration == INVERSE_MAX_ITERATIONS or not np.nanmax(residual_px, initial=0.0) > INVERSE_TOLERANCE_PX:
            break
        # The Jacobian of the distortion is symmetric: ∂δu/∂ṽ = ∂δv/∂ũ.
        j_uu = 1.0 + g + ut * ut * h + 2.0 * p1 * vt + 6.0 * p2 * ut
        j_vv = 1.0 + g + vt * vt * h + 6.0 * p1 * vt + 2.0 * p2 * ut
        j_uv = uv * h + 2.0 * p1 * ut + 2.0 * p2 * vt
        det = j_uu * j_vv - j_uv * j_uv
        ut = ut - (j_vv * fu - j_uv * fv) / det
        vt = vt - (j_uu * fv - j_uv * fu) / det
    return ut, vt, residual_px


def fit_inverse_model(camera: Camera) -> InverseModel:
    """Fit a1..a8 by linear least squares on a 45 × 45 grid over 110 % of the image, then measure the residual.

    The grid is laid out in pixels so that it covers the image whatever the distortion; its ideal points are
    found by Newton on the forward model and distorted again with it, so each (distorted, ideal) pair is exact.
    """
    width, height = camera.image_width_px, camera.image_height_px
    half_u = 0.5 * width * INVERSE_GRID_COVERAGE
    half_v = 0.5 * height * INVERSE_GRID_COVERAGE
    centre_u, centre_v = 0.5 * (width - 1), 0.5 * (height - 1)
    grid_u, grid_v = np.meshgrid(
        np.linspace(centre_u - half_u, centre_u + half_u, INVERSE_GRID_POINTS),
        np.linspace(centre_v - half_v, centre_v + half_v, INVERSE_GRID_POINTS),
    )
    q_px = np.column_stack([grid_u.ravel(), grid_v.ravel()])
    ub0, vb0 = _distorted_mm_from_pixels(camera, q_px)
    ut, vt, _ = _refine_ideal(camera, ub0, vb0, ub0.copy(), vb0.copy())
    du, dv = distortion_mm(ut, vt, camera)
    ub, vb = ut + du, vt + dv

    r2 = ub * ub + vb * vb
    rows_u = np.column_stack(
        [ub * r2, ub * r2 * r2, 2 * ub * vb, r2 + 2 * ub * ub, -ut * r2 * r2, -ut * ub * r2, -ut * vb * r2, -ut * r2]
    )
    rows_v = np.column_stack(
        [vb * r2, vb * r2 * r2, r2 + 2 * vb * vb, 2 * ub * vb, -vt * r2 * r2, -vt * ub * r2, -vt * vb * r2, -vt * r2]
    )
    design = np.vstack([rows_u, rows_v])
    target = np.concatenate([ut - ub, vt - vb])
    # Columns span many orders of magnitude (r⁴ vs r); equilibrate them so lstsq is well conditioned.
    column_norms = np.linalg.norm(design, axis=0)
    column_norms[column_norms == 0] = 1.0
    solution, *_ = np.linalg.lstsq(design / column_norms, target, rcond=None)
    coefficients = solution / column_norms
    a_by_name = {f"a{i}": float(value) for i, value in enumerate(coefficients, start=1)}
    provisional = InverseModel(**a_by_name, residual_px=np.nan, approximation_residual_px=np.nan)

    sx, sy = camera.pixels_per_mm
    ut_approx, vt_approx = _apply_inverse_approximation(provisional, ub, vb)
    approx_px = np.hypot((ut_approx - ut) * sx, (vt_approx - vt) * sy)
    q_grid_px = np.column_stack([ub * sx + camera.u0_px, vb * sy + camera.v0_px])
    ut_full, vt_full = ideal_from_pixels(camera, q_grid_px, inverse=provisional)
    du_full, dv_full = distortion_mm(ut_full, vt_full, camera)
    full_px = np.hypot((ut_full + du_full - ub) * sx, (vt_full + dv_full - vb) * sy)
    return InverseModel(
        **a_by_name,
        residual_px=float(np.max(full_px)),
        approximation_residual_px=float(np.max(approx_px)),
    )


def ideal_from_pixels(
    camera: Camera, q_px: np.ndarray, *, inverse: InverseModel | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Ideal (undistorted) sensor coordinates (ũ, ṽ) in mm, each shape (N,), of pixels q_px, shape (N, 2).

    The 8-parameter inverse model gives the start; Newton on the forward model refines it until the forward model
    reproduces the pixel to 1e-7 px. Pixels where that fails (far outside the image, where the distortion
    polynomial folds over) come back as NaN rather than as a wrong point.
    """
    q = checked_array(q_px, shape=(None, 2), name="q_px")
    if inverse is None:
        inverse = fit_inverse_model(camera)
    ub, vb = _distorted_mm_from_pixels(camera, q)
    ut, vt = _apply_inverse_approximation(inverse, ub, vb)
    ut, vt, residual_px = _refine_ideal(camera, ub, vb, ut, vt)
    failed = ~(residual_px <= 1e-3)
    if np.any(failed):
        ut = np.where(failed, np.nan, ut)
        vt = np.where(failed, np.nan, vt)
    return ut, vt


def camera_centre_obj_mm(camera: Camera) -> np.ndarray:
    """Projection centre C = −Mᵀ·[x0, y0, z0] in the object frame, shape (3,)."""
    return -camera.rotation.T @ camera.translation_mm


def rays_from_pixels(
    camera: Camera, q_px: np.ndarray, *, inverse: InverseModel | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Rays of pixels q_px, shape (N, 2): camera centre, shape (3,), and unit directions, shape (N, 3), object frame."""
    ut, vt = ideal_from_pixels(camera, q_px, inverse=inverse)
    directions_cam = np.column_stack([ut, vt, np.full_like(ut, camera.f_mm)])
    # (Mᵀ·d)ᵀ = dᵀ·M for row vectors.
    directions_obj = directions_cam @ camera.rotation
    directions_obj /= np.linalg.norm(directions_obj, axis=1, keepdims=True)
    return camera_centre_obj_mm(camera), directions_obj


def backproject_to_z(
    camera: Camera, q_px: np.ndarray, z_mm: float | np.ndarray, *, inverse: InverseModel | None = None
) -> np.ndarray:
    """Object points, shape (N, 3), where the rays of pixels q_px, shape (N, 2), meet the planes Z = z_mm.

    `z_mm` is a scalar or shape (N,). Fits the inverse model when `inverse` is None; pass it when calling often.
    Rays parallel to the plane, and pixels that cannot be undistorted, give NaN.
    """
    q = checked_array(q_px, shape=(None, 2), name="q_px")
    z = np.asarray(z_mm, dtype=np.float64)
    if z.ndim == 1:
        z = checked_array(z, shape=(len(q),), name="z_mm")
    elif z.ndim != 0:
        raise ValueError(f"z_mm: expected a scalar or shape (N,) with N = {len(q)}, got {z.shape}")
    ut, vt = ideal_from_pixels(camera, q, inverse=inverse)
    return _rays_to_z(camera, ut, vt, z)


def _rays_to_z(camera: Camera, ut: np.ndarray, vt: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Object points (N, 3) where the rays of ideal sensor points (ũ, ṽ) meet the planes Z = z (scalar or (N,))."""
    m = camera.rotation
    f = camera.f_mm
    # d = Mᵀ·[ũ, ṽ, f]; written out per component to avoid an (N, 3) temporary on the hot path.
    dx = m[0, 0] * ut + m[1, 0] * vt + m[2, 0] * f
    dy = m[0, 1] * ut + m[1, 1] * vt + m[2, 1] * f
    dz = m[0, 2] * ut + m[1, 2] * vt + m[2, 2] * f
    centre = camera_centre_obj_mm(camera)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (z - centre[2]) / dz
    out = np.empty((len(ut), 3))
    out[:, 0] = centre[0] + lam * dx
    out[:, 1] = centre[1] + lam * dy
    out[:, 2] = z
    out[~np.isfinite(lam)] = np.nan
    return out


def camera_as_opencv(camera: Camera) -> OpenCVCamera:
    """The same camera in OpenCV's form (docs/method.md §3): exact, k3 = 0."""
    f = camera.f_mm
    sx, sy = camera.pixels_per_mm
    rvec = Rotation.from_matrix(camera.rotation).as_rotvec()
    return OpenCVCamera(
        image_width_px=camera.image_width_px,
        image_height_px=camera.image_height_px,
        fx_px=f * sx,
        fy_px=f * sy,
        cx_px=camera.u0_px,
        cy_px=camera.v0_px,
        k1=camera.k1_per_mm2 * f**2,
        k2=camera.k2_per_mm4 * f**4,
        p1=camera.p1_per_mm * f,
        p2=camera.p2_per_mm * f,
        r_cam_from_obj_rad=(float(rvec[0]), float(rvec[1]), float(rvec[2])),
        t_cam_from_obj_mm=(camera.x0_mm, camera.y0_mm, camera.z0_mm),
    )


def camera_from_opencv(
    opencv_camera: OpenCVCamera, *, du_px_per_mm: float, dv_px_per_mm: float, scale_on: ScaleAxis = "u"
) -> Camera:
    """The Heikkilä camera of an OpenCV one, given D_u, D_v; f follows from the axis without the scale factor.

    Raises ValueError when k3 ≠ 0 (the Heikkilä model has no r⁶ term, so the mapping would not be exact).
    """
    if opencv_camera.k3 != 0.0:
        raise ValueError(f"k3 must be 0 for the Heikkilä model (no r⁶ term), got {opencv_camera.k3}")
    if scale_on not in SCALE_ON_CHOICES:
        raise ValueError(f"scale_on: expected one of {SCALE_ON_CHOICES}, got {scale_on!r}")
    if scale_on == "u":
        f_mm = opencv_camera.fy_px / dv_px_per_mm
        su = opencv_camera.fx_px / (f_mm * du_px_per_mm)
    else:
        f_mm = opencv_camera.fx_px / du_px_per_mm
        su = opencv_camera.fy_px / (f_mm * dv_px_per_mm)
    rotation = Rotation.from_rotvec(np.asarray(opencv_camera.r_cam_from_obj_rad, dtype=np.float64)).as_matrix()
    omega, phi, kappa = angles_from_rotation(rotation)
    x0, y0, z0 = (float(t) for t in opencv_camera.t_cam_from_obj_mm)
    return Camera(
        image_width_px=opencv_camera.image_width_px,
        image_height_px=opencv_camera.image_height_px,
        du_px_per_mm=du_px_per_mm,
        dv_px_per_mm=dv_px_per_mm,
        su=su,
        f_mm=f_mm,
        u0_px=opencv_camera.cx_px,
        v0_px=opencv_camera.cy_px,
        k1_per_mm2=opencv_camera.k1 / f_mm**2,
        k2_per_mm4=opencv_camera.k2 / f_mm**4,
        p1_per_mm=opencv_camera.p1 / f_mm,
        p2_per_mm=opencv_camera.p2 / f_mm,
        x0_mm=x0,
        y0_mm=y0,
        z0_mm=z0,
        omega_rad=omega,
        phi_rad=phi,
        kappa_rad=kappa,
        scale_on=scale_on,
    )
