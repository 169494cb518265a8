"""Files of the structured-light side: projector tables, topography results, exports, edge chunks, recordings.

Belongs here (the only module of the fringe/topography side that touches files): the projector calibration HDF5,
the streaming topography result HDF5 (layout below), its exports (points CSV, grid NPZ, MATLAB .mat, VTK time
series for ParaView, profile CSV), stored edges of frame chunks for parallel runs, the test log `frames.csv`,
and writing frame recordings (folder or ZIP of PNG) for the virtual experiment. Every file is written to a
temporary name beside its target and renamed when complete.

Topography result (schema "fringelab.topography", version 1); lengths in mm in the object frame (METHOD.md §2:
+Z toward the camera), frames are recording frame indices; every dataset has `unit` and `description` attrs:
  /                 attrs: schema, schema_version, created_utc, n_frames, z_flat_mm (median Z of the first frame:
                    w = z − z_flat), grid_step_mm, grid_max_edge_mm, axis, settings_json, edge_settings_json,
                    provenance_json (code versions, input checksums)
  /calibration      attrs: camera_json (the camera calibration document or the camera's parameters),
                    camera_fingerprint, projector_json (its settings, QA, provenance, table size)
  /frames           index (n,) int64; time_s, punch_displacement_mm, force_kN (n,) float64, NaN if not logged
  /points           offsets (n + 1,) int64: frame i's points are rows offsets[i]:offsets[i+1] of
                    x_mm, y_mm, z_mm (P,) float32, edge (P,) int32 (edge index k), line (P,) int32 (scan line)
  /grid             x_mm (nx,), y_mm (ny,); z_mm (n, ny, nx) float32, chunked one frame per chunk, NaN outside
                    the data
  /peak             w_mm, x_mm, y_mm (n,): the largest deflection of the grid and where; centre_x_mm,
                    centre_y_mm (n,): centroid of the area above half the peak (the punch axis), NaN early on
  /qa               n_points, n_tracks, n_ended, n_out_of_range, n_unmatched (n,) int64; edge_noise_px,
                    grid_coverage (n,) float64 (fraction of the first frame's grid area still with data)
  /summary          attrs: flat_rms_mm (RMS of w over the first frame), n_tracks_first_frame, clamp_centre_x_mm,
                    clamp_centre_y_mm, clamp_radius_mm (circle through the outermost first-frame points),
                    punch_axis_x_mm, punch_axis_y_mm (median of the per-frame centres), n_out_of_range_total
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import tempfile
import zipfile
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import h5py
import numpy as np

from fringelab.science.fields import Grid, Peak, line_profile
from fringelab.science.fringes import EdgeSettings, FrameEdges
from fringelab.science.projector import ProjectorCalibration, ProjectorQA

if TYPE_CHECKING:
    from fringelab.science.topography import FrameMeasurement

PROJECTOR_SCHEMA = "fringelab.projector-calibration"
TOPOGRAPHY_SCHEMA = "fringelab.topography"
EDGES_SCHEMA = "fringelab.frame-edges"
SCHEMA_VERSION = 1
EXPORT_FORMATS = ("points-csv", "grid-npz", "mat", "vtk", "profile-csv")


@contextmanager
def _atomic_path(path: Path) -> Iterator[Path]:
    """A temporary path beside `path` that is renamed over it when the block completes (removed on error)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    os.close(handle)
    temp = Path(temp_name)
    try:
        yield temp
        os.replace(temp, path)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise


def _dataset(group: h5py.Group, name: str, data: Any, *, unit: str, description: str, **kwargs: Any) -> h5py.Dataset:
    dataset = group.create_dataset(name, data=data, **kwargs)
    dataset.attrs["unit"] = unit
    dataset.attrs["description"] = description
    return dataset


def _json(value: Any) -> str:
    def clean(obj: Any) -> Any:
        if isinstance(obj, dict):
            return {str(k): clean(v) for k, v in obj.items()}
        if isinstance(obj, list | tuple):
            return [clean(v) for v in obj]
        if isinstance(obj, float | np.floating):
            return float(obj) if math.isfinite(obj) else None
        if isinstance(obj, np.integer):
            return int(obj)
        if isinstance(obj, np.ndarray):
            return clean(obj.tolist())
        return obj

    return json.dumps(clean(value))


def _require_schema(file: h5py.File, schema: str, path: Path) -> None:
    found = file.attrs.get("schema")
    if found != schema:
        raise ValueError(f"{path}: not a {schema} file (schema {found!r})")
    if int(file.attrs.get("schema_version", -1)) != SCHEMA_VERSION:
        raise ValueError(f"{path}: schema version {file.attrs.get('schema_version')} is not supported (expected 1)")


