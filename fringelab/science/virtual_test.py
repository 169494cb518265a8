"""The virtual test: stripes rendered through a camera and a pinhole projector onto a deforming plate.

Belongs here: image-space test stripes with known edges, the scene (clamped plate, punch, perforation), the
pinhole projector, the renderer (supersampled, antialiased stripes, Lambertian shading, blur that grows away
from focus, uneven illumination, soft partial shadows, highlights, photon, read and fixed-pattern noise, 8-bit
output at any exposure), presets for the paper's two cameras, and writing a whole experiment (camera
calibration, projector calibration and test recordings plus ground truth) in the recording formats.
Not here: the camera model (`camera.py`) and the chessboard renderer (`synthetic.py`), which it uses.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from scipy import special

from .camera import Camera, backproject_to_z, camera_centre_obj_mm, fit_inverse_model, project_points
from .scenarios import SCENARIOS
from .synthetic import reference_camera


def square_wave_box_mean(x: np.ndarray, width: np.ndarray | float, period: float) -> np.ndarray:
    """Mean of a 50 % square wave (1 on [0, P/2), 0 on [P/2, P), period P) over [x − w/2, x + w/2].

    The exact box average through the antiderivative, so a sample's value moves continuously with the edge
    position (no staircase from point sampling). Zero width gives the point value.
    """
    x = np.asarray(x, dtype=np.float64)
    w = np.broadcast_to(np.asarray(width, dtype=np.float64), x.shape)
    half = 0.5 * period

    def antiderivative(y: np.ndarray) -> np.ndarray:
        cycles = np.floor(y / period)
        return cycles * half + np.minimum(y - cycles * period, half)

    point = ((x - np.floor(x / period) * period) < half).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = (antiderivative(x + 0.5 * w) - antiderivative(x - 0.5 * w)) / w
    return np.where(w > 1e-9, mean, point)


def square_wave_blurred(x: np.ndarray, sigma: np.ndarray | float, period: float) -> np.ndarray:
    """A 50 % square wave (1 on [0, P/2), 0 on [P/2, P), period P) convolved with a Gaussian of width sigma.

    Each sample takes the normal CDF of its signed distance to the nearest edge. The next edge is at least P/4
    away: for sigma ≤ P/14 (10 px stripes under 0.7 px of blur) what that leaves out is below 2e-4 of the
    contrast mid-stripe and below 1e-6 within two sigma of an edge, so the edges stay where the wave has them.
    """
    u = np.mod(np.asarray(x), period)
    quarter = 0.25 * period
    # Nearest edge: 0 (rising) for u < P/4, P/2 (falling) for P/4 ≤ u < 3P/4, P (rising) beyond.
    signed = np.where(u < quarter, u, np.where(u < 3.0 * quarter, 2.0 * quarter - u, u - 4.0 * quarter))
    return special.ndtr(signed / sigma)


def render_straight_stripes(
    shape: tuple[int, int],
    *,
    period_px: float,
    angle_deg: float,
    phase_px: float,
    rng: np.random.Generator,
    blur_px: float = 0.7,
    noise_grey: float = 2.0,
    dark_grey: float = 40.0,
    bright_grey: float = 200.0,
    supersample: int = 4,
    uneven_illumination: bool = True,
    electrons_per_grey: float = 0.0,
    pixel_gain_spread: float = 0.0,
    blur_kernel: str = "gaussian",
) -> np.ndarray:
    """An 8-bit image, shape (H, W), of straight stripes with exactly known edges: test data for edge location.

    The stripe coordinate of pixel (u, v) is x = u·cos θ + v·sin θ − phase_px (θ = angle_deg; 0 = vertical
    stripes); the image is bright where x mod period_px < period_px / 2, so rising edges (dark → bright along
    +x) lie at x = m·period_px and falling ones at x = (m + ½)·period_px. Each pixel integrates its
    supersample² sub-pixels, each the exact box mean of the square wave over its footprint; the optical blur
    (Gaussian, blur_px) acts at the supersampled level, before pixel integration, as in a camera.
    The harder noise of `Imaging` is there too: electrons_per_grey > 0 makes noise_grey the read noise and adds
    photon (Poisson) noise; pixel_gain_spread a fixed per-pixel gain; blur_kernel "disk" blurs with a pillbox of
    the same σ instead of a Gaussian (`BLUR_KERNELS`).
    """
    height, width = shape
    ss = int(supersample)
    theta = np.deg2rad(angle_deg)
    normal = np.array([np.cos(theta), np.sin(theta)])
    grid_v, grid_u = np.mgrid[0 : height * ss, 0 : width * ss].astype(np.float64)
    grid_u = (grid_u + 0.5) / ss - 0.5
    grid_v = (grid_v + 0.5) / ss - 0.5
    x = grid_u * normal[0] + grid_v * normal[1] - phase_px
    stripes = square_wave_box_mean(x, (abs(normal[0]) + abs(normal[1])) / ss, period_px)
    stripes = _blurred(stripes, blur_px * ss, blur_kernel)
    illumination = 1.0
    if uneven_illumination:
        illumination = 0.75 + 0.25 * np.cos(2.0 * (grid_u / width - 0.3)) * np.cos(grid_v / height - 0.6)
    image = illumination * (dark_grey + (bright_grey - dark_grey) * stripes)
    image = image.reshape(height, ss, width, ss).mean(axis=(1, 3))
    return _exposed(image, rng=rng, noise_grey=noise_grey, electrons_per_grey=electrons_per_grey,
                    pixel_gain_spread=pixel_gain_spread)  # fmt: skip


# How the optics may blur: "gaussian", or "disk", a pillbox (a defocused lens's blur) of the same σ (radius 2σ).
BLUR_KERNELS = ("gaussian", "disk")
# The fixed-pattern noise is the camera's: the same per-pixel gains in every frame of every recording.
FIXED_PATTERN_SEED = 20070913


def _blurred(image: np.ndarray, sigma_px: float, kernel: str) -> np.ndarray:
    """The image blurred by a Gaussian of σ sigma_px, or a pillbox of the same σ (`BLUR_KERNELS`)."""
    if kernel not in BLUR_KERNELS:
        raise ValueError(f"blur_kernel: expected one of {BLUR_KERNELS}, got {kernel!r}")
    if not sigma_px > 0:
        return image
    if kernel == "gaussian":
        return cv2.GaussianBlur(image, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
    # A pillbox of radius R has σ = R/2 along any direction; sampled 8 × 8 per pixel so a small one is round.
    radius = 2.0 * sigma_px
    half = int(np.ceil(radius))
    fine = (np.arange(-half * 8, half * 8 + 8) + 0.5) / 8.0 - 0.5
    fy, fx = np.meshgrid(fine, fine, indexing="ij")
    inside = (fx * fx + fy * fy <= radius * radius).astype(np.float64)
    disk = inside.reshape(2 * half + 1, 8, 2 * half + 1, 8).sum(axis=(1, 3))
    disk /= disk.sum()
    return cv2.filter2D(image, -1, disk.astype(image.dtype), borderType=cv2.BORDER_REPLICATE)


def _exposed(
    image: np.ndarray,
    *,
    rng: np.random.Generator,
    noise_grey: float,
    electrons_per_grey: float = 0.0,
    pixel_gain_spread: float = 0.0,
    camera_vignetting: float = 0.0,
) -> np.ndarray:
    """The 8-bit frame a camera makes of a noise-free image in grey levels: its own vignetting (1 − v·r²/r²_corner),
    per-pixel gains (fixed-pattern noise, spread pixel_gain_spread, the same for every frame), photon noise
    (Poisson, electrons_per_grey electrons per grey level; none for 0) and read noise (Gaussian, noise_grey; the
    only noise for electrons_per_grey = 0), rounded and clipped to 0..255."""
    height, width = image.shape
    if camera_vignetting:
        v, u = np.mgrid[0:height, 0:width].astype(np.float64)
        r2 = ((u - 0.5 * (width - 1)) ** 2 + (v - 0.5 * (height - 1)) ** 2) / (0.25 * (width**2 + height**2))
        image = image * (1.0 - camera_vignetting * r2)
    if pixel_gain_spread:
        gains = np.random.default_rng(FIXED_PATTERN_SEED).normal(1.0, pixel_gain_spread, image.shape)
        image = image * gains
    if electrons_per_grey > 0:
        image = rng.poisson(np.maximum(image, 0.0) * electrons_per_grey) / electrons_per_grey
    image = image + rng.normal(0.0, noise_grey, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


# ----------------------------------------------------------------------------------------------------------------
# The scene: a clamped plate pushed at its centre, a pinhole projector, a camera.


@dataclass(frozen=True)
class Projector:
    """A pinhole slide projector with a binary stripe slide (a Ronchi ruling), possibly with lens distortion.

    Slide coordinates (x_s, y_s) in mm: x_s = f·x/z, y_s = f·y/z of a point in the projector frame
    (points_proj = rotation · (points_obj − centre_obj_mm)), then radial distortion x_s·(1 + k1·r²). The slide
    is bright where (x_s − phase_mm) mod period_mm < period_mm / 2, so the stripes are lines of constant x_s and
    the light sheets are planes through the projector centre.
    """

    centre_obj_mm: tuple[float, float, float]
    rotation: tuple[tuple[float, float, float], ...]
    f_mm: float
    period_mm: float
    phase_mm: float = 0.0
    k1_per_mm2: float = 0.0

    def slide_mm(self, x_mm: np.ndarray, y_mm: np.ndarray, z_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Slide coordinates (x_s, y_s) in mm of object points given by their coordinate arrays."""
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self.rotation
        dx, dy, dz = x_mm - self.centre_obj_mm[0], y_mm - self.centre_obj_mm[1], z_mm - self.centre_obj_mm[2]
        scale = self.f_mm / (r20 * dx + r21 * dy + r22 * dz)
        xs = (r00 * dx + r01 * dy + r02 * dz) * scale
        ys = (r10 * dx + r11 * dy + r12 * dz) * scale
        if self.k1_per_mm2:
            factor = 1.0 + self.k1_per_mm2 * (xs * xs + ys * ys)
            xs, ys = xs * factor, ys * factor
        return xs, ys


