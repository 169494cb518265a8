"""The checked simulation (HDF5): what a simulation's check job read from the uploaded files, stored so that the
web server never opens an uploaded model itself (issue 26, finding 4). The mapping form's live preview reads this.

Schema "fringelab.simulation", version 1; in the model's own units (as the files were; `length_unit` and
`time_unit_s` where they declare them):
  /            attrs: schema, schema_version, kind (d3plot, vtu, exodus, csv), length_unit ("" where not declared),
               time_unit_s (NaN where not declared)
  /model       node_ids (N,) int64, node_xyz (N, 3), shells (E, k) int64, solids (F, k) int64, time (S,),
               displacement (S, N, 3) float64 (one state a chunk, NaN for a node a state does not have),
               shell_thickness (N,) where the files have it
  /nodout      time (T,), node_ids (M,), displacement (T, M, 3): the nodal histories (the punch node is chosen when
               the model is compared); attrs name (the file's name)
  /rcforc      one group per interface and side, `{id}-{side}`: time (T,), force (T, 3); attrs name
  /punch_csv   one dataset per column of the punch CSV; attrs name
Written by the check (`write_checked`, atomically, state after state); read lazily, a state when it is asked for
(`read_checked`), into the parts `fringelab.formats.simulations.assemble` makes one `FEResults` of, the same way
the upload's files are.
"""

from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np

from fringelab.formats.atomic import atomic_path
from fringelab.formats.hdf5 import open_read_only
from fringelab.formats.simulation_lsdyna_ascii import ContactForces, NodeHistories
from fringelab.formats.simulations import SimulationParts
from fringelab.science.fe_results import FEResults

SCHEMA = "fringelab.simulation"
SCHEMA_VERSION = 1
CHECKED_FILE = "checked.h5"


def stored_bytes(parts: SimulationParts) -> int:
    """About the bytes `write_checked` writes for these parts (its states, 8 bytes a value, and the mesh)."""
    model = parts.model
    return 8 * (model.n_states * len(model.node_xyz) * 3 + 4 * len(model.node_xyz) + model.shells.size
                + model.solids.size) + 2**16  # fmt: skip


def write_checked(path: str | Path, parts: SimulationParts) -> Path:
    """Store a simulation's parts (every state read once, one at a time, as the check must anyway)."""
    model = parts.model
    path = Path(path)
    with atomic_path(path) as partial, h5py.File(partial, "w") as out:
        out.attrs.update(schema=SCHEMA, schema_version=SCHEMA_VERSION, kind=model.kind,
                         length_unit=model.length_unit or "",
                         time_unit_s=math.nan if model.time_unit_s is None else float(model.time_unit_s))  # fmt: skip
        group = out.create_group("model")
        for name in ("node_ids", "node_xyz", "shells", "solids", "time"):
            group.create_dataset(name, data=np.asarray(getattr(model, name)))
        if model.shell_thickness is not None:
            group.create_dataset("shell_thickness", data=np.asarray(model.shell_thickness, np.float64))
        n_nodes = len(model.node_xyz)
        states = group.create_dataset("displacement", shape=(model.n_states, n_nodes, 3), dtype=np.float64,
                                      chunks=(1, max(n_nodes, 1), 3))  # fmt: skip
        for i in range(model.n_states):
            states[i] = model.displacement(i)
        if parts.nodout is not None:
            nodout = out.create_group("nodout")
            nodout.attrs["name"] = parts.nodout_name
            for name in ("time", "node_ids", "displacement"):
                nodout.create_dataset(name, data=getattr(parts.nodout, name))
        if parts.rcforc is not None:
            rcforc = out.create_group("rcforc")
            rcforc.attrs["name"] = parts.rcforc_name
            for (ident, side), (time, force) in parts.rcforc.series.items():
                series = rcforc.create_group(f"{ident}-{side}")
                series.create_dataset("time", data=time)
                series.create_dataset("force", data=force)
        if parts.punch_table is not None:
            table = out.create_group("punch_csv")
            table.attrs["name"] = parts.punch_table_name
            for name, values in parts.punch_table.items():
                table.create_dataset(name, data=values)
    return path


def read_checked(path: str | Path) -> SimulationParts:
    """The parts a check stored (`write_checked`); ValueError naming the file when it is none."""
    path = Path(path)
    with open_read_only(path) as stored:
        if stored.attrs.get("schema") != SCHEMA:
            raise ValueError(f"{path.name}: not a checked simulation (schema {stored.attrs.get('schema')!r})")
        group = stored["model"]
        arrays = {name: group[name][()] for name in ("node_ids", "node_xyz", "shells", "solids", "time")}
        thickness = group["shell_thickness"][()] if "shell_thickness" in group else None
        unit = str(stored.attrs["length_unit"]) or None
        time_unit = float(stored.attrs["time_unit_s"])
        kind = str(stored.attrs["kind"])
        nodout = nodout_name = None
        if "nodout" in stored:
            found = stored["nodout"]
            nodout = NodeHistories(time=found["time"][()], node_ids=found["node_ids"][()],
                                   displacement=found["displacement"][()])  # fmt: skip
            nodout_name = str(found.attrs["name"])
        rcforc = rcforc_name = None
        if "rcforc" in stored:
            found = stored["rcforc"]
            series = {}
            for key, item in found.items():
                ident, side = key.split("-", 1)
                series[(int(ident), side)] = (item["time"][()], item["force"][()])
            rcforc, rcforc_name = ContactForces(series), str(found.attrs["name"])
        table = table_name = None
        if "punch_csv" in stored:
            found = stored["punch_csv"]
            table = {name: found[name][()] for name in found}
            table_name = str(found.attrs["name"])
    n_states = len(arrays["time"])

    def displacement(i: int) -> np.ndarray:
        if not 0 <= i < n_states:
            raise ValueError(f"{path.name}: no state {i}; it has {n_states}")
        with open_read_only(path) as again:
            return np.asarray(again["model/displacement"][i])

    model = FEResults(source=str(path), kind=kind, shell_thickness=thickness, displacement=displacement,
                      length_unit=unit, time_unit_s=None if math.isnan(time_unit) else time_unit,
                      **arrays)  # fmt: skip
    return SimulationParts(model=model, nodout=nodout, nodout_name=nodout_name or "nodout", rcforc=rcforc,
                           rcforc_name=rcforc_name or "rcforc", punch_table=table,
                           punch_table_name=table_name or "punch.csv")  # fmt: skip