# --------------------------------------------------------------------------------------------------------------
# Projector calibration

_PROJECTOR_ARRAYS = {
    "reference_t_px": ("px", "position of edge k on scan line s at the reference Z"),
    "t_centre_px": ("px", "centre of the polynomial's variable τ = (t − t_centre)/t_scale"),
    "t_scale_px": ("px", "scale of the polynomial's variable"),
    "t_lo_px": ("px", "lowest position looked up (sampled range plus noise margin)"),
    "t_hi_px": ("px", "highest position looked up (sampled range plus noise margin)"),
    "z_lo_mm": ("mm", "lowest Z sampled for the entry"),
    "z_hi_mm": ("mm", "highest Z sampled for the entry"),
    "sensitivity_px_per_mm": ("px/mm", "dt/dZ of the entry (linear fit)"),
    "fit_rms_mm": ("mm", "RMS residual in Z of the entry's polynomial fit"),
}


def write_projector_calibration(calibration: ProjectorCalibration, path: str | Path) -> Path:
    """Write a projector calibration as HDF5 (arrays (K, S[, J]) with NaN where there is no entry)."""
    path = Path(path)
    with _atomic_path(path) as temp, h5py.File(temp, "w") as file:
        file.attrs["schema"] = PROJECTOR_SCHEMA
        file.attrs["schema_version"] = SCHEMA_VERSION
        file.attrs["created_utc"] = datetime.now(UTC).isoformat(timespec="seconds")
        file.attrs["image_height_px"], file.attrs["image_width_px"] = calibration.image_shape
        file.attrs["axis"] = calibration.axis
        file.attrs["period_px"] = calibration.period_px
        file.attrs["reference_z_mm"] = calibration.reference_z_mm
        file.attrs["camera_fingerprint"] = calibration.camera_fingerprint
        file.attrs["edge_settings_json"] = _json(asdict(calibration.edges))
        file.attrs["qa_json"] = _json(asdict(calibration.qa))
        file.attrs["provenance_json"] = _json(calibration.provenance)
        file.attrs["description"] = (
            "Projector look-up table (METHOD.md §4): lut_t_px[k, s, j] is the position (px, along scan line s) of "
            "stripe edge k on the flat plate at Z = z_mm[j]; Z(t) = Σ_i coefficients[k, s, i]·τ^i with "
            "τ = (t − t_centre_px)/t_scale_px for t_lo_px ≤ t ≤ t_hi_px. axis 'rows': scan lines are image rows and "
            "t the column; 'cols': scan lines are columns and t the row."
        )
        n_lines = calibration.n_lines
        chunk = (1, n_lines, len(calibration.z_mm))
        _dataset(file, "z_mm", calibration.z_mm, unit="mm", description="calibration heights, increasing")
        _dataset(file, "polarity", calibration.polarity, unit="1", description="+1 dark→bright along +t, −1 falling")
        _dataset(
            file,
            "lut_t_px",
            calibration.lut_t_px,
            unit="px",
            description="the table, NaN where not seen",
            chunks=chunk,
            compression="gzip",
            compression_opts=4,
            shuffle=True,
        )
        _dataset(
            file,
            "coefficients",
            calibration.coefficients,
            unit="mm",
            description="Z(τ) polynomial coefficients, lowest power first",
            compression="gzip",
        )
        for name, (unit, description) in _PROJECTOR_ARRAYS.items():
            _dataset(file, name, getattr(calibration, name), unit=unit, description=description, compression="gzip")
    return path


def read_projector_calibration(path: str | Path) -> ProjectorCalibration:
    """Read a projector calibration written by `write_projector_calibration`. ValueError for anything else."""
    path = Path(path)
    try:
        file = h5py.File(path, "r")
    except OSError as error:
        raise ValueError(f"{path}: not a readable HDF5 file ({error})") from None
    with file:
        _require_schema(file, PROJECTOR_SCHEMA, path)
        try:
            qa: dict[str, Any] = {
                key: tuple(np.nan if v is None else v for v in value)
                if isinstance(value, list)
                else (np.nan if value is None else value)
                for key, value in json.loads(file.attrs["qa_json"]).items()
            }
            arrays = {name: file[name][()] for name in _PROJECTOR_ARRAYS}
            return ProjectorCalibration(
                image_shape=(int(file.attrs["image_height_px"]), int(file.attrs["image_width_px"])),
                edges=EdgeSettings(**json.loads(file.attrs["edge_settings_json"])),
                reference_z_mm=float(file.attrs["reference_z_mm"]),
                z_mm=file["z_mm"][()],
                polarity=file["polarity"][()],
                lut_t_px=file["lut_t_px"][()],
                coefficients=file["coefficients"][()],
                qa=ProjectorQA(**qa),
                camera_fingerprint=str(file.attrs["camera_fingerprint"]),
                provenance=json.loads(file.attrs["provenance_json"]),
                **arrays,
            )
        except (KeyError, TypeError) as error:
            raise ValueError(f"{path}: malformed projector calibration ({type(error).__name__}: {error})") from None


