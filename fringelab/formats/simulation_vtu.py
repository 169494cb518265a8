"""Simulations as VTK time series: a ParaView .pvd collection of .vtu files, or a folder of .vtu files.

Each .vtu holds the mesh at its reference coordinates and the displacement as point data: one vector (named
`displacement`, `DISP`, `U`, … case ignored) or three scalars (`DISPLACEMENT_X`, `U_X`, …), as `simulation_mesh`
says; a 2-component vector is a 2-D result and refused. Its cells are read as `simulation_mesh` says (quadratic
ones through their corners). Optionally a point-data `thickness` (shells). The .pvd's
`timestep` attributes give the times (a bare folder: the field `TimeValue` of each file, else 0, 1, 2, ... in
natural name order). Read through meshio, one file per state when it is asked for, so a long series is never
in memory at once.
"""

from __future__ import annotations

import re
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from fringelab.formats.atomic import atomic_path
from fringelab.formats.simulation_budget import DEFAULT_MAX_BYTES, check_declared
from fringelab.formats.simulation_mesh import CellBlock, displacement_vector, shells_and_solids
from fringelab.science.fe_results import FEResults


def _natural_key(path: Path) -> list[object]:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


HEAD_BYTES = 1 << 16  # where a .vtu's <Piece NumberOfPoints=… NumberOfCells=…> must be
_PIECE = re.compile(rb"<Piece\b([^>]*)>")
_COUNT = re.compile(rb"\b(NumberOfPoints|NumberOfCells)\s*=\s*[\"']\s*([0-9]+)\s*[\"']")
MAX_CELL_NODES = 8  # corners counted per declared cell (a hexahedron's; higher-order cells keep their corners)


def _check_piece(path: Path, max_bytes: int) -> None:
    """The sizes a .vtu's Piece declares (NumberOfPoints, NumberOfCells) and the file's text, which meshio holds
    whole while it parses, against the budget (`simulation_budget`), before meshio reads it."""
    with open(path, "rb") as handle:
        head = handle.read(HEAD_BYTES)
    piece = _PIECE.search(head)  # none: no .vtu, which meshio says (its text is still counted)
    counts = {name.decode(): int(value) for name, value in _COUNT.findall(piece.group(1) if piece else b"")}
    n_cells = counts.get("NumberOfCells", 0)
    # the cells' connectivity, offsets and types (MAX_CELL_NODES + 2 values a cell), and the text twice (the text
    # and the arrays decoded from it)
    check_declared(path.name, max_bytes=max_bytes, n_nodes=counts.get("NumberOfPoints", 0), n_elements=n_cells,
                   n_corners=n_cells * (MAX_CELL_NODES + 2), file_bytes=2 * path.stat().st_size,
                   what="its Piece's NumberOfPoints and NumberOfCells, and its size")  # fmt: skip


def _read_mesh(path: Path, max_bytes: int = DEFAULT_MAX_BYTES):
    import meshio

    _check_piece(path, max_bytes)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return meshio.vtu.read(str(path))  # not meshio.read, which exits the process on a bad file
    except Exception as error:  # meshio raises many kinds for a file it cannot parse
        raise ValueError(f"{path.name}: not a readable mesh file ({type(error).__name__}: {error})") from None


def displacement_field(point_data: dict[str, np.ndarray], where: str) -> np.ndarray:
    """The displacement vectors (N, 3) among a mesh's point data (`simulation_mesh.displacement_vector`)."""
    return displacement_vector(point_data, where)


