"""A job's or a calibration's result files for the API: found by their stored path under the data directory, and
the calibration reports cut out of them (JSON with `json`, HDF5 with `h5py`) without loading more than asked.

Belongs here: `result_path` and `succeeded_file` (a stored file, or the error that says what to do), a succeeded
topography job's result opened (`topography`), the camera and projector calibration reports and tables, and
turning what is read into JSON-able values (`plain`, `listed`). Not here: cutting topography and comparison
results for the dashboard (the routes, through `fringelab.formats.topography` and `fringelab.formats.comparison`);
computing results (worker/); HTTP (backend/api/). Never imports OpenCV or task code.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from fringelab.core.errors import Conflict, Gone, Invalid, NotFound
from fringelab.core.jobs import job_error
from fringelab.core.models import Job
from fringelab.formats.hdf5 import FrameCache
from fringelab.formats.topography import FrameNotInResult, OutsideGrid, ResultUnavailable, TopographyResult
from fringelab.science.projector_quality import PROJECTOR_LIMITS, judge_projector, projector_maps


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
    "n_points", "converged", "frames", "residuals", "residual_map", "verdict", "board", "provenance", "pose",
)  # fmt: skip


def camera_report(data_path: Path, relative: str) -> dict[str, Any]:
    """The report of a camera calibration (`camera.json`, schema fringelab.camera-calibration): parameters with
    standard errors, per-frame RMS, residual vectors, the residual map and the verdict."""
    document = read_json(data_path, relative)
    if document.get("schema") != "fringelab.camera-calibration":
        raise ResultUnavailable(f"{relative} is not a camera calibration (schema {document.get('schema')!r})")
    return {key: document.get(key) for key in CAMERA_REPORT_KEYS}


def plain(value: Any) -> Any:
    """An HDF5 attribute as JSON-able Python (NaN becomes None)."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return [plain(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def listed(values: np.ndarray, decimals: int = 4) -> list[Any]:
    """JSON list of a float array, rounded, with null for NaN (nested for 2-D)."""
    rounded = np.round(np.asarray(values, dtype=np.float64), decimals)
    if rounded.ndim > 1:
        return [listed(row, decimals) for row in rounded]
    return [None if not math.isfinite(v) else v for v in rounded.tolist()]


# ---------------------------------------------------------------------------------------------- jobs' files

TOPOGRAPHY_FILE = "topography.h5"


def succeeded_file(job: Job, data_path: Path, *, kind: str, name: str) -> Path:
    """The file `name` of a succeeded job of `kind`; a job error (404/409/410) with what to do otherwise."""
    if job.kind != kind:
        raise job_error(NotFound, f"not_{kind}", f"job {job.id} is a {job.kind} job, not a {kind}")
    if job.state != "succeeded":
        raise job_error(
            Conflict, "job_not_succeeded", f"job {job.id} is {job.state}; its results come when it succeeds"
        )
    entry = next((f for f in job.files if f["name"] == name), None)
    if entry is None:
        raise job_error(Gone, "result_missing", f"job {job.id} has no {name}; retry the job")
    try:
        return result_path(data_path, entry["path"])
    except ResultUnavailable as error:
        raise job_error(Gone, "result_missing", str(error)) from None


def topography_file(job: Job, data_path: Path) -> Path:
    """The result file of a succeeded topography job (`succeeded_file`)."""
    return succeeded_file(job, data_path, kind="topography", name=TOPOGRAPHY_FILE)


@contextmanager
def topography(job: Job, data_path: Path, *, frames: FrameCache | None = None) -> Iterator[TopographyResult]:
    """The result of a succeeded topography job, open (its grids' frames through `frames`, the process's cache of
    frames read, when given); a job error (409/410/422) with what to do otherwise."""
    path = topography_file(job, data_path)
    try:
        with TopographyResult(path, frame_cache=frames) as reader:
            yield reader
    except FrameNotInResult as error:
        raise job_error(Invalid, "frame_not_in_result", str(error), field="frame") from None
    except OutsideGrid as error:
        raise job_error(Invalid, "outside_grid", str(error)) from None
    except ResultUnavailable as error:
        raise job_error(Gone, "result_missing", str(error)) from None


