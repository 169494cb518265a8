"""The comparison file (HDF5): a measured topography against a finite-element simulation, with its exports.

Schema "fringelab.comparison", version 1; lengths in mm in the plate frame of the measurement (METHOD.md §2),
w = deflection toward the cameras; every dataset has `unit` and `description` attrs; NaN marks what was not
compared, and /frames/reason says why for a frame without a simulation partner:
  /            attrs: schema, schema_version, created_utc, result (the topography file), simulation (what was
               read), simulation_kind, alignment ("displacement", "time" or "peak"), mapping_json (every mapping
               choice, those detected listed in "detected", with notes), n_frames
  /grid        x_mm (nx,), y_mm (ny,): the measurement's grid
  /frames      index (n,) recording frame; time_s, punch_displacement_mm, force_kN (n,) as measured;
               peak_w_mm (n,) measured; state_lo (n,) int64 (−1: no partner), state_fraction (n,): the
               simulation at state_lo + fraction; reason (n,) str ("" when compared); sim_time_s,
               sim_punch_displacement_mm, sim_force_kN, sim_peak_w_mm (n,) of that blend; rms_diff_mm,
               max_diff_mm, mean_diff_mm (n,), n_nodes (n,) int64, fraction_beyond_2sigma (n,)
  /fields      w_meas_mm, w_sim_mm, diff_mm (= w_meas − w_sim), sigma_w_mm (n, ny, nx) float32, one frame a chunk
  /profiles    through the punch axis along X and Y: {x,y}/s_mm (M,), {x,y}/x_mm, y_mm (M,), {x,y}/measured_mm,
               simulated_mm, sigma_mm (n, M)
  /simulation  time_s, punch_displacement_mm, force_kN, peak_w_mm (S,) per simulation state (NaN where the
               simulation has none)
Pairing a result with a simulation (`pair_result`: the result's grid, frames, log and punch axis fed to
`science.compare.pair_with_measurement`) is here too, for the comparison and the dashboard's live preview.
Its exports (COMPARISON_EXPORTS: per-frame CSV, HDF5 copy, MAT, VTK, profile CSV) are written by
`fringelab.formats.exports.export_comparison`, the owner of every export format.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from fringelab.formats.atomic import commit_partial, partial_path
from fringelab.formats.hdf5 import SCHEMA_VERSION, ResultReader, json_text, open_read_only, require_schema, unit_dataset
from fringelab.formats.topography import TopographyResult
from fringelab.science import compare
from fringelab.science.fe_results import FEResults
from fringelab.science.fields import Grid

COMPARISON_SCHEMA = "fringelab.comparison"

FRAME_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("time_s", "s", "time of the frame (frames.csv)"),
    ("punch_displacement_mm", "mm", "punch displacement (frames.csv)"),
    ("force_kN", "kN", "punch force (frames.csv)"),
    ("peak_w_mm", "mm", "largest measured deflection where the peak was measured (NaN: not, see peak_measured)"),
    ("peak_measured", "1", "1: the frame's peak was measured, 0: only a lower bound (docs/method.md §8), NaN: unknown"),
    ("state_fraction", "1", "the simulation compared is state_lo + this fraction toward the next state"),
    ("sim_time_s", "s", "simulation time of the compared blend"),
    ("sim_punch_displacement_mm", "mm", "simulated punch displacement of the compared blend"),
    ("sim_force_kN", "kN", "simulated punch force of the compared blend"),
    ("sim_peak_w_mm", "mm", "largest simulated deflection on the grid"),
    ("rms_diff_mm", "mm", "RMS of w_meas − w_sim over the nodes with both"),
    ("max_diff_mm", "mm", "largest |w_meas − w_sim| over the nodes with both"),
    ("mean_diff_mm", "mm", "mean of w_meas − w_sim over the nodes with both"),
    ("fraction_beyond_2sigma", "1", "share of the compared nodes where |w_meas − w_sim| > 2 σ_w"),
)
FIELDS = (
    ("w_meas_mm", "measured deflection"),
    ("w_sim_mm", "simulated deflection sampled on the grid"),
    ("diff_mm", "w_meas − w_sim, NaN where either is missing"),
    ("sigma_w_mm", "σ of the measured deflection (edge noise, projector table, camera calibration)"),
)
PROFILE_AXES = ("x", "y")
SIMULATION_COLUMNS = (
    ("time_s", "s", "time of the state (in s)"),
    ("punch_displacement_mm", "mm", "punch displacement of the state"),
    ("force_kN", "kN", "punch force at the state"),
    ("peak_w_mm", "mm", "largest deflection of the model's surface at the state"),
)


def plate_frame_of(result: TopographyResult) -> compare.PlateFrame:
    """The measured plate of a result: the extent of its first frame's data and its punch axis (the summary's,
    else the clamp centre, else the data's centre)."""
    summary = result.summary()
    axis = None
    for prefix in ("punch_axis", "clamp_centre"):
        candidate = (float(summary.get(f"{prefix}_x_mm", np.nan)), float(summary.get(f"{prefix}_y_mm", np.nan)))
        if np.all(np.isfinite(candidate)):
            axis = candidate
            break
    try:
        return compare.plate_frame_of(result.grid, result.w_grid(0), axis_xy_mm=axis)
    except compare.ComparisonError as error:
        raise compare.ComparisonError(f"{result.path.name}: {error}") from None


