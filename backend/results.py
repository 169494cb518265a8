"""The one place where the backend reads result files (JSON with `json`, HDF5 with `h5py`).

Belongs here: opening a job's or a calibration's files by their stored path under the data directory, and
cutting what the dashboard asks for out of them (a report, a decimated grid, a profile) without loading more
than that. Not here: computing results (worker/), HTTP (backend/api/). Never imports OpenCV or task code.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np


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


# ---------------------------------------------------------------------------------------------- topography

TOPOGRAPHY_SCHEMA = "fringelab.topography"
GRID_BUDGET_NODES = 250  # per side: a 250 × 250 float32 frame is 250 kB, what a browser redraws smoothly


@dataclass(frozen=True)
class GridCut:
    """A frame's deflection w = z − z_flat on (part of) the grid: w_mm (ny, nx) float32, NaN where no data;
    x_mm (nx,), y_mm (ny,) the node (or block-centre) coordinates; step: grid nodes per returned node."""

    frame: int
    x_mm: np.ndarray
    y_mm: np.ndarray
    w_mm: np.ndarray
    step: int


class TopographyReader:
    """A topography result (`topography.h5`, schema fringelab.topography; layout in
    fringelab/science/topography_files.py) opened read-only. Reads one frame's grid at a time; frames are named
    by their recording index (`/frames/index`)."""

    def __init__(self, path: Path) -> None:
        try:
            self.file = h5py.File(path, "r")
        except OSError as error:
            raise ResultUnavailable(f"{path.name} is not a readable result ({error}); run the job again") from None
        try:
            if self.file.attrs.get("schema") != TOPOGRAPHY_SCHEMA:
                raise KeyError("schema")
            self.frames = self.file["frames/index"][()]
            self.x_mm = self.file["grid/x_mm"][()]
            self.y_mm = self.file["grid/y_mm"][()]
            self.z_flat_mm = float(self.file.attrs["z_flat_mm"])
        except KeyError as error:
            self.file.close()
            raise ResultUnavailable(
                f"{path.name} is not a complete topography result ({error}); run it again"
            ) from None

    def __enter__(self) -> TopographyReader:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.file.close()

    def position(self, frame: int) -> int:
        """The row of recording frame `frame` in the file; FrameNotInResult if it was not computed."""
        found = np.flatnonzero(self.frames == frame)
        if found.size == 0:
            span = f"{self.frames[0]}..{self.frames[-1]}" if self.frames.size else "none"
            raise FrameNotInResult(f"frame {frame} is not in this result (frames {span})")
        return int(found[0])

    def column(self, name: str) -> np.ndarray:
        return self.file[name][()] if name in self.file else np.full(self.frames.shape, np.nan)

    def summary(self) -> dict[str, Any]:
        attrs = dict(self.file["summary"].attrs) if "summary" in self.file else {}
        return {key: _plain(value) for key, value in attrs.items()}

    def grid(
        self,
        frame: int,
        *,
        budget: int = GRID_BUDGET_NODES,
        window_mm: tuple[float, float, float, float] | None = None,
    ) -> GridCut:
        """w of one frame, block-averaged (NaN-aware) to at most `budget` nodes per side; `window_mm`
        (x_min, x_max, y_min, y_max) cuts a zoom window first, at full resolution when it fits the budget."""
        i = self.position(frame)
        ix = np.arange(self.x_mm.size)
        iy = np.arange(self.y_mm.size)
        if window_mm is not None:
            x_min, x_max, y_min, y_max = window_mm
            ix = np.flatnonzero((self.x_mm >= x_min) & (self.x_mm <= x_max))
            iy = np.flatnonzero((self.y_mm >= y_min) & (self.y_mm <= y_max))
            if ix.size == 0 or iy.size == 0:
                raise OutsideGrid(
                    f"the window holds no grid node; the grid spans X {self.x_mm[0]:g}..{self.x_mm[-1]:g} mm, "
                    f"Y {self.y_mm[0]:g}..{self.y_mm[-1]:g} mm"
                )
        rows, cols = slice(iy[0], iy[-1] + 1), slice(ix[0], ix[-1] + 1)
        w = self.file["grid/z_mm"][i, rows, cols].astype(np.float32) - np.float32(self.z_flat_mm)
        step = max(1, math.ceil(max(w.shape) / budget))
        return GridCut(
            frame=frame,
            x_mm=_block_mean(self.x_mm[cols][None, :], step)[0],
            y_mm=_block_mean(self.y_mm[rows][:, None], step)[:, 0],
            w_mm=_block_mean(w, step).astype(np.float32),
            step=step,
        )

    def profile(self, frames: list[int], line_mm: tuple[float, float, float, float], *, n_points: int) -> dict:
        """w along the segment (x0, y0) → (x1, y1) for each frame, bilinear between grid nodes (NaN when a
        neighbouring node has no data); s_mm is the distance from (x0, y0)."""
        x0, y0, x1, y1 = line_mm
        t = np.linspace(0.0, 1.0, n_points)
        x, y = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
        weights = self._bilinear(x, y)
        profiles = []
        for frame in frames:
            z = self.file["grid/z_mm"][self.position(frame)].astype(np.float64)
            profiles.append({"frame": frame, "w_mm": _sample(z, weights) - self.z_flat_mm})
        return {"s_mm": t * math.hypot(x1 - x0, y1 - y0), "x_mm": x, "y_mm": y, "profiles": profiles}

    def history(self, x_mm: float, y_mm: float) -> np.ndarray:
        """w(t) at one point over every frame of the result (bilinear; NaN where it has no data). Reads only the
        2 × 2 nodes around the point from each frame."""
        (iy, ix, wy, wx) = self._bilinear(np.array([x_mm]), np.array([y_mm]))
        rows, cols = slice(int(iy[0]), int(iy[0]) + 2), slice(int(ix[0]), int(ix[0]) + 2)
        block = self.file["grid/z_mm"][:, rows, cols].astype(np.float64)
        w = (
            block[:, 0, 0] * (1 - wy[0]) * (1 - wx[0])
            + block[:, 0, 1] * (1 - wy[0]) * wx[0]
            + block[:, 1, 0] * wy[0] * (1 - wx[0])
            + block[:, 1, 1] * wy[0] * wx[0]
        )
        return w - self.z_flat_mm

    def _bilinear(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Lower-left node indices and fractional weights of points on the (regular, increasing) grid."""
        for name, values, axis in (("X", x, self.x_mm), ("Y", y, self.y_mm)):
            if np.any(values < axis[0]) or np.any(values > axis[-1]):
                raise OutsideGrid(f"{name} must lie within the grid, {axis[0]:g}..{axis[-1]:g} mm")
        fx = np.interp(x, self.x_mm, np.arange(self.x_mm.size, dtype=np.float64))
        fy = np.interp(y, self.y_mm, np.arange(self.y_mm.size, dtype=np.float64))
        ix = np.minimum(np.floor(fx).astype(int), max(self.x_mm.size - 2, 0))
        iy = np.minimum(np.floor(fy).astype(int), max(self.y_mm.size - 2, 0))
        return iy, ix, fy - iy, fx - ix


