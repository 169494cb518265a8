"""The virtual experiment: stripes rendered through a camera and a pinhole projector onto a deforming plate.

Belongs here: image-space test stripes with known edges, the scene (clamped plate, punch, perforation), the
pinhole projector, the renderer (supersampled, antialiased stripes, Lambertian shading, blur, uneven
illumination, 8-bit noise), presets for the paper's two cameras, and writing a whole experiment (camera
calibration, projector calibration and test recordings plus ground truth) in the recording formats.
Not here: the camera model (`camera.py`) and the chessboard renderer (`synthetic.py`), which it uses.
"""

from __future__ import annotations

import cv2
import numpy as np


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
) -> np.ndarray:
    """An 8-bit image, shape (H, W), of straight stripes with exactly known edges: test data for edge location.

    The stripe coordinate of pixel (u, v) is x = u·cos θ + v·sin θ − phase_px (θ = angle_deg; 0 = vertical
    stripes); the image is bright where x mod period_px < period_px / 2, so rising edges (dark → bright along
    +x) lie at x = m·period_px and falling ones at x = (m + ½)·period_px. Each pixel integrates its
    supersample² sub-pixels, each the exact box mean of the square wave over its footprint; the optical blur
    (Gaussian, blur_px) acts at the supersampled level, before pixel integration, as in a camera.
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
    if blur_px > 0:
        stripes = cv2.GaussianBlur(stripes, (0, 0), blur_px * ss)
    illumination = 1.0
    if uneven_illumination:
        illumination = 0.75 + 0.25 * np.cos(2.0 * (grid_u / width - 0.3)) * np.cos(grid_v / height - 0.6)
    image = illumination * (dark_grey + (bright_grey - dark_grey) * stripes)
    image = image.reshape(height, ss, width, ss).mean(axis=(1, 3))
    image += rng.normal(0.0, noise_grey, shape)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)