def mesh_cells(cells: list, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Shells (E, 4) and solids (F, 8|6|4) of meshio cell blocks, as `simulation_mesh.shells_and_solids` reads
    them (quadratic ones through their corners; points and lines beside them left aside; others refused)."""
    blocks = [
        CellBlock(block.type, np.asarray(block.data, np.int64), f"cell block {k + 1}") for k, block in enumerate(cells)
    ]
    return shells_and_solids(blocks, where)


def read_pvd(path: str | Path) -> list[tuple[float, Path]]:
    """(time, file) of every data set of a .pvd collection, in time order."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as error:
        raise ValueError(f"{path.name}: not a readable .pvd file ({error})") from None
    entries = []
    for item in root.iter("DataSet"):
        name = item.get("file")
        if name is None:
            raise ValueError(f"{path.name}: a DataSet without a file attribute")
        try:
            time = float(item.get("timestep", "nan"))
        except ValueError:
            raise ValueError(
                f"{path.name}: DataSet {name}: timestep {item.get('timestep')!r} is not a number"
            ) from None
        entries.append((time, path.parent / name))
    if not entries:
        raise ValueError(f"{path.name}: the collection lists no DataSet")
    for _, file in entries:
        if not file.is_file():
            raise ValueError(f"{path.name}: lists {file.name}, which is not there")
    return sorted(entries, key=lambda entry: entry[0])


def read_vtu_series(path: str | Path, *, max_bytes: int = DEFAULT_MAX_BYTES) -> FEResults:
    """A .pvd collection or a folder of .vtu files (or one .vtu) as `FEResults` (length and time units not
    declared). Each file is read one at a time, each refused before meshio reads it when its Piece declares more
    than `max_bytes` (`simulation_budget`)."""
    path = Path(path)
    if path.is_dir():
        pvds = sorted(path.glob("*.pvd"))
        if pvds:
            return read_vtu_series(pvds[0], max_bytes=max_bytes)
        files = sorted(path.glob("*.vtu"), key=_natural_key)
        if not files:
            raise ValueError(f"{path.name}: no .pvd or .vtu file in the folder")
        entries = [(float("nan"), f) for f in files]
    elif path.suffix.lower() == ".pvd":
        entries = read_pvd(path)
    else:
        entries = [(float("nan"), path)]
    first = _read_mesh(entries[0][1], max_bytes)
    where = entries[0][1].name
    shells, solids = mesh_cells(first.cells, where)
    times = np.array([t for t, _ in entries])
    if np.any(np.isnan(times)):
        values = []
        for index, (_, file) in enumerate(entries):
            mesh = first if index == 0 else _read_mesh(file, max_bytes)
            value = mesh.field_data.get("TimeValue")
            values.append(float(np.ravel(value)[0]) if value is not None else float(index))
        times = np.array(values)
    n_nodes = len(first.points)
    thickness = first.point_data.get("thickness")
    files = [f for _, f in entries]
    displacement_field(first.point_data, where)  # fails early on a file without one

    ids = first.point_data.get("node_id")

    def displacement(i: int) -> np.ndarray:
        mesh = first if i == 0 else _read_mesh(files[i], max_bytes)
        if len(mesh.points) == n_nodes:
            return displacement_field(mesh.point_data, files[i].name)
        # A state that leaves nodes out (eroded elements): matched by node_id, the missing ones NaN (FEResults).
        later = mesh.point_data.get("node_id")
        if ids is None or later is None:
            raise ValueError(
                f"{files[i].name}: {len(mesh.points)} nodes, the first file has {n_nodes}; a series whose node set "
                "changes (eroded elements) needs a node_id point array in every file"
            )
        first_ids = np.asarray(ids, np.int64).ravel()
        order = np.argsort(first_ids)
        later_ids = np.asarray(later, np.int64).ravel()
        at = np.clip(np.searchsorted(first_ids, later_ids, sorter=order), 0, n_nodes - 1)
        if not np.array_equal(first_ids[order[at]], later_ids):
            raise ValueError(f"{files[i].name}: node ids that the first file does not have")
        u = np.full((n_nodes, 3), np.nan)
        u[order[at]] = displacement_field(mesh.point_data, files[i].name)
        return u

    return FEResults(
        source=str(path), kind="vtu", node_ids=np.arange(1, n_nodes + 1) if ids is None else np.asarray(ids, np.int64),
        node_xyz=np.asarray(first.points, np.float64), shells=shells, solids=solids,
        shell_thickness=None if thickness is None else np.asarray(thickness, np.float64), time=times,
        displacement=displacement,
    )  # fmt: skip


def write_vtu_series(
    folder: str | Path,
    *,
    node_xyz: np.ndarray,
    cells: list[tuple[str, np.ndarray]],
    time: np.ndarray,
    displacement: np.ndarray,
    node_ids: np.ndarray | None = None,
    thickness: np.ndarray | None = None,
    name: str = "plate",
) -> Path:
    """Write states (S, N, 3) as folder/name_0000.vtu … and the collection folder/name.pvd (returned)."""
    import meshio

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    entries = []
    for s in range(len(time)):
        point_data: dict[str, np.ndarray] = {"displacement": np.asarray(displacement[s], np.float64)}
        if thickness is not None:
            point_data["thickness"] = np.asarray(thickness, np.float64)
        if node_ids is not None:
            point_data["node_id"] = np.asarray(node_ids, np.int64)
        file = folder / f"{name}_{s:04d}.vtu"
        with atomic_path(file) as partial:
            meshio.write(partial, meshio.Mesh(node_xyz, cells, point_data=point_data), file_format="vtu")
        entries.append(f'    <DataSet timestep="{float(time[s])!r}" part="0" file="{file.name}"/>')
    text = '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
    text += "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n"
    pvd = folder / f"{name}.pvd"
    with atomic_path(pvd) as partial:
        partial.write_text(text, encoding="utf-8")
    return pvd
