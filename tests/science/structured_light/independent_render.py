"""Frames of the virtual punch test made apart from `fringelab.science.virtual_test`'s imaging (issue 29): the
check that σ_w holds on renders whose noise, blur, radiometry and geometry the σ model and the simulator share
nothing of but the scene's truth.

What it takes from the repository: the scene's surface w(X, Y) (the truth the measurement is compared with), the
camera's pixel rays (`camera.rays_from_pixels`, the calibration model) and the projector's pose. Everything else is
its own:
- geometry: the rendering camera's radial distortion differs from the one the measurement is given (k1 2 % off:
  0.1 px at the image corners, a calibration error no budget knows of), and the projector's lens has its own
  distortion and stripe phase, which the projector table made from these same renders must absorb;
- each of ss × ss sub-pixel rays meets the plate (a plane, or the deflected plate by fixed-point iteration on the
  ray) and is lit by a binary slide whose stripes are blurred by the projector's defocus, a box (a linear ramp
  across each stripe edge) that widens away from its focus at Z = 20 mm, so the blur changes with height;
- radiometry: Lambertian plate with its own texture, projector fall-off 1/d² and cos⁴ of the projector's field
  angle, the camera's cos⁴ vignetting;
- optics: an elliptical Gaussian core (σ 0.8 × 0.55 px, turned 25°) plus 12 % of a wide halo (σ 3 px), on the
  sub-pixel image, then the pixel's box;
- sensor: per-pixel gain (2.5 %) and a per-column offset (0.4 grey), photon noise of 5 electrons per grey level,
  read noise 1.2 grey, 8-bit frames exposed to about a third of the range.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from fringelab.science.camera import fit_inverse_model, rays_from_pixels
from fringelab.science.virtual_test import PlateState, Preset

SENSOR_SEED = 424242  # this camera's own fixed pattern, the same in every frame


@dataclass(frozen=True)
class IndependentImaging:
    """What this renderer does differently; the defaults are the issue's "another program"."""

    supersample: int = 3
    k1_error: float = 0.02  # rendering camera's k1 relative to the measured one's
    projector_k1_per_mm2: float = 2e-5
    projector_phase_fraction: float = 0.55
    projector_blur_slide_mm: float = 0.004  # half-width of the ramp in focus (slide mm)
    projector_blur_per_mm: float = 0.0004  # its growth per mm of |Z − 20 mm|
    full_scale_grey: float = 120.0
    dark_fraction: float = 0.12
    ambient_grey: float = 4.0
    core_sigma_px: tuple[float, float] = (0.8, 0.55)
    core_angle_deg: float = 25.0
    halo_fraction: float = 0.12
    halo_sigma_px: float = 3.0
    pixel_gain_spread: float = 0.025
    column_offset_grey: float = 0.4
    electrons_per_grey: float = 20.0
    read_noise_grey: float = 0.8