class FrameNotInResult(ResultUnavailable):
    """The frame asked for was not computed."""


class OutsideGrid(ResultUnavailable):
    """A point, line or window lies outside the result's grid."""


def _sample(z: np.ndarray, weights: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    iy, ix, wy, wx = weights
    return (
        z[iy, ix] * (1 - wy) * (1 - wx)
        + z[iy, ix + 1] * (1 - wy) * wx
        + z[iy + 1, ix] * wy * (1 - wx)
        + z[iy + 1, ix + 1] * wy * wx
    )


def _block_mean(values: np.ndarray, step: int) -> np.ndarray:
    """Mean over step × step blocks, ignoring NaN (a block without data stays NaN); the last blocks may be
    smaller."""
    if step == 1:
        return values
    ny, nx = values.shape
    pad_y, pad_x = (-ny) % step, (-nx) % step
    padded = np.pad(values.astype(np.float64), ((0, pad_y), (0, pad_x)), constant_values=np.nan)
    blocks = padded.reshape(padded.shape[0] // step, step, padded.shape[1] // step, step)
    finite = np.isfinite(blocks)
    count = finite.sum(axis=(1, 3))
    total = np.where(finite, blocks, 0.0).sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan)


def _plain(value: Any) -> Any:
    """An HDF5 attribute as JSON-able Python (NaN becomes None)."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


# ---------------------------------------------------------------------------------------------- projector

PROJECTOR_SCHEMA = "fringelab.projector-calibration"


def projector_table(data_path: Path, relative: str, *, line: int | None, edges: list[int] | None) -> dict[str, Any]:
    """Curves of a projector look-up table (`projector.h5`, schema fringelab.projector-calibration): the position
    t (px, along scan line `line`, default the middle one) of each stripe edge against the plate's Z, with the
    table's settings and QA. Reads one scan line of the table."""
    path = result_path(data_path, relative)
    try:
        file = h5py.File(path, "r")
    except OSError as error:
        raise ResultUnavailable(f"{relative} is not readable ({error}); run the calibration again") from None
    with file:
        if file.attrs.get("schema") != PROJECTOR_SCHEMA:
            raise ResultUnavailable(f"{relative} is not a projector calibration")
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
            "axis": _plain(file.attrs["axis"]),
            "period_px": _plain(file.attrs["period_px"]),
            "reference_z_mm": _plain(file.attrs["reference_z_mm"]),
            "n_edges": int(n_edges),
            "n_lines": int(n_lines),
            "line": line,
            "z_mm": file["z_mm"][()],
            "curves": [{"edge": k, "polarity": int(polarity[k]), "t_px": rows[k]} for k in chosen],
            "qa": json.loads(file.attrs["qa_json"]),
        }
