"""Exports of a topography result for other tools: points CSV, grid NPZ, MATLAB .mat, VTK time series, profile CSV.

Every export takes an optional frame range (`frames`: first and last recording frame number, both included) and
holds the result grid itself (never a display grid); the profile CSV takes any number of lines, labelled."""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from contextvars import ContextVar
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np

from fringelab.formats import EXPORT_FILES, EXPORT_FORMATS, ExportFormat  # noqa: F401  (declared once, there)
from fringelab.formats.atomic import atomic_path
from fringelab.formats.topography import TopographyResult
from fringelab.science.fields import line_profile

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
    """CSV of every 3-D point: frame,x_mm,y_mm,z_mm (written frame by frame).

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
    out.write("frame,x_mm,y_mm,z_mm\n")
    for k, i in enumerate(positions):
        points = result.points(i)
        block = np.column_stack([np.full(len(points), result.frames[i]), points])
        np.savetxt(out, block, fmt=["%d", "%.4f", "%.4f", "%.4f"], delimiter=",")
        if progress:
            _tick(k + 1, len(positions), "points")


def read_points_csv(path: str | Path) -> np.ndarray:
    """The rows (P, 4) frame, x_mm, y_mm, z_mm of a points CSV."""
    return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def _grid_stack(result: TopographyResult, positions: np.ndarray) -> np.ndarray:
    def frame(k: int, i: int) -> np.ndarray:
        _tick(k + 1, len(positions), "grids")
        return result.file["grid/z_mm"][i]

    return (
        np.stack([frame(k, i) for k, i in enumerate(positions)])
        if len(positions)
        else np.zeros((0, *result.grid.shape), np.float32)
    )


def export_grid_npz(result: TopographyResult, path: str | Path, *, frames: FrameRange | None = None) -> Path:
    """NPZ with x_mm (nx), y_mm (ny), z_mm (frames, ny, nx) NaN outside the data, frames (recording indices),
    and z_flat_mm (w = z − z_flat_mm). Holds the whole grid stack in memory (as `numpy.load` will)."""
    path = Path(path)
    positions = frame_positions(result, frames)
    with atomic_path(path) as temp, open(temp, "wb") as out:
        np.savez_compressed(
            out,
            x_mm=result.grid.x_mm,
            y_mm=result.grid.y_mm,
            z_mm=_grid_stack(result, positions),
            frames=result.frames[positions],
            z_flat_mm=np.float64(result.z_flat_mm),
        )
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
    """The small variables of the MAT export (the grid stack and the points are written separately)."""
    return {
        "x_mm": result.grid.x_mm,
        "y_mm": result.grid.y_mm,
        "frames": result.frames[positions].astype(np.float64),
        "camera_frames": result.camera_frames[positions].astype(np.float64),
        "time_s": result.column("frames/time_s")[positions],
        "punch_displacement_mm": result.column("frames/punch_displacement_mm")[positions],
        "force_kN": result.column("frames/force_kN")[positions],
        "peak_w_mm": result.column("peak/w_mm")[positions],
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
    """MATLAB .mat: grid x_mm, y_mm, z_mm (frames × ny × nx, single), frames, camera_frames, time_s,
    punch_displacement_mm, force_kN, peak_w_mm, z_flat_mm, points (P × 4 single: frame, x_mm, y_mm, z_mm), units.

    z_mm and points are single precision: the result stores them as float32, so double would add bytes, not
    digits. version "auto" writes v5 (scipy.io.savemat, compressed) while every variable fits v5's 2 GB per
    variable (a 1024² grid passes it after ~500 frames), else v7.3 (HDF5, written frame by frame; MATLAB `load`,
    h5py, or `mat73` in Python read it).
    """
    path = Path(path)
    positions = frame_positions(result, frames)
    ny, nx = result.grid.shape
    n_points = sum(int(result.offsets[i + 1] - result.offsets[i]) for i in positions)
    largest = max(len(positions) * ny * nx * 4, n_points * 4 * 4)
    limit = MAT_V5_MAX_VARIABLE_BYTES if v5_max_variable_bytes is None else v5_max_variable_bytes
    if version == "7.3" or (version == "auto" and largest > limit):
        return _export_mat_v73(result, path, positions, n_points)
    from scipy.io import savemat

    points = [
        np.column_stack([np.full(len(p), result.frames[i]), p]).astype(np.float32)
        for i, p in ((i, result.points(i)) for i in positions)
    ]
    data = {
        **_mat_variables(result, positions),
        "z_mm": _grid_stack(result, positions).astype(np.float32),
        "points": np.vstack(points) if points else np.zeros((0, 4), np.float32),
        "units": _MAT_UNITS,
    }
    with atomic_path(path) as temp, open(temp, "wb") as out:
        savemat(out, data, do_compression=True)
    return path


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
            z = file.create_dataset("z_mm", shape=(nx, ny, n), dtype=np.float32, chunks=(nx, ny, 1) if n else None,
                                    compression="gzip", compression_opts=1, fillvalue=np.nan)  # fmt: skip
            z.attrs["MATLAB_class"] = np.bytes_("single")
            points = file.create_dataset("points", shape=(4, n_points), dtype=np.float32,
                                         chunks=(4, min(max(n_points, 1), 1 << 16)), compression="gzip",
                                         compression_opts=1)  # fmt: skip
            points.attrs["MATLAB_class"] = np.bytes_("single")
            start = 0
            for k, i in enumerate(positions):
                z[:, :, k] = result.file["grid/z_mm"][i].T
                block = result.points(i)
                rows = np.column_stack([np.full(len(block), result.frames[i]), block]).astype(np.float32)
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


def export_vtk(result: TopographyResult, path: str | Path, *, frames: FrameRange | None = None) -> Path:
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
    positions = frame_positions(result, frames)
    for k, i in enumerate(positions):
        frame = result.frames[i]
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
        _tick(k + 1, len(positions), "surfaces")
    pvd = (
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
        "  <Collection>\n" + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n"
    )
    with atomic_path(path) as temp:
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
    result: TopographyResult,
    path: str | Path,
    *,
    line: Line | None = None,
    lines: Sequence[Line] | None = None,
    frames: FrameRange | None = None,
) -> Path:
    """CSV of section profiles along lines X0,Y0 → X1,Y1 (mm) for every frame, sampled on the result grid:
    line,frame,time_s,s_mm,x_mm,y_mm,z_mm,w_mm (s along the line; NaN where the grid has no data). `lines` are
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
        out.write("line,frame,time_s,s_mm,x_mm,y_mm,z_mm,w_mm\n")
        done, total = 0, len(chosen) * len(positions)
        for label, (x0, y0, x1, y1) in zip(LINE_LABELS, chosen, strict=False):
            for i in positions:
                done += 1
                _tick(done, total, "profiles")
                profile = line_profile(result.z_grid(i), result.grid, (x0, y0), (x1, y1))
                m = len(profile.s_mm)
                block = np.column_stack(
                    [
                        np.full(m, result.frames[i]),
                        np.full(m, times[i]),
                        profile.s_mm,
                        profile.x_mm,
                        profile.y_mm,
                        profile.values,
                        profile.values - result.z_flat_mm,
                    ]
                )
                for row in block:
                    out.write(
                        f"{label},{int(row[0])},{row[1]:.6g},{row[2]:.4f},{row[3]:.4f},{row[4]:.4f},"
                        f"{row[5]:.4f},{row[6]:.4f}\n"
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
