"""Simulations as plain CSV: the nodal table and the punch table (writer and reader of each).

Nodal table, one row per (state, node), header `state,time_s,node,x_mm,y_mm,z_mm,ux_mm,uy_mm,uz_mm` (columns in
any order): x, y, z are the node's reference coordinates (the same in every state), ux, uy, uz its displacement
in that state. Lengths in mm, times in s. No connectivity: the surface is triangulated from the nodes. A state may
leave nodes out (the nodes of eroded elements after a perforation, as solvers and post-processors write them): a
node missing from a state is missing there (its displacement NaN, a hole in that state's surface).

Punch table, header `time_s,force_kN` with an optional `punch_displacement_mm` column: the punch's force and
travel over time (on their own time base).

Errors are ValueError naming the file and the line.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from fringelab.formats.atomic import atomic_path
from fringelab.formats.simulation_budget import DEFAULT_MAX_BYTES, check_declared, estimated_rows
from fringelab.science.fe_results import FEResults

NODES_COLUMNS = ("state", "time_s", "node", "x_mm", "y_mm", "z_mm", "ux_mm", "uy_mm", "uz_mm")
PUNCH_COLUMNS = ("time_s", "force_kN", "punch_displacement_mm")


def csv_header(path: str | Path) -> list[str]:
    """The column names of a CSV file's first line (lower-case stripped), [] when it has none."""
    with open(path, encoding="utf-8", errors="replace") as handle:
        first = handle.readline()
    return [c.strip() for c in first.strip().split(",")] if first.strip() else []


PARSE_COPIES = 3  # the parsed table, the parser's growing buffer and the index arrays made from its columns


def _table(
    path: Path, required: tuple[str, ...], optional: tuple[str, ...] = (), *, max_bytes: int = DEFAULT_MAX_BYTES
) -> dict[str, np.ndarray]:
    header = csv_header(path)
    missing = [c for c in required if c not in header]
    if missing:
        raise ValueError(f"{path.name}: line 1: missing column(s) {', '.join(missing)} (header {','.join(header)})")
    unknown = [c for c in header if c not in required + optional]
    if unknown:
        raise ValueError(
            f"{path.name}: line 1: unknown column(s) {', '.join(unknown)}; expected {','.join(required + optional)}"
        )
    rows = estimated_rows(path)  # before the parser allocates them: its rows from its size
    check_declared(path.name, max_bytes=max_bytes, n_nodes=0, n_values=PARSE_COPIES * rows * len(header),
                   what=f"about {rows} rows of {len(header)} columns, from its size")  # fmt: skip
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=np.float64)
    except ValueError:
        _raise_bad_line(path, len(header))
        raise
    if data.shape[0] == 0:
        raise ValueError(f"{path.name}: no rows after the header")
    if data.shape[1] != len(header):
        _raise_bad_line(path, len(header))
    if not np.all(np.isfinite(data[:, [header.index(c) for c in required]])):
        row = int(np.flatnonzero(~np.all(np.isfinite(data), axis=1))[0])
        raise ValueError(f"{path.name}: line {row + 2}: a value is not finite")
    return {name: data[:, header.index(name)] for name in header}


def _raise_bad_line(path: Path, n_columns: int) -> None:
    with open(path, encoding="utf-8", errors="replace") as handle:
        for number, line in enumerate(handle, start=1):
            if number == 1 or not line.strip():
                continue
            cells = line.strip().split(",")
            if len(cells) != n_columns:
                raise ValueError(f"{path.name}: line {number}: {len(cells)} values, the header has {n_columns}")
            for cell in cells:
                try:
                    float(cell)
                except ValueError:
                    raise ValueError(f"{path.name}: line {number}: {cell.strip()!r} is not a number") from None


