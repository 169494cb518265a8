"""order_statistics.median and .percentile give numpy's values exactly (they replace np.median/np.percentile in the
per-frame levels of the edge locator and the σ checks, whose outputs must not change)."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.science.order_statistics import RADIX_MIN_VALUES, median, percentile


def _same(a: float, b: float) -> bool:
    return (np.isnan(a) and np.isnan(b)) or a == b


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_equal_to_numpy(dtype: type) -> None:
    rng = np.random.default_rng(29)
    for trial in range(300):
        n = int(rng.integers(1, 2000))
        kind = trial % 5
        if kind == 0:
            x = rng.chisquare(1, n) * 100.0
        elif kind == 1:
            x = rng.standard_normal(n)
        elif kind == 2:
            x = rng.integers(-3, 3, n).astype(float)  # ties
        elif kind == 3:
            x = (rng.random(n) * 255.0).round(3)
        else:
            x = rng.standard_normal(n) * 10.0 ** rng.integers(-30, 30, n)  # many binades
        if trial % 37 == 0:
            x[rng.integers(0, n)] = np.nan
        x = x.astype(dtype)
        assert _same(median(x), float(np.median(x)))
        for q in (0, 1, 10, 37.5, 50, 95, 100):
            assert _same(percentile(x, q), float(np.percentile(x, q)))


def test_strided_and_2d() -> None:
    image = np.random.default_rng(3).random((97, 131)).astype(np.float32) * 255.0
    view = image[::4, ::4]
    assert percentile(view, 95) == float(np.percentile(view, 95))
    assert median(view) == float(np.median(view))


def test_refuses_integers_and_empty() -> None:
    with pytest.raises(ValueError, match="float32 or float64"):
        median(np.arange(5))
    with pytest.raises(ValueError, match="at least one"):
        percentile(np.zeros(0), 50)


def test_float32_selection_across_its_digits() -> None:
    # The float32 radix selection's paths: the wanted rank the last of its 12-bit, 12-bit or 8-bit digit's values
    # (the next rank then the least value above), ties across digits, both signs, ±0 and ±inf.
    rng = np.random.default_rng(41)
    for trial in range(200):
        n = int(rng.integers(2, 30000))
        x = rng.standard_normal(n).astype(np.float32) * np.float32(10.0 ** rng.integers(-3, 4))
        if trial % 3 == 0:
            x = np.round(x).astype(np.float32)  # many ties
        if trial % 7 == 0:
            x[rng.integers(0, n, 3)] = np.array([np.inf, -np.inf, 0.0], np.float32)
        for q in (0, 1, 5, 10, 50, 95, 99, 100):
            assert _same(percentile(x, q), float(np.percentile(x, q)))
        assert _same(median(x), float(np.median(x)))


@pytest.mark.parametrize("kind", ["chi-square", "ties", "binades", "infinities", "nan"])
def test_radix_ranks_equal_to_numpy(kind: str) -> None:
    """From RADIX_MIN_VALUES float64 values on, the ranks are selected by their bits: the same values as numpy's."""
    rng = np.random.default_rng(31)
    for _ in range(20):
        n = int(rng.integers(RADIX_MIN_VALUES, 3 * RADIX_MIN_VALUES))
        if kind == "chi-square":
            x = rng.chisquare(1, n)
        elif kind == "ties":
            x = rng.integers(-3, 3, n).astype(float)
        elif kind == "binades":
            x = rng.standard_normal(n) * 10.0 ** rng.integers(-300, 300, n)
        elif kind == "infinities":
            x = np.where(rng.random(n) < 0.3, np.inf, rng.standard_normal(n))
            x[rng.random(n) < 0.2] = -np.inf
        else:
            x = rng.standard_normal(n)
            x[rng.integers(0, n)] = np.nan
        assert _same(median(x), float(np.median(x)))
        assert _same(median(x[:-1]), float(np.median(x[:-1])))
        for q in (0, 0.1, 37.5, 99.9, 100):
            assert _same(percentile(x, q), float(np.percentile(x, q)))
