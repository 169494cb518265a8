"""Exports for other tools, the one owner of every export format: of a topography result (points CSV, grid NPZ,
MATLAB .mat, VTK time series, profile CSV) and of a comparison with a simulation (per-frame CSV, HDF5 copy, .mat,
VTK time series, profile CSV with the points beyond 2σ marked).

Every topography export takes an optional frame range (`frames`: first and last recording frame number, both
included) and holds the result grid itself (never a display grid); the profile CSV takes any number of lines,
labelled. The VTK series of both are written by one writer (`write_surface_series`)."""

from __future__ import annotations

import io
import shutil
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextvars import ContextVar
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np

from fringelab.formats import (  # noqa: F401  (declared once, there)
    COMPARISON_EXPORT_FILES,
    COMPARISON_EXPORTS,
    EXPORT_FILES,
    EXPORT_FORMATS,
    ExportFormat,
)
from fringelab.formats.atomic import atomic_path
from fringelab.formats.comparison import FIELDS, FRAME_COLUMNS, SIMULATION_COLUMNS, ComparisonResult
from fringelab.formats.topography import TopographyResult
from fringelab.science.fields import Grid, line_profile

Line = tuple[float, float, float, float]  # X0, Y0, X1, Y1 in mm
FrameRange = tuple[int, int]  # first and last recording frame number, both included
LINE_LABELS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ"  # the viewer's names of section lines, in the order drawn


def frame_positions(result: TopographyResult, frames: FrameRange | None) -> np.ndarray:
    """Positions (indices into the result's frames) of the frames in `frames`, in order; ValueError when none is."""
    if frames is None:
        return np.arange(result.n_frames)
    first, last = frames
    if first > last:
        raise ValueError(f"frames: the first frame {first} comes after the last {last}")
    chosen = np.flatnonzero((result.frames >= first) & (result.frames <= last))
    if not len(chosen):
        shown = f"{int(result.frames[0])}…{int(result.frames[-1])}" if result.n_frames else "none"
        raise ValueError(f"frames: no frame of the result lies in {first}…{last} (its frames: {shown})")
    return chosen


# progress(done, total, stage) of the export running in this context (export_result sets it; the CLI draws a bar)
_PROGRESS: ContextVar[Callable[[int, int, str], None] | None] = ContextVar("export_progress", default=None)


def _tick(done: int, total: int, stage: str) -> None:
    progress = _PROGRESS.get()
    if progress is not None:
        progress(done, total, stage)


SPREADSHEET_MAX_ROWS = 1_048_576  # Excel and LibreOffice Calc: rows of one sheet, the header row included


class SpreadsheetLimitWarning(UserWarning):
    """A CSV export has more rows than a spreadsheet shows; the file is complete, a spreadsheet cuts it."""


def export_points_csv(
    result: TopographyResult, path: str | Path, *, frames: FrameRange | None = None, per_frame: bool = False
) -> Path:
    """CSV of every 3-D point: frame,x_mm,y_mm,z_mm,w_mm,sigma_w_mm (w = z − z_flat_mm, σ_w its standard
    deviation, empty where unknown; written frame by frame).

    per_frame: write one CSV per frame into the folder `path` (frame_<n>.csv, same columns) instead, so each opens
    in a spreadsheet. A single file of more than SPREADSHEET_MAX_ROWS rows is still written whole (scripts read
    it), with a SpreadsheetLimitWarning that says a spreadsheet will cut it and how to get one file per frame.
    """
    path = Path(path)
    positions = frame_positions(result, frames)
    if per_frame:
        path.mkdir(parents=True, exist_ok=True)
        for k, i in enumerate(positions):
            with atomic_path(path / f"frame_{int(result.frames[i]):06d}.csv") as temp, open(temp, "w") as out:
                _write_points(out, result, [i])
            _tick(k + 1, len(positions), "points")
        return path
    rows = 1 + sum(int(result.offsets[i + 1] - result.offsets[i]) for i in positions)
    with atomic_path(path) as temp, open(temp, "w", newline="") as out:
        _write_points(out, result, list(positions), progress=True)
    if rows > SPREADSHEET_MAX_ROWS:
        warnings.warn(
            f"{path.name}: {rows} rows, more than the {SPREADSHEET_MAX_ROWS} a spreadsheet shows (it will cut the "
            "file); export one CSV per frame (--per-frame) to open them in a spreadsheet",
            SpreadsheetLimitWarning,
            stacklevel=2,
        )
    return path