def read_nodes_csv(path: str | Path, *, max_bytes: int = DEFAULT_MAX_BYTES) -> FEResults:
    """The nodal table as `FEResults` (mm, s; no elements). States are numbered by their `state` value; the
    nodes are every node of any state, and a node a state leaves out (an eroded element's) has a NaN displacement
    there (`FEResults`). Refused (ValueError) before it is parsed when its rows, estimated from its size, would
    take more than `max_bytes` (`simulation_budget`), and before its states are laid out when states × nodes
    would."""
    path = Path(path)
    table = _table(path, NODES_COLUMNS, max_bytes=max_bytes)
    state = table["state"].astype(np.int64)
    node = table["node"].astype(np.int64)
    states, state_pos = np.unique(state, return_inverse=True)
    node_ids, node_pos = np.unique(node, return_inverse=True)
    n_states, n_nodes = len(states), len(node_ids)
    # every state holds every node: a few rows naming far-apart states and nodes declare a large table
    check_declared(path.name, max_bytes=max_bytes, n_nodes=n_nodes, n_states_held=n_states, n_states=n_states,
                   n_values=PARSE_COPIES * len(state) * len(table), what="its state and node numbers")  # fmt: skip
    flat = state_pos * n_nodes + node_pos
    unique_flat, first_row = np.unique(flat, return_index=True)
    if len(unique_flat) != len(flat):
        twice = np.setdiff1d(np.arange(len(flat)), first_row)[0]
        raise ValueError(f"{path.name}: line {twice + 2}: node {node[twice]} appears twice in state {state[twice]}")
    # Each node's reference position from the first row that lists it (a node may join after state 0).
    _, first = np.unique(node_pos, return_index=True)
    xyz = np.full((n_nodes, 3), np.nan)
    xyz[node_pos[first]] = np.column_stack([table["x_mm"][first], table["y_mm"][first], table["z_mm"][first]])
    disp = np.full((n_states, n_nodes, 3), np.nan)
    disp[state_pos, node_pos] = np.column_stack([table["ux_mm"], table["uy_mm"], table["uz_mm"]])
    time_s = np.zeros(n_states)
    time_s[state_pos] = table["time_s"]
    return FEResults(
        source=str(path), kind="csv", node_ids=node_ids, node_xyz=xyz, shells=np.zeros((0, 4), np.int64),
        solids=np.zeros((0, 8), np.int64), shell_thickness=None, time=time_s, displacement=lambda i: disp[i],
        length_unit="mm", time_unit_s=1.0,
    )  # fmt: skip


def read_punch_csv(path: str | Path, *, max_bytes: int = DEFAULT_MAX_BYTES) -> dict[str, np.ndarray]:
    """The punch table: time_s, force_kN and, if present, punch_displacement_mm, each (Q,)."""
    path = Path(path)
    table = _table(path, ("time_s", "force_kN"), ("punch_displacement_mm",), max_bytes=max_bytes)
    return dict(table)


def write_nodes_csv(
    path: str | Path, *, node_ids: np.ndarray, node_xyz_mm: np.ndarray, time_s: np.ndarray, displacement_mm: np.ndarray
) -> Path:
    """Write the nodal table; displacement_mm (S, N, 3) over states of times time_s (S,)."""
    n_states, n_nodes = displacement_mm.shape[:2]
    buffer = io.StringIO()
    buffer.write(",".join(NODES_COLUMNS) + "\n")
    for s in range(n_states):
        block = np.column_stack([
            np.full(n_nodes, s), np.full(n_nodes, time_s[s]), node_ids, node_xyz_mm, displacement_mm[s],
        ])  # fmt: skip
        np.savetxt(buffer, block, delimiter=",", fmt=["%d", "%.9g", "%d"] + ["%.9g"] * 6)
    with atomic_path(path) as partial:
        partial.write_text(buffer.getvalue(), encoding="utf-8")
    return Path(path)


def write_punch_csv(
    path: str | Path, *, time_s: np.ndarray, force_kN: np.ndarray, punch_displacement_mm: np.ndarray | None = None
) -> Path:
    """Write the punch table (force, and the punch travel when given)."""
    columns = [time_s, force_kN] + ([] if punch_displacement_mm is None else [punch_displacement_mm])
    header = "time_s,force_kN" + ("" if punch_displacement_mm is None else ",punch_displacement_mm")
    buffer = io.StringIO()
    np.savetxt(buffer, np.column_stack(columns), delimiter=",", fmt="%.9g", header=header, comments="")
    with atomic_path(path) as partial:
        partial.write_text(buffer.getvalue(), encoding="utf-8")
    return Path(path)