def projector_looking_at(
    centre_obj_mm: tuple[float, float, float],
    target_obj_mm: tuple[float, float, float],
    *,
    stripe_normal_obj: tuple[float, float, float],
    f_mm: float,
    period_mm: float,
    phase_mm: float = 0.0,
    k1_per_mm2: float = 0.0,
) -> Projector:
    """A projector at `centre_obj_mm` aimed at `target_obj_mm`, its slide x axis as close as possible to
    `stripe_normal_obj` (so the stripes on a plate facing it run across that direction)."""
    centre = np.asarray(centre_obj_mm, dtype=np.float64)
    axis = np.asarray(target_obj_mm, dtype=np.float64) - centre
    axis /= np.linalg.norm(axis)
    x_axis = np.asarray(stripe_normal_obj, dtype=np.float64)
    x_axis = x_axis - axis * (x_axis @ axis)
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(axis, x_axis)
    rotation = tuple((float(row[0]), float(row[1]), float(row[2])) for row in (x_axis, y_axis, axis))
    return Projector(
        centre_obj_mm=(float(centre[0]), float(centre[1]), float(centre[2])),
        rotation=rotation,
        f_mm=f_mm,
        period_mm=period_mm,
        phase_mm=phase_mm,
        k1_per_mm2=k1_per_mm2,
    )


@dataclass(frozen=True)
class SoftShadow:
    """A soft, partial shadow on the plate (of the punch or its holder, lit around by a large light source): an
    ellipse centred at centre_xy_mm from the plate centre, semi-axes semi_axes_mm (along X, Y before turning by
    angle_deg), inside which transmission of the projector's light is left (0.2–0.5: stripes at 20–50 % of their
    brightness), with a soft rim rim_mm wide (10–90 %). It lies on the plate and moves with it. With
    inner_semi_axes_mm it is a ring (the shadow of an annular holder): lit again inside that smaller ellipse of the
    same centre and angle, behind a rim as soft.
    """

    centre_xy_mm: tuple[float, float]
    semi_axes_mm: tuple[float, float]
    transmission: float
    rim_mm: float
    angle_deg: float = 0.0
    inner_semi_axes_mm: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.transmission <= 1.0:
            raise ValueError(f"transmission: expected 0..1, got {self.transmission}")
        if not (self.rim_mm > 0 and min(self.semi_axes_mm) > 0):
            raise ValueError(f"rim_mm and semi_axes_mm: expected > 0, got {self.rim_mm}, {self.semi_axes_mm}")
        inner = self.inner_semi_axes_mm
        within = inner is None or all(0 < a < b for a, b in zip(inner, self.semi_axes_mm, strict=True))
        if not within:
            raise ValueError(f"inner_semi_axes_mm: expected > 0 and < semi_axes_mm {self.semi_axes_mm}, got {inner}")

    def light(self, dx_mm: np.ndarray, dy_mm: np.ndarray) -> np.ndarray:
        """The share of the projector's light left at points (dx, dy) from the plate centre, in [transmission, 1]."""
        # A 10–90 % rim of width W is an erf of σ = W / 2.563.
        lit = special.ndtr(self._outside_mm(dx_mm, dy_mm, self.semi_axes_mm) * 2.563 / self.rim_mm)
        if self.inner_semi_axes_mm is not None:
            inside_inner = special.ndtr(-self._outside_mm(dx_mm, dy_mm, self.inner_semi_axes_mm) * 2.563 / self.rim_mm)
            lit = 1.0 - (1.0 - lit) * (1.0 - inside_inner)
        return self.transmission + (1.0 - self.transmission) * lit

    def _outside_mm(self, dx_mm: np.ndarray, dy_mm: np.ndarray, semi_axes_mm: tuple[float, float]) -> np.ndarray:
        """Distance (mm) of points outside the ellipse of these semi-axes (negative inside), near enough: (ρ − 1)
        times the semi-axis in that direction."""
        theta = np.deg2rad(self.angle_deg)
        px, py = dx_mm - self.centre_xy_mm[0], dy_mm - self.centre_xy_mm[1]
        along = (np.cos(theta) * px + np.sin(theta) * py) / semi_axes_mm[0]
        across = (-np.sin(theta) * px + np.cos(theta) * py) / semi_axes_mm[1]
        rho = np.hypot(along, across)
        with np.errstate(invalid="ignore", divide="ignore"):
            reach = np.hypot(along * semi_axes_mm[0], across * semi_axes_mm[1]) / rho
        reach = np.where(rho > 1e-9, reach, min(semi_axes_mm))
        return np.asarray((rho - 1.0) * reach)