def _write_points(out: Any, result: TopographyResult, positions: list[int], *, progress: bool = False) -> None:
    out.write("frame,x_mm,y_mm,z_mm,w_mm,sigma_w_mm\n")
    for k, i in enumerate(positions):
        points = result.points(i)
        sigma = result.sigma_points(i)
        sigma = np.full(len(points), np.nan) if sigma is None else sigma
        block = np.column_stack([np.full(len(points), result.frames[i]), points, points[:, 2] - result.z_flat_mm,
                                 sigma])  # fmt: skip
        text = io.StringIO()
        np.savetxt(text, block, fmt=["%d", "%.4f", "%.4f", "%.4f", "%.4f", "%.4f"], delimiter=",")
        out.write(text.getvalue().replace("nan", ""))  # unknown σ: an empty cell
        if progress:
            _tick(k + 1, len(positions), "points")


def read_points_csv(path: str | Path) -> np.ndarray:
    """The rows (P, 6) frame, x_mm, y_mm, z_mm, w_mm, sigma_w_mm of a points CSV (NaN where a cell is empty)."""
    return np.genfromtxt(path, delimiter=",", skip_header=1, ndmin=2, filling_values=np.nan)


def _grid_stacks(result: TopographyResult, positions: np.ndarray, *names: str) -> dict[str, np.ndarray]:
    """The stacks (frames, ny, nx) float32 of "z_mm", "w_mm" (z − z_flat) and "sigma_w_mm" (NaN: unknown) asked
    for, read frame by frame (progress per frame)."""
    stacks = {name: np.empty((len(positions), *result.grid.shape), np.float32) for name in names}
    for k, i in enumerate(positions):
        z = result.file["grid/z_mm"][i]
        for name, stack in stacks.items():
            if name == "sigma_w_mm":
                sigma = result.sigma_grid(i)
                stack[k] = np.nan if sigma is None else sigma
            else:
                stack[k] = z - np.float32(result.z_flat_mm) if name == "w_mm" else z
        _tick(k + 1, len(positions), "grids")
    return stacks


def export_grid_npz(result: TopographyResult, path: str | Path, *, frames: FrameRange | None = None) -> Path:
    """NPZ with x_mm (nx), y_mm (ny), z_mm, w_mm (= z − z_flat_mm) and sigma_w_mm (σ of w; NaN: unknown)
    (frames, ny, nx) NaN outside the data, frames (recording indices), and z_flat_mm. Holds the grid stacks in
    memory (as `numpy.load` will)."""
    path = Path(path)
    positions = frame_positions(result, frames)
    arrays: dict[str, Any] = {
        "x_mm": result.grid.x_mm,
        "y_mm": result.grid.y_mm,
        **_grid_stacks(result, positions, "z_mm", "w_mm", "sigma_w_mm"),
        "frames": result.frames[positions],
        "z_flat_mm": np.float64(result.z_flat_mm),
    }
    with atomic_path(path) as temp, open(temp, "wb") as out:
        np.savez_compressed(out, **arrays)
    return path


MAT_V5_MAX_VARIABLE_BYTES = 2**31 - 1  # MATLAB's limit on one variable of a v5/v7 MAT-file (2 GB)
MatVersion = Literal["auto", "5", "7.3"]
_MAT_UNITS = {
    "length": "mm",
    "time": "s",
    "force": "kN",
    "frame": "X, Y in the plate plane, +Z toward the camera; w = z - z_flat_mm",
}


