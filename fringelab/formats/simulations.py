"""Opening a simulation, whatever form it comes in: one file or a folder of them.

A folder holds one model (a d3plot family, a .pvd or .vtu series, an Exodus file, or the nodal CSV) and, beside
it, what gives the punch: an LS-DYNA `nodout` (the punch node's travel), `rcforc` (the contact force) or a punch
CSV (`time_s,force_kN[,punch_displacement_mm]`). Each format has its own module (`simulation_*`); this one only
recognises them (`read_parts`) and puts the pieces into one `FEResults` (`assemble`): the check of an upload stores
the parts (`fringelab.formats.simulation_store`), and what is read back from there is assembled the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fringelab.formats.simulation_budget import DEFAULT_MAX_BYTES
from fringelab.science.fe_results import FEResults, with_updates

if TYPE_CHECKING:
    from fringelab.formats.simulation_lsdyna_ascii import ContactForces, NodeHistories

SIMULATION_FORMATS = ("d3plot", "vtu", "pvd", "exodus", "csv", "nodout", "rcforc")


def _kind(path: Path) -> str | None:
    from fringelab.formats.simulation_csv import csv_header
    from fringelab.formats.simulation_exodus import EXODUS_SUFFIXES

    name, suffix = path.name.lower(), path.suffix.lower()
    if name == "d3plot" or suffix == ".d3plot":
        return "d3plot"
    if suffix in (".pvd", ".vtu"):
        return suffix[1:]
    if suffix in EXODUS_SUFFIXES:
        return "exodus"
    if name.startswith("nodout"):
        return "nodout"
    if name.startswith("rcforc"):
        return "rcforc"
    if suffix == ".csv":
        return "punch-csv" if "force_kN" in csv_header(path) else "nodes-csv"
    return None


@dataclass(frozen=True)
class SimulationParts:
    """What a simulation's files hold, before the punch is chosen: the model (no punch travel or force yet), and
    beside it the nodout's nodal histories, the rcforc's contact forces and the punch CSV's columns where they
    are there (each with its file's name, for messages)."""

    model: FEResults
    nodout: NodeHistories | None = None
    nodout_name: str = "nodout"
    rcforc: ContactForces | None = None
    rcforc_name: str = "rcforc"
    punch_table: dict[str, np.ndarray] | None = None
    punch_table_name: str = "punch.csv"


def read_parts(path: str | Path, *, max_bytes: int = DEFAULT_MAX_BYTES) -> SimulationParts:
    """Read a simulation (file or folder) into its parts; each file refused by its reader before it allocates
    more than `max_bytes` of the arrays it declares (`simulation_budget`: FRINGELAB_SIMULATION_MAX_BYTES)."""
    from fringelab.formats import simulation_csv, simulation_lsdyna_ascii

    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: no such file or folder")
    files = sorted(p for p in path.iterdir() if p.is_file()) if path.is_dir() else [path]
    kinds: dict[str, list[Path]] = {}
    for file in files:
        kind = _kind(file)
        if kind is not None:
            kinds.setdefault(kind, []).append(file)
    model_kinds = [k for k in ("d3plot", "pvd", "vtu", "exodus", "nodes-csv") if k in kinds]
    if not model_kinds:
        found = ", ".join(p.name for p in files[:10]) or "nothing"
        raise ValueError(
            f"{path.name}: no simulation model found ({found}); expected a d3plot family, a .pvd/.vtu series, "
            "an Exodus file (.e, .exo) or a CSV with columns " + ",".join(simulation_csv.NODES_COLUMNS)
        )
    kind = model_kinds[0]
    if kind == "d3plot":
        from fringelab.formats.simulation_d3plot import read_d3plot

        results = read_d3plot(kinds["d3plot"][0], max_bytes=max_bytes)
    elif kind in ("pvd", "vtu"):
        from fringelab.formats.simulation_vtu import read_vtu_series

        results = read_vtu_series(kinds["pvd"][0] if kind == "pvd" else path, max_bytes=max_bytes)
    elif kind == "exodus":
        from fringelab.formats.simulation_exodus import read_exodus

        results = read_exodus(kinds["exodus"][0], max_bytes=max_bytes)
    else:
        results = simulation_csv.read_nodes_csv(kinds["nodes-csv"][0], max_bytes=max_bytes)
    parts = SimulationParts(model=results)
    if "nodout" in kinds:
        file = kinds["nodout"][0]
        histories = simulation_lsdyna_ascii.read_nodout(file, max_bytes=max_bytes)
        parts = SimulationParts(**{**parts.__dict__, "nodout": histories, "nodout_name": file.name})
    if "rcforc" in kinds:
        file = kinds["rcforc"][0]
        forces = simulation_lsdyna_ascii.read_rcforc(file, max_bytes=max_bytes)
        parts = SimulationParts(**{**parts.__dict__, "rcforc": forces, "rcforc_name": file.name})
    if "punch-csv" in kinds:
        file = kinds["punch-csv"][0]
        table = simulation_csv.read_punch_csv(file, max_bytes=max_bytes)
        parts = SimulationParts(**{**parts.__dict__, "punch_table": table, "punch_table_name": file.name})
    return parts


def assemble(
    parts: SimulationParts,
    *,
    punch_node: int | None = None,
    contact_interface: int | None = None,
    punch_needed: bool = True,
) -> FEResults:
    """One `FEResults` of a simulation's parts, with its punch travel and force where it has them.

    punch_node: the node whose travel is the punch displacement (a nodout node, or a mesh node); None: nodout's
    only node, or none. contact_interface: the rcforc interface of the punch; None: the one with the largest force.
    punch_needed: a nodout of several nodes without a punch_node is a ValueError naming them (for a comparison);
    False reads it without a punch travel (an upload: the punch node is chosen when it is compared).
    """
    results = parts.model
    updates: dict[str, object] = {}
    if parts.nodout is not None:
        histories = parts.nodout
        ambiguous = punch_node is None and len(histories.node_ids) > 1
        if (punch_node is None or punch_node in histories.node_ids) and (punch_needed or not ambiguous):
            travel = histories.punch_travel(punch_node, where=parts.nodout_name)
            updates.update(punch_time=histories.time, punch_displacement=travel)
    if parts.rcforc is not None:
        time, force, _ = parts.rcforc.punch_force(contact_interface, where=parts.rcforc_name)
        updates.update(force_time=time, force=force, force_unit_kN=None)
    if parts.punch_table is not None:
        table = parts.punch_table
        updates.update(force_time=table["time_s"], force=table["force_kN"], force_unit_kN=1.0)
        if "punch_displacement_mm" in table and "punch_displacement" not in updates:
            updates.update(
                punch_time=table["time_s"], punch_displacement=table["punch_displacement_mm"], punch_in_mm=True
            )
    if punch_node is not None and "punch_displacement" not in updates:
        index = results.node_index(punch_node)
        travel = np.array([np.linalg.norm(results.displacement(i)[index]) for i in range(results.n_states)])
        updates.update(punch_time=results.time, punch_displacement=travel)
    return with_updates(results, **updates) if updates else results


def open_simulation(
    path: str | Path,
    *,
    punch_node: int | None = None,
    contact_interface: int | None = None,
    punch_needed: bool = True,
    max_bytes: int = DEFAULT_MAX_BYTES,
) -> FEResults:
    """Read a simulation (file or folder) into `FEResults`, with its punch travel and force where it has them:
    `assemble(read_parts(path, max_bytes=...), ...)` (see both)."""
    parts = read_parts(path, max_bytes=max_bytes)
    return assemble(parts, punch_node=punch_node, contact_interface=contact_interface, punch_needed=punch_needed)