def pair_result(
    result: TopographyResult,
    simulation: FEResults,
    *,
    mapping: compare.MappingSettings | None = None,
    align: str = "displacement",
) -> compare.Pairing:
    """A simulation paired with a result's frames: `science.compare.pair_with_measurement` fed with the result's
    grid, frames, test log and punch axis (what the comparison and the dashboard's live preview both use)."""
    return compare.pair_with_measurement(
        simulation, grid=result.grid, plate=plate_frame_of(result), measured_w=result.w_grid,
        frame_time_s=result.column("frames/time_s"), frame_punch_mm=result.column("frames/punch_displacement_mm"),
        frame_peak_mm=result.measured_peaks(), mapping=mapping, align=align,
    )  # fmt: skip


class ComparisonWriter:
    """Streams a comparison into HDF5, one frame at a time; `close()` moves it into place, an exception removes it."""

    def __init__(self, path: str | Path, *, grid: Grid, profile_s_mm: dict[str, np.ndarray],
                 profile_xy_mm: dict[str, tuple[np.ndarray, np.ndarray]], attrs: dict[str, Any]) -> None:  # fmt: skip
        self.path = Path(path)
        self._temp = partial_path(self.path)
        self._n = 0
        file = self._file = h5py.File(self._temp, "w")
        file.attrs["schema"] = COMPARISON_SCHEMA
        file.attrs["schema_version"] = SCHEMA_VERSION
        file.attrs["created_utc"] = datetime.now(UTC).isoformat(timespec="seconds")
        file.attrs["length_unit"] = "mm"
        for key, value in attrs.items():
            file.attrs[key] = value
        group = file.create_group("grid")
        unit_dataset(group, "x_mm", grid.x_mm, unit="mm", description="X of the grid nodes")
        unit_dataset(group, "y_mm", grid.y_mm, unit="mm", description="Y of the grid nodes")
        frames = file.create_group("frames")
        growing = {"maxshape": (None,), "chunks": (1024,)}
        unit_dataset(frames, "index", np.zeros(0, np.int64), unit="1", description="recording frame", **growing)
        unit_dataset(frames, "state_lo", np.zeros(0, np.int64), unit="1",
                     description="simulation state compared (−1: none, see reason)", **growing)  # fmt: skip
        unit_dataset(frames, "n_nodes", np.zeros(0, np.int64), unit="1", description="nodes compared", **growing)
        unit_dataset(frames, "reason", np.zeros(0, h5py.string_dtype()), unit="1",
                     description="why the frame was not compared (empty when it was)", **growing)  # fmt: skip
        for name, unit, description in FRAME_COLUMNS:
            unit_dataset(frames, name, np.zeros(0), unit=unit, description=description, **growing)
        ny, nx = grid.shape
        fields = file.create_group("fields")
        for name, description in FIELDS:
            unit_dataset(fields, name, np.zeros((0, ny, nx), np.float32), unit="mm", description=description,
                         maxshape=(None, ny, nx), chunks=(1, ny, nx), compression="gzip", compression_opts=1,
                         shuffle=True, fillvalue=np.nan)  # fmt: skip
        profiles = file.create_group("profiles")
        for axis in PROFILE_AXES:
            group = profiles.create_group(axis)
            s = profile_s_mm[axis]
            unit_dataset(group, "s_mm", s, unit="mm", description=f"distance along the line through the axis ({axis})")
            unit_dataset(group, "x_mm", profile_xy_mm[axis][0], unit="mm", description="X of the profile points")
            unit_dataset(group, "y_mm", profile_xy_mm[axis][1], unit="mm", description="Y of the profile points")
            for name, description in (("measured_mm", "measured w"), ("simulated_mm", "simulated w"),
                                      ("sigma_mm", "σ of the measured w")):  # fmt: skip
                unit_dataset(group, name, np.zeros((0, len(s))), unit="mm", description=description,
                             maxshape=(None, len(s)), chunks=(1, len(s)))  # fmt: skip

    def __enter__(self) -> ComparisonWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is not None:
            self.abort()

    @staticmethod
    def _append(dataset: h5py.Dataset, value: Any) -> None:
        n = dataset.shape[0]
        dataset.resize(n + 1, axis=0)
        dataset[n] = value

    def append(self, *, frame: int, state_lo: int, n_nodes: int, reason: str, columns: dict[str, float],
               fields: dict[str, np.ndarray], profiles: dict[str, dict[str, np.ndarray]]) -> None:  # fmt: skip
        """Add one frame: its row (every FRAME_COLUMNS name), its fields (FIELDS) and profiles (per axis:
        measured_mm, simulated_mm, sigma_mm)."""
        file = self._file
        self._append(file["frames/index"], frame)
        self._append(file["frames/state_lo"], state_lo)
        self._append(file["frames/n_nodes"], n_nodes)
        self._append(file["frames/reason"], reason)
        for name, _, _ in FRAME_COLUMNS:
            self._append(file[f"frames/{name}"], float(columns[name]))
        for name, _ in FIELDS:
            self._append(file[f"fields/{name}"], np.asarray(fields[name], np.float32))
        for axis in PROFILE_AXES:
            for name in ("measured_mm", "simulated_mm", "sigma_mm"):
                self._append(file[f"profiles/{axis}/{name}"], profiles[axis][name])
        self._n += 1

    def close(self, simulation: dict[str, np.ndarray]) -> Path:
        """Write the per-state simulation curves (SIMULATION_COLUMNS), close and move the file into place."""
        file = self._file
        group = file.create_group("simulation")
        for name, unit, description in SIMULATION_COLUMNS:
            unit_dataset(group, name, np.asarray(simulation[name], np.float64), unit=unit, description=description)
        file.attrs["n_frames"] = self._n
        file.close()
        return commit_partial(self._temp, self.path)

    def abort(self) -> None:
        try:
            self._file.close()
        finally:
            self._temp.unlink(missing_ok=True)