def _mat_variables(result: TopographyResult, positions: np.ndarray) -> dict[str, Any]:
    """The small variables of the MAT export (the grid stacks and the points are written separately).

    peak_w_mm is NaN where the frame's peak was not measured (docs/method.md §8): there peak_w_lower_bound_mm holds
    the largest measured w; peak_measured is 1, 0 or NaN (unknown, a result written before the flag)."""
    peaks, measured = result.column("peak/w_mm")[positions], result.peak_measured()[positions]
    return {
        "x_mm": result.grid.x_mm,
        "y_mm": result.grid.y_mm,
        "frames": result.frames[positions].astype(np.float64),
        "camera_frames": result.camera_frames[positions].astype(np.float64),
        "time_s": result.column("frames/time_s")[positions],
        "punch_displacement_mm": result.column("frames/punch_displacement_mm")[positions],
        "force_kN": result.column("frames/force_kN")[positions],
        "peak_w_mm": np.where(measured == 0.0, np.nan, peaks),
        "peak_measured": measured,
        "peak_w_lower_bound_mm": np.where(measured == 0.0, peaks, np.nan),
        "z_flat_mm": result.z_flat_mm,
    }


def export_mat(
    result: TopographyResult,
    path: str | Path,
    *,
    frames: FrameRange | None = None,
    version: MatVersion = "auto",
    v5_max_variable_bytes: int | None = None,
) -> Path:
    """MATLAB .mat: grid x_mm, y_mm, w_mm (the deflection), sigma_w_mm (its σ; NaN: unknown) and z_mm (frames ×
    ny × nx, single), frames, camera_frames, time_s, punch_displacement_mm, force_kN, peak_w_mm (NaN where not
    measured), peak_measured, peak_w_lower_bound_mm, z_flat_mm, points (P × 6 single: frame, x_mm, y_mm, z_mm,
    w_mm, sigma_w_mm), units.

    The grids and points are single precision: the result stores them as float32, so double would add bytes, not
    digits. version "auto" writes v5 (scipy.io.savemat, compressed) while every variable fits v5's 2 GB per
    variable (a 1024² grid passes it after ~500 frames), else v7.3 (HDF5, written frame by frame; MATLAB `load`,
    h5py, or `mat73` in Python read it).
    """
    path = Path(path)
    positions = frame_positions(result, frames)
    ny, nx = result.grid.shape
    n_points = sum(int(result.offsets[i + 1] - result.offsets[i]) for i in positions)
    largest = max(len(positions) * ny * nx * 4, n_points * POINT_COLUMNS * 4)
    limit = MAT_V5_MAX_VARIABLE_BYTES if v5_max_variable_bytes is None else v5_max_variable_bytes
    if version == "7.3" or (version == "auto" and largest > limit):
        return _export_mat_v73(result, path, positions, n_points)
    from scipy.io import savemat

    points = [_point_rows(result, i) for i in positions]
    data = {
        **_mat_variables(result, positions),
        **_grid_stacks(result, positions, "w_mm", "sigma_w_mm", "z_mm"),
        "points": np.vstack(points) if points else np.zeros((0, POINT_COLUMNS), np.float32),
        "units": _MAT_UNITS,
    }
    with atomic_path(path) as temp, open(temp, "wb") as out:
        savemat(out, data, do_compression=True)
    return path


POINT_COLUMNS = 6  # frame, x_mm, y_mm, z_mm, w_mm, sigma_w_mm


def _point_rows(result: TopographyResult, i: int) -> np.ndarray:
    """Frame position i's points as rows (N, POINT_COLUMNS) float32 of the MAT export."""
    points = result.points(i)
    sigma = result.sigma_points(i)
    sigma = np.full(len(points), np.nan) if sigma is None else sigma
    columns = [np.full(len(points), result.frames[i]), points, points[:, 2] - result.z_flat_mm, sigma]
    return np.column_stack(columns).astype(np.float32)


