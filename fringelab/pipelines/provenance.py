"""What every result records of the code that made it."""

from __future__ import annotations

import cv2
import numpy as np


def code_versions() -> dict[str, str]:
    """Versions of fringelab and the numerical libraries, for provenance."""
    from importlib.metadata import PackageNotFoundError, version

    import scipy

    try:
        fringelab = version("fringelab")
    except PackageNotFoundError:
        fringelab = "unknown"
    return {"code_version": fringelab, "numpy": np.__version__, "scipy": scipy.__version__, "opencv": cv2.__version__}
