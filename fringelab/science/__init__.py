"""The measurement science of fringelab: camera and projector calibration, fringe edges, topography.

Pure: arrays and frozen dataclasses in and out, units and frames in names (docs/method.md). Nothing here imports
web, queue or database code, configures logging or reads the environment; file I/O lives only in the
file formats (`fringelab.formats`).
"""

import re


class Cancelled(Exception):
    """The caller asked to stop (its `should_cancel()` returned True, or its job ended): not a failure. The one
    cancellation exception of fringelab, from the science up to the worker's job runner."""


class MeasurementError(Exception):
    """A measurement failed for a reason the user must act on (board not found, Z out of range, ...)."""


def natural_key(name: str) -> list[object]:
    """Sort key that orders frame2 before frame10.

    >>> sorted(["frame10.png", "frame2.png", "Frame1.png"], key=natural_key)
    ['Frame1.png', 'frame2.png', 'frame10.png']
    """
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]