def _export_mat_v73(result: TopographyResult, path: Path, positions: np.ndarray, n_points: int) -> Path:
    """A MATLAB v7.3 MAT-file: HDF5 with a 512-byte user block holding the MAT header, one dataset per variable
    with its MATLAB_class, dimensions reversed (HDF5 is row-major, MATLAB column-major), vectors as 1 × n."""
    import h5py

    ny, nx = result.grid.shape
    n = len(positions)
    with atomic_path(path) as temp:
        with h5py.File(temp, "w", userblock_size=512) as file:
            for name, value in _mat_variables(result, positions).items():
                array = np.asarray(value, dtype=np.float64)
                array = array.reshape(1, 1) if array.ndim == 0 else array.reshape(-1, 1)  # MATLAB 1 × n
                _mat_dataset(file, name, array, "double")
            stacks = {}
            for name in ("w_mm", "sigma_w_mm", "z_mm"):
                stacks[name] = file.create_dataset(name, shape=(nx, ny, n), dtype=np.float32,
                                                   chunks=(nx, ny, 1) if n else None, compression="gzip",
                                                   compression_opts=1, fillvalue=np.nan)  # fmt: skip
                stacks[name].attrs["MATLAB_class"] = np.bytes_("single")
            points = file.create_dataset("points", shape=(POINT_COLUMNS, n_points), dtype=np.float32,
                                         chunks=(POINT_COLUMNS, min(max(n_points, 1), 1 << 16)), compression="gzip",
                                         compression_opts=1)  # fmt: skip
            points.attrs["MATLAB_class"] = np.bytes_("single")
            start = 0
            for k, i in enumerate(positions):
                z_frame = result.file["grid/z_mm"][i]
                sigma = result.sigma_grid(i)
                stacks["z_mm"][:, :, k] = z_frame.T
                stacks["w_mm"][:, :, k] = (z_frame - np.float32(result.z_flat_mm)).T
                if sigma is not None:
                    stacks["sigma_w_mm"][:, :, k] = sigma.astype(np.float32).T
                rows = _point_rows(result, i)
                points[:, start : start + len(rows)] = rows.T
                start += len(rows)
                _tick(k + 1, n, "frames")
            units = file.create_group("units")
            units.attrs["MATLAB_class"] = np.bytes_("struct")
            units.attrs.create(
                "MATLAB_fields",
                np.array([np.array(list(key), dtype="S1") for key in _MAT_UNITS], dtype=object),
                dtype=h5py.vlen_dtype(np.dtype("S1")),
            )
            for key, text in _MAT_UNITS.items():
                chars = np.frombuffer(text.encode("utf-16-le"), dtype="<u2").reshape(-1, 1)  # MATLAB 1 × len
                dataset = _mat_dataset(units, key, chars, "char")
                dataset.attrs["MATLAB_int_decode"] = np.int32(2)
        header = f"MATLAB 7.3 MAT-file, Platform: fringelab, Created on: {time.ctime()} HDF5 schema 1.00 ."
        with open(temp, "r+b") as out:
            out.write(header.encode("ascii")[:116].ljust(116) + bytes(8) + b"\x00\x02IM")
    return path


def _mat_dataset(group: Any, name: str, array: np.ndarray, matlab_class: str) -> Any:
    dataset = group.create_dataset(name, data=array)
    dataset.attrs["MATLAB_class"] = np.bytes_(matlab_class)
    return dataset