# --------------------------------------------------------------------------------------------------------------
# frames.csv


@dataclass(frozen=True, eq=False)
class FrameTable:
    """The test log (frames.csv): per-frame time, punch displacement and force; NaN where not given."""

    frame: np.ndarray
    time_s: np.ndarray
    punch_displacement_mm: np.ndarray
    force_kN: np.ndarray

    COLUMNS = ("time_s", "punch_displacement_mm", "force_kN")

    @classmethod
    def empty(cls) -> FrameTable:
        """A log with no rows (every frame gets NaN)."""
        nothing = np.zeros(0)
        return cls(frame=np.zeros(0, np.int64), time_s=nothing, punch_displacement_mm=nothing, force_kN=nothing)

    def rows(self, frames: Sequence[int]) -> dict[str, np.ndarray]:
        """The columns for the given frame indices (NaN for frames not in the log)."""
        out = {name: np.full(len(frames), np.nan) for name in self.COLUMNS}
        position = {int(f): i for i, f in enumerate(self.frame)}
        for j, f in enumerate(frames):
            i = position.get(int(f))
            if i is not None:
                for name in self.COLUMNS:
                    out[name][j] = getattr(self, name)[i]
        return out


def read_frames_csv(text: str, *, name: str = "frames.csv") -> FrameTable:
    """Parse `frame,time_s,punch_displacement_mm,force_kN` (any subset after `frame`); errors name the line."""
    reader = csv.DictReader(io.StringIO(text))
    fields = [f.strip() for f in (reader.fieldnames or [])]
    if "frame" not in fields:
        raise ValueError(f"{name}: expected a 'frame' column and any of {', '.join(FrameTable.COLUMNS)}, got {fields}")
    unknown = [f for f in fields if f != "frame" and f not in FrameTable.COLUMNS]
    if unknown:
        raise ValueError(f"{name}: unknown columns {unknown} (expected frame, {', '.join(FrameTable.COLUMNS)})")
    frames: list[int] = []
    columns: dict[str, list[float]] = {c: [] for c in FrameTable.COLUMNS}
    for line_no, raw in enumerate(reader, start=2):
        row = {k.strip(): (v or "").strip() for k, v in raw.items() if k is not None}
        try:
            frame = int(row["frame"])
        except ValueError:
            raise ValueError(f"{name} line {line_no}: 'frame' must be an integer, got {row['frame']!r}") from None
        if frame in frames:
            raise ValueError(f"{name} line {line_no}: frame {frame} appears twice")
        frames.append(frame)
        for column in FrameTable.COLUMNS:
            text_value = row.get(column, "")
            try:
                columns[column].append(float(text_value) if text_value else float("nan"))
            except ValueError:
                raise ValueError(f"{name} line {line_no}: {column} must be a number, got {text_value!r}") from None
    if not frames:
        raise ValueError(f"{name}: no rows")
    return FrameTable(frame=np.array(frames), **{c: np.array(v) for c, v in columns.items()})


def frames_csv_text(table: FrameTable) -> str:
    """The text of a frames.csv for a table."""
    lines = ["frame," + ",".join(FrameTable.COLUMNS)]
    for i, frame in enumerate(table.frame):
        values = [getattr(table, c)[i] for c in FrameTable.COLUMNS]
        lines.append(f"{int(frame)}," + ",".join("" if not np.isfinite(v) else repr(float(v)) for v in values))
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------------------------
# The topography result


