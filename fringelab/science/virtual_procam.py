"""The virtual digital-projector rig: a known camera and DLP projector, and what the camera sees of chessboard
poses, a sphere in front of a screen, or any of them, under any projector image (docs/procam.md §6).

Belongs here: the default rig (`virtual_procam_rig`), scenes made of planes, spheres and chessboards given in the
camera frame, the projector's patterns (Gray code bit frames, white, black, N-step sinusoids) as 1-D profiles
along projector columns or rows, and the renderer. Not here: the slide-projector virtual test and its plate
(`simulate.py`), decoding or triangulating (`graycode.py`, `procam.py`).

Rendering. Every camera pixel is split into supersample² sub-pixels; each sub-pixel's ray (the camera's own
distortion undone exactly) meets the nearest surface; the point's projector pixel comes from the projector's model
(its distortion included), and the projector's light there is its image: square pixels (a DLP's micromirrors)
blurred by the projector's lens (Gaussian, projector_blur_px), taken from a profile sampled 16 times per projector
pixel. Light: ambient + gain · albedo · cos(incidence) · pattern, none where another surface shadows the point
from the projector. The camera's blur acts on the sub-pixel image, then the sub-pixels are averaged, noise added and
the grey levels rounded to 8 bits.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import cv2
import numpy as np
from scipy import special

from .camera import Camera, backproject_to_z, camera_as_opencv
from .graycode import PatternSequence, WhiteBlack, gray_pattern_values
from .procam import ProcamModel, normalised_from_pixels, project_to_projector, rigid_transform
from .procam_table import StripePattern
from .virtual_test import FringeRenderer, PlateState, Preset, square_wave_blurred
from .virtual_test import Projector as SlideProjector

# Each projector pixel is sampled this many times along the profile, so a sub-pixel reads the blurred square
# pixels to 1/16 px before the linear interpolation (error ~1e-4 of the contrast at an edge).
PROFILE_UPSAMPLE = 16


def look_at_rotation(forward: np.ndarray, down_hint: np.ndarray) -> np.ndarray:
    """Rotation whose rows are the x, y, z axes of a camera looking along `forward` with y close to `down_hint`."""
    z = np.asarray(forward, np.float64) / np.linalg.norm(forward)
    y = np.asarray(down_hint, np.float64) - z * (z @ down_hint)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    return np.vstack([x, y, z])


def virtual_procam_rig(*, camera_size_wh_px: tuple[int, int] = (360, 270)) -> ProcamModel:
    """The default virtual rig (truth): a 360 × 270 px camera with mild barrel distortion looking along +z, and a
    320 × 200 px DLP projector 120 mm to its right, aimed at the point 300 mm in front of the camera (a 22°
    triangulation angle), with a little distortion of its own. Both see ~110 mm × 80 mm there: one projector pixel
    is ~1.3 camera pixels."""
    width, height = camera_size_wh_px
    scale = width / 360.0
    f_px = 1000.0 * scale
    camera_matrix = np.array([[f_px, 0.0, 0.5 * (width - 1) + 3.0], [0.0, f_px, 0.5 * (height - 1) - 2.0],
                              [0.0, 0.0, 1.0]])  # fmt: skip
    projector_matrix = np.array([[740.0, 0.0, 161.0], [0.0, 740.0, 100.0], [0.0, 0.0, 1.0]])
    centre_cam = np.array([120.0, -8.0, 10.0])
    target = np.array([0.0, 0.0, 300.0])
    rotation = look_at_rotation(target - centre_cam, np.array([0.0, 1.0, 0.0]))
    return ProcamModel(
        camera_matrix=camera_matrix, camera_dist=np.array([-0.08, 0.05, 0.0005, -0.0003, 0.0]),
        camera_size_wh_px=(width, height), projector_matrix=projector_matrix,
        projector_dist=np.array([0.04, -0.02, 0.0, 0.0, 0.0]), projector_size_wh_px=(320, 200),
        r_proj_from_cam=rotation, t_proj_from_cam_mm=-rotation @ centre_cam,
    )  # fmt: skip


@dataclass(frozen=True)
class Plane:
    """The plane n·p = offset (camera frame, mm, n a unit normal toward the camera), of one albedo."""

    normal: tuple[float, float, float]
    offset_mm: float
    albedo: float = 0.8


@dataclass(frozen=True)
class Sphere:
    centre_cam_mm: tuple[float, float, float]
    radius_mm: float
    albedo: float = 0.8


@dataclass(frozen=True)
class ChessboardPose:
    """A printed chessboard: `cols` × `rows` inner corners of `square_mm`, white margin of one square around the
    squares; board coordinates (X, Y, 0) of inner corner (i, j) are (i·square, j·square); pose board → camera."""

    cols: int
    rows: int
    square_mm: float
    rvec: tuple[float, float, float]
    tvec_mm: tuple[float, float, float]
    white: float = 0.85
    black: float = 0.08

    @property
    def rotation(self) -> np.ndarray:
        return cv2.Rodrigues(np.asarray(self.rvec, np.float64))[0]

    def inner_corners_board_mm(self) -> np.ndarray:
        """(cols·rows, 3) board coordinates, row by row."""
        j, i = np.mgrid[0 : self.rows, 0 : self.cols]
        return np.column_stack([i.ravel() * self.square_mm, j.ravel() * self.square_mm, np.zeros(i.size)])

    def inner_corners_cam_mm(self) -> np.ndarray:
        return self.inner_corners_board_mm() @ self.rotation.T + np.asarray(self.tvec_mm)


Surface = Plane | Sphere | ChessboardPose


@dataclass(frozen=True)
class ProcamImaging:
    """Grey levels and optics of the rendered frames (8-bit)."""

    supersample: int = 3
    camera_blur_px: float = 0.6
    projector_blur_px: float = 0.4
    gain_grey: float = 220.0
    ambient_grey: float = 8.0
    noise_grey: float = 1.0


@dataclass(frozen=True)
class Pattern:
    """One projector image that varies along one axis: `values` (one per projector pixel along it, 0..1)."""

    axis: Literal["columns", "rows"]
    values: np.ndarray = field(repr=False)


def gray_code_patterns(sequence: PatternSequence) -> dict[int, Pattern]:
    """The projector images of a sequence whose threshold is white and black, by frame number (the phase frames
    follow the sequence's phase). `in_frame_order` lists one or several sequences' images as a recording."""
    extent = sequence.extent_px
    coordinate = np.arange(extent)
    bits = gray_pattern_values(sequence, coordinate)
    frames: dict[int, Pattern] = {}
    for i, frame in enumerate(sequence.gray_frames):
        frames[frame] = Pattern(sequence.axis, bits[i].astype(np.float64))
    if not isinstance(sequence.threshold, WhiteBlack):
        raise ValueError("gray_code_patterns renders sequences with white and black threshold frames only")
    frames[sequence.threshold.white] = Pattern(sequence.axis, np.ones(extent))
    frames[sequence.threshold.black] = Pattern(sequence.axis, np.zeros(extent))
    if sequence.phase is not None:
        n = len(sequence.phase.frames)
        offset = sequence.phase.offset_px or 0.0
        for step, frame in enumerate(sequence.phase.frames):
            phase = 2.0 * np.pi * (coordinate - offset) / sequence.phase.period_px - 2.0 * np.pi * step / n
            frames[frame] = Pattern(sequence.axis, 0.5 + 0.5 * np.cos(phase))
    return frames


def in_frame_order(*patterns: dict[int, Pattern]) -> list[Pattern]:
    """The images of one or more sequences (sharing frame numbers where they share frames) in recording order."""
    merged: dict[int, Pattern] = {}
    for each in patterns:
        merged.update(each)
    if sorted(merged) != list(range(len(merged))):
        raise ValueError(f"the sequences' frames are not numbered 0..{len(merged) - 1}: {sorted(merged)}")
    return [merged[i] for i in range(len(merged))]


class ProcamRenderer:
    """Renders scenes of the rig's camera frame under projector patterns (see the module docstring)."""

    def __init__(self, rig: ProcamModel, *, imaging: ProcamImaging | None = None) -> None:
        self.rig = rig
        self.imaging = imaging or ProcamImaging()
        ss = self.imaging.supersample
        width, height = rig.camera_size_wh_px
        sub_u = (np.arange(width * ss) + 0.5) / ss - 0.5
        sub_v = (np.arange(height * ss) + 0.5) / ss - 0.5
        grid_u, grid_v = np.meshgrid(sub_u, sub_v)
        xy = normalised_from_pixels(
            rig.camera_matrix, rig.camera_dist, np.column_stack([grid_u.ravel(), grid_v.ravel()])
        )
        self._rays = np.column_stack([xy, np.ones(len(xy))])
        self._shape = (height * ss, width * ss)

    def hits(self, surfaces: Sequence[Surface]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For every sub-pixel: the nearest surface point (M, 3) (NaN: none), its unit normal (M, 3) and albedo (M,)."""
        rays = self._rays
        best = np.full(len(rays), np.inf)
        normal = np.zeros((len(rays), 3))
        albedo = np.zeros(len(rays))
        for surface in surfaces:
            lam, n, a = _intersect(surface, rays, self._shape)
            closer = np.isfinite(lam) & (lam > 0) & (lam < best)
            best[closer] = lam[closer]
            normal[closer] = n[closer]
            albedo[closer] = a[closer]
        points = np.where(np.isfinite(best)[:, None], best[:, None] * rays, np.nan)
        return points, normal, albedo

    def render(
        self, surfaces: Sequence[Surface], patterns: Sequence[Pattern], *, rng: np.random.Generator
    ) -> list[np.ndarray]:
        """One 8-bit frame, shape (H, W), per pattern, of the scene made of `surfaces`."""
        rig, imaging = self.rig, self.imaging
        points, normal, albedo = self.hits(surfaces)
        seen = np.isfinite(points[:, 0])
        q_proj = np.full((len(points), 2), np.nan)
        q_proj[seen] = project_to_projector(rig, points[seen])
        centre = rig.projector_centre_cam_mm
        to_projector = centre - np.where(seen[:, None], points, 0.0)
        distance = np.linalg.norm(to_projector, axis=1)
        cos_incidence = np.maximum(np.sum(normal * to_projector, axis=1) / np.maximum(distance, 1e-9), 0.0)
        lit = seen & (cos_incidence > 0) & ~_shadowed(surfaces, points, centre, seen)
        width_p, height_p = rig.projector_size_wh_px
        inside = lit & (q_proj[:, 0] > -0.5) & (q_proj[:, 0] < width_p - 0.5) & (q_proj[:, 1] > -0.5) & (
            q_proj[:, 1] < height_p - 0.5)  # fmt: skip
        light = np.where(inside, albedo * cos_incidence, 0.0)
        ss = imaging.supersample
        width, height = rig.camera_size_wh_px
        frames = []
        for pattern in patterns:
            coordinate = q_proj[:, 0 if pattern.axis == "columns" else 1]
            value = _sample_profile(pattern.values, np.where(inside, coordinate, 0.0), imaging.projector_blur_px)
            radiance = imaging.ambient_grey * np.where(seen, albedo, 0.0) / 0.8 + imaging.gain_grey * light * value
            image = radiance.reshape(self._shape).astype(np.float32)
            if imaging.camera_blur_px > 0:
                image = cv2.GaussianBlur(image, (0, 0), imaging.camera_blur_px * ss, borderType=cv2.BORDER_REPLICATE)
            image = image.reshape(height, ss, width, ss).mean(axis=(1, 3))
            image = image + rng.normal(0.0, imaging.noise_grey, image.shape)
            frames.append(np.clip(np.rint(image), 0, 255).astype(np.uint8))
        return frames

    def true_points(self, surfaces: Sequence[Surface], q_px: np.ndarray) -> np.ndarray:
        """Where the rays of camera pixels q_px (N, 2) meet the scene (N, 3), NaN where they miss."""
        xy = normalised_from_pixels(self.rig.camera_matrix, self.rig.camera_dist, q_px)
        rays = np.column_stack([xy, np.ones(len(xy))])
        best = np.full(len(rays), np.inf)
        for surface in surfaces:
            lam, _, _ = _intersect(surface, rays)
            closer = np.isfinite(lam) & (lam > 0) & (lam < best)
            best[closer] = lam[closer]
        return np.where(np.isfinite(best)[:, None], best[:, None] * rays, np.nan)


def _sample_profile(values: np.ndarray, coordinate: np.ndarray, blur_px: float) -> np.ndarray:
    """The blurred square-pixel profile at projector coordinates (pixel i covers i − ½ .. i + ½)."""
    fine = np.repeat(np.asarray(values, np.float64), PROFILE_UPSAMPLE)
    pad = 4 * PROFILE_UPSAMPLE
    fine = np.concatenate([np.full(pad, fine[0]), fine, np.full(pad, fine[-1])])
    if blur_px > 0:
        blurred = cv2.GaussianBlur(fine.reshape(1, -1), (0, 0), sigmaX=blur_px * PROFILE_UPSAMPLE, sigmaY=0,
                                   borderType=cv2.BORDER_REPLICATE)  # fmt: skip
        fine = np.asarray(blurred, np.float64).ravel()
    # Fine sample j (after the pad) is the centre of sub-interval j: coordinate (j + ½)/U − ½.
    positions = (np.arange(len(fine)) - pad + 0.5) / PROFILE_UPSAMPLE - 0.5
    return np.interp(coordinate, positions, fine)


def _dot(vectors: np.ndarray, v: np.ndarray) -> np.ndarray:
    """vectors (N, 3) · v (3,), per component (see `procam.rigid_transform` for why not BLAS)."""
    return vectors[:, 0] * v[0] + vectors[:, 1] * v[1] + vectors[:, 2] * v[2]


def _footprint_sigma(coordinate: np.ndarray) -> np.ndarray:
    """σ (in the coordinate's units) of one sub-pixel's box footprint, from the coordinate's change per sub-pixel."""
    with np.errstate(invalid="ignore"):
        du = np.gradient(coordinate, axis=1)
        dv = np.gradient(coordinate, axis=0)
    sigma = np.sqrt((du * du + dv * dv) / 12.0).ravel()
    return np.where(np.isfinite(sigma), np.maximum(sigma, 1e-6), 1e-6)


def _intersect(
    surface: Surface, rays: np.ndarray, grid_shape: tuple[int, int] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ray parameter λ (p = λ·ray), unit normal and albedo of each ray's hit with one surface (λ NaN: miss);
    grid_shape: the rays' sub-pixel grid, for the footprint of each (None: point samples)."""
    n_rays = len(rays)
    if isinstance(surface, Plane):
        normal = np.asarray(surface.normal, np.float64)
        normal = normal / np.linalg.norm(normal)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = surface.offset_mm / _dot(rays, normal)
        return lam, np.broadcast_to(normal, (n_rays, 3)), np.full(n_rays, surface.albedo)
    if isinstance(surface, Sphere):
        c = np.asarray(surface.centre_cam_mm, np.float64)
        a = np.sum(rays * rays, axis=1)
        b = _dot(rays, c)
        disc = b * b - a * (c @ c - surface.radius_mm**2)
        with np.errstate(invalid="ignore"):
            lam = np.where(disc >= 0, (b - np.sqrt(disc)) / a, np.nan)
        points = lam[:, None] * rays
        normal = (points - c) / surface.radius_mm
        return lam, normal, np.full(n_rays, surface.albedo)
    rotation = surface.rotation
    t = np.asarray(surface.tvec_mm, np.float64)
    normal = rotation[:, 2]
    if normal @ t > 0:  # the board's face toward the camera
        normal = -normal
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (normal @ t) / _dot(rays, normal)
    points = lam[:, None] * rays
    board = rigid_transform(rotation.T, -rotation.T @ t, points)  # board coordinates (X, Y, ~0)
    s = surface.square_mm
    x, y = board[:, 0] / s, board[:, 1] / s
    # Squares between inner corners: square (a, b) spans [a, a+1] × [b, b+1] for a in −1..cols−1; the margin
    # beyond the outer squares is white. Each sub-pixel takes the share of its footprint that is dark (a Gaussian
    # of the box's σ in board units, separable along the board's axes): point samples of a step would put every
    # square border on the sub-pixel grid, up to half a sub-pixel off, which no later blur undoes.
    if grid_shape is not None:
        sigma_x = _footprint_sigma(x.reshape(grid_shape))
        sigma_y = _footprint_sigma(y.reshape(grid_shape))
    else:
        sigma_x = sigma_y = np.full(n_rays, 1e-6)
    odd_x = square_wave_blurred(x - 1.0, sigma_x, 2.0)  # P(⌊x⌋ odd)
    odd_y = square_wave_blurred(y - 1.0, sigma_y, 2.0)
    inside = (special.ndtr((x + 1.0) / sigma_x) - special.ndtr((x - surface.cols) / sigma_x)) * (
        special.ndtr((y + 1.0) / sigma_y) - special.ndtr((y - surface.rows) / sigma_y))  # fmt: skip
    dark = inside * (odd_x * odd_y + (1.0 - odd_x) * (1.0 - odd_y))
    on_board = (x > -2) & (x < surface.cols + 1) & (y > -2) & (y < surface.rows + 1)
    albedo = surface.white + (surface.black - surface.white) * dark
    lam = np.where(on_board, lam, np.nan)
    return lam, np.broadcast_to(normal, (n_rays, 3)), albedo


def _shadowed(
    surfaces: Sequence[Surface], points: np.ndarray, light_cam_mm: np.ndarray, seen: np.ndarray
) -> np.ndarray:
    """Whether a sphere stands between each point and the projector (only spheres cast shadows here)."""
    shadow = np.zeros(len(points), bool)
    for surface in surfaces:
        if not isinstance(surface, Sphere):
            continue
        c = np.asarray(surface.centre_cam_mm, np.float64)
        p = np.where(seen[:, None], points, 0.0)
        d = light_cam_mm - p
        length = np.linalg.norm(d, axis=1)
        d = d / np.maximum(length, 1e-9)[:, None]
        pc = c - p
        along = np.sum(pc * d, axis=1)
        closest2 = np.sum(pc * pc, axis=1) - along**2
        # The point itself on this sphere: the segment leaves its surface (along ≤ 0 on the lit side).
        shadow |= seen & (along > 1e-6) & (closest2 < surface.radius_mm**2 * (1 - 1e-9)) & (along < length)
    return shadow


def digital_projector_of(
    camera: Camera, projector: SlideProjector, *, stripe_period_px: float = 8.0
) -> tuple[ProcamModel, StripePattern]:
    """The virtual test's slide projector as a digital one with the same light sheets: a camera–projector model
    (the camera in OpenCV's form, exact) and the stripe pattern that shows the slide's stripes, with pixels of
    period_mm / stripe_period_px on the slide and the principal point in the middle of an image large enough for
    the whole slide area the camera sees from Z = −100 to +200 mm."""
    opencv = camera_as_opencv(camera)
    pixel_mm = projector.period_mm / stripe_period_px
    f_px = projector.f_mm / pixel_mm
    m, t = camera.rotation, camera.translation_mm
    rotation = np.asarray(projector.rotation, np.float64)
    centre = np.asarray(projector.centre_obj_mm, np.float64)
    r_proj_from_cam = rotation @ m.T
    t_proj_from_cam = -rotation @ (m.T @ t + centre)
    corners = np.array([[0, 0], [camera.image_width_px - 1, 0], [0, camera.image_height_px - 1],
                        [camera.image_width_px - 1, camera.image_height_px - 1]], np.float64)  # fmt: skip
    reach = []
    for z in (-100.0, 200.0):
        points = backproject_to_z(camera, corners, z)
        xs, ys = projector.slide_mm(points[:, 0], points[:, 1], points[:, 2])
        reach += [np.abs(xs).max(), np.abs(ys).max()]
    half_px = int(np.ceil(1.1 * max(reach) / pixel_mm))
    size = 2 * half_px
    cx = cy = half_px - 0.5
    model = ProcamModel(
        camera_matrix=opencv.camera_matrix, camera_dist=opencv.dist_coeffs,
        camera_size_wh_px=(camera.image_width_px, camera.image_height_px),
        projector_matrix=np.array([[f_px, 0.0, cx], [0.0, f_px, cy], [0.0, 0.0, 1.0]]),
        projector_dist=np.array([projector.k1_per_mm2 * projector.f_mm**2, 0.0, 0.0, 0.0, 0.0]),
        projector_size_wh_px=(size, size), r_proj_from_cam=r_proj_from_cam, t_proj_from_cam_mm=t_proj_from_cam,
    )  # fmt: skip
    pattern = StripePattern("columns", period_px=stripe_period_px, offset_px=cx + projector.phase_mm / pixel_mm)
    return model, pattern


def gray_code_on_plate(
    setup: Preset, model: ProcamModel, sequence: PatternSequence, *, state: PlateState, rng: np.random.Generator
) -> list[np.ndarray]:
    """What the virtual test's camera records of its plate in `state` while the slide projector, taken as the
    digital one `model` of `digital_projector_of` (same pixels), shows a Gray-code sequence along projector
    columns with all-white and all-black threshold frames: the frames in the sequence's numbering.

    Each Gray bit is itself a square wave along projector x (bit j from the least significant: bright where
    (x + ½)/band_px − 2^j mod 2^(j+2) < 2^(j+1)), so it is the slide projector with another period and phase,
    rendered exactly as the test's stripes are (same blur, shading, noise)."""
    if sequence.axis != "columns" or not isinstance(sequence.threshold, WhiteBlack):
        raise ValueError("gray_code_on_plate: expected a code along projector columns with white and black frames")
    projector = setup.projector
    pixel_mm = projector.f_mm / float(model.projector_matrix[0, 0])
    cx = float(model.projector_matrix[0, 2])
    band_mm = sequence.band_px * pixel_mm
    slides: dict[int, tuple[float, float]] = {}  # frame → (period_mm, phase_mm)
    for i, frame in enumerate(sequence.gray_frames):
        j = sequence.n_bits - 1 - i
        slides[frame] = (2.0 ** (j + 2) * band_mm, (2.0**j * sequence.band_px - cx - 0.5) * pixel_mm)
    wide = 1e9  # one stripe wider than anything the camera sees: bright (white) or dark (black) everywhere
    slides[sequence.threshold.white] = (wide, -0.25 * wide)
    slides[sequence.threshold.black] = (wide, 0.25 * wide)
    frames: list[np.ndarray] = []
    for frame in range(max(slides) + 1):
        if frame not in slides:
            raise ValueError(f"gray_code_on_plate: the sequence leaves frame {frame} unnamed")
        period_mm, phase_mm = slides[frame]
        shown = replace(setup, projector=replace(projector, period_mm=period_mm, phase_mm=phase_mm))
        frames.append(FringeRenderer(shown).render_test(state, rng=rng))
    return frames
