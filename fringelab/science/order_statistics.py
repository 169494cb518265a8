"""Medians and percentiles equal to numpy's, from one selection: for the per-frame levels of the edge locator and
the σ checks, where np.median and np.percentile cost 0.2–1 ms on a frame (they partition around two or three ranks
at once, which numpy does several times slower than around one).

Belongs here: `median` and `percentile` of 1-D float data, the same values as np.median and np.percentile (the
default "linear" method) for float32 and float64: the value of the lower wanted rank (float32: a radix selection on
the bits, `_ranks_float32`; float64: np.partition around it, from RADIX_MIN_VALUES values on a radix selection too,
`_radix_ranks`), the next rank's, and numpy's own interpolation arithmetic. Not here: weighted quantiles, other
interpolation methods, integer data.
"""

from __future__ import annotations

import math

import numba
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


# From this many float64 values on, the ranks are selected by their bits (`_radix_ranks`): np.partition takes
# about 10 ns a value (0.24 ms for a 512 x 480 frame's 24 000 σ checks), the radix passes 2-3 ns.
RADIX_MIN_VALUES = 4096


def _ranks(flat: np.ndarray, low: int, high: int) -> tuple[bool, float, float]:
    """The values of ranks low ≤ high ≤ low + 1 (0 = smallest) of flat (N,), and False instead where any value is
    NaN (np.partition puts NaN last, so one lies at or after rank low, and min passes it on)."""
    if flat.dtype == np.float32:
        # np.partition of float32 took 89 µs for a 512 × 480 frame's 15 360 samples, the selection 15 µs.
        found, key_low, key_high = _ranks_float32(flat.view(np.uint32), low, high)
        if not found:
            return False, math.nan, math.nan
        a, b = _float32_from_keys(np.array([key_low, key_high], np.uint32))
        return True, float(a), float(b)
    if flat.dtype == np.float64 and flat.size >= RADIX_MIN_VALUES:
        return _radix_ranks(np.ascontiguousarray(flat), low, high)
    part = np.partition(flat, low)
    if np.isnan(part[low:].min()):
        return False, math.nan, math.nan
    return True, float(part[low]), float(part[high] if high == low else part[high:].min())


def _float32_from_keys(keys: np.ndarray) -> np.ndarray:
    """The float32 values of `_ranks_float32`'s ordered keys (N,) uint32."""
    negative = keys < np.uint32(0x80000000)
    return np.where(negative, ~keys, keys ^ np.uint32(0x80000000)).view(np.float32)


@numba.njit(cache=True, nogil=True)
def _ranks_float32(bits: np.ndarray, low: int, high: int) -> tuple[bool, np.uint32, np.uint32]:
    """The ranks low ≤ high ≤ low + 1 of float32 values given as their bits (N,) uint32, as ordered keys (the bits
    with the sign bit flipped, all bits of negative values flipped: unsigned order is the values' order, −0 just below
    +0); False where any value is NaN. A radix selection, 12 + 12 + 8 bits: each digit's histogram over the values
    whose higher digits are the wanted rank's, O(N)."""
    n = len(bits)
    keys = np.empty(n, np.uint32)
    magnitude_max = np.uint32(0)
    for i in range(n):  # without branches, so that it vectorises
        b = bits[i]
        magnitude_max = max(magnitude_max, b & np.uint32(0x7FFFFFFF))
        keys[i] = b ^ ((b >> np.uint32(31)) * np.uint32(0x7FFFFFFF) | np.uint32(0x80000000))
    if magnitude_max > np.uint32(0x7F800000):
        return False, np.uint32(0), np.uint32(0)
    histogram = np.zeros(4096, np.int64)
    for i in range(n):
        histogram[keys[i] >> np.uint32(20)] += 1
    rank = low
    candidates = keys
    prefix = np.uint32(0)
    # (shift, digit mask, histogram length) of the three digits, high to low
    for level in range(3):
        if level == 0:
            shift, mask, size = 20, 0xFFF, 4096
        elif level == 1:
            shift, mask, size = 8, 0xFFF, 4096
        else:
            shift, mask, size = 0, 0xFF, 256
        if level > 0:
            histogram[:size] = 0
            for key in candidates:
                histogram[(key >> np.uint32(shift)) & np.uint32(mask)] += 1
        digit = 0
        while rank >= histogram[digit]:
            rank -= histogram[digit]
            digit += 1
        prefix |= np.uint32(digit) << np.uint32(shift)
        if level < 2:
            kept = np.empty(histogram[digit], np.uint32)
            m = 0
            for key in candidates:
                if (key >> np.uint32(shift)) & np.uint32(mask) == digit:
                    kept[m] = key
                    m += 1
            candidates = kept
        if high > low and rank + 1 == histogram[digit]:
            # rank low is the greatest of this digit's values, rank high the least key above them
            above = np.uint32(0xFFFFFFFF)
            top = prefix | np.uint32((1 << shift) - 1)
            for key in keys:
                if key > top and key < above:
                    above = key
            return True, prefix if level == 2 else candidates.max(), above
    return True, prefix, prefix


