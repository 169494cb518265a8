"""Stripe edges of one frame (docs/method.md §5): direction, period, sub-pixel location, polarity, masks, errors."""

from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from fringelab.science import fringes
from fringelab.science.fringes import (
    EdgeSettings,
    FrameEdges,
    NoStripesError,
    _link_chains,
    _smooth_along_chains,
    detect_stripes,
    locate_edges,
)
from fringelab.science.virtual_test import render_straight_stripes

PERIOD_PX = 10.3
PHASE_PX = 3.37


def edge_errors_px(edges: FrameEdges, *, angle_deg: float, period_px: float, phase_px: float) -> np.ndarray:
    """Signed error of each edge along its scan line, against the nearest true edge of the renderer."""
    theta = np.deg2rad(angle_deg)
    normal = np.array([np.cos(theta), np.sin(theta)])
    q = edges.q_px()
    x = q @ normal - phase_px
    half_periods = x / (0.5 * period_px)
    across = (half_periods - np.round(half_periods)) * 0.5 * period_px
    along_scan = abs(normal[0]) if edges.axis == "rows" else abs(normal[1])
    return across / along_scan


def true_polarity(edges: FrameEdges, *, angle_deg: float, period_px: float, phase_px: float) -> np.ndarray:
    """+1 where the renderer has a rising edge along increasing t, −1 for a falling one."""
    theta = np.deg2rad(angle_deg)
    normal = np.array([np.cos(theta), np.sin(theta)])
    x = edges.q_px() @ normal - phase_px
    rising_along_x = np.round(x / (0.5 * period_px)).astype(int) % 2 == 0
    t_component = normal[0] if edges.axis == "rows" else normal[1]
    return np.where(rising_along_x == (t_component > 0), 1, -1)


@pytest.mark.parametrize("angle_deg", [0.0, 20.0, -35.0, 70.0, 90.0])
def test_edges_of_known_stripes_have_small_bias_and_noise(angle_deg: float) -> None:
    rng = np.random.default_rng(7)
    image = render_straight_stripes((240, 256), period_px=PERIOD_PX, angle_deg=angle_deg, phase_px=PHASE_PX, rng=rng)
    edges = locate_edges(image)
    assert edges.axis == ("rows" if abs(angle_deg) < 45 else "cols")
    errors = edge_errors_px(edges, angle_deg=angle_deg, period_px=PERIOD_PX, phase_px=PHASE_PX)
    # Every line crosses ~ 25 edges; borders lose a few lines to the along-stripe smoothing.
    assert len(edges) > 0.8 * 25 * 240
    # Bias: the probit chord leaves < 0.01 px of pixel locking at blur 0.7 px, and it averages over the phases.
    assert abs(np.mean(errors)) < 0.005
    # Noise σ = 2 grey levels on a 160-level step gives ≈ 0.02 px per crossing before smoothing along the edge,
    # ≈ 0.01 px after; 0.02 px RMS leaves room for the residual pixel locking.
    assert np.sqrt(np.mean(errors**2)) < 0.02
    assert np.max(np.abs(errors)) < 0.1
    assert np.array_equal(
        edges.polarity, true_polarity(edges, angle_deg=angle_deg, period_px=PERIOD_PX, phase_px=PHASE_PX)
    )
    assert 0.0 < edges.noise_px < 0.03


