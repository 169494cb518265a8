"""The one place where the backend reads result files (JSON with `json`, HDF5 with `h5py`).

Belongs here: opening a job's or a calibration's files by their stored path under the data directory, and
cutting what the dashboard asks for out of them (a report, a decimated grid, a profile) without loading more
than that. Not here: computing results (worker/), HTTP (backend/api/). Never imports OpenCV or task code.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


class ResultUnavailable(Exception):
    """A result file is missing or unreadable; the message says which and what to do."""


def result_path(data_path: Path, relative: str) -> Path:
    path = (data_path / relative).resolve()
    if data_path.resolve() not in path.parents:
        raise ResultUnavailable(f"{relative} is outside the data directory")
    if not path.is_file():
        raise ResultUnavailable(f"{relative} is no longer on disk; run the job that made it again")
    return path


def read_json(data_path: Path, relative: str) -> dict[str, Any]:
    path = result_path(data_path, relative)
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as error:
        raise ResultUnavailable(f"{relative} cannot be read ({error}); run the job that made it again") from None
    if not isinstance(document, dict):
        raise ResultUnavailable(f"{relative} is not a result document")
    return document


CAMERA_REPORT_KEYS = (
    "mode", "image_size_px", "sensor", "parameters", "opencv", "inverse_model", "rms_px", "residual_std_px",
    "n_points", "converged", "frames", "residuals", "residual_map", "verdict", "board", "provenance",
)  # fmt: skip


def camera_report(data_path: Path, relative: str) -> dict[str, Any]:
    """The report of a camera calibration (`camera.json`, schema fringelab.camera-calibration): parameters with
    standard errors, per-frame RMS, residual vectors, the residual map and the verdict."""
    document = read_json(data_path, relative)
    if document.get("schema") != "fringelab.camera-calibration":
        raise ResultUnavailable(f"{relative} is not a camera calibration (schema {document.get('schema')!r})")
    return {key: document.get(key) for key in CAMERA_REPORT_KEYS}
