"""σ_w honest on frames rendered apart from fringelab's simulator (issue 29): `independent_render` makes the
projector calibration and the test frames with its own ray casting, projector blur that changes with height,
optics (elliptical core and a wide halo), per-pixel gain and column offsets, Poisson and read noise at a third of
the 8-bit range, and a camera whose distortion differs from the one the measurement is given.

2σ_w must cover 90–99 % of the points' true errors in every frame, and hold where the budget used to fail: within
30 mm of the punch, on the steep wall (|∇w| > 0.3) and in every decile of σ. Measured (512 × 480, seed 11, the
flat frame and the 8-frame test's frames 2–5):

| | before the local check | local check | and the table's leverage |
|---|---|---|---|
| per frame | 91.3–95.1 % | 94.7–96.0 % | 94.9–97.6 % |
| within 30 mm of the punch, w0 ≥ 19 mm | 77.3–90.4 % | 94.1–97.2 % | 92.5–95.4 % |
| |∇w| > 0.3 | 87.9–90.2 % | 94.6–96.4 % | 93.1–94.7 % |
| lowest σ decile | 81–91 % | 90–93 % | 91–95 % |
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from fringelab.science.projector import build_projector_calibration, exact_camera_model
from fringelab.science.topography import locate_test_edges, track_and_measure
from fringelab.science.virtual_test import preset, punch_timeline, true_deflection_mm

from .independent_render import IndependentImaging, IndependentRenderer

PUNCH_NEAR_MM = 30.0
STEEP_SLOPE = 0.3


@dataclass(frozen=True)
class Checked:
    """One measured frame against the truth: w0, the points' true error, σ, radius from the punch and slope."""

    w0_mm: float
    error_mm: np.ndarray
    sigma_mm: np.ndarray
    radius_mm: np.ndarray
    slope: np.ndarray

    @property
    def within(self) -> np.ndarray:
        return np.abs(self.error_mm) <= 2.0 * self.sigma_mm


@pytest.fixture(scope="module")
def checked() -> list[Checked]:
    # 2 × 2 sub-pixel rays (the optics' core blur is 0.55–0.8 px, so sampling the binary slide's ramps at
    # 0.5 px adds no bias the blur does not smooth); calibration every 4 mm to 64 mm, above the 60 mm peak.
    setup = preset("kodak")
    renderer = IndependentRenderer(setup, IndependentImaging(supersample=2))
    rng = np.random.default_rng(11)
    z_mm = np.arange(0.0, 64.0 + 1e-9, 4.0)
    calibration = [renderer.render_flat(z, rng=rng) for z in z_mm]
    timeline = punch_timeline(8, max_deflection_mm=setup.max_deflection_mm)
    states = [timeline.states[i] for i in (0, 3, 5)]  # flat, 32 mm and 60 mm (the last before perforation)
    frames = [renderer.render_test(state, rng=rng) for state in states]
    camera = exact_camera_model(setup.camera)
    projector = build_projector_calibration(calibration, z_mm, camera)
    measured = list(track_and_measure(locate_test_edges(frames, projector), projector, camera))
    assert len(measured) == len(states)
    out = []
    for state, measurement in zip(states, measured, strict=True):
        points, sigma = measurement.points_obj_mm, measurement.sigma_z_mm
        assert sigma is not None and np.all(np.isfinite(sigma)) and len(points) > 20000
        x, y = points[:, 0], points[:, 1]
        _, wx, wy = setup.scene.deflection_mm(x, y, state.w0_mm)
        error = points[:, 2] - true_deflection_mm(setup.scene, state, x, y)
        out.append(Checked(state.w0_mm, error, sigma, setup.scene.radius_mm(x, y), np.hypot(wx, wy)))
    return out


def test_two_sigma_covers_90_to_99_percent_in_every_frame(checked: list[Checked]) -> None:
    for frame in checked:
        within = float(np.mean(frame.within))
        ratio = float(np.sqrt(np.mean(frame.error_mm**2) / np.mean(frame.sigma_mm**2)))
        assert 0.90 <= within <= 0.99, (frame.w0_mm, within)
        # The RMS error against the RMS σ: measured 0.87–1.03 (1.00–1.17 before the local check).
        assert 0.8 <= ratio <= 1.1, (frame.w0_mm, ratio)


def test_near_the_punch_and_on_the_steep_wall_two_sigma_still_covers(checked: list[Checked]) -> None:
    # ~350 points within 30 mm of the punch: a coverage of 0.95 has a binomial spread of ±1.2 %; the bound is
    # loose (85 %, the issue's) since these points' errors are correlated along their ~10 edges.
    for frame in checked[1:]:
        near = frame.radius_mm < PUNCH_NEAR_MM
        steep = frame.slope > STEEP_SLOPE
        assert near.sum() > 200 and steep.sum() > 200
        assert float(np.mean(frame.within[near])) >= 0.85, frame.w0_mm
        assert float(np.mean(frame.within[steep])) >= 0.88, frame.w0_mm


def test_small_sigma_is_covered_about_as_often_as_large(checked: list[Checked]) -> None:
    for frame in checked:
        edges = np.quantile(frame.sigma_mm, np.linspace(0.0, 1.0, 11))
        decile = np.clip(np.searchsorted(edges, frame.sigma_mm, side="right") - 1, 0, 9)
        coverage = np.array([np.mean(frame.within[decile == d]) for d in range(10)])
        # ~2500 points a decile: ±0.5 %. Measured 0.91–0.98 (0.81–0.97 before the local check).
        assert coverage.min() >= 0.87 and coverage.max() <= 0.995, (frame.w0_mm, coverage.round(3))
        assert coverage.max() - coverage.min() <= 0.09, (frame.w0_mm, coverage.round(3))