class IndependentRenderer:
    """Flat calibration frames and test frames of `preset`'s scene, rendered as `IndependentImaging` says."""

    def __init__(self, preset: Preset, imaging: IndependentImaging | None = None) -> None:
        self.preset = preset
        self.imaging = imaging = imaging or IndependentImaging()
        camera = preset.camera
        rendering = replace(camera, k1_per_mm2=camera.k1_per_mm2 * (1.0 + imaging.k1_error))
        ss = imaging.supersample
        h, w = camera.image_height_px * ss, camera.image_width_px * ss
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        q = np.column_stack([((u + 0.5) / ss - 0.5).ravel(), ((v + 0.5) / ss - 0.5).ravel()])
        centre, directions = rays_from_pixels(rendering, q, inverse=fit_inverse_model(rendering))
        self._shape = (h, w)
        # Each ray as X = a + b·Z; in the projector's frame p = R·(X − C_p) = p0 + p1·Z.
        per_z = directions / directions[:, 2:3]
        b = per_z.T.reshape(3, h, w)
        a = (centre[:, None] - per_z.T * centre[2]).reshape(3, h, w)
        rotation = np.asarray(preset.projector.rotation)
        p_centre = np.asarray(preset.projector.centre_obj_mm)
        self._a, self._b = a[:2].astype(np.float32), b[:2].astype(np.float32)
        self._p0 = np.einsum("ij,jhw->ihw", rotation, a - p_centre[:, None, None]).astype(np.float32)
        self._p1 = np.einsum("ij,jhw->ihw", rotation, b).astype(np.float32)
        cos_camera = np.abs(directions[:, 2]).reshape(h, w)
        self._camera_vignette = ((cos_camera / cos_camera.max()) ** 4).astype(np.float32)
        reach = self._a - np.asarray(preset.scene.centre_xy_mm, np.float32)[:, None, None]
        self._on_plate = np.flatnonzero(np.hypot(reach[0], reach[1]).ravel() < preset.scene.clamp_radius_mm + 20.0)
        self._kernel = self._optics_kernel(ss)
        rng = np.random.default_rng(SENSOR_SEED)
        shape = (camera.image_height_px, camera.image_width_px)
        self._gain = rng.normal(1.0, imaging.pixel_gain_spread, shape)
        self._offset = np.broadcast_to(rng.normal(0.0, imaging.column_offset_grey, shape[1]), shape)

    def _optics_kernel(self, ss: int) -> np.ndarray:
        """The elliptical core of the optics' blur on the sub-pixel grid (the halo is blurred apart)."""
        im = self.imaging
        half = int(np.ceil(3.0 * max(im.core_sigma_px) * ss))
        y, x = np.mgrid[-half : half + 1, -half : half + 1].astype(np.float64) / ss
        a = np.deg2rad(im.core_angle_deg)
        along, across = np.cos(a) * x + np.sin(a) * y, -np.sin(a) * x + np.cos(a) * y
        core = np.exp(-0.5 * ((along / im.core_sigma_px[0]) ** 2 + (across / im.core_sigma_px[1]) ** 2))
        return (core / core.sum()).astype(np.float32)

    def render_flat(self, z_mm: float, *, rng: np.random.Generator) -> np.ndarray:
        z = np.full(self._shape, float(z_mm), np.float32)
        return self._frame(z, None, None, None, rng)

    def render_test(self, state: PlateState, *, rng: np.random.Generator) -> np.ndarray:
        scene = self.preset.scene
        ax, ay = self._a[0].ravel()[self._on_plate], self._a[1].ravel()[self._on_plate]
        bx, by = self._b[0].ravel()[self._on_plate], self._b[1].ravel()[self._on_plate]
        zc = np.zeros(len(ax), np.float64)
        for _ in range(40):  # fixed point on each ray: |∇w·b| ≤ 0.2 here, so it contracts by 5 each step
            w, _, _ = scene.surface_mm(ax + bx * zc, ay + by * zc, state)
            change = float(np.max(np.abs(w - zc), initial=0.0))
            zc = w
            if change < 1e-6:
                break
        _, wxc, wyc = scene.surface_mm(ax + bx * zc, ay + by * zc, state)
        z, wx, wy = (np.zeros(self._shape, np.float32) for _ in range(3))
        for field, values in ((z, zc), (wx, wxc), (wy, wyc)):
            field.ravel()[self._on_plate] = values
        return self._frame(z, wx, wy, state, rng)

    def _frame(
        self,
        z: np.ndarray,
        wx: np.ndarray | None,
        wy: np.ndarray | None,
        state: PlateState | None,
        rng: np.random.Generator,
    ) -> np.ndarray:
        im, scene, projector = self.imaging, self.preset.scene, self.preset.projector
        p = self._p0 + self._p1 * z
        xs, ys = projector.f_mm * p[0] / p[2], projector.f_mm * p[1] / p[2]
        xs = xs * (1.0 + im.projector_k1_per_mm2 * (xs * xs + ys * ys))
        # Binary slide behind a defocused lens: a box blur of the slide, so a linear ramp across each edge.
        period = projector.period_mm
        phase = np.mod(xs - im.projector_phase_fraction * period, period)
        to_edge = np.minimum(np.abs(phase - 0.5 * period), np.minimum(phase, period - phase))
        half_width = im.projector_blur_slide_mm + im.projector_blur_per_mm * np.abs(z - 20.0)
        ramp = np.clip(0.5 + to_edge / (2.0 * half_width), 0.0, 1.0)
        stripes = np.where(phase < 0.5 * period, ramp, 1.0 - ramp)
        # Projector light: 1/d² fall-off, cos⁴ of the field angle, cos of the incidence on the plate (−p is the
        # way to the projector, in its frame; the plate's normal (−wx, −wy, 1) turned into it).
        distance2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2]
        rotation = np.asarray(projector.rotation, np.float32)
        if wx is None or wy is None:
            normal_dot = -(rotation[0, 2] * p[0] + rotation[1, 2] * p[1] + rotation[2, 2] * p[2])
            cos_in = normal_dot / np.sqrt(distance2)
        else:
            n = [-wx * rotation[i, 0] - wy * rotation[i, 1] + rotation[i, 2] for i in range(3)]
            normal_dot = -(n[0] * p[0] + n[1] * p[1] + n[2] * p[2])
            cos_in = normal_dot / np.sqrt(distance2 * (1.0 + wx * wx + wy * wy))
        field = (p[2] * p[2] / distance2) ** 2
        nominal = np.linalg.norm(np.asarray(projector.centre_obj_mm) - np.r_[scene.centre_xy_mm, 0.0]) ** 2
        light = np.maximum(cos_in, 0.0) * field * np.float32(nominal) / distance2
        x, y = self._a[0] + self._b[0] * z, self._a[1] + self._b[1] * z
        albedo = 0.8 * (1.0 + 0.03 * np.cos(x / 23.0 + 0.4) * np.sin(y / 31.0))
        if state is not None:
            r = scene.radius_mm(x, y)
            albedo = np.where(r < scene.clamp_radius_mm, albedo, 0.05)
            albedo = np.where(r < scene.clamp_outer_radius_mm, albedo, 0.02)
        grey = im.full_scale_grey * albedo * light * (im.dark_fraction + (1.0 - im.dark_fraction) * stripes)
        grey = (grey * self._camera_vignette + im.ambient_grey).astype(np.float32)
        ss = im.supersample
        core = cv2.filter2D(grey, -1, self._kernel, borderType=cv2.BORDER_REFLECT)
        halo = cv2.GaussianBlur(grey, (0, 0), im.halo_sigma_px * ss, borderType=cv2.BORDER_REFLECT)
        grey = (1.0 - im.halo_fraction) * core + im.halo_fraction * halo
        h, w = self._shape
        image = grey.reshape(h // ss, ss, w // ss, ss).mean(axis=(1, 3)).astype(np.float64)
        image = image * self._gain + self._offset
        image = rng.poisson(np.maximum(image, 0.0) * im.electrons_per_grey) / im.electrons_per_grey
        image = image + rng.normal(0.0, im.read_noise_grey, image.shape)
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)