@pytest.mark.parametrize("angle_deg", [0.0, 20.0])
def test_each_edge_carries_a_sigma_that_follows_its_contrast_and_noise(angle_deg: float) -> None:
    """Top: 160 grey levels of contrast; bottom: 40, blurred by a pillbox, both with photon noise (2 electrons per
    grey level) and 2 % fixed-pattern gain, which the σ model does not assume. One σ per frame would be ~0.06 px
    for both and cover ~70 % of the dim half's errors; each edge's own σ covers 90–99 % in either half (measured:
    90–92 % at 0°, where pixel locking, constant along a vertical edge, is an error no residual shows; 98–100 % at
    20°, where the pixel locking varies along the edge and its residuals make σ err large)."""
    rng = np.random.default_rng(11)
    stripes = {
        "period_px": PERIOD_PX,
        "angle_deg": angle_deg,
        "phase_px": PHASE_PX,
        "rng": rng,
        "uneven_illumination": False,
        "noise_grey": 1.0,
        "electrons_per_grey": 2.0,
        "pixel_gain_spread": 0.02,
    }
    top = render_straight_stripes((120, 256), dark_grey=40.0, bright_grey=200.0, **stripes)  # type: ignore[arg-type]
    bottom = render_straight_stripes((240, 256), dark_grey=20.0, bright_grey=60.0, blur_kernel="disk",
                                     **stripes)[120:]  # type: ignore[arg-type]  # fmt: skip
    edges = locate_edges(np.vstack([top, bottom]))
    assert edges.sigma_px is not None and edges.contrast_grey is not None
    assert edges.sigma_px.shape == edges.contrast_grey.shape == (len(edges),)
    assert np.all(np.isfinite(edges.sigma_px)) and np.all(edges.sigma_px > 0)
    errors = edge_errors_px(edges, angle_deg=angle_deg, period_px=PERIOD_PX, phase_px=PHASE_PX)
    bright, dim = edges.line < 110, edges.line > 130  # the stripes' contrast changes at line 120
    assert np.median(edges.contrast_grey[bright]) == pytest.approx(165, abs=10)
    assert np.median(edges.contrast_grey[dim]) == pytest.approx(45, abs=5)
    # Four times less contrast, half the photon noise: σ about twice as large or more.
    assert np.median(edges.sigma_px[dim]) > 2.0 * np.median(edges.sigma_px[bright])
    for half in (bright, dim):
        within = np.mean(np.abs(errors[half]) <= 2.0 * edges.sigma_px[half])
        assert 0.88 <= within <= 1.0, within


@pytest.mark.parametrize(("angle_deg", "axis"), [(0.0, "rows"), (12.0, "rows"), (90.0, "cols"), (-60.0, "cols")])
def test_detect_stripes_finds_direction_and_period(angle_deg: float, axis: str) -> None:
    rng = np.random.default_rng(1)
    image = render_straight_stripes((200, 220), period_px=9.0, angle_deg=angle_deg, phase_px=1.0, rng=rng)
    geometry = detect_stripes(image)
    assert geometry.axis == axis
    # The period along the scan line is the stripe period over the cosine of the angle to the scan normal.
    along = 9.0 / max(abs(np.cos(np.deg2rad(angle_deg))), abs(np.sin(np.deg2rad(angle_deg))))
    assert geometry.period_px == pytest.approx(along, rel=0.02)
    # The gradient angle is the stripe normal, known modulo 180°.
    assert (geometry.angle_deg - angle_deg + 90.0) % 180.0 - 90.0 == pytest.approx(0.0, abs=1.0)
    assert geometry.coherence > 0.9


def test_fixed_geometry_gives_the_same_edges_as_detection() -> None:
    rng = np.random.default_rng(2)
    image = render_straight_stripes((120, 160), period_px=PERIOD_PX, angle_deg=5.0, phase_px=2.0, rng=rng)
    geometry = detect_stripes(image)
    auto = locate_edges(image)
    fixed = locate_edges(image, EdgeSettings(axis=geometry.axis, period_px=geometry.period_px))
    np.testing.assert_array_equal(auto.t_px, fixed.t_px)


