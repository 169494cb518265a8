"""Stored edges of a chunk of frames (HDF5, schema "fringelab.frame-edges"), handed between the workers of a
topography job.

Per edge point: line, t_px, polarity, chain, and (since issue 29) sigma_px, contrast_grey and beside_dark. Files
written before them lack them; they read with None: σ falls back to the frame's estimate from noise_px
(`uncertainty.edge_sigmas_px`), and no edge counts as beside a dark area (none was kept there at fringe periods)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from fringelab.formats.atomic import atomic_path
from fringelab.formats.hdf5 import SCHEMA_VERSION, json_text, require_schema
from fringelab.science.fringes import FrameEdges

if TYPE_CHECKING:
    pass


EDGES_SCHEMA = "fringelab.frame-edges"


def write_edges(path: str | Path, frames: Sequence[int], edges: Sequence[FrameEdges]) -> Path:
    """Store the located edges of a chunk of frames (recording indices `frames`) in one HDF5 file."""
    path = Path(path)
    if len(frames) != len(edges):
        raise ValueError(f"frames: {len(frames)} indices for {len(edges)} located frames")
    with atomic_path(path) as temp, h5py.File(temp, "w") as file:
        file.attrs["schema"] = EDGES_SCHEMA
        file.attrs["schema_version"] = SCHEMA_VERSION
        offsets = np.r_[0, np.cumsum([len(e) for e in edges])].astype(np.int64)
        file["frames"] = np.asarray(frames, np.int64)
        file["offsets"] = offsets
        for name, dtype in (("line", np.int32), ("t_px", np.float32), ("polarity", np.int8), ("chain", np.int32)):
            data = np.concatenate([getattr(e, name) for e in edges]) if edges else np.zeros(0, dtype)
            file.create_dataset(name, data=data.astype(dtype), compression="gzip", compression_opts=1, shuffle=True)
        meta = [
            {
                "axis": e.axis,
                "period_px": e.period_px,
                "image_shape": list(e.image_shape_hw_px),
                "noise_px": e.noise_px,
                "saturated_fraction": e.saturated_fraction,
                "dark_fraction": e.dark_fraction,
            }
            for e in edges
        ]
        for name in ("sigma_px", "contrast_grey"):
            if edges and all(getattr(e, name) is not None for e in edges):
                data = np.concatenate([np.asarray(getattr(e, name), np.float32) for e in edges])
                file.create_dataset(name, data=data, compression="gzip", compression_opts=1, shuffle=True)
        if edges and all(e.beside_dark is not None for e in edges):
            data = np.concatenate([np.asarray(e.beside_dark, np.bool_) for e in edges])
            file.create_dataset("beside_dark", data=data, compression="gzip", compression_opts=1)
        file.attrs["frames_json"] = json_text(meta)
        if edges and all(e.unusable is not None for e in edges):
            file.create_dataset(
                "unusable", data=np.stack([np.asarray(e.unusable, np.uint8) for e in edges]),
                compression="gzip", compression_opts=1,
            )  # fmt: skip
    return path


def read_edges(path: str | Path) -> tuple[np.ndarray, list[FrameEdges]]:
    """Frame indices and located edges stored by `write_edges`."""
    path = Path(path)
    with h5py.File(path, "r") as file:
        require_schema(file, EDGES_SCHEMA, path)
        offsets = file["offsets"][()]
        arrays = {name: file[name][()] for name in ("line", "t_px", "polarity", "chain")}
        # Absent in files written before the per-edge σ (see the module docstring).
        per_edge = {name: file[name][()] if name in file else None for name in ("sigma_px", "contrast_grey")}
        beside_dark = file["beside_dark"][()].astype(np.bool_) if "beside_dark" in file else None
        meta = json.loads(file.attrs["frames_json"])
        frames = file["frames"][()]
        unusable = file["unusable"][()] if "unusable" in file else None
    edges = []
    for i, m in enumerate(meta):
        lo, hi = offsets[i], offsets[i + 1]
        edges.append(
            FrameEdges(
                axis=m["axis"],
                period_px=float(m["period_px"]),
                image_shape_hw_px=(int(m["image_shape"][0]), int(m["image_shape"][1])),
                line=arrays["line"][lo:hi],
                t_px=arrays["t_px"][lo:hi],
                polarity=arrays["polarity"][lo:hi],
                chain=arrays["chain"][lo:hi],
                noise_px=float("nan") if m["noise_px"] is None else float(m["noise_px"]),
                saturated_fraction=float(m["saturated_fraction"]),
                dark_fraction=float(m["dark_fraction"]),
                unusable=None if unusable is None else unusable[i],
                sigma_px=None if per_edge["sigma_px"] is None else per_edge["sigma_px"][lo:hi],
                contrast_grey=None if per_edge["contrast_grey"] is None else per_edge["contrast_grey"][lo:hi],
                beside_dark=None if beside_dark is None else beside_dark[lo:hi],
            )
        )
    return frames, edges
