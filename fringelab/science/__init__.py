"""The measurement science of fringelab: camera and projector calibration, fringe edges, topography.

Pure: arrays and frozen dataclasses in and out, units and frames in names (METHOD.md). Nothing here imports
web, queue or database code, configures logging or reads the environment; file I/O lives only in the
file formats (`fringelab.formats`).
"""

import re


class MeasurementError(Exception):
    """A measurement failed for a reason the user must act on (board not found, Z out of range, ...)."""


def natural_key(name: str) -> list[object]:
    """Sort key that orders frame2 before frame10.

    >>> sorted(["frame10.png", "frame2.png", "Frame1.png"], key=natural_key)
    ['Frame1.png', 'frame2.png', 'frame10.png']
    """
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]
