"""The one shape check of the measurement package: turn an array argument into float64 of the expected shape.

Every public function that takes arrays calls `checked_array` once at its boundary, so errors read the same
everywhere ("q_px: expected shape (N, 2), got (3,)"). Nothing else belongs here.
"""

from __future__ import annotations

import numpy as np


def checked_array(values: object, *, shape: tuple[int | None, ...], name: str) -> np.ndarray:
    """Return `values` as a float64 array of `shape`, where None stands for any length (written N).

    Raises ValueError naming the argument, the expected shape and the shape that came. Finiteness is left to
    the caller: NaN is a legal "no data" marker in several places.

    >>> checked_array([[1, 2]], shape=(None, 2), name="q_px").shape
    (1, 2)
    """
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != len(shape) or any(
        want is not None and want != got for want, got in zip(shape, array.shape, strict=True)
    ):
        dims = ", ".join("N" if want is None else str(want) for want in shape)
        expected = f"({dims},)" if len(shape) == 1 else f"({dims})"
        raise ValueError(f"{name}: expected shape {expected}, got {array.shape}")
    return array
