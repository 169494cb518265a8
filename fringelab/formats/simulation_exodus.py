"""Simulations as Exodus II files (.e, .exo, .ex2): mesh through meshio, the time steps through netCDF4.

meshio reads the mesh (coordinates and element blocks) but only the first time step of nodal variables, so the
states are read here from the file's own variables, one state when it is asked for: `time_whole` (time_step,)
and the nodal displacement as three scalar variables named in `name_nod_var` (DISPX/DISPY/DISPZ,
DISPLX/..., displacement_x/..., disp_x/..., ux/uy/uz; case ignored), each `vals_nod_var{k}` (time_step,
num_nodes) or, in the older layout, one `vals_nod_var` (time_step, num_nod_var, num_nodes). Node ids from
`node_num_map` where the file has it. An optional nodal variable `thickness` gives shell thickness.
"""

from __future__ import annotations

import contextlib
import io
import re
import warnings
from pathlib import Path

import numpy as np

from fringelab.formats.simulation_vtu import mesh_cells
from fringelab.science.fe_results import FEResults

EXODUS_SUFFIXES = (".e", ".exo", ".ex2", ".exodus")
_COMPONENT = re.compile(r"^(displ?|displacement|disp|u)[_ ]?([xyz])$", re.IGNORECASE)


def _names(variable) -> list[str]:
    variable.set_auto_mask(False)
    return [b"".join(row).decode("utf-8", "replace").strip("\x00 ").strip() for row in variable[:]]


def read_exodus(path: str | Path) -> FEResults:
    """An Exodus II file as `FEResults` (length and time units not declared)."""
    import meshio
    import netCDF4

    path = Path(path)
    try:
        # meshio prints "Skipping some time data" for every transient file: the time steps are read below.
        with warnings.catch_warnings(), contextlib.redirect_stderr(io.StringIO()):
            warnings.simplefilter("ignore")
            mesh = meshio.exodus.read(str(path))  # not meshio.read, which exits the process on a bad file
    except Exception as error:
        raise ValueError(f"{path.name}: not a readable Exodus II file ({type(error).__name__}: {error})") from None
    shells, solids = mesh_cells(mesh.cells, path.name)
    n_nodes = len(mesh.points)
    with netCDF4.Dataset(path) as nc:
        variables = nc.variables
        if "time_whole" not in variables or "name_nod_var" not in variables:
            raise ValueError(f"{path.name}: no time steps with nodal variables (time_whole, name_nod_var)")
        time = np.asarray(variables["time_whole"][:], np.float64)
        names = _names(variables["name_nod_var"])
        ids = np.asarray(variables["node_num_map"][:], np.int64) if "node_num_map" in variables else None
    components: dict[str, int] = {}
    for index, name in enumerate(names):
        match = _COMPONENT.match(name)
        if match:
            components.setdefault(match.group(2).lower(), index)
    if not {"x", "y", "z"} <= components.keys():
        raise ValueError(
            f"{path.name}: no displacement among the nodal variables {names} "
            "(expected DISPX, DISPY, DISPZ or displacement_x, …)"
        )
    thickness_index = next((i for i, n in enumerate(names) if n.lower() == "thickness"), None)

    def nodal(nc, k: int, i: int) -> np.ndarray:
        if f"vals_nod_var{k + 1}" in nc.variables:
            variable = nc.variables[f"vals_nod_var{k + 1}"]
            variable.set_auto_mask(False)
            return np.asarray(variable[i], np.float64)
        variable = nc.variables["vals_nod_var"]
        variable.set_auto_mask(False)
        return np.asarray(variable[i, k], np.float64)

    def displacement(i: int) -> np.ndarray:
        with netCDF4.Dataset(path) as nc:
            return np.column_stack([nodal(nc, components[axis], i) for axis in "xyz"])

    thickness = None
    if thickness_index is not None:
        with netCDF4.Dataset(path) as nc:
            thickness = nodal(nc, thickness_index, 0)
    return FEResults(
        source=str(path), kind="exodus", node_ids=ids if ids is not None else np.arange(1, n_nodes + 1),
        node_xyz=np.asarray(mesh.points, np.float64), shells=shells, solids=solids, shell_thickness=thickness,
        time=time, displacement=displacement,
    )  # fmt: skip


def write_exodus(
    path: str | Path,
    *,
    node_xyz: np.ndarray,
    cells: list[tuple[str, np.ndarray]],
    time: np.ndarray,
    displacement: np.ndarray,
    node_ids: np.ndarray | None = None,
) -> Path:
    """Write an Exodus II file: the mesh through meshio, then time steps (S,) and DISPX/DISPY/DISPZ (S, N)."""
    import meshio
    import netCDF4

    from fringelab.formats.atomic import atomic_path

    path = Path(path)
    with atomic_path(path) as partial:
        meshio.write(partial, meshio.Mesh(node_xyz, cells), file_format="exodus")
        with netCDF4.Dataset(partial, "a") as nc:
            nc.createDimension("num_nod_var", 3)
            names = nc.createVariable("name_nod_var", "S1", ("num_nod_var", "len_string"))
            for k, name in enumerate(("DISPX", "DISPY", "DISPZ")):
                names[k, : len(name)] = np.array(list(name), "S1")
            whole = nc.variables["time_whole"]
            for s, t in enumerate(time):
                whole[s] = t
            for k in range(3):
                values = nc.createVariable(f"vals_nod_var{k + 1}", "f8", ("time_step", "num_nodes"))
                for s in range(len(time)):
                    values[s] = displacement[s, :, k]
            if node_ids is not None:
                mapping = nc.createVariable("node_num_map", "i4", ("num_nodes",))
                mapping[:] = node_ids
    return path
