"""Stripe edges beside a dark area and stripes wider than the detectable periods (docs/method.md §5, issue 29).

A dark area is dark; the lit edge beside it is a stripe edge when its own two sides are stripes. With stripes wider
than MAX_PERIOD_PX (a Gray code's bit frames on a dim scene, whose dark stripes merge with the background): where
the area is black (darker than the dark stripes: a hole, the clamp, a crack) its rim may cut a stripe anywhere and
the transitions within half a period of it are rejected, as before; where it is as dark as the dark stripes, the edge
beside it is kept unless the area cut its stripe short. The same at fringe periods (up to MAX_PERIOD_PX), where
the kept ones are flagged (`FrameEdges.beside_dark`) and carry no fringe order (tests/science/test_fringe_order.py).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import special

from fringelab.science.fringes import (
    MAX_FIXED_PERIOD_PX,
    EdgeSettings,
    _dilate_along_lines,
    locate_edges,
)

PERIOD_PX = 240.0
BRIGHT_GREY, DARK_GREY = 150.0, 30.0
BLUR_PX = 1.5
N_LINES, N_SAMPLES = 60, 2000
SETTINGS = EdgeSettings(axis="rows", period_px=PERIOD_PX, mid_level="envelopes")


def stripes_beside(area_from_px: float, area_grey: float, *, seed: int, period_px: float = PERIOD_PX) -> np.ndarray:
    """Vertical stripes (bright from t = 0 to P/2, dark from P/2 to P, …; P = period_px), blurred, with an area of
    `area_grey` from t = area_from_px on, its rim blurred alike, and σ = 1 grey of noise."""
    t = np.arange(N_SAMPLES, dtype=np.float64)
    # A blurred square wave: the sum of the blurred steps at every edge (k · P / 2).
    pattern = np.zeros(N_SAMPLES)
    for k in range(-2, int(2 * N_SAMPLES / period_px) + 3):
        pattern += (-1) ** k * special.ndtr((t - 0.5 * k * period_px) / BLUR_PX)
    grey = DARK_GREY + (BRIGHT_GREY - DARK_GREY) * np.clip(pattern, 0.0, 1.0)
    lit = special.ndtr((area_from_px - t) / BLUR_PX)
    line = lit * grey + (1.0 - lit) * area_grey
    rng = np.random.default_rng(seed)
    return np.clip(line + rng.normal(0.0, 1.0, (N_LINES, N_SAMPLES)), 0, 255).astype(np.uint8)


def found_near(edges, t_px: float, *, within_px: float) -> float:
    """Share of the scan lines (away from the first and last 5) with an edge within `within_px` of t_px."""
    lines = np.arange(5, N_LINES - 5)
    near = np.abs(edges.t_px - t_px) <= within_px
    return float(np.isin(lines, edges.line[near]).mean())


def test_the_lit_edge_beside_a_background_as_dark_as_the_dark_stripes_is_kept() -> None:
    # The dark stripe from 1200 to 1320 runs into the background: the edge at 1200 has a whole bright stripe on
    # one side and a dark stripe on the other (before: rejected, as every transition within half a period).
    edges = locate_edges(stripes_beside(1230.0, DARK_GREY, seed=1), SETTINGS)
    assert found_near(edges, 1200.0, within_px=0.1) > 0.95  # 0.1 px: 10 × the edge noise here
    assert not np.any(edges.t_px > 1210.0)  # nothing inside the background


def test_beside_a_black_area_the_transitions_its_rim_may_have_cut_are_rejected() -> None:
    # The same geometry with a black background (a hole): its rim may cut a stripe anywhere, so the transitions
    # within half a period of it are rejected, as they always were.
    edges = locate_edges(stripes_beside(1230.0, 0.0, seed=2), SETTINGS)
    assert not np.any(edges.t_px > 1230.0 - 0.5 * PERIOD_PX)
    assert found_near(edges, 1080.0, within_px=0.1) > 0.95  # the edges before it are kept


def test_a_stripe_cut_short_by_a_dark_area_that_is_not_black_gives_no_edge_at_the_cut() -> None:
    # The area (as dark as the dark stripes) begins a sixth of the way into the bright stripe from 960 to 1080: the
    # transition at its rim (980) is no stripe edge, and the stripe's own first edge (960) is.
    edges = locate_edges(stripes_beside(980.0, DARK_GREY, seed=3), SETTINGS)
    assert found_near(edges, 980.0, within_px=5.0) == 0.0
    assert found_near(edges, 960.0, within_px=0.1) > 0.95


@pytest.mark.parametrize("period_px", [12.0, 40.0])
def test_at_fringe_periods_the_lit_edge_beside_a_background_as_dark_as_the_dark_stripes_is_kept_and_flagged(
    period_px: float,
) -> None:
    # The dark stripe from m P to (m + ½) P runs into the background (from (m + ¼) P on, halfway along the lines):
    # the edge at m P is kept, flagged as beside the dark area; the edges a few periods before it are not flagged.
    settings = EdgeSettings(axis="rows", period_px=period_px)
    last = (N_SAMPLES // 2 // period_px) * period_px
    edges = locate_edges(stripes_beside(last + 0.25 * period_px, DARK_GREY, seed=5, period_px=period_px), settings)
    assert edges.beside_dark is not None
    assert found_near(edges, last, within_px=0.1) > 0.95  # 0.1 px: 10 × the edge noise here
    assert not np.any(edges.t_px > last + 0.1 * period_px)  # nothing inside the background
    assert np.all(edges.beside_dark[np.abs(edges.t_px - last) < 0.1 * period_px])
    assert not np.any(edges.beside_dark[edges.t_px < last - 2.5 * period_px])
    # Beside a black area (a hole) the transitions within a period of it are rejected, as before.
    edges = locate_edges(stripes_beside(last + 0.25 * period_px, 0.0, seed=6, period_px=period_px), settings)
    assert not np.any(edges.t_px > last - 0.25 * period_px)
    assert found_near(edges, last - period_px, within_px=0.1) > 0.95


def test_fixed_periods_far_beyond_the_detectable_ones_are_accepted_up_to_the_limit() -> None:
    assert EdgeSettings(axis="rows", period_px=MAX_FIXED_PERIOD_PX).period_px == MAX_FIXED_PERIOD_PX
    with pytest.raises(ValueError, match="period_px: expected 3.0..8192.0 px"):
        EdgeSettings(axis="rows", period_px=MAX_FIXED_PERIOD_PX + 1)


def test_stripes_of_a_thousand_pixels_are_located_from_their_own_two_sides() -> None:
    # A Gray code's wide bit stripes (period 1000 px) on a dim scene whose two halves are lit differently (a 3:1
    # step in the light across the middle of a bright stripe): each edge sits at its own sides' mid-level.
    t = np.arange(3000, dtype=np.float64)
    step = special.ndtr((np.abs(((t + 250.0) % 1000.0) - 500.0) - 250.0) / 1.5)  # bright where |…| < 250
    light = np.where(t < 1250.0, 90.0, 30.0)
    grey = 3.0 + light * (1.0 - step)
    rng = np.random.default_rng(4)
    image = np.clip(grey + rng.normal(0.0, 1.0, (60, 3000)), 0, 255).astype(np.uint8)
    edges = locate_edges(image, EdgeSettings(axis="rows", period_px=1000.0, mid_level="envelopes"))
    for edge_px in (500.0, 1000.0, 1500.0, 2000.0, 2500.0):
        near = np.abs(edges.t_px - edge_px) < 2.0
        assert np.count_nonzero(near) > 40, edge_px  # of the 60 − 2 × 3 lines the smoothing leaves
        assert abs(float(np.median(edges.t_px[near])) - edge_px) < 0.05, edge_px


@pytest.mark.parametrize("width", [3, 161, 163, 999, 5001])
def test_the_running_maximum_along_lines_equals_opencvs_dilation(width: int) -> None:
    rng = np.random.default_rng(width)
    a = rng.random((7, 1200)).astype(np.float32)
    expected = cv2.dilate(a, np.ones((3, width), np.uint8))
    np.testing.assert_array_equal(_dilate_along_lines(a, width, lines=3), expected)
