"""The virtual test's harder imaging: soft partial shadows, photon and fixed-pattern noise, another blur kernel,
blur away from focus, exposure to a third of the 8-bit range (issue 29). Each is checked against its definition
on small renders."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.science.virtual_test import (
    DOME_SHADOWS,
    FringeRenderer,
    Imaging,
    SoftShadow,
    _blurred,
    _exposed,
    preset,
    render_straight_stripes,
    scenario,
)


def test_soft_shadow_dims_to_its_transmission_with_a_rim_of_its_width() -> None:
    shadow = SoftShadow(centre_xy_mm=(10.0, -5.0), semi_axes_mm=(30.0, 15.0), transmission=0.3, rim_mm=8.0)
    x = np.linspace(-40.0, 80.0, 4801)  # along the long axis through the centre
    light = shadow.light(x, np.full_like(x, -5.0))
    assert light[np.argmin(np.abs(x - 10.0))] == pytest.approx(0.3, abs=1e-6)
    assert light[0] == pytest.approx(1.0, abs=1e-6) and light[-1] == pytest.approx(1.0, abs=1e-6)
    # 10–90 % of the way from the shadow to full light across the rim at X = 10 + 30 mm: rim_mm wide (to the
    # sampling step, 0.025 mm).
    share = (light - 0.3) / 0.7
    right = x > 10.0
    width = x[right][np.argmin(np.abs(share[right] - 0.9))] - x[right][np.argmin(np.abs(share[right] - 0.1))]
    assert width == pytest.approx(8.0, abs=0.06)
    with pytest.raises(ValueError, match="transmission"):
        SoftShadow(centre_xy_mm=(0.0, 0.0), semi_axes_mm=(1.0, 1.0), transmission=1.5, rim_mm=1.0)


def test_a_ring_shadow_is_lit_again_inside_its_inner_ellipse() -> None:
    ring = SoftShadow(centre_xy_mm=(0.0, 0.0), semi_axes_mm=(75.0, 75.0), transmission=0.4, rim_mm=6.0,
                      inner_semi_axes_mm=(50.0, 50.0))  # fmt: skip
    x = np.array([0.0, 62.5, 120.0])  # centre, middle of the ring (12.5 mm from both rims: 5 rim σ), outside
    np.testing.assert_allclose(ring.light(x, np.zeros(3)), [1.0, 0.4, 1.0], atol=1e-6)
    with pytest.raises(ValueError, match="inner_semi_axes_mm"):
        SoftShadow(centre_xy_mm=(0.0, 0.0), semi_axes_mm=(5.0, 5.0), transmission=0.4, rim_mm=1.0,
                   inner_semi_axes_mm=(5.0, 2.0))  # fmt: skip


def test_dome_shadows_dim_stripes_to_20_to_50_percent() -> None:
    assert sorted(s.transmission for s in DOME_SHADOWS) == [0.2, 0.3, 0.5]
    assert len({s.rim_mm for s in DOME_SHADOWS}) == 3


def test_photon_noise_grows_with_the_level_and_the_gain_pattern_is_fixed() -> None:
    rng = np.random.default_rng(3)
    levels = np.array([10.0, 40.0, 80.0])
    flat = np.repeat(levels, 20000).reshape(3, 20000)
    image = _exposed(flat, rng=rng, noise_grey=1.0, electrons_per_grey=12.0).astype(np.float64)
    # Poisson: variance = level / electrons per grey, plus the read noise's 1 and rounding's 1/12 (5 % of the
    # variance is the sampling error of 20000 samples at 3σ).
    expected = levels / 12.0 + 1.0 + 1.0 / 12.0
    assert image.var(axis=1) == pytest.approx(expected, rel=0.05)
    assert image.mean(axis=1) == pytest.approx(levels, abs=0.05)
    # Fixed-pattern: the same gains in two frames, whatever the frame's noise.
    bright = np.full((64, 64), 200.0)
    a = _exposed(bright, rng=rng, noise_grey=0.0, pixel_gain_spread=0.01).astype(np.float64)
    b = _exposed(bright, rng=rng, noise_grey=0.0, pixel_gain_spread=0.01).astype(np.float64)
    assert np.array_equal(a, b) and 1.5 < a.std() < 2.5  # 1 % of 200, plus rounding


def test_disk_blur_has_the_sigma_of_the_gaussian_it_replaces() -> None:
    impulse = np.zeros((41, 41), np.float32)
    impulse[20, 20] = 1.0
    for kernel in ("gaussian", "disk"):
        spread = _blurred(impulse, 3.0, kernel)
        offsets = np.arange(41) - 20.0
        variance_u = float(np.sum(spread * offsets[None, :] ** 2) / np.sum(spread))
        # The pillbox sampled 8 × 8 per pixel: its σ to 2 %.
        assert np.sqrt(variance_u) == pytest.approx(3.0, rel=0.02), kernel
    with pytest.raises(ValueError, match="blur_kernel"):
        Imaging(blur_kernel="box")


def test_straight_stripes_take_the_harder_noise() -> None:
    rng = np.random.default_rng(4)
    plain = render_straight_stripes((32, 64), period_px=10.0, angle_deg=0.0, phase_px=0.0, rng=rng, noise_grey=0.0,
                                    uneven_illumination=False)  # fmt: skip
    harder = render_straight_stripes((32, 64), period_px=10.0, angle_deg=0.0, phase_px=0.0, rng=rng, noise_grey=0.0,
                                     uneven_illumination=False, electrons_per_grey=5.0, blur_kernel="disk")  # fmt: skip
    difference = harder.astype(np.float64) - plain
    # Photon noise on the bright stripes (200 grey: σ = √(200/5) ≈ 6.3) and none worth the name on the dark ones.
    assert 5.0 < difference[:, 2:3].std() < 8.0


def test_dim_scenario_uses_a_third_of_the_range_with_soft_shadows_over_the_dome() -> None:
    setup, timeline = scenario("dim", preset("kodak", imaging=Imaging(supersample=1)), 4)
    assert setup.imaging.electrons_per_grey > 0 and setup.imaging.pixel_gain_spread > 0
    renderer = FringeRenderer(setup)
    frame = renderer.render_test(timeline.states[-1], rng=np.random.default_rng(5))
    # The plate's bright stripes at about a third of 255 (the highlight above them, unclipped).
    assert 60 <= np.percentile(frame, 99) <= 100 and frame.max() < 250
    # The shadow near the punch dims the stripes under it to about 30 %: the brightest stripes on a patch inside
    # it against a patch beside it.
    scene = setup.scene
    inside = renderer.surface_block(slice(0, frame.shape[0]), flat_z_mm=None, state=timeline.states[-1])
    x, y = inside[0], inside[1]
    light = np.ones_like(x)
    for shadow in scene.soft_shadows:
        light *= shadow.light(x - scene.centre_xy_mm[0], y - scene.centre_xy_mm[1])
    core = light < 0.32
    lit = (light > 0.999) & (np.hypot(x - scene.centre_xy_mm[0], y - scene.centre_xy_mm[1]) < 120.0)
    assert np.count_nonzero(core) > 100
    ratio = np.percentile(frame[core], 95) / np.percentile(frame[lit], 95)
    assert 0.2 < ratio < 0.45
