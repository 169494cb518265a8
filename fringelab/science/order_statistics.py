"""Medians and percentiles equal to numpy's, from one partition: for the per-frame levels of the edge locator and
the σ checks, where np.median and np.percentile cost 0.2–1 ms on a frame (they partition around two or three ranks
at once, which numpy does several times slower than around one).

Belongs here: `median` and `percentile` of 1-D float data, the same values as np.median and np.percentile (the
default "linear" method) for float32 and float64: np.partition around the lower wanted rank, the next rank the
least value above it, and numpy's own interpolation arithmetic. Not here: weighted quantiles, other interpolation
methods, integer data.
"""

from __future__ import annotations

import math

import numpy as np


def median(values: np.ndarray) -> float:
    """np.median of values (any shape, float32 or float64, at least one), NaN if any is NaN. The same value (which
    of −0 and +0 it gives where the middle falls among zeros of both signs aside)."""
    flat = _flat(values)
    n = flat.size
    found, a, b = _ranks(flat, (n - 1) // 2, n // 2)
    if not found:
        return float("nan")
    low, high = flat.dtype.type(a), flat.dtype.type(b)
    # np.median's mean of the two middle values: their sum in the data's precision, halved.
    return float(low) if n % 2 else float((low + high) / 2)


def percentile(values: np.ndarray, q: float) -> float:
    """np.percentile(values, q) (method "linear"; values any shape, float32 or float64, at least one; 0 ≤ q ≤ 100),
    NaN if any is NaN: the same arithmetic on the two values it interpolates between."""
    flat = _flat(values)
    n = flat.size
    virtual = (n - 1) * (q / 100)
    previous = float(math.floor(virtual))
    if virtual >= n - 1:
        lo = hi = n - 1
        previous = -1.0  # as numpy, whose γ is then measured from index −1
    elif virtual < 0:
        lo = hi = 0
        previous = 0.0
    else:
        lo, hi = int(previous), int(previous) + 1
    found, a, b = _ranks(flat, lo, hi)
    if not found:
        return float("nan")
    gamma = virtual - previous
    below, above = flat.dtype.type(a), flat.dtype.type(b)
    # numpy's _lerp with a Python-float weight: the difference and the products in the data's precision.
    difference = above - below
    return float(above - difference * (1 - gamma) if gamma >= 0.5 else below + difference * gamma)


def _flat(values: np.ndarray) -> np.ndarray:
    flat = np.ravel(values)  # a view where it can be: np.partition copies
    if flat.dtype not in (np.float32, np.float64):
        raise ValueError(f"values: expected float32 or float64, got {flat.dtype}")
    if flat.size == 0:
        raise ValueError("values: expected at least one value, got none")
    return flat


def _ranks(flat: np.ndarray, low: int, high: int) -> tuple[bool, float, float]:
    """The values of ranks low ≤ high ≤ low + 1 (0 = smallest) of flat (N,), and False instead where any value is
    NaN (np.partition puts NaN last, so one lies at or after rank low, and min passes it on)."""
    part = np.partition(flat, low)
    if np.isnan(part[low:].min()):
        return False, math.nan, math.nan
    return True, float(part[low]), float(part[high] if high == low else part[high:].min())