def test_a_frames_edges_are_its_own_whatever_frames_come_after_it_or_beside_it() -> None:
    # locate_edges keeps its full-frame working arrays from one frame to the next, one set per thread: what it
    # returns must not be among them, and threads must not share them.
    rng = np.random.default_rng(7)
    frames = []
    for angle_deg, phase_px in ((3.0, 1.0), (-4.0, 2.5), (86.0, 0.5)):
        image = render_straight_stripes((160, 200), period_px=PERIOD_PX, angle_deg=angle_deg, phase_px=phase_px,
                                        rng=rng)  # fmt: skip
        image[60:90, 80:120] = 6  # a dark area, with edges beside it
        frames.append(image)

    def arrays(edges: FrameEdges) -> dict[str, np.ndarray]:
        return {f.name: getattr(edges, f.name) for f in dataclasses.fields(edges)
                if isinstance(getattr(edges, f.name), np.ndarray)}  # fmt: skip

    first = [arrays(locate_edges(f)) for f in frames]
    kept = [{name: a.copy() for name, a in edges.items()} for edges in first]
    with ThreadPoolExecutor(max_workers=3) as pool:
        again = [arrays(e) for e in pool.map(locate_edges, frames * 4)]
    assert len(first[0]["line"]) > 500 and first[2]["line"].size > 500
    for k, edges in enumerate(again):
        for name, a in edges.items():
            np.testing.assert_array_equal(a, kept[k % 3][name], err_msg=name)
    for edges, copies in zip(first, kept, strict=True):
        for name, a in edges.items():
            np.testing.assert_array_equal(a, copies[name], err_msg=name)


def test_what_a_thread_keeps_between_frames_is_bounded_and_changes_no_edge(monkeypatch: pytest.MonkeyPatch) -> None:
    # Beyond SCRATCH_KEPT_MAX_BYTES the largest working arrays are let go once a frame is done (a 4096² frame's
    # would be about 1 GB a thread): here a bound of 1 MiB against the ~13 MiB a 480² frame uses.
    image = render_straight_stripes((480, 480), period_px=PERIOD_PX, angle_deg=3.0, phase_px=0.3,
                                    rng=np.random.default_rng(8))  # fmt: skip
    unbounded = locate_edges(image)
    assert sum(a.nbytes for a in fringes._SCRATCH.arrays.values()) > 8 * 2**20
    monkeypatch.setattr(fringes, "SCRATCH_KEPT_MAX_BYTES", 2**20)
    for _ in range(2):  # from the unbounded set, then from what the bound kept
        bounded = locate_edges(image)
        assert sum(a.nbytes for a in fringes._SCRATCH.arrays.values()) <= 2**20
        np.testing.assert_array_equal(bounded.t_px, unbounded.t_px)
        np.testing.assert_array_equal(bounded.sigma_px, unbounded.sigma_px)
        np.testing.assert_array_equal(bounded.unusable, unbounded.unusable)


def test_dark_areas_give_no_edges_near_them() -> None:
    rng = np.random.default_rng(3)
    image = render_straight_stripes((200, 200), period_px=PERIOD_PX, angle_deg=0.0, phase_px=0.0, rng=rng)
    rows, cols = np.mgrid[0:200, 0:200]
    outside = np.hypot(cols - 100, rows - 100) > 80
    hole = np.hypot(cols - 100, rows - 100) < 20
    image[outside | hole] = (8 + rng.normal(0, 2, image.shape)).clip(0, 255).astype(np.uint8)[outside | hole]
    edges = locate_edges(image)
    # Along its scan line, no edge is within ~half a period of a dark pixel: there the mid-level would be set by
    # the dark area (the 1.5 px slack is the sub-pixel position within the straddling pair).
    reach = int(0.5 * PERIOD_PX - 1.5)
    columns = np.round(edges.t_px).astype(int)[:, None] + np.arange(-reach, reach + 1)[None, :]
    near = (outside | hole)[edges.line[:, None], np.clip(columns, 0, 199)]
    # Where the hole is less than a period across (its top and bottom rows) it is not "dark" at this scale, and
    # an edge may come within the reach; such an edge is still a true one.
    r_px = np.hypot(edges.q_px()[:, 0] - 100, edges.q_px()[:, 1] - 100)
    assert not np.any(near[r_px > 50])
    assert np.count_nonzero(near.any(axis=1)) < 10
    errors = edge_errors_px(edges, angle_deg=0.0, period_px=PERIOD_PX, phase_px=0.0)
    assert np.max(np.abs(errors)) < 0.15
    assert len(edges) > 2000
    errors = edge_errors_px(edges, angle_deg=0.0, period_px=PERIOD_PX, phase_px=0.0)
    assert np.max(np.abs(errors)) < 0.1