def write_surface_series(
    path: str | Path,
    grid: Grid,
    surfaces: Iterable[tuple[int, float, np.ndarray, dict[str, np.ndarray]]],
    *,
    count: int | None = None,
) -> Path:
    """A ParaView time series of gridded surfaces: `path` (.pvd) listing one .vtu per frame in the folder
    `<stem>_vtu` beside it (the one writer of the VTK exports).

    surfaces: (frame, time, z (ny, nx), point data {name: (ny, nx)}) per frame, in order; each .vtu is the surface
    at height z as quads between nodes that all have a z, with the point data at those nodes; the .pvd gives
    each frame its time. count: the number of surfaces, for progress.
    """
    import meshio

    path = Path(path)
    folder = path.parent / f"{path.stem}_vtu"
    folder.mkdir(parents=True, exist_ok=True)
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    ny, nx = grid.shape
    node = np.arange(ny * nx).reshape(ny, nx)
    quads_all = np.column_stack(
        [node[:-1, :-1].ravel(), node[:-1, 1:].ravel(), node[1:, 1:].ravel(), node[1:, :-1].ravel()]
    )
    entries = []
    for k, (frame, time_s, z_grid, data) in enumerate(surfaces):
        z = z_grid.ravel()
        quads = quads_all[np.all(np.isfinite(z)[quads_all], axis=1)]
        used = np.unique(quads)
        renumber = np.full(ny * nx, -1)
        renumber[used] = np.arange(len(used))
        points = np.column_stack([gx.ravel()[used], gy.ravel()[used], z[used]])
        point_data = {name: values.ravel()[used] for name, values in data.items()}
        name = f"frame_{int(frame):06d}.vtu"
        with atomic_path(folder / name) as temp:
            meshio.write(temp, meshio.Mesh(points, [("quad", renumber[quads])], point_data=point_data),
                         file_format="vtu", binary=True)  # fmt: skip
        entries.append(f'    <DataSet timestep="{float(time_s)!r}" part="0" file="{folder.name}/{name}"/>')
        _tick(k + 1, count or k + 1, "surfaces")
    pvd = (
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
        "  <Collection>\n" + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n"
    )
    with atomic_path(path) as temp:
        temp.write_text(pvd)
    return path


def export_vtk(result: TopographyResult, path: str | Path, *, frames: FrameRange | None = None) -> Path:
    """A ParaView time series (`write_surface_series`): per frame the gridded surface at its measured height, with
    point data z_mm, w_mm and sigma_w_mm (σ of w; NaN: unknown); each frame at its time (time_s where logged,
    else the frame index)."""
    times = result.column("frames/time_s")
    positions = frame_positions(result, frames)

    def surfaces() -> Iterator[tuple[int, float, np.ndarray, dict[str, np.ndarray]]]:
        for i in positions:
            frame = int(result.frames[i])
            z = result.z_grid(i)
            time_s = float(times[i]) if np.isfinite(times[i]) else float(frame)
            sigma = result.sigma_grid(i)
            sigma = np.full(z.shape, np.nan) if sigma is None else sigma
            yield frame, time_s, z, {"z_mm": z, "w_mm": z - result.z_flat_mm, "sigma_w_mm": sigma}

    return write_surface_series(path, result.grid, surfaces(), count=len(positions))


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
    result: TopographyResult,
    path: str | Path,
    *,
    line: Line | None = None,
    lines: Sequence[Line] | None = None,
    frames: FrameRange | None = None,
) -> Path:
    """CSV of section profiles along lines X0,Y0 → X1,Y1 (mm) for every frame, sampled on the result grid:
    line,frame,time_s,s_mm,x_mm,y_mm,z_mm,w_mm,sigma_w_mm (s along the line; NaN where the grid has no data or
    σ is unknown). `lines` are
    labelled A, B, … in their order (as the viewer names them); `line` is one line labelled A; neither: a line
    along X through the punch axis."""
    path = Path(path)
    if line is not None and lines:
        raise ValueError("give `line` or `lines`, not both")
    chosen = list(lines) if lines else [default_profile_line(result) if line is None else line]
    if len(chosen) > len(LINE_LABELS):
        raise ValueError(f"lines: at most {len(LINE_LABELS)}, got {len(chosen)}")
    positions = frame_positions(result, frames)
    times = result.column("frames/time_s")
    with atomic_path(path) as temp, open(temp, "w", newline="") as out:
        out.write("line,frame,time_s,s_mm,x_mm,y_mm,z_mm,w_mm,sigma_w_mm\n")
        done, total = 0, len(chosen) * len(positions)
        for label, (x0, y0, x1, y1) in zip(LINE_LABELS, chosen, strict=False):
            for i in positions:
                done += 1
                _tick(done, total, "profiles")
                profile = line_profile(result.z_grid(i), result.grid, (x0, y0), (x1, y1))
                sigma_grid = result.sigma_grid(i)
                m = len(profile.s_mm)
                sigma = (
                    np.full(m, np.nan)
                    if sigma_grid is None
                    else line_profile(sigma_grid, result.grid, (x0, y0), (x1, y1)).values
                )
                block = np.column_stack(
                    [
                        np.full(m, result.frames[i]),
                        np.full(m, times[i]),
                        profile.s_mm,
                        profile.x_mm,
                        profile.y_mm,
                        profile.values,
                        profile.values - result.z_flat_mm,
                        sigma,
                    ]
                )
                for row in block:
                    out.write(
                        f"{label},{int(row[0])},{row[1]:.6g},{row[2]:.4f},{row[3]:.4f},{row[4]:.4f},"
                        f"{row[5]:.4f},{row[6]:.4f},{row[7]:.4f}\n"
                    )
    return path