# ---------------------------------------------------------------------------------------------- projector

PROJECTOR_SCHEMA = "fringelab.projector-calibration"


@contextmanager
def _projector_file(data_path: Path, relative: str) -> Iterator[h5py.File]:
    """A projector calibration's `projector.h5`, open; ResultUnavailable (what to do) if it cannot be read."""
    try:
        file = h5py.File(result_path(data_path, relative), "r")
    except OSError as error:
        raise ResultUnavailable(f"{relative} is not readable ({error}); run the calibration again") from None
    with file:
        if file.attrs.get("schema") != PROJECTOR_SCHEMA:
            raise ResultUnavailable(f"{relative} is not a projector calibration")
        yield file


def projector_table(data_path: Path, relative: str, *, line: int | None, edges: list[int] | None) -> dict[str, Any]:
    """Curves of a projector look-up table (`projector.h5`, schema fringelab.projector-calibration): the position
    t (px, along scan line `line`, default the middle one) of each stripe edge against the plate's Z, with the
    table's settings and QA. Reads one scan line of the table."""
    with _projector_file(data_path, relative) as file:
        table = file["lut_t_px"]
        n_edges, n_lines, _n_z = table.shape
        line = n_lines // 2 if line is None else line
        if not 0 <= line < n_lines:
            raise OutsideGrid(f"line must be 0..{n_lines - 1}")
        chosen = list(range(n_edges)) if edges is None else edges
        if any(not 0 <= k < n_edges for k in chosen):
            raise OutsideGrid(f"edges must be 0..{n_edges - 1}")
        rows = table[:, line, :]  # one scan line of every edge
        polarity = file["polarity"][()]
        return {
            "axis": plain(file.attrs["axis"]),
            "period_px": plain(file.attrs["period_px"]),
            "reference_z_mm": plain(file.attrs["reference_z_mm"]),
            "n_edges": int(n_edges),
            "n_lines": int(n_lines),
            "line": line,
            "z_mm": file["z_mm"][()],
            "curves": [{"edge": k, "polarity": int(polarity[k]), "t_px": rows[k]} for k in chosen],
            "qa": json.loads(file.attrs["qa_json"]),
        }


def projector_report(data_path: Path, relative: str, *, cell_px: int) -> dict[str, Any]:
    """The verdict of a projector table and its maps over the whole image: sensitivity (px/mm), the Z resolution
    at the measured edge noise (mm), coverage over the image and over Z (`fringelab.science.projector_quality`).
    Reads the (K, S) arrays of the table, not the table itself."""
    with _projector_file(data_path, relative) as file:
        qa = json.loads(file.attrs["qa_json"])
        image_shape = (int(file.attrs["image_height_px"]), int(file.attrs["image_width_px"]))
        maps = projector_maps(
            image_shape=image_shape,
            axis=str(plain(file.attrs["axis"])),
            reference_t_px=file["reference_t_px"][()],
            sensitivity_px_per_mm=file["sensitivity_px_per_mm"][()],
            z_mm=file["z_mm"][()],
            z_lo_mm=file["z_lo_mm"][()],
            z_hi_mm=file["z_hi_mm"][()],
            edge_noise_px=float(qa["edge_noise_px"]),
            cell_px=cell_px,
        )
    verdict = judge_projector(qa)
    return {
        "image_size_px": {"width": image_shape[1], "height": image_shape[0]},
        "verdict": {
            "level": verdict.level,
            "reasons": list(verdict.reasons),
            "checks": [check.__dict__ for check in verdict.checks],
        },
        "limits": {name: {"good": good, "bad": bad} for name, (good, bad) in PROJECTOR_LIMITS.items()},
        "qa": qa,
        "cell_px": maps.cell_px,
        "cells_u": maps.cells_u,
        "cells_v": maps.cells_v,
        "sensitivity_px_per_mm": maps.sensitivity_px_per_mm,
        "z_resolution_mm": maps.z_resolution_mm,
        "coverage": maps.coverage,
        "z_mm": maps.z_mm,
        "coverage_z": maps.coverage_z,
    }
