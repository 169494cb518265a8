"""LS-DYNA d3plot families (d3plot, d3plot01, d3plot02, …) through lasso-python (the optional extra
`fringelab[lsdyna]`).

The geometry (node ids and coordinates, shell and solid connectivity) and the state times are read once; the
nodal positions of a state are read when that state is asked for (lasso's `state_filter`), so a family of many
gigabytes is never in memory at once. A d3plot stores the current coordinates of every node in each state
(lasso's `node_displacement`); the displacement is that minus the reference coordinates. Shell thickness, when the
file has it, is taken from the first state and averaged onto the nodes. (`buffered_reading=True` is passed
with every `state_filter`: lasso 2.0 takes a filter of state 0 alone, `{0}`, as no filter and reads all states.)
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.science.fe_results import FEResults

INSTALL_HINT = "reading d3plot files needs lasso-python: pip install 'fringelab[lsdyna]'"


def _lasso() -> tuple[Any, Any]:
    try:
        from lasso.dyna import ArrayType, D3plot
    except ImportError:
        raise ValueError(INSTALL_HINT) from None
    return D3plot, ArrayType


def is_d3plot(path: Path) -> bool:
    """Whether a file is the first file of a d3plot family, by name (d3plot, *.d3plot)."""
    return path.is_file() and (path.name.lower() == "d3plot" or path.suffix.lower() == ".d3plot")


def read_d3plot(path: str | Path) -> FEResults:
    """The first file of a d3plot family as `FEResults` (length and time units not declared)."""
    D3plot, ArrayType = _lasso()
    path = Path(path)
    wanted = [ArrayType.global_timesteps, ArrayType.element_shell_thickness]
    try:
        header = D3plot(str(path), state_filter={0}, state_array_filter=wanted, buffered_reading=True)
        times = D3plot(str(path), state_array_filter=[ArrayType.global_timesteps]).arrays[ArrayType.global_timesteps]
    except Exception as error:  # lasso raises many kinds for a file it cannot parse
        raise ValueError(f"{path.name}: not a readable d3plot ({type(error).__name__}: {error})") from None
    arrays = header.arrays
    xyz = np.asarray(arrays[ArrayType.node_coordinates], np.float64)
    n_nodes = len(xyz)
    shells = np.asarray(arrays.get(ArrayType.element_shell_node_indexes, np.zeros((0, 4))), np.int64)
    solids = np.asarray(arrays.get(ArrayType.element_solid_node_indexes, np.zeros((0, 8))), np.int64)
    thickness = None
    if ArrayType.element_shell_thickness in arrays and len(shells):
        per_shell = np.asarray(arrays[ArrayType.element_shell_thickness], np.float64)[0]
        total = np.bincount(shells.ravel(), weights=np.repeat(per_shell, shells.shape[1]), minlength=n_nodes)
        count = np.bincount(shells.ravel(), minlength=n_nodes)
        with np.errstate(invalid="ignore", divide="ignore"):
            thickness = np.where(count > 0, total / count, np.nan)
    ids = arrays.get(ArrayType.node_ids)
    cache: dict[int, np.ndarray] = {}

    def displacement(i: int) -> np.ndarray:
        if i not in cache:
            state = D3plot(
                str(path), state_filter={i}, state_array_filter=[ArrayType.node_displacement], buffered_reading=True
            )
            current = np.asarray(state.arrays[ArrayType.node_displacement], np.float64)
            if current.shape != (1, n_nodes, 3):
                raise ValueError(f"{path.name}: state {i}: expected positions (1, {n_nodes}, 3), got {current.shape}")
            cache.clear()
            cache[i] = current[0] - xyz
        return cache[i]

    return FEResults(
        source=str(path), kind="d3plot",
        node_ids=np.asarray(ids, np.int64) if ids is not None else np.arange(1, n_nodes + 1), node_xyz=xyz,
        shells=shells, solids=solids, shell_thickness=thickness, time=np.asarray(times, np.float64),
        displacement=displacement,
    )  # fmt: skip


def write_d3plot(
    path: str | Path,
    *,
    node_xyz: np.ndarray,
    shells: np.ndarray,
    time: np.ndarray,
    displacement: np.ndarray,
    node_ids: np.ndarray | None = None,
    shell_thickness: float | None = None,
) -> Path:
    """Write a d3plot family with lasso-python's writer: shells (E, 4) (triangles repeat their last corner),
    states (S, N, 3) of displacement at times (S,); the geometry in `path`, the states in `path`01. For tests and
    examples; the state files are moved into place before the geometry, so a reader never sees a family
    without its states."""
    from fringelab.formats.atomic import commit_partial, partial_path

    D3plot, ArrayType = _lasso()
    d3plot = D3plot()
    d3plot.arrays[ArrayType.node_coordinates] = np.asarray(node_xyz, np.float64)
    d3plot.arrays[ArrayType.node_ids] = (
        np.arange(1, len(node_xyz) + 1) if node_ids is None else np.asarray(node_ids, np.int64)
    )
    d3plot.arrays[ArrayType.element_shell_node_indexes] = np.asarray(shells, np.int64)
    d3plot.arrays[ArrayType.element_shell_part_indexes] = np.zeros(len(shells), np.int64)
    d3plot.arrays[ArrayType.global_timesteps] = np.asarray(time, np.float64)
    d3plot.arrays[ArrayType.node_displacement] = np.asarray(node_xyz, np.float64)[None] + np.asarray(displacement)
    if shell_thickness is not None:
        d3plot.arrays[ArrayType.element_shell_thickness] = np.full((len(time), len(shells)), float(shell_thickness))
    path = Path(path)
    # lasso 2.0 writes a wrong file to an open handle, and to a path it writes the geometry there and the states
    # to path01: the family is written in a hidden folder beside the target, then each file moved into place.
    folder = partial_path(path)
    folder.mkdir()
    try:
        d3plot.write_d3plot(str(folder / path.name), single_file=True)
        for file in sorted(folder.iterdir(), key=lambda f: (len(f.name), f.name), reverse=True):
            commit_partial(file, path.parent / file.name)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return path