def export_result(
    result_path: str | Path,
    fmt: str,
    out_path: str | Path,
    *,
    line: Line | None = None,
    lines: Sequence[Line] | None = None,
    frames: FrameRange | None = None,
    per_frame: bool = False,
    mat_version: MatVersion = "auto",
    progress: Callable[[int, int, str], None] | None = None,
) -> Path:
    """Export a topography result in one of EXPORT_FORMATS; `line`/`lines` (X0, Y0, X1, Y1 mm) for profile-csv
    only; `frames` (first, last recording frame number) for every format; `per_frame` (one CSV per frame into the
    folder out_path) for points-csv only; `mat_version` for mat only; progress(done, total, stage) per frame."""
    if fmt not in EXPORT_FORMATS:
        raise ValueError(f"format: expected one of {EXPORT_FORMATS}, got {fmt!r}")
    if (line is not None or lines) and fmt != "profile-csv":
        raise ValueError("a line is only used by the profile-csv format")
    if per_frame and fmt != "points-csv":
        raise ValueError("per_frame is only used by the points-csv format")
    if mat_version not in get_args(MatVersion):
        raise ValueError(f"mat_version: expected one of {get_args(MatVersion)}, got {mat_version!r}")
    token = _PROGRESS.set(progress)
    try:
        with TopographyResult(result_path) as result:
            if fmt == "points-csv":
                return export_points_csv(result, out_path, frames=frames, per_frame=per_frame)
            if fmt == "grid-npz":
                return export_grid_npz(result, out_path, frames=frames)
            if fmt == "mat":
                return export_mat(result, out_path, frames=frames, version=mat_version)
            if fmt == "vtk":
                return export_vtk(result, out_path, frames=frames)
            return export_profile_csv(result, out_path, line=line, lines=lines, frames=frames)
    finally:
        _PROGRESS.reset(token)


# ---- a comparison with a simulation (formats.comparison) ----------------------------------------------------------