def test_saturated_stripes_are_rejected() -> None:
    rng = np.random.default_rng(4)
    image = render_straight_stripes(
        (100, 200),
        period_px=PERIOD_PX,
        angle_deg=0.0,
        phase_px=0.0,
        rng=rng,
        bright_grey=300.0,
        uneven_illumination=False,
    )
    image[:, :100] = render_straight_stripes((100, 100), period_px=PERIOD_PX, angle_deg=0.0, phase_px=0.0, rng=rng)
    edges = locate_edges(image)
    assert edges.saturated_fraction > 0.15
    # The right half clips at 255: none of its edges may come through.
    assert np.all(edges.t_px < 100 + PERIOD_PX)
    assert len(edges) > 0


def test_uniform_or_noise_frames_have_no_stripes() -> None:
    rng = np.random.default_rng(5)
    with pytest.raises(NoStripesError, match="no stripes found"):
        locate_edges(np.full((64, 64), 128, np.uint8))
    with pytest.raises(NoStripesError, match="no stripes found"):
        locate_edges(rng.normal(128, 20, (64, 64)).clip(0, 255).astype(np.uint8))


def test_malformed_images_and_settings_are_value_errors() -> None:
    with pytest.raises(ValueError, match=r"expected a 2-D grey image of shape \(H, W\)"):
        locate_edges(np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(ValueError, match="axis: expected one of"):
        EdgeSettings(axis="diagonal")
    with pytest.raises(ValueError, match="period_px"):
        EdgeSettings(period_px=1.0)


def test_sixteen_bit_frames_give_the_edges_of_eight_bit_ones() -> None:
    rng = np.random.default_rng(6)
    image = render_straight_stripes((80, 120), period_px=PERIOD_PX, angle_deg=3.0, phase_px=1.0, rng=rng)
    settings = EdgeSettings(axis="rows", period_px=PERIOD_PX)
    eight = locate_edges(image, settings)
    sixteen = locate_edges(image.astype(np.uint16) * 257, settings)
    np.testing.assert_allclose(sixteen.t_px, eight.t_px, atol=1e-4)


def test_a_curve_broken_by_one_lost_crossing_is_linked_across_it_and_smoothed_by_its_lines() -> None:
    # Two edges (rising at t = 10 + 0.3 s, falling at 40 + 0.3 s) on lines 0..40; the rising one lost on line 20.
    lines = np.arange(41)
    rows = [(s, 10.0 + 0.3 * s, 1) for s in lines if s != 20] + [(s, 40.0 + 0.3 * s, -1) for s in lines]
    rows.sort()
    line = np.array([r[0] for r in rows])
    t = np.array([r[1] for r in rows])
    polarity = np.array([r[2] for r in rows], np.int8)
    chain = _link_chains(line, t, polarity, n_samples=100, max_step_px=1.5, across_gaps=True)
    rising = polarity == 1
    assert len(np.unique(chain[rising])) == 1 and len(np.unique(chain[~rising])) == 1
    assert len(np.unique(_link_chains(line, t, polarity, n_samples=100, max_step_px=1.5)[rising])) == 2  # the default
    # A straight edge stays straight through the skipped line: each point is fitted at its own line offset (taken
    # as consecutive, the points would show a step of 0.3 px at the gap).
    smoothed, _ = _smooth_along_chains(line, t, np.unique(chain, return_inverse=True)[1], sigma_lines=3.0)
    np.testing.assert_allclose(smoothed, t, atol=1e-9)
    # Ends that disagree are not joined: beyond two steps apart, or of the other polarity.
    far = t + np.where(rising & (line > 20), 3.5, 0.0)
    chain = _link_chains(line, far, polarity, n_samples=100, max_step_px=1.5, across_gaps=True)
    assert len(np.unique(chain[rising])) == 2
    flipped = polarity.copy()
    flipped[rising & (line > 20)] = -1
    chain = _link_chains(line, t, flipped, n_samples=100, max_step_px=1.5, across_gaps=True)
    assert len(np.unique(chain[rising & (line < 20)])) == 1
    assert not np.any(np.isin(chain[rising & (line > 20)], chain[rising & (line < 20)]))
