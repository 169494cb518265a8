"""Simulations as Exodus II files (.e, .exo, .ex2): read through netCDF4, one state when it is asked for.

The mesh: the node coordinates (`coordx`/`coordy`/`coordz`, or `coord` (num_dim, num_nodes)) and the element blocks
(`connect1`, `connect2`, … with their `elem_type`, 1-based node numbers), read as `simulation_mesh` says (shells and
solids, quadratic ones through their corners; points and lines beside them left aside; anything else refused by
block). The states: `time_whole` (time_step,) and the nodal displacement as three nodal variables named in
`name_nod_var` (DISPLACEMENT_X, DISPX, DISPLX, disp_x, MODEL_DISPLACEMENT_X, U_X, …; case ignored), each
`vals_nod_var{k}` (time_step, num_nodes) or, in the older layout, one `vals_nod_var` (time_step, num_nod_var,
num_nodes). Node ids from `node_num_map` where the file has it. An optional nodal variable `thickness` gives shell
thickness. A 2-D file (num_dim 2, or displacements in x and y only) is refused: it has no out-of-plane
displacement.

Element death (eroded elements): Exodus II has no one convention for it (SEACAS's BLOT asks the user which element
variable marks death and which value means alive). Read here: an element variable named `death_status` (Sierra/SM's
element death output) or `status` (Abaqus's STATUS, as translators carry it), case ignored, 1 alive and 0 dead, in
`vals_elem_var{v}eb{b}` (time_step, num_el_in_blk{b}); a block without it (truth table 0) counts as alive. A node all
of whose elements are dead in a state is missing there (NaN displacement: `FEResults`' rule). Values outside 0..1 are
refused: they are some other convention, and guessing it would show the wrong nodes as the hole.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.formats.simulation_budget import DEFAULT_MAX_BYTES, check_declared
from fringelab.formats.simulation_mesh import CellBlock, displacement_components, shells_and_solids, two_d_message
from fringelab.science.fe_results import FEResults

EXODUS_SUFFIXES = (".e", ".exo", ".ex2", ".exodus")
STATUS_NAMES = ("death_status", "status")  # element variables marking element death, 1 alive, 0 dead; in this order


def _text(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace").strip("\x00 ").strip()
    return str(value).strip("\x00 ").strip()


def _names(variable: Any) -> list[str]:
    variable.set_auto_mask(False)
    return [b"".join(row).decode("utf-8", "replace").strip("\x00 ").strip() for row in variable[:]]


def _values(variable: Any, index: Any = slice(None)) -> np.ndarray:
    variable.set_auto_mask(False)
    return np.asarray(variable[index])


def _mesh(nc: Any, where: str) -> tuple[np.ndarray, list[CellBlock], list[int]]:
    """Node coordinates (N, 3), the element blocks of an open Exodus file and each block's number k (its
    `connect{k}`, `vals_elem_var{v}eb{k}`)."""
    variables, dimensions = nc.variables, nc.dimensions
    n_dim = len(dimensions["num_dim"]) if "num_dim" in dimensions else 3
    if "num_nodes" not in dimensions:
        raise ValueError(f"{where}: no nodes (no num_nodes dimension): is it an Exodus II results file?")
    if n_dim == 2:
        raise ValueError(two_d_message(where, "num_dim is 2"))
    if n_dim != 3:
        raise ValueError(f"{where}: num_dim is {n_dim}; fringelab reads 3-D models")
    if all(f"coord{axis}" in variables for axis in "xyz"):
        xyz = np.column_stack([_values(variables[f"coord{axis}"]) for axis in "xyz"]).astype(np.float64)
    elif "coord" in variables:
        xyz = _values(variables["coord"]).astype(np.float64).T
    else:
        raise ValueError(f"{where}: no node coordinates (coordx/coordy/coordz or coord)")
    n_blocks = len(dimensions["num_el_blk"]) if "num_el_blk" in dimensions else 0
    block_ids = _values(variables["eb_prop1"]) if "eb_prop1" in variables else np.arange(1, n_blocks + 1)
    blocks, numbers = [], []
    for k in range(1, n_blocks + 1):
        name = f"connect{k}"
        if name not in variables:  # a block without elements
            continue
        variable = variables[name]
        elem_type = _text(variable.getncattr("elem_type")) if "elem_type" in variable.ncattrs() else "?"
        connectivity = _values(variable).astype(np.int64) - 1
        if connectivity.size and (connectivity.min() < 0 or connectivity.max() >= len(xyz)):
            raise ValueError(f"{where}: element block {block_ids[k - 1]} refers to nodes outside 1..{len(xyz)}")
        blocks.append(CellBlock(elem_type, connectivity, f"element block {block_ids[k - 1]}"))
        numbers.append(k)
    return xyz, blocks, numbers


def _status_variable(nc: Any) -> tuple[int, str] | None:
    """The index and name of the element variable that marks element death (STATUS_NAMES), or None."""
    if "name_elem_var" not in nc.variables:
        return None
    names = _names(nc.variables["name_elem_var"])
    lower = [name.lower() for name in names]
    for wanted in STATUS_NAMES:
        if wanted in lower:
            return lower.index(wanted), names[lower.index(wanted)]
    return None


def _missing_nodes(nc: Any, blocks: list[CellBlock], numbers: list[int], status: tuple[int, str], i: int,
                   n_nodes: int, where: str) -> np.ndarray:  # fmt: skip
    """(N,) bool: the nodes all of whose elements are dead at time step i (nodes of no element are not missing)."""
    index, name = status
    in_element = np.zeros(n_nodes, bool)
    alive = np.zeros(n_nodes, bool)
    for block, k in zip(blocks, numbers, strict=True):
        connectivity = np.asarray(block.connectivity, np.int64)
        in_element[connectivity.ravel()] = True
        variable = nc.variables.get(f"vals_elem_var{index + 1}eb{k}")
        if variable is None:  # the truth table leaves this block out: its elements never die
            alive[connectivity.ravel()] = True
            continue
        values = _values(variable, i).astype(np.float64)
        if values.shape != (len(connectivity),):
            raise ValueError(
                f"{where}: element variable {name!r}, {block.where}, step {i}: {values.shape} values, "
                f"{len(connectivity)} elements"
            )
        if not np.all((values >= 0.0) & (values <= 1.0)):
            raise ValueError(
                f"{where}: element variable {name!r}, {block.where}, step {i}: values outside 0..1 (from "
                f"{np.nanmin(values):.6g} to {np.nanmax(values):.6g}); fringelab reads element death as 1 alive, 0 "
                "dead: rename the variable if it means something else"
            )
        alive[connectivity[values >= 0.5].ravel()] = True
    return in_element & ~alive


@contextlib.contextmanager
def _damage_named(where: str) -> Iterator[None]:
    """netCDF4 and HDF5 raise RuntimeError, OSError, KeyError, IndexError … for a damaged file: one sentence."""
    try:
        yield
    except ValueError:
        raise
    except Exception as error:
        raise ValueError(
            f"{where}: not a readable Exodus II file ({type(error).__name__}: {error}): cut short or damaged? copy it "
            "again from the solver's folder"
        ) from None


def _check_dimensions(nc: Any, where: str, max_bytes: int) -> None:
    """The sizes the file's dimensions declare (nodes, each block's elements × nodes per element, time steps)
    against the budget (`simulation_budget`), before any variable is read: a dimension costs nothing to declare."""
    dimensions = nc.dimensions

    def size(name: str) -> int:
        return len(dimensions[name]) if name in dimensions else 0

    n_blocks = size("num_el_blk")
    n_elements = sum(size(f"num_el_in_blk{k}") for k in range(1, n_blocks + 1))
    n_corners = sum(size(f"num_el_in_blk{k}") * size(f"num_nod_per_el{k}") for k in range(1, n_blocks + 1))
    check_declared(where, max_bytes=max_bytes, n_nodes=size("num_nodes"), n_elements=n_elements,
                   n_corners=n_corners, n_states=size("time_step"), what="its header's dimensions")  # fmt: skip


def read_exodus(path: str | Path, *, max_bytes: int = DEFAULT_MAX_BYTES) -> FEResults:
    """An Exodus II file as `FEResults` (length and time units not declared); ValueError before anything is read
    when its dimensions declare more than `max_bytes` (`simulation_budget`)."""
    import netCDF4

    path = Path(path)
    where = path.name
    try:
        nc = netCDF4.Dataset(path)
    except Exception as error:  # netCDF4 raises OSError and others for a file it cannot parse
        raise ValueError(f"{where}: not a readable Exodus II file ({type(error).__name__}: {error})") from None
    with nc, _damage_named(where):
        _check_dimensions(nc, where, max_bytes)
        xyz, blocks, numbers = _mesh(nc, where)
        variables = nc.variables
        if "time_whole" not in variables or "name_nod_var" not in variables:
            raise ValueError(f"{where}: no time steps with nodal variables (time_whole, name_nod_var)")
        time = _values(variables["time_whole"]).astype(np.float64)
        names = _names(variables["name_nod_var"])
        ids = _values(variables["node_num_map"]).astype(np.int64) if "node_num_map" in variables else None
        status = _status_variable(nc)
    shells, solids = shells_and_solids(blocks, where)
    components = displacement_components(names, where)
    thickness_index = next((i for i, n in enumerate(names) if n.lower() == "thickness"), None)
    n_nodes = len(xyz)

    def nodal(nc: Any, k: int, i: int) -> np.ndarray:
        if f"vals_nod_var{k + 1}" in nc.variables:
            values = _values(nc.variables[f"vals_nod_var{k + 1}"], i)
        elif "vals_nod_var" in nc.variables:
            values = _values(nc.variables["vals_nod_var"], (i, k))
        else:
            raise ValueError(f"{where}: nodal variable {names[k]!r} has no values (vals_nod_var{k + 1})")
        if values.shape != (n_nodes,):
            raise ValueError(f"{where}: nodal variable {names[k]!r}, step {i}: {values.shape} values, {n_nodes} nodes")
        return values.astype(np.float64)

    def displacement(i: int) -> np.ndarray:
        if not 0 <= i < len(time):
            raise ValueError(f"{where}: no time step {i}; it has {len(time)}")
        with _damage_named(where), netCDF4.Dataset(path) as nc:
            u = np.column_stack([nodal(nc, k, i) for k in components])
            if status is not None:  # eroded elements: their nodes are a hole in this state
                u[_missing_nodes(nc, blocks, numbers, status, i, n_nodes, where)] = np.nan
            return u

    thickness = None
    if thickness_index is not None and len(time):
        with _damage_named(where), netCDF4.Dataset(path) as nc:
            thickness = nodal(nc, thickness_index, 0)
    return FEResults(
        source=str(path), kind="exodus", node_ids=ids if ids is not None else np.arange(1, n_nodes + 1),
        node_xyz=xyz, shells=shells, solids=solids, shell_thickness=thickness, time=time, displacement=displacement,
    )  # fmt: skip


def write_exodus(
    path: str | Path,
    *,
    node_xyz: np.ndarray,
    cells: list[tuple[str, np.ndarray]],
    time: np.ndarray,
    displacement: np.ndarray,
    node_ids: np.ndarray | None = None,
    names: tuple[str, ...] = ("DISPX", "DISPY", "DISPZ"),
    element_status: np.ndarray | None = None,
    status_name: str = "death_status",
) -> Path:
    """Write an Exodus II file: the mesh through meshio (cells as meshio names them: "quad", "triangle6",
    "vertex" for SPHERE, …), then time steps (S,) and one nodal variable per name, displacement[..., k] (S, N);
    element_status (S, E) over the cells' elements in order (1 alive, 0 dead), as the element variable
    `status_name`, one block after another."""
    import meshio
    import netCDF4

    from fringelab.formats.atomic import atomic_path

    path = Path(path)
    with atomic_path(path) as partial:
        meshio.write(partial, meshio.Mesh(node_xyz, cells), file_format="exodus")
        with netCDF4.Dataset(partial, "a") as nc:
            nc.createDimension("num_nod_var", len(names))
            name_variable = nc.createVariable("name_nod_var", "S1", ("num_nod_var", "len_string"))
            for k, name in enumerate(names):
                name_variable[k, : len(name)] = np.array(list(name), "S1")
            whole = nc.variables["time_whole"]
            for s, t in enumerate(time):
                whole[s] = t
            for k in range(len(names)):
                values = nc.createVariable(f"vals_nod_var{k + 1}", "f8", ("time_step", "num_nodes"))
                for s in range(len(time)):
                    values[s] = displacement[s, :, k]
            if element_status is not None:
                nc.createDimension("num_elem_var", 1)
                elem_names = nc.createVariable("name_elem_var", "S1", ("num_elem_var", "len_string"))
                elem_names[0, : len(status_name)] = np.array(list(status_name), "S1")
                start = 0
                for b, (_, connectivity) in enumerate(cells, start=1):
                    values = nc.createVariable(f"vals_elem_var1eb{b}", "f8", ("time_step", f"num_el_in_blk{b}"))
                    for s in range(len(time)):
                        values[s] = element_status[s, start : start + len(connectivity)]
                    start += len(connectivity)
            if node_ids is not None:
                mapping = nc.createVariable("node_num_map", "i4", ("num_nodes",))
                mapping[:] = node_ids
    return path