def export_comparison(comparison: str | Path, fmt: str, out: str | Path, *, line: Line | None = None) -> Path:
    """Write an export of a comparison file: "csv" (per-frame table), "hdf5" (a copy), "mat", "vtk" (.pvd), or
    "profile-csv" along `line` (X0, Y0, X1, Y1 in mm; default along X through the punch axis)."""
    if fmt not in COMPARISON_EXPORTS:
        raise ValueError(f"format: expected one of {COMPARISON_EXPORTS}, got {fmt!r}")
    if line is not None and fmt != "profile-csv":
        raise ValueError("line is only used by the profile-csv format")
    out = Path(out)
    if fmt == "hdf5":
        with ComparisonResult(comparison):
            pass  # refuse to copy what is not a comparison file
        with atomic_path(out) as temp:
            shutil.copyfile(comparison, temp)
        return out
    with ComparisonResult(comparison) as result:
        if fmt == "csv":
            names = ["frame", "state_lo", "n_nodes"] + [name for name, _, _ in FRAME_COLUMNS]
            rows = [result.frames, result.column("state_lo"), result.column("n_nodes")]
            rows += [result.column(name) for name, _, _ in FRAME_COLUMNS]
            reasons = result.column("reason")
            with atomic_path(out) as temp, open(temp, "w", newline="") as handle:
                handle.write(",".join(names) + ",reason\n")
                for i in range(result.n_frames):
                    cells = [f"{rows[c][i]:.6g}" if np.isfinite(rows[c][i]) else "" for c in range(len(names))]
                    handle.write(",".join(cells) + "," + reasons[i].replace(",", ";") + "\n")
            return out
        if fmt == "profile-csv":
            return _export_comparison_profile(result, out, line)
        if fmt == "mat":
            from scipy.io import savemat

            data: dict[str, Any] = {"x_mm": result.grid.x_mm, "y_mm": result.grid.y_mm,
                                    "frames": result.frames.astype(np.float64)}  # fmt: skip
            for name, _, _ in FRAME_COLUMNS:
                data[name] = result.column(name)
            data["state_lo"] = result.column("state_lo").astype(np.float64)
            for name, _ in FIELDS:
                data[name] = result.file[f"fields/{name}"][()].astype(np.float64)
            for name, _, _ in SIMULATION_COLUMNS:
                data[f"sim_state_{name}"] = result.column(f"simulation/{name}")
            data["mapping_json"] = result.file.attrs["mapping_json"]
            with atomic_path(out) as temp, open(temp, "wb") as handle:
                savemat(handle, data, do_compression=True)
            return out
        return _export_comparison_vtk(result, out)


def _export_comparison_profile(result: ComparisonResult, path: Path, line: Line | None) -> Path:
    """CSV frame,s_mm,x_mm,y_mm,w_meas_mm,w_sim_mm,diff_mm,sigma_w_mm,beyond_2sigma along a line, every frame
    (empty cells where there is no value; beyond_2sigma is 1 where |diff| > 2σ, 0 where not, empty unknown)."""
    grid = result.grid
    if line is None:  # the stored profile along X: through the punch axis
        through = float(result.file["profiles/x/y_mm"][0])
        line = (float(grid.x_mm[0]), through, float(grid.x_mm[-1]), through)
    names = ("w_meas_mm", "w_sim_mm", "diff_mm", "sigma_w_mm")
    with atomic_path(path) as temp, open(temp, "w", newline="") as handle:
        handle.write("frame,s_mm,x_mm,y_mm," + ",".join(names) + ",beyond_2sigma\n")
        for i, frame in enumerate(result.frames):
            stack = np.stack([result.field(name, i) for name in names])
            profile = line_profile(stack, grid, line[:2], line[2:])
            meas, sim, diff, sigma = profile.values
            with np.errstate(invalid="ignore"):
                beyond = np.where(np.isfinite(diff) & np.isfinite(sigma), np.abs(diff) > 2 * sigma, np.nan)
            for j in range(len(profile.s_mm)):
                cells = [profile.s_mm[j], profile.x_mm[j], profile.y_mm[j], meas[j], sim[j], diff[j], sigma[j]]
                text = ",".join(f"{v:.5f}" if np.isfinite(v) else "" for v in cells)
                flag = "" if np.isnan(beyond[j]) else str(int(beyond[j]))
                handle.write(f"{int(frame)},{text},{flag}\n")
    return path


def _export_comparison_vtk(result: ComparisonResult, path: Path) -> Path:
    """ParaView time series (`write_surface_series`): per frame the measured surface carrying w_meas_mm, w_sim_mm,
    diff_mm and sigma_w_mm."""
    times = result.column("time_s")

    def surfaces() -> Iterator[tuple[int, float, np.ndarray, dict[str, np.ndarray]]]:
        for i, frame in enumerate(result.frames):
            data = {name: result.field(name, i) for name, _ in FIELDS}
            time_s = float(times[i]) if np.isfinite(times[i]) else float(frame)
            yield int(frame), time_s, data["w_meas_mm"], data

    return write_surface_series(path, result.grid, surfaces(), count=result.n_frames)