class ComparisonResult(ResultReader):
    """A comparison file opened read-only (a context manager); frames are read one at a time."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.file = open_read_only(self.path)
        try:
            require_schema(self.file, COMPARISON_SCHEMA, self.path)
            self.grid = Grid(x_mm=self.file["grid/x_mm"][()], y_mm=self.file["grid/y_mm"][()])
            self.frames = self.file["frames/index"][()]
        except (ValueError, KeyError) as error:
            self.file.close()
            raise ValueError(f"{self.path.name}: not a complete comparison file ({error})") from None

    @property
    def mapping(self) -> dict[str, Any]:
        return dict(json.loads(self.file.attrs["mapping_json"]))

    def column(self, name: str) -> np.ndarray:
        """A per-frame column ("rms_diff_mm", "state_lo", …) or a per-state one ("simulation/peak_w_mm")."""
        if name == "reason":
            return np.array([r.decode() if isinstance(r, bytes) else str(r) for r in self.file["frames/reason"][()]])
        key = name if "/" in name else f"frames/{name}"
        if key not in self.file and key.startswith("frames/"):  # a column newer than the file (peak_measured)
            return np.full(self.n_frames, np.nan)
        return self.file[key][()]

    def field(self, name: str, i: int) -> np.ndarray:
        """One of FIELDS (ny, nx) of frame position i."""
        return self.file[f"fields/{name}"][i].astype(np.float64)

    def position(self, frame: int) -> int:
        """Position of recording frame `frame` in this file; ValueError naming the frames held otherwise."""
        hits = np.flatnonzero(self.frames == frame)
        if len(hits) == 0:
            held = f"{int(self.frames[0])}…{int(self.frames[-1])}" if self.n_frames else "none"
            raise ValueError(f"frame {frame} is not in this comparison (its frames are {held})")
        return int(hits[0])

    def field_cut(self, name: str, i: int, *, budget: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Field `name` of frame position i block-averaged (NaN-aware) to at most `budget` nodes per side, for
        display: (x_mm, y_mm, values, step)."""
        import math

        from fringelab.formats.topography import _block_mean

        values = self.file[f"fields/{name}"][i].astype(np.float64)
        step = max(1, math.ceil(max(values.shape) / budget))
        x = _block_mean(self.grid.x_mm[None, :], step)[0]
        y = _block_mean(self.grid.y_mm[:, None], step)[:, 0]
        return x, y, _block_mean(values, step), step

    def profile(self, axis: str, i: int) -> dict[str, np.ndarray]:
        group = self.file[f"profiles/{axis}"]
        out = {name: group[name][()] for name in ("s_mm", "x_mm", "y_mm")}
        out.update({name: group[name][i] for name in ("measured_mm", "simulated_mm", "sigma_mm")})
        return out

    def frames_table(self) -> dict[str, Any]:
        """Every per-frame column as lists (for JSON)."""
        table: dict[str, Any] = {"frame": self.frames.tolist(), "state_lo": self.column("state_lo").tolist()}
        table.update(n_nodes=self.column("n_nodes").tolist(), reason=self.column("reason").tolist())
        for name, _, _ in FRAME_COLUMNS:
            table[name] = json.loads(json_text(self.column(name)))
        return table