@dataclass(frozen=True)
class PlateScene:
    """The test rig as the camera sees it: a plate clamped over a circle, a dark clamp ring, dark background.

    The plate deflects toward the camera (+Z) with a smoothed membrane profile
    w(r) = w0 · ln(ρ_R/ρ) / ln(ρ_R/b), ρ = √(r² + b²), ρ_R = √(R² + b²), b the punch radius, r from the punch
    axis, R the clamp radius: flat-topped under the punch, zero at the clamp, logarithmic between (the shape of a
    membrane under a central load). After perforation a hole of radius hole_radius_mm opens on the punch axis.

    Harder cases (all off by default): crack_count radial cracks (crack_width_mm wide, the first at
    crack_angle_deg from +X) run from the hole out to the state's crack_length_mm beyond its rim; between them the
    petals lift by petal_lift_mm[i] (cycled over the petals; + toward the camera) at the hole's rim, falling
    quadratically to 0 at the crack tips, so w jumps across each crack. A specular highlight (a Gaussian spot of
    the projector's light reflected straight into the camera, highlight_gain times the plate's diffuse level at
    its centre) sits at highlight_xy_mm; with highlight_rim_mm it is a disc of radius highlight_sigma_mm with a
    soft rim that wide (10–90 %) instead. room_light lights the scene evenly besides the projector (as a fraction
    of the projector's light at the plate centre), so a shadow is dim, not black. soft_shadows: partial shadows
    of the punch and its holder on the plate (`SoftShadow`), which dim the projector's light but not the room's.
    """

    centre_xy_mm: tuple[float, float] = (8.0, -5.0)
    clamp_radius_mm: float = 250.0
    clamp_outer_radius_mm: float = 330.0
    punch_radius_mm: float = 10.0
    plate_albedo: float = 0.85
    clamp_albedo: float = 0.06
    background_albedo: float = 0.02
    texture_amplitude: float = 0.02
    crack_count: int = 0
    crack_width_mm: float = 4.0
    crack_angle_deg: float = 20.0
    petal_lift_mm: tuple[float, ...] = ()
    highlight_xy_mm: tuple[float, float] | None = None
    highlight_sigma_mm: float = 10.0
    highlight_gain: float = 1.5
    highlight_rim_mm: float | None = None
    room_light: float = 0.0
    soft_shadows: tuple[SoftShadow, ...] = ()

    def deflection_mm(self, x_mm: np.ndarray, y_mm: np.ndarray, w0_mm: float) -> tuple[np.ndarray, ...]:
        """w and its slopes ∂w/∂X, ∂w/∂Y at object points (zero outside the clamp circle)."""
        dx = x_mm - self.centre_xy_mm[0]
        dy = y_mm - self.centre_xy_mm[1]
        r2 = dx * dx + dy * dy
        b2 = self.punch_radius_mm**2
        rho_r2 = self.clamp_radius_mm**2 + b2
        scale = w0_mm / np.log(np.sqrt(rho_r2 / b2))
        inside = r2 < self.clamp_radius_mm**2
        w = np.where(inside, scale * 0.5 * np.log(rho_r2 / (r2 + b2)), 0.0)
        dw_dr2 = np.where(inside, -0.5 * scale / (r2 + b2), 0.0)
        return w, 2.0 * dx * dw_dr2, 2.0 * dy * dw_dr2

    def radius_mm(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        return np.hypot(x_mm - self.centre_xy_mm[0], y_mm - self.centre_xy_mm[1])

    def surface_mm(self, x_mm: np.ndarray, y_mm: np.ndarray, state: PlateState) -> tuple[np.ndarray, ...]:
        """w and its slopes at object points for a plate state, petals included (`deflection_mm` without them)."""
        w, wx, wy = self.deflection_mm(x_mm, y_mm, state.w0_mm)
        if not (self.crack_count and self.petal_lift_mm and state.crack_length_mm > 0 and state.hole_radius_mm > 0):
            return w, wx, wy
        dx, dy = x_mm - self.centre_xy_mm[0], y_mm - self.centre_xy_mm[1]
        r = np.maximum(np.hypot(dx, dy), 1e-9)
        span = state.crack_length_mm
        tip = state.hole_radius_mm + span
        petal = self.petal_index(x_mm, y_mm)
        lift = np.asarray(self.petal_lift_mm, np.float64)[petal % len(self.petal_lift_mm)]
        inside = (r < tip) & (r >= state.hole_radius_mm)
        fall = np.where(inside, (tip - r) / span, 0.0)
        extra = lift * fall**2
        d_extra_dr = np.where(inside, -2.0 * lift * fall / span, 0.0)
        return (
            w + extra.astype(w.dtype),
            wx + (d_extra_dr * dx / r).astype(w.dtype),
            wy + (d_extra_dr * dy / r).astype(w.dtype),
        )

    def petal_index(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """Which petal (0..crack_count−1) each point lies in, counted from the first crack anticlockwise."""
        angle = np.arctan2(y_mm - self.centre_xy_mm[1], x_mm - self.centre_xy_mm[0]) - np.deg2rad(self.crack_angle_deg)
        sector = 2.0 * np.pi / max(self.crack_count, 1)
        return (np.mod(angle, 2.0 * np.pi) // sector).astype(np.int64)

    def in_crack(self, x_mm: np.ndarray, y_mm: np.ndarray, state: PlateState) -> np.ndarray:
        """Whether points lie in a crack (open, no surface) in this state."""
        if not (self.crack_count and state.crack_length_mm > 0 and state.hole_radius_mm > 0):
            return np.zeros(np.shape(x_mm), bool)
        dx, dy = x_mm - self.centre_xy_mm[0], y_mm - self.centre_xy_mm[1]
        r = np.hypot(dx, dy)
        angle = np.arctan2(dy, dx) - np.deg2rad(self.crack_angle_deg)
        sector = 2.0 * np.pi / self.crack_count
        # Angle to the nearest crack line, then the distance across it.
        off = np.mod(angle + 0.5 * sector, sector) - 0.5 * sector
        across = r * np.abs(np.sin(off))
        return (
            (across < 0.5 * self.crack_width_mm)
            & (np.cos(off) > 0)
            & (r < state.hole_radius_mm + state.crack_length_mm)
        )


@dataclass(frozen=True)
class PlateState:
    """One instant of the test: central deflection w0, the radius of the hole (0 before perforation), how far the
    cracks run beyond the hole's rim (0: none), and the height of the punch's nose once it has come through the
    hole (NaN while it is behind the plate; a black punch that hides what is behind it and casts a shadow)."""

    w0_mm: float
    hole_radius_mm: float = 0.0
    crack_length_mm: float = 0.0
    punch_tip_z_mm: float = float("nan")


@dataclass(frozen=True)
class Imaging:
    """Grey levels and optics of the rendered frames (8-bit output).

    gain_grey: grey level of the projector's full light on the plate's albedo (230: near the top of the range;
    about 85 uses a third of it). vignetting: the projector's fall-off toward the slide's edge; camera_vignetting:
    the lens's, 1 − v·r²/r²_corner over the image. blur_px: the optics' blur σ in focus; away from focus_z_mm it
    grows as √(blur² + (defocus_blur_px_per_mm·ΔZ)²); blur_kernel "disk" blurs with a pillbox of that σ instead of
    a Gaussian. noise_grey: Gaussian noise, the only noise with electrons_per_grey = 0, the read noise beside
    photon (Poisson) noise of electrons_per_grey electrons per grey level otherwise. pixel_gain_spread: the
    per-pixel gain's spread (fixed-pattern noise, the same in every frame).
    """

    supersample: int = 2
    blur_px: float = 0.7
    gain_grey: float = 230.0
    dark_stripe_fraction: float = 0.15
    ambient_grey: float = 6.0
    vignetting: float = 0.25
    noise_grey: float = 2.0
    electrons_per_grey: float = 0.0
    pixel_gain_spread: float = 0.0
    camera_vignetting: float = 0.0
    defocus_blur_px_per_mm: float = 0.0
    focus_z_mm: float = 0.0
    blur_kernel: str = "gaussian"

    def __post_init__(self) -> None:
        if self.blur_kernel not in BLUR_KERNELS:
            raise ValueError(f"blur_kernel: expected one of {BLUR_KERNELS}, got {self.blur_kernel!r}")


def harder_imaging(*, supersample: int = 2, blur_kernel: str = "gaussian") -> Imaging:
    """Frames as a dim real test makes them: exposed to a third of the 8-bit range, photon noise of 12 electrons
    per grey level and 1 grey level of read noise (σ ≈ 2.6 on the bright stripes, 1 on the dark ones), 1 % of
    fixed-pattern gain, 30 % camera vignetting in the corners, and blur growing by 0.012 px per mm away from the
    flat plate's focus (0.9 px at 60 mm)."""
    return Imaging(
        supersample=supersample, gain_grey=95.0, ambient_grey=3.0, noise_grey=1.0, electrons_per_grey=12.0,
        pixel_gain_spread=0.01, camera_vignetting=0.3, defocus_blur_px_per_mm=0.012, blur_kernel=blur_kernel,
    )  # fmt: skip


# How far the projector calibration's Z-stack reaches below the plate's rest height, in Z steps.
REST_MARGIN_STEPS = 2


def calibration_heights_mm(step_mm: float = 2.0, *, max_deflection_mm: float = 60.0) -> tuple[float, ...]:
    """The heights of a virtual test's projector calibration (its flat-plate Z-stack), in steps of step_mm: from
    REST_MARGIN_STEPS steps below the plate's rest height (Z = 0, where the table counts its edges) to 20 mm beyond
    the deepest deflection, 0 among them.

    The margin below the rest height keeps the flat first frame inside the calibrated range: at the lowest
    calibrated Z, the noise of its points put those below the table outside the range (the `dim` scenario: 4.0–4.3 %
    of its ~25 100 points in frame 0, seeds 29–31, with 4 mm steps from 0; none from −8 mm).

    >>> calibration_heights_mm(4.0)[:4], calibration_heights_mm(4.0)[-1]
    ((-8.0, -4.0, 0.0, 4.0), 80.0)
    """
    if not step_mm > 0:
        raise ValueError(f"step_mm: expected > 0, got {step_mm}")
    n_above = int(np.floor((max_deflection_mm + 20.0) / step_mm + 1e-9))
    return tuple(float(step_mm * i) for i in range(-REST_MARGIN_STEPS, n_above + 1))


@dataclass(frozen=True)
class Preset:
    """A whole virtual set-up: camera, projector, scene and imaging."""

    name: str
    camera: Camera
    projector: Projector
    scene: PlateScene
    imaging: Imaging
    max_deflection_mm: float = 60.0
    calibration_z_mm: tuple[float, ...] = calibration_heights_mm()


class FringeRenderer:
    """Renders the stripes of a preset's projector on the plate through its camera.

    For every sub-pixel (supersample² per pixel) the camera ray is found once (X, Y at Z = 0 and the ray's slope
    dX/dZ, dY/dZ); each frame then intersects the rays with the plate surface (Newton on Z − w(X(Z), Y(Z))),
    projects the surface points into the projector, and takes the slide's value there, box-averaged over the
    sub-pixel's footprint on the slide so that it moves continuously with the edge. Lambertian shading,
    projector vignetting and 1/d² fall-off make the illumination uneven; the optical blur acts on the supersampled
    image before pixel integration; then noise and rounding to 8 bits.
    """

    _BLOCK_ROWS = 64

    def __init__(self, preset: Preset) -> None:
        self.preset = preset
        camera = preset.camera
        ss = preset.imaging.supersample
        height, width = camera.image_height_px * ss, camera.image_width_px * ss
        inverse = fit_inverse_model(camera)
        sub_u = (np.arange(width) + 0.5) / ss - 0.5
        self._x0 = np.empty((height, width), np.float32)
        self._y0 = np.empty((height, width), np.float32)
        self._sx = np.empty((height, width), np.float32)
        self._sy = np.empty((height, width), np.float32)
        for start in range(0, height, 256):
            rows = np.arange(start, min(start + 256, height))
            grid_u, grid_v = np.meshgrid(sub_u, (rows + 0.5) / ss - 0.5)
            q_px = np.column_stack([grid_u.ravel(), grid_v.ravel()])
            at_0 = backproject_to_z(camera, q_px, 0.0, inverse=inverse)
            at_100 = backproject_to_z(camera, q_px, 100.0, inverse=inverse)
            shape = (len(rows), width)
            self._x0[rows] = at_0[:, 0].reshape(shape)
            self._y0[rows] = at_0[:, 1].reshape(shape)
            self._sx[rows] = ((at_100[:, 0] - at_0[:, 0]) / 100.0).reshape(shape)
            self._sy[rows] = ((at_100[:, 1] - at_0[:, 1]) / 100.0).reshape(shape)
        self._camera_centre = camera_centre_obj_mm(camera)
        centre = np.asarray(preset.projector.centre_obj_mm)
        self._nominal_distance_mm = float(np.linalg.norm(centre - np.r_[preset.scene.centre_xy_mm, 0.0]))

    def render_flat(self, z_mm: float, *, rng: np.random.Generator) -> np.ndarray:
        """A projector-calibration frame: a flat matte plate filling the view at height z_mm."""
        return self._render(rng=rng, flat_z_mm=float(z_mm), state=None)

    def render_test(self, state: PlateState, *, rng: np.random.Generator) -> np.ndarray:
        """A test frame: the clamped plate deflected to state.w0_mm, with its hole if perforated."""
        return self._render(rng=rng, flat_z_mm=None, state=state)

    def _render(self, *, rng: np.random.Generator, flat_z_mm: float | None, state: PlateState | None) -> np.ndarray:
        imaging = self.preset.imaging
        ss = imaging.supersample
        reflected: np.ndarray = np.empty(self._x0.shape, np.float32)
        pattern: np.ndarray = np.empty(self._x0.shape, np.float32)
        step = self._BLOCK_ROWS * ss
        for start in range(0, reflected.shape[0], step):
            rows = slice(start, min(start + step, reflected.shape[0]))
            reflected[rows], pattern[rows] = self._radiance_block(rows, flat_z_mm=flat_z_mm, state=state)
        # The stripes come blurred already; the optics blur the rest of the scene (the clamp ring, the hole)
        # here. Blurring the product would be exact; the two factors vary on very different scales, so this
        # differs only within a blur width of the clamp and the hole, which no measurement uses. A pillbox blur
        # is not analytic in the stripes: it blurs the whole product (the stripes carry only their defocus).
        disk = imaging.blur_kernel == "disk"
        if not disk:
            reflected = _blurred(reflected, imaging.blur_px * ss, "gaussian")
        grey = imaging.ambient_grey + imaging.gain_grey * reflected * pattern
        if disk:
            grey = _blurred(grey, imaging.blur_px * ss, "disk")
        camera = self.preset.camera
        image = grey.reshape(camera.image_height_px, ss, camera.image_width_px, ss).mean(axis=(1, 3))
        return _exposed(
            image, rng=rng, noise_grey=imaging.noise_grey, electrons_per_grey=imaging.electrons_per_grey,
            pixel_gain_spread=imaging.pixel_gain_spread, camera_vignetting=imaging.camera_vignetting,
        )  # fmt: skip

    def surface_block(
        self, rows: slice, *, flat_z_mm: float | None, state: PlateState | None
    ) -> tuple[np.ndarray, ...]:
        """Where the sub-pixel rays of `rows` meet the surface: X, Y, Z, ∂w/∂X, ∂w/∂Y (float32 arrays)."""
        x0, y0, sx, sy = self._x0[rows], self._y0[rows], self._sx[rows], self._sy[rows]
        if flat_z_mm is not None:
            z = np.full_like(x0, flat_z_mm)
            zero = np.zeros_like(x0)
            return x0 + sx * z, y0 + sy * z, z, zero, zero
        assert state is not None
        scene = self.preset.scene
        # Only rays that pass within the clamp circle below the highest point can meet the deflected plate;
        # elsewhere the surface is the plane Z = 0 (the clamp ring and what lies beyond).
        highest = max(state.w0_mm, 0.0) + max((abs(v) for v in scene.petal_lift_mm), default=0.0)
        reach = highest * float(max(np.abs(sx).max(), np.abs(sy).max()))
        candidates = np.flatnonzero(scene.radius_mm(x0, y0).ravel() < scene.clamp_radius_mm + reach + 1.0)
        x0c, y0c = x0.ravel()[candidates], y0.ravel()[candidates]
        sxc, syc = sx.ravel()[candidates], sy.ravel()[candidates]
        zc, wx, wy = scene.surface_mm(x0c, y0c, state)
        for _ in range(8):
            w, wx, wy = scene.surface_mm(x0c + sxc * zc, y0c + syc * zc, state)
            residual = zc - w
            zc = zc - residual / (1.0 - wx * sxc - wy * syc)
            if float(np.max(np.abs(residual), initial=0.0)) < 1e-4:
                break
        z = np.zeros(x0.size, np.float32)
        slope_x = np.zeros(x0.size, np.float32)
        slope_y = np.zeros(x0.size, np.float32)
        # The slopes of the last iteration are those at the final point to within 1e-4 mm of Z.
        z[candidates], slope_x[candidates], slope_y[candidates] = zc, wx, wy
        shape = x0.shape
        z_mm = z.reshape(shape)
        return x0 + sx * z_mm, y0 + sy * z_mm, z_mm, slope_x.reshape(shape), slope_y.reshape(shape)

    def _radiance_block(
        self, rows: slice, *, flat_z_mm: float | None, state: PlateState | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Reflectance × illumination, and the projected pattern (blurred), of the sub-pixels of `rows`."""
        preset = self.preset
        scene, projector, imaging = preset.scene, preset.projector, preset.imaging
        x, y, z, wx, wy = self.surface_block(rows, flat_z_mm=flat_z_mm, state=state)
        xs, ys = projector.slide_mm(x, y, z)
        # The optical blur (Gaussian, blur_px) and the sub-pixel's own box (width 1/ss px, variance 1/(12 ss²))
        # act on the stripes through the local scale of the slide: x_s changes by |∇x_s| per px. A Gaussian of
        # the combined width is exact for the blur and a close, symmetric stand-in for the box, so the edges stay
        # where they are; it needs no fine sampling, and the supersampling then integrates the pixel.
        ss = imaging.supersample
        slide_per_px = ss * np.hypot(np.gradient(xs, axis=0), np.gradient(xs, axis=1))
        focus_blur_px = 0.0 if imaging.blur_kernel == "disk" else imaging.blur_px
        defocus_px = imaging.defocus_blur_px_per_mm * (z - imaging.focus_z_mm)
        sigma = slide_per_px * np.sqrt(focus_blur_px**2 + defocus_px**2 + 1.0 / (12.0 * ss * ss))
        stripes = square_wave_blurred(xs - projector.phase_mm, np.maximum(sigma, 1e-6), projector.period_mm)
        lx, ly, lz = (projector.centre_obj_mm[0] - x, projector.centre_obj_mm[1] - y, projector.centre_obj_mm[2] - z)
        distance2 = lx * lx + ly * ly + lz * lz
        cos_incidence = (lz - wx * lx - wy * ly) / np.sqrt(distance2 * (1.0 + wx * wx + wy * wy))
        vignette = 1.0 - imaging.vignetting * (xs * xs + ys * ys) / (0.2 * projector.f_mm) ** 2
        falloff = self._nominal_distance_mm**2 / distance2
        if state is None:
            albedo = scene.plate_albedo * (1.0 + scene.texture_amplitude * np.sin(x / 29.0) * np.cos(y / 41.0))
        else:
            r = scene.radius_mm(x, y)
            texture = 1.0 + scene.texture_amplitude * np.sin(x / 37.0 + 1.0) * np.sin(y / 53.0)
            albedo = np.where(r < scene.clamp_radius_mm, scene.plate_albedo * texture, scene.clamp_albedo)
            albedo = np.where(r < scene.clamp_outer_radius_mm, albedo, scene.background_albedo)
            albedo = np.where(r < state.hole_radius_mm, scene.background_albedo, albedo)
            albedo = np.where(scene.in_crack(x, y, state), scene.background_albedo, albedo)
        light = np.maximum(cos_incidence, 0.0) * np.maximum(vignette, 0.0) * falloff
        if state is not None and np.isfinite(state.punch_tip_z_mm):
            # The punch's shadow (no projector light) and the punch itself (black) where it hides the plate.
            light = np.where(self._behind_punch(x, y, z, projector.centre_obj_mm, state), 0.0, light)
            albedo = np.where(self._behind_punch(x, y, z, self._camera_centre, state), 0.0, albedo)
        if state is not None and scene.soft_shadows:
            dx, dy = x - scene.centre_xy_mm[0], y - scene.centre_xy_mm[1]
            for shadow in scene.soft_shadows:
                light = light * shadow.light(dx, dy)
        if state is not None and scene.highlight_xy_mm is not None:
            hx, hy = scene.highlight_xy_mm
            r2 = (x - hx) ** 2 + (y - hy) ** 2
            if scene.highlight_rim_mm is None:
                profile = np.exp(-0.5 * r2 / scene.highlight_sigma_mm**2)
            else:
                profile = special.ndtr((scene.highlight_sigma_mm - np.sqrt(r2)) * 2.563 / scene.highlight_rim_mm)
            spot = scene.highlight_gain * profile
            light = light * (1.0 + spot / np.maximum(scene.plate_albedo, 1e-6))
        pattern = imaging.dark_stripe_fraction + (1.0 - imaging.dark_stripe_fraction) * stripes
        if scene.room_light > 0:
            # Room light adds to the projector's everywhere, shadows included: fold it into both factors.
            total = light + scene.room_light
            pattern = (light * pattern + scene.room_light) / total
            light = total
        return (albedo * light).astype(np.float32), pattern.astype(np.float32)

    def _behind_punch(
        self, x: np.ndarray, y: np.ndarray, z: np.ndarray, eye_obj_mm: Any, state: PlateState
    ) -> np.ndarray:
        """Whether the segment from each surface point to `eye_obj_mm` passes through the punch: a cylinder of
        the punch radius about the punch axis, from behind the plate up to state.punch_tip_z_mm."""
        scene = self.preset.scene
        cx, cy = scene.centre_xy_mm
        ex, ey, ez = (float(v) for v in eye_obj_mm)
        px, py = x - cx, y - cy
        dx, dy, dz = ex - x, ey - y, ez - z
        # |p + λ d|² = b² in the plate plane: a λ² + 2 β λ + c = 0.
        a = dx * dx + dy * dy
        beta = px * dx + py * dy
        c = px * px + py * py - scene.punch_radius_mm**2
        disc = beta * beta - a * c
        root = np.sqrt(np.maximum(disc, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            enter = (-beta - root) / a
            leave = (-beta + root) / a
        lam = np.maximum(enter, 0.0)
        hit = (disc > 0) & (leave > 0) & (enter < 1.0) & (z + lam * dz <= state.punch_tip_z_mm)
        return np.asarray(hit, bool)


PRESETS = ("kodak", "phantom")
# Soft partial shadows of the punch and its holder over the dome top (from the plate centre), of several sizes,
# rims and depths: stripes at 30, 50 and 20 % of their brightness, rims 8, 20 and 5 mm wide (about 6, 15 and 4 px
# on the virtual Kodak, against a 10 px period).
DOME_SHADOWS = (
    SoftShadow(centre_xy_mm=(0.0, 22.0), semi_axes_mm=(28.0, 16.0), transmission=0.3, rim_mm=8.0, angle_deg=30.0),
    SoftShadow(centre_xy_mm=(-55.0, -35.0), semi_axes_mm=(40.0, 40.0), transmission=0.5, rim_mm=20.0),
    SoftShadow(centre_xy_mm=(45.0, -40.0), semi_axes_mm=(14.0, 22.0), transmission=0.2, rim_mm=5.0, angle_deg=-20.0),
)
# Stripe period in the image near the plate centre, as in docs/method.md §7 ("stripes ~10 px per period").
TARGET_PERIOD_PX = 10.0
# The paper's projector: an 85 mm Kodak Retinar lens about 2 m from the plate.
PROJECTOR_F_MM = 85.0
PROJECTOR_DISTANCE_MM = 2000.0


def _stripe_period_for(camera: Camera, projector: Projector, scene: PlateScene, scan_axis: str) -> float:
    """Slide period (mm) that gives TARGET_PERIOD_PX along the scan axis at the image point of the plate centre."""
    centre = np.array([[scene.centre_xy_mm[0], scene.centre_xy_mm[1], 0.0]])
    q0 = project_points(camera, centre)[0]
    step = np.array([1.0, 0.0]) if scan_axis == "rows" else np.array([0.0, 1.0])
    points = backproject_to_z(camera, np.array([q0 - step, q0 + step]), 0.0)
    xs, _ = projector.slide_mm(points[:, 0], points[:, 1], points[:, 2])
    return float(TARGET_PERIOD_PX * abs(xs[1] - xs[0]) / 2.0)


def preset(name: str, *, imaging: Imaging | None = None) -> Preset:
    """The virtual set-up of one of the paper's cameras, about 2 m from the plate.

    "kodak": 512 × 480 px (the Kodak MotionCorder's size), stripes roughly vertical in the image, the projector
    30° off the plate normal on the −X side (edges move ~0.6 px per mm of Z). "phantom": 1024 × 1024 px (the
    Phantom v5.0's size), stripes roughly horizontal, the projector 15° off the normal on the +Y side, opposite the
    camera's 27° tilt (edges move ~1.2 px per mm of Z, so calibration steps must stay at about 2 mm). Both use
    the paper's reference cameras (Table 1 distortion) with a shorter focal length so the whole Ø500 mm plate
    and part of the clamp are in view.
    """
    scene = PlateScene()
    target = (scene.centre_xy_mm[0], scene.centre_xy_mm[1], 0.0)
    if name == "kodak":
        camera = replace(reference_camera("512x480"), f_mm=17.0)
        angle, direction, normal, scan_axis = np.deg2rad(30.0), np.array([-1.0, 0.0]), (1.0, 0.0, 0.0), "rows"
    elif name == "phantom":
        camera = replace(reference_camera("1024x1024"), f_mm=16.0)
        angle, direction, normal, scan_axis = np.deg2rad(15.0), np.array([0.0, 1.0]), (0.0, 1.0, 0.0), "cols"
    else:
        raise ValueError(f"preset: expected one of {PRESETS}, got {name!r}")
    offset = PROJECTOR_DISTANCE_MM * np.sin(angle) * direction
    centre = (target[0] + offset[0], target[1] + offset[1], PROJECTOR_DISTANCE_MM * np.cos(angle))
    provisional = projector_looking_at(centre, target, stripe_normal_obj=normal, f_mm=PROJECTOR_F_MM, period_mm=1.0)
    period_mm = _stripe_period_for(camera, provisional, scene, scan_axis)
    projector = replace(provisional, period_mm=period_mm, phase_mm=0.3 * period_mm, k1_per_mm2=5e-5)
    return Preset(name=name, camera=camera, projector=projector, scene=scene, imaging=imaging or Imaging())


# ----------------------------------------------------------------------------------------------------------------
# The whole virtual test


@dataclass(frozen=True, eq=False)
class PunchTimeline:
    """What happens in each frame of the virtual test, and the log it writes (frames.csv).

    states: (n,) plate states; time_s, punch_displacement_mm, force_kN: (n,); perforation_frame: the first frame
    with a hole.
    """

    states: tuple[PlateState, ...]
    time_s: np.ndarray
    punch_displacement_mm: np.ndarray
    force_kN: np.ndarray
    perforation_frame: int


def _timeline(
    states: list[PlateState], peak: int, max_deflection_mm: float, frame_interval_s: float, *,
    push_mm_per_frame: float, force_decay: float,
) -> PunchTimeline:  # fmt: skip
    """The log of a punch test whose plate goes through `states`, deepest at frame `peak`: the punch indents the
    plate a little (2 % of the deflection), and after perforation pushes on through by push_mm_per_frame; the force
    grows as (w0/w_max)^1.5 to 120 kN, then falls by force_decay per frame."""
    w0 = np.array([s.w0_mm for s in states])
    index = np.arange(len(states))
    after = index - peak
    punch = np.where(after <= 0, 1.02 * w0, 1.02 * max_deflection_mm + push_mm_per_frame * after)
    force = np.where(after <= 0, 120.0 * (w0 / max_deflection_mm) ** 1.5, 120.0 * force_decay**after)
    return PunchTimeline(
        states=tuple(states), time_s=index * frame_interval_s, punch_displacement_mm=punch, force_kN=force,
        perforation_frame=peak + 1,
    )  # fmt: skip


def punch_timeline(
    n_frames: int = 40,
    *,
    max_deflection_mm: float = 60.0,
    punch_radius_mm: float = 10.0,
    perforation_fraction: float = 0.75,
    frame_interval_s: float = 0.5,
) -> PunchTimeline:
    """A quasi-static punch test in n_frames: flat in frame 0, the centre deflected to max_deflection_mm at the
    frame perforation_fraction of the way through, then a hole opening from half to 1.2 times the punch radius.

    The deflection grows as (t/t_peak)^1.25: slowly at first, as the punch beds in, so even a short recording
    moves the edges little from frame to frame at the start, where the tracking has no motion to predict from.
    """
    if n_frames < 4:
        raise ValueError(f"n_frames: expected ≥ 4, got {n_frames}")
    peak = max(1, int(round(perforation_fraction * (n_frames - 1))))
    if peak >= n_frames - 1:
        peak = n_frames - 2
    states = []
    for i in range(n_frames):
        if i <= peak:
            states.append(PlateState(max_deflection_mm * (i / peak) ** 1.25))
        else:
            progress = (i - peak) / max(n_frames - 1 - peak, 1)
            radius = punch_radius_mm * (0.5 + 0.7 * progress)
            states.append(PlateState(max_deflection_mm * (1.0 + 0.02 * progress), hole_radius_mm=radius))
    return _timeline(states, peak, max_deflection_mm, frame_interval_s, push_mm_per_frame=3.0, force_decay=0.25)


def fast_timeline(
    n_frames: int = 16,
    *,
    max_deflection_mm: float = 60.0,
    hole_radius_mm: float = 9.0,
    springback_mm: float = 6.0,
    crack_length_mm: tuple[float, float] = (0.0, 0.0),
    punch_protrusion_mm_per_frame: float = 0.0,
    frame_interval_s: float = 2e-4,
) -> PunchTimeline:
    """A dynamic punch test filmed at a modest frame rate: large motion between frames, then perforation with
    springback within one frame.

    Frame 0 is flat; the centre then deflects in equal steps to max_deflection_mm at frame n − 4 (about 4.6 mm
    per frame for 16 frames); in the next frame a hole of hole_radius_mm opens and the plate springs back by
    springback_mm; it stays there for the last frames. Cracks, if any, run crack_length_mm[0] beyond the hole in
    the first perforated frame, growing to crack_length_mm[1] in the last. With punch_protrusion_mm_per_frame > 0
    the punch's nose comes through the hole (from the height of the plate's centre at perforation) by that much
    per frame, casting a shadow.
    """
    if n_frames < 6:
        raise ValueError(f"n_frames: expected ≥ 6, got {n_frames}")
    peak = n_frames - 4
    states = [PlateState(max_deflection_mm * i / peak) for i in range(peak + 1)]
    after = max_deflection_mm - springback_mm
    n_after = n_frames - 1 - peak
    for j in range(n_after):
        fraction = j / max(n_after - 1, 1)
        crack = crack_length_mm[0] + fraction * (crack_length_mm[1] - crack_length_mm[0])
        tip = (
            max_deflection_mm + punch_protrusion_mm_per_frame * (j + 1) if punch_protrusion_mm_per_frame > 0 else np.nan
        )
        states.append(PlateState(after, hole_radius_mm=hole_radius_mm, crack_length_mm=crack, punch_tip_z_mm=tip))
    return _timeline(states, peak, max_deflection_mm, frame_interval_s, push_mm_per_frame=8.0, force_decay=0.1)


def scenario(name: str, setup: Preset, n_frames: int) -> tuple[Preset, PunchTimeline]:
    """A preset's scene and timeline for one of the virtual tests.

    "quasi-static": the paper's test (`punch_timeline`). "fast": `fast_timeline` (large motion per frame, an
    18 mm hole and 6 mm of springback within one frame). "petals": the fast test with four radial cracks growing
    from 15 to 35 mm beyond the hole and petals lifting by different amounts, so w jumps across each crack.
    "highlight": the quasi-static test with a specular highlight on the plate. "shadow": the fast test with the
    punch coming through the hole, shadowing part of the stripes (dim room light, so the shadow is not black).
    "hard": all of them at once. "dim": the quasi-static test in dim, uneven light (`harder_imaging`: a third of
    the 8-bit range, photon and fixed-pattern noise, vignetting, blur growing away from focus), with soft partial
    shadows over the dome top (`DOME_SHADOWS`) and a highlight with a soft rim; the preset's supersampling is
    kept.
    """
    scene = setup.scene
    petals: dict[str, Any] = {"crack_count": 4, "petal_lift_mm": (5.0, -3.0, 4.0, -2.0)}
    highlight: dict[str, Any] = {"highlight_xy_mm": (scene.centre_xy_mm[0] - 110.0, scene.centre_xy_mm[1] + 90.0)}
    fast: dict[str, Any] = {"max_deflection_mm": setup.max_deflection_mm}
    if name == "quasi-static":
        timeline = punch_timeline(n_frames, max_deflection_mm=setup.max_deflection_mm,
                                  punch_radius_mm=scene.punch_radius_mm)  # fmt: skip
        return setup, timeline
    if name == "fast":
        return setup, fast_timeline(n_frames, **fast)
    if name == "petals":
        return replace(setup, scene=replace(scene, **petals)), fast_timeline(
            n_frames, crack_length_mm=(15.0, 35.0), **fast
        )
    if name == "highlight":
        timeline = punch_timeline(n_frames, max_deflection_mm=setup.max_deflection_mm,
                                  punch_radius_mm=scene.punch_radius_mm)  # fmt: skip
        return replace(setup, scene=replace(scene, **highlight)), timeline
    if name == "shadow":
        return replace(setup, scene=replace(scene, room_light=0.1)), fast_timeline(
            n_frames, punch_protrusion_mm_per_frame=12.0, **fast
        )
    if name == "hard":
        timeline = fast_timeline(n_frames, crack_length_mm=(15.0, 35.0), punch_protrusion_mm_per_frame=12.0, **fast)
        return replace(setup, scene=replace(scene, room_light=0.1, **petals, **highlight)), timeline
    if name == "dim":
        timeline = punch_timeline(n_frames, max_deflection_mm=setup.max_deflection_mm,
                                  punch_radius_mm=scene.punch_radius_mm)  # fmt: skip
        dim_scene = replace(scene, soft_shadows=DOME_SHADOWS, room_light=0.03, highlight_rim_mm=6.0,
                            highlight_sigma_mm=14.0, highlight_gain=0.8, **highlight)  # fmt: skip
        return replace(setup, scene=dim_scene, imaging=harder_imaging(supersample=setup.imaging.supersample)), timeline
    raise ValueError(f"scenario: expected one of {SCENARIOS}, got {name!r}")


def true_deflection_mm(scene: PlateScene, state: PlateState, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """The true w at object points (NaN inside the hole and the cracks)."""
    x, y = np.asarray(x_mm, np.float64), np.asarray(y_mm, np.float64)
    w, _, _ = scene.surface_mm(x, y, state)
    missing = (scene.radius_mm(x, y) < state.hole_radius_mm) | scene.in_crack(x, y, state)
    return np.where(missing, np.nan, w)


def true_camera_calibration(camera: Camera) -> Any:
    """A camera calibration document object for the exact camera (for ground truth and demos).

    Made by the calibration solver on noise-free corners of a 3-D grid, then pinned to the exact parameters, so
    it carries every field a calibration file has.
    """
    from .calibration import CornerView, calibrate_from_views

    grid_x, grid_y = np.meshgrid(np.linspace(-200, 200, 9), np.linspace(-160, 160, 7))
    views = []
    for z in (-20.0, 40.0, 100.0):
        points = np.column_stack([grid_x.ravel(), grid_y.ravel(), np.full(grid_x.size, z)])
        views.append(CornerView(f"z={z:g}", points, project_points(camera, points), z))
    calibration = calibrate_from_views(
        views,
        image_size_wh_px=(camera.image_width_px, camera.image_height_px),
        mode="zstack",
        du_px_per_mm=camera.du_px_per_mm,
        dv_px_per_mm=camera.dv_px_per_mm,
        scale_on=camera.scale_on,
        provenance={"input": "virtual experiment (exact camera)"},
    )
    return replace(calibration, camera=camera, inverse=fit_inverse_model(camera))


# ----------------------------------------------------------------------------------------------------------------
# The true surface as a finite-element model (to test the comparison with simulations)


@dataclass(frozen=True, eq=False)
class TruePlateModel:
    """The virtual plate's true surface as a shell model in the plate frame (mm): nodes (N, 3) at Z = 0,
    triangles (T, 3), and per state (S,) the displacement (S, N, 3) (only Z: the renderer's plate moves along Z),
    the punch travel and force of each state, and the punch node's travel."""

    node_xyz_mm: np.ndarray
    triangles: np.ndarray
    time_s: np.ndarray
    displacement_mm: np.ndarray
    punch_displacement_mm: np.ndarray
    force_kN: np.ndarray


def true_plate_model(
    scene: PlateScene,
    timeline: PunchTimeline,
    *,
    state_punch_mm: np.ndarray | None = None,
    quarter: bool = False,
    resolution: float = 0.06,
) -> TruePlateModel:
    """A triangulated disc over the clamp circle carrying the true deflection at chosen punch displacements.

    Nodes lie on rings whose spacing and in-ring spacing are `resolution` × √(r² + b²) (b the punch radius):
    w'' scales as 1/(r² + b²), so linear interpolation on the triangles is off by about resolution²·w0/(8·ln(ρ_R/b))
    everywhere, 0.01 mm at 60 mm for 0.06, well under the measurement's noise. States: the timeline's frames, or
    the punch displacements `state_punch_mm` (w0, time and force interpolated from the timeline; deflection is
    linear in w0, so a state between two frames is exactly the blend of theirs). quarter: only X ≥ 0, Y ≥ 0 about
    the plate centre, with the centre as origin (a quarter model); otherwise in plate coordinates. The hole
    after perforation is not cut: the measurement has no data there, so nothing is compared.
    """
    from scipy.spatial import Delaunay

    b = scene.punch_radius_mm
    radius = scene.clamp_radius_mm
    rings = [0.0]
    while rings[-1] < radius:
        rings.append(min(rings[-1] + resolution * np.hypot(rings[-1], b), radius))
    points = [(0.0, 0.0)]
    for r in rings[1:]:
        n = max(int(np.ceil(2.0 * np.pi * r / (resolution * np.hypot(r, b)))), 8)
        n = int(np.ceil(n / 4.0)) * 4  # the quarter's edges then lie on the axes
        angles = 2.0 * np.pi * np.arange(n) / n
        if quarter:
            angles = angles[angles <= 0.5 * np.pi + 1e-12]
        points += [(r * np.cos(a), r * np.sin(a)) for a in angles]
    local = np.array(points)
    triangles = Delaunay(local).simplices.astype(np.int64)
    xy = local if quarter else local + np.asarray(scene.centre_xy_mm)
    frame_punch = timeline.punch_displacement_mm
    w0_frames = np.array([s.w0_mm for s in timeline.states])
    punch = frame_punch if state_punch_mm is None else np.asarray(state_punch_mm, np.float64)
    w0 = np.interp(punch, frame_punch, w0_frames)
    time_s = np.interp(punch, frame_punch, timeline.time_s)
    # Beyond the last frame the punch goes on at its last speed (states there keep distinct times).
    speed = (frame_punch[-1] - frame_punch[-2]) / (timeline.time_s[-1] - timeline.time_s[-2])
    time_s = np.where(punch > frame_punch[-1], timeline.time_s[-1] + (punch - frame_punch[-1]) / speed, time_s)
    force = np.interp(punch, frame_punch, timeline.force_kN)
    plate_xy = local + np.asarray(scene.centre_xy_mm)
    shape, _, _ = scene.deflection_mm(plate_xy[:, 0], plate_xy[:, 1], 1.0)
    displacement = np.zeros((len(punch), len(xy), 3))
    displacement[:, :, 2] = w0[:, None] * shape[None, :]
    return TruePlateModel(
        node_xyz_mm=np.column_stack([xy, np.zeros(len(xy))]), triangles=triangles, time_s=time_s,
        displacement_mm=displacement, punch_displacement_mm=punch, force_kN=force,
    )  # fmt: skip
