"""The along-edge smoothing filter's weights and what they do to noise (pure numpy, no OpenCV).

Belongs here: the interior weights of the Gaussian-weighted local quadratic fit that `fringes` smooths located
edges with, and the ratio between the noise of a smoothed position and the raw − smoothed residual each frame
reports, which `uncertainty` turns into σ. Kept apart from `fringes` (which needs OpenCV) so the API, which
reads σ through the result file's writer and reader, never imports OpenCV.
"""

from __future__ import annotations

import functools

import numpy as np


def edge_smoothing_weights(sigma_lines: float) -> np.ndarray:
    """The interior weights (2h + 1,), h = ⌈3σ⌉, of the along-edge smoothing: a Gaussian-weighted local quadratic
    fit (Savitzky–Golay) evaluated at its centre."""
    half = max(1, int(np.ceil(3.0 * sigma_lines)))
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    gauss = np.exp(-0.5 * (offsets / sigma_lines) ** 2)
    moments = np.array([np.sum(gauss * offsets**m) for m in range(5)])
    design = np.array([[moments[i + j] for j in range(3)] for i in range(3)])
    # Row 0 of the inverse normal matrix times [1, d, d²]·g: the weights that give the fitted value at d = 0.
    return np.asarray(np.linalg.solve(design, np.eye(3))[0] @ np.vstack([gauss, gauss * offsets, gauss * offsets**2]))


@functools.lru_cache(maxsize=16)
def smoothed_noise_ratio(sigma_lines: float, *, presmooth_px: float = 0.0) -> float:
    """σ of a smoothed edge position over the RMS of raw − smoothed (`FrameEdges.noise_px`).

    The image is presmoothed along the stripes (Gaussian σ_p px), so the raw positions' noise on lines d apart
    correlates as C(d) = exp(−d²/4σ_p²) (white noise through a Gaussian); with the interior smoothing weights w
    the ratio is √(wᵀCw / (e₀ − w)ᵀC(e₀ − w)). NaN without edge smoothing (noise_px is then NaN too).

    >>> round(smoothed_noise_ratio(3.0), 3), round(smoothed_noise_ratio(3.0, presmooth_px=1.0), 3)
    (0.466, 1.326)
    """
    if not sigma_lines > 0:
        return float("nan")
    w = edge_smoothing_weights(sigma_lines)
    d = np.arange(len(w)) - len(w) // 2
    gap = d[:, None] - d[None, :]
    correlation = np.exp(-(gap**2) / (4.0 * presmooth_px**2)) if presmooth_px > 0 else np.eye(len(w))
    residual = -w
    residual[len(w) // 2] += 1.0
    return float(np.sqrt((w @ correlation @ w) / (residual @ correlation @ residual)))


@functools.lru_cache(maxsize=16)
def smoothing_noise_tables(sigma_lines: float, *, presmooth_px: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """What the along-edge smoothing does to the noise of a point with b lines of its edge before it and a after
    it, as two tables (h + 1, h + 1) indexed [min(b, h), min(a, h)], h = ⌈3σ⌉: the σ of the smoothed position and
    the RMS of raw − smoothed, both over the raw positions' σ (raw noise of constant σ, correlated between lines as
    in `smoothed_noise_ratio`). Within a half-width of an edge's end the fit is one-sided (or the weighted mean
    where a quadratic would be ill-conditioned), as `fringes._smooth_along_chains` does, and amplifies the noise.
    [h, h] is the interior: its ratio is `smoothed_noise_ratio`.
    """
    half = max(1, int(np.ceil(3.0 * sigma_lines)))
    gain = np.full((half + 1, half + 1), np.nan)
    residual = np.full((half + 1, half + 1), np.nan)
    for before in range(half + 1):
        for after in range(half + 1):
            d = np.arange(-before, after + 1, dtype=np.float64)
            g = np.exp(-0.5 * (d / sigma_lines) ** 2)
            moments = [float(np.sum(g * d**m)) for m in range(5)]
            design = np.array([[moments[i + j] for j in range(3)] for i in range(3)])
            det = float(np.linalg.det(design))
            if before == half and after == half:
                w = edge_smoothing_weights(sigma_lines)
            elif abs(det) > 1e-9 * moments[0] ** 3 * sigma_lines**6:
                w = np.linalg.solve(design, np.eye(3))[0] @ np.vstack([g, g * d, g * d * d])
            else:
                w = g / moments[0]
            gap = d[:, None] - d[None, :]
            correlation = np.exp(-(gap**2) / (4.0 * presmooth_px**2)) if presmooth_px > 0 else np.eye(len(d))
            rest = -w
            rest[before] += 1.0
            gain[before, after] = np.sqrt(w @ correlation @ w)
            residual[before, after] = np.sqrt(max(rest @ correlation @ rest, 0.0))
    return gain, residual