_SIGN = np.uint64(1) << np.uint64(63)
# Levels of `_radix_ranks`: the key's bits from the top, 12 at a time (4096 counts), the last 4.
_RADIX_SHIFTS = np.array([52, 40, 28, 16, 4, 0], np.uint64)
_RADIX_BINS = 4096


@numba.njit(cache=True, nogil=True, inline="always")
def _key(bits: np.uint64) -> np.uint64:
    """An unsigned key in the order of the float64 whose bits these are (−0 just below +0)."""
    if bits & _SIGN:
        return ~bits
    return bits | _SIGN


@numba.njit(cache=True, nogil=True)
def _radix_ranks(x: np.ndarray, low: int, high: int) -> tuple[bool, float, float]:
    """`_ranks` of float64 x (N,) by most-significant-digit radix selection over the values' keys: each level
    counts the candidates' next bits, keeps those in the digit where rank `low` falls (indices, compacted in place
    after the first level) and the least key of a higher digit (rank `high`'s value when it lies beyond rank low's
    equal values). The values are the data's own, so they are numpy's (which of −0 and +0 aside)."""
    n = len(x)
    bits = x.view(np.uint64)
    # Four interleaved counts: the keys crowd into a few digits, and one count's increments would wait on each other.
    counts = np.zeros((4, _RADIX_BINS), np.int64)
    any_nan = False
    for i in range(n):
        any_nan |= x[i] != x[i]
        counts[i & 3, _key(bits[i]) >> _RADIX_SHIFTS[0]] += 1
    if any_nan:
        return False, np.nan, np.nan
    for d in range(_RADIX_BINS):
        counts[0, d] += counts[1, d] + counts[2, d] + counts[3, d]
    below = 0
    digit = 0
    while below + counts[0, digit] <= low:
        below += counts[0, digit]
        digit += 1
    size = counts[0, digit]
    selected = np.uint64(digit)  # compared with the keys' digits unsigned (mixed with a signed one: as floats)
    candidates = np.empty(size + 1, np.int64)  # one slot beyond: the branch-free compaction writes every index
    no_key = ~np.uint64(0)
    successor = no_key  # the least key above the selected digits
    m = 0
    for i in range(n):
        key = _key(bits[i])
        d = key >> _RADIX_SHIFTS[0]
        candidates[m] = i
        m += d == selected
        successor = min(successor, key if d > selected else no_key)
    mask = np.uint64(_RADIX_BINS - 1)
    for level in range(1, len(_RADIX_SHIFTS)):
        shift = _RADIX_SHIFTS[level]
        counts[0, :] = 0
        for j in range(size):
            counts[0, (_key(bits[candidates[j]]) >> shift) & mask] += 1
        digit = 0
        while below + counts[0, digit] <= low:
            below += counts[0, digit]
            digit += 1
        selected = np.uint64(digit)
        m = 0
        for j in range(size):
            i = candidates[j]
            key = _key(bits[i])
            d = (key >> shift) & mask
            candidates[m] = i
            m += d == selected
            successor = min(successor, key if d > selected else no_key)
        size = m
    # The candidates left are equal values (every bit of their keys selected): ranks below … below + size − 1.
    a = x[candidates[0]]
    if high < below + size:
        return True, a, a
    found = np.empty(1, np.uint64)
    found[0] = successor ^ _SIGN if successor & _SIGN else ~successor
    return True, a, found.view(np.float64)[0]