class TopographyWriter:
    """Streams a topography result into HDF5, one frame at a time (memory does not grow with the frame count).

    Use as a context manager: the file is written under a temporary name and renamed into place by `close()`
    after the summary; on an exception it is removed.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        grid: Grid,
        max_edge_mm: float,
        z_flat_mm: float,
        axis: str,
        attrs: dict[str, Any],
        calibration_attrs: dict[str, Any],
    ) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        handle, temp_name = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".partial", dir=self.path.parent)
        os.close(handle)
        self._temp = Path(temp_name)
        self.grid = grid
        self.z_flat_mm = z_flat_mm
        self._n = 0
        self._n_points = 0
        self._first_coverage_nodes: int | None = None
        file = self._file = h5py.File(self._temp, "w")
        file.attrs["schema"] = TOPOGRAPHY_SCHEMA
        file.attrs["schema_version"] = SCHEMA_VERSION
        file.attrs["created_utc"] = datetime.now(UTC).isoformat(timespec="seconds")
        file.attrs["length_unit"] = "mm"
        file.attrs["object_frame"] = "X, Y in the plate plane, +Z toward the camera (METHOD.md §2)"
        file.attrs["z_flat_mm"] = z_flat_mm
        file.attrs["grid_step_mm"] = grid.step_mm
        file.attrs["grid_max_edge_mm"] = max_edge_mm
        file.attrs["axis"] = axis
        for key, value in attrs.items():
            file.attrs[key] = value
        calibration = file.create_group("calibration")
        for key, value in calibration_attrs.items():
            calibration.attrs[key] = value
        ny, nx = grid.shape
        frames = file.create_group("frames")
        _dataset(
            frames,
            "index",
            np.zeros(0, np.int64),
            unit="1",
            description="frame index in the recording",
            maxshape=(None,),
            chunks=(1024,),
        )
        for name, unit, description in (
            ("time_s", "s", "time of the frame (frames.csv)"),
            ("punch_displacement_mm", "mm", "punch displacement (frames.csv)"),
            ("force_kN", "kN", "punch force (frames.csv)"),
        ):
            _dataset(frames, name, np.zeros(0), unit=unit, description=description, maxshape=(None,), chunks=(1024,))
        points = file.create_group("points")
        _dataset(
            points,
            "offsets",
            np.zeros(1, np.int64),
            unit="1",
            description="frame i's points are rows offsets[i]:offsets[i+1]",
            maxshape=(None,),
            chunks=(1024,),
        )
        for name, dtype, unit, description in (
            ("x_mm", np.float32, "mm", "X of each edge point"),
            ("y_mm", np.float32, "mm", "Y of each edge point"),
            ("z_mm", np.float32, "mm", "Z of each edge point (the deflection is z − z_flat_mm)"),
            ("edge", np.int32, "1", "edge index k in the projector table"),
            ("line", np.int32, "1", "scan line (image row for axis 'rows', column for 'cols')"),
        ):
            _dataset(
                points,
                name,
                np.zeros(0, dtype),
                unit=unit,
                description=description,
                maxshape=(None,),
                chunks=(65536,),
                compression="gzip",
                compression_opts=1,
                shuffle=True,
            )
        grid_group = file.create_group("grid")
        _dataset(grid_group, "x_mm", grid.x_mm, unit="mm", description="X of the grid nodes")
        _dataset(grid_group, "y_mm", grid.y_mm, unit="mm", description="Y of the grid nodes")
        _dataset(
            grid_group,
            "z_mm",
            np.zeros((0, ny, nx), np.float32),
            unit="mm",
            description="gridded Z per frame [frame, iy, ix], NaN outside the data",
            maxshape=(None, ny, nx),
            chunks=(1, ny, nx),
            compression="gzip",
            compression_opts=1,
            shuffle=True,
            fillvalue=np.nan,
        )
        peak = file.create_group("peak")
        for name, description in (
            ("w_mm", "largest deflection w = z − z_flat of the grid"),
            ("x_mm", "X of the largest deflection"),
            ("y_mm", "Y of the largest deflection"),
            ("centre_x_mm", "X of the centroid of the area above half the peak"),
            ("centre_y_mm", "Y of the centroid of the area above half the peak"),
        ):
            _dataset(peak, name, np.zeros(0), unit="mm", description=description, maxshape=(None,), chunks=(1024,))
        qa = file.create_group("qa")
        for name, description in (
            ("n_points", "3-D points of the frame"),
            ("n_tracks", "tracked (edge, line) points, with or without Z"),
            ("n_ended", "tracks that ended at this frame"),
            ("n_out_of_range", "tracked points beyond the calibrated Z range (masked)"),
            ("n_unmatched", "edge points that belong to no track"),
        ):
            _dataset(
                qa, name, np.zeros(0, np.int64), unit="1", description=description, maxshape=(None,), chunks=(1024,)
            )
        _dataset(
            qa,
            "edge_noise_px",
            np.zeros(0),
            unit="px",
            description="edge-location noise estimate",
            maxshape=(None,),
            chunks=(1024,),
        )
        _dataset(
            qa,
            "grid_coverage",
            np.zeros(0),
            unit="1",
            description="grid nodes with data / those of the first frame",
            maxshape=(None,),
            chunks=(1024,),
        )

    def __enter__(self) -> TopographyWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is not None:
            self.abort()

    def _append(self, dataset: h5py.Dataset, values: np.ndarray) -> None:
        start = dataset.shape[0]
        dataset.resize(start + len(values), axis=0)
        dataset[start:] = values

    def append(
        self,
        measurement: FrameMeasurement,
        z_grid_mm: np.ndarray,
        peak: Peak,
        *,
        log: tuple[float, float, float],
    ) -> None:
        """Add one frame: its points, grid, peak, test-log row (time_s, punch_displacement_mm, force_kN), QA."""
        file = self._file
        self._append(file["frames/index"], np.array([measurement.frame]))
        for name, value in zip(("time_s", "punch_displacement_mm", "force_kN"), log, strict=True):
            self._append(file[f"frames/{name}"], np.array([value]))
        points = measurement.points_obj_mm
        self._append(file["points/x_mm"], points[:, 0].astype(np.float32))
        self._append(file["points/y_mm"], points[:, 1].astype(np.float32))
        self._append(file["points/z_mm"], points[:, 2].astype(np.float32))
        self._append(file["points/edge"], measurement.k.astype(np.int32))
        self._append(file["points/line"], measurement.line.astype(np.int32))
        self._n_points += len(points)
        self._append(file["points/offsets"], np.array([self._n_points]))
        grid_z = file["grid/z_mm"]
        grid_z.resize(self._n + 1, axis=0)
        grid_z[self._n] = z_grid_mm.astype(np.float32)
        for name in ("w_mm", "x_mm", "y_mm", "centre_x_mm", "centre_y_mm"):
            self._append(file[f"peak/{name}"], np.array([getattr(peak, name)]))
        nodes = int(np.count_nonzero(np.isfinite(z_grid_mm)))
        if self._first_coverage_nodes is None:
            self._first_coverage_nodes = max(nodes, 1)
        qa = {
            "n_points": len(points),
            "n_tracks": measurement.n_tracks,
            "n_ended": measurement.n_ended,
            "n_out_of_range": measurement.n_out_of_range,
            "n_unmatched": measurement.n_unmatched,
            "edge_noise_px": measurement.edge_noise_px,
            "grid_coverage": nodes / self._first_coverage_nodes,
        }
        for name, value in qa.items():
            self._append(file[f"qa/{name}"], np.array([value]))
        self._n += 1

    def close(self, summary: dict[str, Any]) -> Path:
        """Write the summary attributes, close the file and move it into place."""
        file = self._file
        file.attrs["n_frames"] = self._n
        group = file.require_group("summary")
        for key, value in summary.items():
            group.attrs[key] = value
        file.close()
        os.replace(self._temp, self.path)
        return self.path

    def abort(self) -> None:
        try:
            self._file.close()
        finally:
            self._temp.unlink(missing_ok=True)


class TopographyResult:
    """A topography result file opened for reading; frames are read one at a time.

    Use as a context manager or call `close()`. Frame positions i are 0..n_frames−1 (the order in the file);
    `frames` holds their recording indices.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self.file = h5py.File(self.path, "r")
        except OSError as error:
            raise ValueError(f"{self.path}: not a readable HDF5 file ({error})") from None
        try:
            _require_schema(self.file, TOPOGRAPHY_SCHEMA, self.path)
        except ValueError:
            self.file.close()
            raise
        self.grid = Grid(x_mm=self.file["grid/x_mm"][()], y_mm=self.file["grid/y_mm"][()])
        self.frames = self.file["frames/index"][()]
        self.offsets = self.file["points/offsets"][()]
        self.z_flat_mm = float(self.file.attrs["z_flat_mm"])

    def __enter__(self) -> TopographyResult:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        self.file.close()

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    def column(self, name: str) -> np.ndarray:
        """A per-frame dataset, e.g. "frames/time_s", "peak/w_mm", "qa/n_points"."""
        return self.file[name][()]

    def points(self, i: int) -> np.ndarray:
        """The 3-D points (N, 3) of frame position i."""
        lo, hi = int(self.offsets[i]), int(self.offsets[i + 1])
        return np.column_stack([self.file[f"points/{axis}_mm"][lo:hi] for axis in "xyz"]).astype(np.float64)

    def point_labels(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Edge index and scan line (N,) of the points of frame position i."""
        lo, hi = int(self.offsets[i]), int(self.offsets[i + 1])
        return self.file["points/edge"][lo:hi], self.file["points/line"][lo:hi]

    def z_grid(self, i: int) -> np.ndarray:
        """Gridded Z (ny, nx) of frame position i (NaN outside the data)."""
        return self.file["grid/z_mm"][i].astype(np.float64)

    def w_grid(self, i: int) -> np.ndarray:
        """Gridded deflection w = z − z_flat (ny, nx) of frame position i."""
        return self.z_grid(i) - self.z_flat_mm

    def summary(self) -> dict[str, Any]:
        return dict(self.file["summary"].attrs) if "summary" in self.file else {}

    def history(self, x_mm: float, y_mm: float) -> np.ndarray:
        """w(t) at one object point over all frames (bilinear on the grid; NaN where it has no data)."""
        from fringelab.science.fields import sample_field

        return np.array(
            [
                sample_field(self.w_grid(i), self.grid, np.array([x_mm]), np.array([y_mm]))[0]
                for i in range(self.n_frames)
            ]
        )


# --------------------------------------------------------------------------------------------------------------
# Exports


def export_points_csv(result: TopographyResult, path: str | Path) -> Path:
    """CSV of every 3-D point: frame,x_mm,y_mm,z_mm (written frame by frame)."""
    path = Path(path)
    with _atomic_path(path) as temp, open(temp, "w", newline="") as out:
        out.write("frame,x_mm,y_mm,z_mm\n")
        for i, frame in enumerate(result.frames):
            points = result.points(i)
            block = np.column_stack([np.full(len(points), frame), points])
            np.savetxt(out, block, fmt=["%d", "%.4f", "%.4f", "%.4f"], delimiter=",")
    return path


def read_points_csv(path: str | Path) -> np.ndarray:
    """The rows (P, 4) frame, x_mm, y_mm, z_mm of a points CSV."""
    return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def _grid_stack(result: TopographyResult) -> np.ndarray:
    return (
        np.stack([result.file["grid/z_mm"][i] for i in range(result.n_frames)])
        if result.n_frames
        else np.zeros((0, *result.grid.shape), np.float32)
    )


def export_grid_npz(result: TopographyResult, path: str | Path) -> Path:
    """NPZ with x_mm (nx), y_mm (ny), z_mm (frames, ny, nx) NaN outside the data, frames (recording indices),
    and z_flat_mm (w = z − z_flat_mm). Holds the whole grid stack in memory (as `numpy.load` will)."""
    path = Path(path)
    with _atomic_path(path) as temp, open(temp, "wb") as out:
        np.savez_compressed(
            out,
            x_mm=result.grid.x_mm,
            y_mm=result.grid.y_mm,
            z_mm=_grid_stack(result),
            frames=result.frames,
            z_flat_mm=np.float64(result.z_flat_mm),
        )
    return path


def export_mat(result: TopographyResult, path: str | Path) -> Path:
    """MATLAB .mat (scipy.io.savemat): grid x_mm, y_mm, z_mm (frames × ny × nx), frames, time_s,
    punch_displacement_mm, force_kN, peak_w_mm, z_flat_mm, points (P × 4: frame, x_mm, y_mm, z_mm), units."""
    from scipy.io import savemat

    path = Path(path)
    points = [
        np.column_stack([np.full(len(p), frame), p])
        for frame, p in ((f, result.points(i)) for i, f in enumerate(result.frames))
    ]
    data = {
        "x_mm": result.grid.x_mm,
        "y_mm": result.grid.y_mm,
        "z_mm": _grid_stack(result).astype(np.float64),
        "frames": result.frames.astype(np.float64),
        "time_s": result.column("frames/time_s"),
        "punch_displacement_mm": result.column("frames/punch_displacement_mm"),
        "force_kN": result.column("frames/force_kN"),
        "peak_w_mm": result.column("peak/w_mm"),
        "z_flat_mm": result.z_flat_mm,
        "points": np.vstack(points) if points else np.zeros((0, 4)),
        "units": {
            "length": "mm",
            "time": "s",
            "force": "kN",
            "frame": "X, Y in the plate plane, +Z toward the camera; w = z - z_flat_mm",
        },
    }
    with _atomic_path(path) as temp, open(temp, "wb") as out:
        savemat(out, data, do_compression=True)
    return path


def export_vtk(result: TopographyResult, path: str | Path) -> Path:
    """A ParaView time series: `path` (.pvd) listing one .vtu per frame in the folder `<stem>_vtu` beside it.

    Each .vtu is the gridded surface (quads between nodes that all have data) at its measured height, with point
    data z_mm and w_mm; the .pvd gives each frame its time (time_s where logged, else the frame index).
    """
    import meshio

    path = Path(path)
    folder = path.parent / f"{path.stem}_vtu"
    folder.mkdir(parents=True, exist_ok=True)
    gx, gy = np.meshgrid(result.grid.x_mm, result.grid.y_mm)
    ny, nx = result.grid.shape
    node = np.arange(ny * nx).reshape(ny, nx)
    quads_all = np.column_stack(
        [node[:-1, :-1].ravel(), node[:-1, 1:].ravel(), node[1:, 1:].ravel(), node[1:, :-1].ravel()]
    )
    times = result.column("frames/time_s")
    entries = []
    for i, frame in enumerate(result.frames):
        z = result.z_grid(i).ravel()
        finite = np.isfinite(z)
        quads = quads_all[np.all(finite[quads_all], axis=1)]
        used = np.unique(quads)
        renumber = np.full(ny * nx, -1)
        renumber[used] = np.arange(len(used))
        points = np.column_stack([gx.ravel()[used], gy.ravel()[used], z[used]])
        mesh = meshio.Mesh(
            points, [("quad", renumber[quads])], point_data={"z_mm": z[used], "w_mm": z[used] - result.z_flat_mm}
        )
        name = f"frame_{int(frame):06d}.vtu"
        meshio.write(folder / name, mesh, binary=True)
        time = float(times[i]) if np.isfinite(times[i]) else float(frame)
        entries.append(f'    <DataSet timestep="{time!r}" part="0" file="{folder.name}/{name}"/>')
    pvd = (
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
        "  <Collection>\n" + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n"
    )
    with _atomic_path(path) as temp:
        temp.write_text(pvd)
    return path


def read_pvd(path: str | Path) -> list[tuple[float, Path]]:
    """(time, .vtu path) of each data set listed in a .pvd collection."""
    import xml.etree.ElementTree as ElementTree

    path = Path(path)
    root = ElementTree.parse(path).getroot()
    return [(float(d.attrib["timestep"]), path.parent / d.attrib["file"]) for d in root.iter("DataSet")]


def default_profile_line(result: TopographyResult) -> tuple[float, float, float, float]:
    """A line along X through the punch axis (or the clamp centre, or the grid centre) across the grid."""
    summary = result.summary()
    for key in ("punch_axis", "clamp_centre"):
        x, y = summary.get(f"{key}_x_mm", np.nan), summary.get(f"{key}_y_mm", np.nan)
        if np.isfinite(x) and np.isfinite(y):
            break
    else:
        x, y = float(np.mean(result.grid.x_mm)), float(np.mean(result.grid.y_mm))
    return float(result.grid.x_mm[0]), float(y), float(result.grid.x_mm[-1]), float(y)


def export_profile_csv(
    result: TopographyResult, path: str | Path, *, line: tuple[float, float, float, float] | None = None
) -> Path:
    """CSV of the section profile along a line X0,Y0 → X1,Y1 (mm) for every frame:
    frame,time_s,s_mm,x_mm,y_mm,z_mm,w_mm (s along the line; NaN where the grid has no data)."""
    path = Path(path)
    x0, y0, x1, y1 = default_profile_line(result) if line is None else line
    times = result.column("frames/time_s")
    with _atomic_path(path) as temp, open(temp, "w", newline="") as out:
        out.write("frame,time_s,s_mm,x_mm,y_mm,z_mm,w_mm\n")
        for i, frame in enumerate(result.frames):
            profile = line_profile(result.z_grid(i), result.grid, (x0, y0), (x1, y1))
            m = len(profile.s_mm)
            block = np.column_stack(
                [
                    np.full(m, frame),
                    np.full(m, times[i]),
                    profile.s_mm,
                    profile.x_mm,
                    profile.y_mm,
                    profile.values,
                    profile.values - result.z_flat_mm,
                ]
            )
            np.savetxt(out, block, fmt=["%d", "%.6g", "%.4f", "%.4f", "%.4f", "%.4f", "%.4f"], delimiter=",")
    return path


def export_result(
    result_path: str | Path, fmt: str, out_path: str | Path, *, line: tuple[float, float, float, float] | None = None
) -> Path:
    """Export a topography result in one of EXPORT_FORMATS; `line` (X0, Y0, X1, Y1 mm) for profile-csv only."""
    if fmt not in EXPORT_FORMATS:
        raise ValueError(f"format: expected one of {EXPORT_FORMATS}, got {fmt!r}")
    if line is not None and fmt != "profile-csv":
        raise ValueError("a line is only used by the profile-csv format")
    with TopographyResult(result_path) as result:
        if fmt == "points-csv":
            return export_points_csv(result, out_path)
        if fmt == "grid-npz":
            return export_grid_npz(result, out_path)
        if fmt == "mat":
            return export_mat(result, out_path)
        if fmt == "vtk":
            return export_vtk(result, out_path)
        return export_profile_csv(result, out_path, line=line)


# --------------------------------------------------------------------------------------------------------------
# Edges of frame chunks (for parallel runs)


def write_edges(path: str | Path, frames: Sequence[int], edges: Sequence[FrameEdges]) -> Path:
    """Store the located edges of a chunk of frames (recording indices `frames`) in one HDF5 file."""
    path = Path(path)
    if len(frames) != len(edges):
        raise ValueError(f"frames: {len(frames)} indices for {len(edges)} located frames")
    with _atomic_path(path) as temp, h5py.File(temp, "w") as file:
        file.attrs["schema"] = EDGES_SCHEMA
        file.attrs["schema_version"] = SCHEMA_VERSION
        offsets = np.r_[0, np.cumsum([len(e) for e in edges])].astype(np.int64)
        file["frames"] = np.asarray(frames, np.int64)
        file["offsets"] = offsets
        for name, dtype in (("line", np.int32), ("t_px", np.float32), ("polarity", np.int8), ("chain", np.int32)):
            data = np.concatenate([getattr(e, name) for e in edges]) if edges else np.zeros(0, dtype)
            file.create_dataset(name, data=data.astype(dtype), compression="gzip", compression_opts=1, shuffle=True)
        meta = [
            {
                "axis": e.axis,
                "period_px": e.period_px,
                "image_shape": list(e.image_shape),
                "noise_px": e.noise_px,
                "saturated_fraction": e.saturated_fraction,
                "dark_fraction": e.dark_fraction,
            }
            for e in edges
        ]
        file.attrs["frames_json"] = _json(meta)
    return path


def read_edges(path: str | Path) -> tuple[np.ndarray, list[FrameEdges]]:
    """Frame indices and located edges stored by `write_edges`."""
    path = Path(path)
    with h5py.File(path, "r") as file:
        _require_schema(file, EDGES_SCHEMA, path)
        offsets = file["offsets"][()]
        arrays = {name: file[name][()] for name in ("line", "t_px", "polarity", "chain")}
        meta = json.loads(file.attrs["frames_json"])
        frames = file["frames"][()]
    edges = []
    for i, m in enumerate(meta):
        lo, hi = offsets[i], offsets[i + 1]
        edges.append(
            FrameEdges(
                axis=m["axis"],
                period_px=float(m["period_px"]),
                image_shape=(int(m["image_shape"][0]), int(m["image_shape"][1])),
                line=arrays["line"][lo:hi],
                t_px=arrays["t_px"][lo:hi],
                polarity=arrays["polarity"][lo:hi],
                chain=arrays["chain"][lo:hi],
                noise_px=float("nan") if m["noise_px"] is None else float(m["noise_px"]),
                saturated_fraction=float(m["saturated_fraction"]),
                dark_fraction=float(m["dark_fraction"]),
            )
        )
    return frames, edges


# --------------------------------------------------------------------------------------------------------------
# Recordings (for the virtual experiment)


def write_recording(
    path: str | Path, frames: Iterable[np.ndarray], *, sidecars: dict[str, str] | None = None, as_zip: bool = False
) -> Path:
    """Write frames one at a time as frame0000.png, ... with sidecar texts, into a folder or a ZIP (`as_zip`).

    Readable with `fringelab.formats.recordings.open_recording`. Frames are encoded as they come, so a long
    recording is never held.
    """
    path = Path(path)

    def encoded(frame: np.ndarray, index: int) -> bytes:
        ok, data = cv2.imencode(".png", frame)
        if not ok:
            raise ValueError(f"{path}: could not encode frame {index} (dtype {frame.dtype}, shape {frame.shape})")
        return data.tobytes()

    if as_zip:
        with _atomic_path(path) as temp, zipfile.ZipFile(temp, "w", compression=zipfile.ZIP_STORED) as archive:
            for index, frame in enumerate(frames):
                archive.writestr(f"frame{index:04d}.png", encoded(frame, index))
            for name, text in (sidecars or {}).items():
                archive.writestr(name, text)
        return path
    path.mkdir(parents=True, exist_ok=True)
    for index, frame in enumerate(frames):
        (path / f"frame{index:04d}.png").write_bytes(encoded(frame, index))
    for name, text in (sidecars or {}).items():
        (path / name).write_text(text)
    return path


def write_json(path: str | Path, document: Any) -> Path:
    """Write a JSON document atomically (NaN and infinities become null)."""
    path = Path(path)
    with _atomic_path(path) as temp:
        temp.write_text(json.dumps(json.loads(_json(document)), indent=1) + "\n")
    return path
