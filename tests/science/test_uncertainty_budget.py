"""The frame's check of σ across edges and the budget's shares (`science.uncertainty`), on synthetic heights."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.science.uncertainty import (
    MIN_CROSS_EDGE_CHECKS,
    budget_shares,
    cross_edge_scale,
    fit_leverage_ratio,
    leverage_polynomials,
    local_excess_variance,
)


def dome(n_edges: int = 40, n_lines: int = 300) -> np.ndarray:
    """Heights (K, S) of a smooth dome sampled every 5 mm across edges: up to 60 mm, curving like the test's."""
    x = np.linspace(-100.0, 100.0, n_edges)[:, None]
    y = np.linspace(-150.0, 150.0, n_lines)[None, :]
    return 60.0 * np.exp(-(x**2 + y**2) / (2 * 90.0**2))


@pytest.mark.parametrize(("true_factor", "expected"), [(1.0, 1.0), (0.5, 1.0), (2.0, 2.0), (3.0, 3.0)])
def test_the_scale_is_how_much_larger_the_errors_are_than_their_sigma(true_factor: float, expected: float) -> None:
    rng = np.random.default_rng(1)
    sigma = rng.uniform(0.02, 0.08, dome().shape)  # σ that varies from point to point, as each edge's does
    z = dome() + true_factor * sigma * rng.standard_normal(sigma.shape)
    # 36 · 296 fourth differences: the median's relative error is ~1 %; the dome leaves < 0.01 σ in them.
    assert cross_edge_scale(z, sigma) == pytest.approx(expected, rel=0.04)


def test_an_error_that_stays_along_an_edge_is_found_and_a_step_at_a_hole_is_not_counted() -> None:
    rng = np.random.default_rng(2)
    sigma = np.full(dome().shape, 0.03)
    bias = 0.06 * rng.standard_normal((sigma.shape[0], 1))  # each edge off by its own constant (pixel locking)
    z = dome() + sigma * rng.standard_normal(sigma.shape) + bias
    z[18:22, 100:200] += 5.0  # a few big steps (the hole's rim): the median does not follow them
    expected = np.sqrt(1.0 + (0.06 / 0.03) ** 2)
    assert cross_edge_scale(z, sigma) == pytest.approx(expected, rel=0.25)


def test_too_few_checks_or_missing_points_leave_sigma_as_it_is() -> None:
    sigma = np.full((6, 10), 0.03)
    z = np.random.default_rng(3).normal(0.0, 1.0, sigma.shape)  # 20 checks, each far off: not enough to judge
    assert MIN_CROSS_EDGE_CHECKS > 2 * 10 and cross_edge_scale(z, sigma) == 1.0
    assert cross_edge_scale(np.full((40, 300), np.nan), np.full((40, 300), 0.03)) == 1.0
    assert cross_edge_scale(np.zeros((4, 300)), np.full((4, 300), 0.03)) == 1.0


def fourth_difference_checks(z: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, ...]:
    """The checks of (K, S) heights as `topography` makes them: middle edge, line, d² and Σc²σ² (M,)."""
    c = np.array([1.0, -4.0, 6.0, -4.0, 1.0])
    n = z.shape[0] - 4
    d = sum(ci * z[i : i + n] for i, ci in enumerate(c))
    predicted = sum(ci * ci * sigma[i : i + n] ** 2 for i, ci in enumerate(c))
    k, line = np.meshgrid(np.arange(2, n + 2), np.arange(z.shape[1]), indexing="ij")
    return k.ravel(), line.ravel(), (d * d).ravel(), predicted.ravel()


def test_the_local_check_finds_edge_biases_where_they_are_and_adds_nothing_where_sigma_is_right() -> None:
    rng = np.random.default_rng(4)
    sigma = rng.uniform(0.02, 0.06, dome().shape)
    z = dome() + sigma * rng.standard_normal(sigma.shape)
    # Near the "punch" (edges 15–24, lines 100–199) each edge is off by its own constant of σ 0.08 mm.
    z[15:25, 100:200] += 0.08 * rng.standard_normal((10, 1))
    k, line = np.meshgrid(np.arange(z.shape[0]), np.arange(z.shape[1]), indexing="ij")
    tau2 = local_excess_variance(*fourth_difference_checks(z, sigma), z.shape, k=k.ravel(), line=line.ravel())
    tau2 = tau2.reshape(z.shape)
    inside, outside = tau2[17:23, 115:185], np.concatenate([tau2[:10].ravel(), tau2[30:].ravel()])
    # 10 edge constants: their sample variance spreads by ±45 %; the window's ~125 checks by ±15 % more.
    assert 0.4 * 0.08**2 < float(np.median(inside)) < 2.0 * 0.08**2
    # Where σ is right the excess averages 0: clipped at 0 it stays a few % of σ² (0.04² mm²).
    assert float(np.mean(outside)) < 0.1 * 0.04**2


def test_the_shares_sum_to_one() -> None:
    shares = budget_shares(np.full(10, 0.05), np.full(10, 0.02), 1.25, np.full(10, 0.01**2))
    assert sum(shares.values()) == pytest.approx(1.0)
    assert shares["across edges"] == pytest.approx(1 - 1 / 1.25**2)
    assert shares["table"] == pytest.approx((0.02 * 1.25) ** 2 / 0.05**2)
    assert shares["local"] == pytest.approx((0.01 * 1.25) ** 2 / 0.05**2)
    assert budget_shares(np.full(10, 0.05), np.full(10, 0.02), 1.0)["local"] == 0.0


@pytest.mark.parametrize("n_heights", [6, 17, 41])
def test_the_table_fit_leverage_averages_to_one_over_its_heights_and_grows_toward_the_ends(n_heights: int) -> None:
    polynomials = leverage_polynomials(3, 41)
    heights = np.linspace(-1.0, 1.0, n_heights)
    ratios = np.array([fit_leverage_ratio(float(tau), polynomials, n_heights) for tau in heights])
    # Σ_j h(τ_j) = trace of the hat matrix = D + 1 exactly, so the mean of h/h̄ over the heights is 1.
    assert np.mean(ratios**2) == pytest.approx(1.0, rel=1e-9)
    # A cubic's prediction is surest near the middle, least sure at the ends (1.2× for 6 heights, 1.63× for 17).
    assert ratios[0] == pytest.approx(ratios[-1]) == pytest.approx(ratios.max()) and ratios[0] > 1.15
    assert fit_leverage_ratio(0.0, polynomials, n_heights) < 0.8
    assert fit_leverage_ratio(0.3, polynomials, 4) == 1.0  # too few heights for the cubic: the average, as before
