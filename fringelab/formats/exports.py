"""Exports of a topography result for other tools: points CSV, grid NPZ, MATLAB .mat, VTK time series, profile CSV.

Every export takes an optional frame range (`frames`: first and last recording frame number, both included) and
holds the result grid itself (never a display grid); the profile CSV takes any number of lines, labelled."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fringelab.formats import EXPORT_FILES, EXPORT_FORMATS, ExportFormat  # noqa: F401  (declared once, there)
from fringelab.formats.atomic import atomic_path
from fringelab.formats.topography import TopographyResult
from fringelab.science.fields import line_profile

if TYPE_CHECKING:
    pass


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


def export_points_csv(result: TopographyResult, path: str | Path, *, frames: FrameRange | None = None) -> Path:
    """CSV of every 3-D point: frame,x_mm,y_mm,z_mm (written frame by frame)."""
    path = Path(path)
    positions = frame_positions(result, frames)
    with atomic_path(path) as temp, open(temp, "w", newline="") as out:
        out.write("frame,x_mm,y_mm,z_mm\n")
        for i in positions:
            frame = result.frames[i]
            points = result.points(i)
            block = np.column_stack([np.full(len(points), frame), points])
            np.savetxt(out, block, fmt=["%d", "%.4f", "%.4f", "%.4f"], delimiter=",")
    return path


def read_points_csv(path: str | Path) -> np.ndarray:
    """The rows (P, 4) frame, x_mm, y_mm, z_mm of a points CSV."""
    return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def _grid_stack(result: TopographyResult, positions: np.ndarray) -> np.ndarray:
    return (
        np.stack([result.file["grid/z_mm"][i] for i in positions])
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


def export_mat(result: TopographyResult, path: str | Path, *, frames: FrameRange | None = None) -> Path:
    """MATLAB .mat (scipy.io.savemat): grid x_mm, y_mm, z_mm (frames × ny × nx), frames, time_s,
    punch_displacement_mm, force_kN, peak_w_mm, z_flat_mm, points (P × 4: frame, x_mm, y_mm, z_mm), units."""
    from scipy.io import savemat

    path = Path(path)
    positions = frame_positions(result, frames)
    points = [
        np.column_stack([np.full(len(p), result.frames[i]), p]) for i, p in ((i, result.points(i)) for i in positions)
    ]
    data = {
        "x_mm": result.grid.x_mm,
        "y_mm": result.grid.y_mm,
        "z_mm": _grid_stack(result, positions).astype(np.float64),
        "frames": result.frames[positions].astype(np.float64),
        "time_s": result.column("frames/time_s")[positions],
        "punch_displacement_mm": result.column("frames/punch_displacement_mm")[positions],
        "force_kN": result.column("frames/force_kN")[positions],
        "peak_w_mm": result.column("peak/w_mm")[positions],
        "z_flat_mm": result.z_flat_mm,
        "points": np.vstack(points) if points else np.zeros((0, 4)),
        "units": {
            "length": "mm",
            "time": "s",
            "force": "kN",
            "frame": "X, Y in the plate plane, +Z toward the camera; w = z - z_flat_mm",
        },
    }
    with atomic_path(path) as temp, open(temp, "wb") as out:
        savemat(out, data, do_compression=True)
    return path


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
    for i in frame_positions(result, frames):
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
        for label, (x0, y0, x1, y1) in zip(LINE_LABELS, chosen, strict=False):
            for i in positions:
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
) -> Path:
    """Export a topography result in one of EXPORT_FORMATS; `line`/`lines` (X0, Y0, X1, Y1 mm) for profile-csv
    only; `frames` (first, last recording frame number) for every format."""
    if fmt not in EXPORT_FORMATS:
        raise ValueError(f"format: expected one of {EXPORT_FORMATS}, got {fmt!r}")
    if (line is not None or lines) and fmt != "profile-csv":
        raise ValueError("a line is only used by the profile-csv format")
    with TopographyResult(result_path) as result:
        if fmt == "points-csv":
            return export_points_csv(result, out_path, frames=frames)
        if fmt == "grid-npz":
            return export_grid_npz(result, out_path, frames=frames)
        if fmt == "mat":
            return export_mat(result, out_path, frames=frames)
        if fmt == "vtk":
            return export_vtk(result, out_path, frames=frames)
        return export_profile_csv(result, out_path, line=line, lines=lines, frames=frames)
