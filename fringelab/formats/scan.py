"""Scan result files (HDF5) and their exports: points CSV and binary PLY (docs/file-formats.md "Scan result").

Belongs here: writing a `science.scan.ScanResult` atomically (`write_scan`), its one reader (`read_scan`, numpy and
h5py only: the API reads scans), and the exports `points-csv` and `ply` (`export_scan`). Not here: computing the
scan (`science/scan.py`).

Layout (schema "fringelab.scan", version 1; every dataset with its unit and description):
  attrs: schema, schema_version, axis, scan_axis, calibration_sigma, qa (JSON), provenance (JSON), patterns (JSON)
  points/xyz_mm (N, 3) float32, camera frame; points/sigma_mm (N,) σ along the camera ray; points/source (N,) uint8
      (0 stripe edge, 1 phase, 2 per-pixel code); points/q_px (N, 2) camera pixel; points/projector_px (N,)
  depth/z_mm, depth/sigma_mm (H, W) float32: camera-frame z of the best point at each pixel (NaN: none)
  decoding/code (H, W) int32 (−1: none), decoding/reason (H, W) uint8, decoding/shading_grey (H, W) float32
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

from fringelab.formats import SCAN_EXPORT_FORMATS
from fringelab.formats.atomic import atomic_path
from fringelab.formats.hdf5 import json_text, require_schema, unit_dataset

if TYPE_CHECKING:
    from fringelab.science.scan import ScanResult

SCHEMA = "fringelab.scan"


def write_scan(path: str | Path, result: ScanResult, *, qa: dict[str, Any], patterns: dict[str, Any] | None = None,
               provenance: dict[str, Any] | None = None) -> Path:  # fmt: skip
    """Write a scan result file atomically (nothing under `path` until it is whole); qa: `science.scan.scan_qa`."""
    path = Path(path)
    decoding = result.decoding
    gzip = {"compression": "gzip", "compression_opts": 4, "shuffle": True}
    with atomic_path(path) as partial, h5py.File(partial, "w") as file:
        file.attrs["schema"] = SCHEMA
        file.attrs["schema_version"] = 1
        file.attrs["axis"] = decoding.sequence.axis
        file.attrs["scan_axis"] = result.edges.scan_axis
        file.attrs["calibration_sigma"] = bool(result.calibration_sigma)
        file.attrs["qa"] = json_text(qa)
        file.attrs["provenance"] = json_text(provenance or {})
        file.attrs["patterns"] = json_text(patterns or {})
        points = file.create_group("points")
        chunked = gzip if len(result) > 1000 else {}
        unit_dataset(
            points,
            "xyz_mm",
            result.points_cam_mm.astype(np.float32),
            unit="mm",
            description="points in the camera frame (x right, y down, z along the optical axis)",
            **chunked,
        )
        unit_dataset(
            points,
            "sigma_mm",
            result.sigma_mm.astype(np.float32),
            unit="mm",
            description="σ of each point along its camera ray (edge or code, and the calibration)",
            **chunked,
        )
        unit_dataset(
            points,
            "source",
            result.source.astype(np.uint8),
            unit="1",
            description="0 stripe edge, 1 phase, 2 per-pixel code",
            **chunked,
        )
        unit_dataset(
            points,
            "q_px",
            result.q_px.astype(np.float32),
            unit="px",
            description="camera pixel (u, v) of each point",
            **chunked,
        )
        unit_dataset(
            points,
            "projector_px",
            result.projector_px.astype(np.float32),
            unit="px",
            description="projector coordinate along the code's axis",
            **chunked,
        )
        depth = file.create_group("depth")
        unit_dataset(
            depth,
            "z_mm",
            result.depth_z_mm,
            unit="mm",
            description="camera-frame z per camera pixel (NaN: none)",
            **gzip,
        )
        unit_dataset(depth, "sigma_mm", result.depth_sigma_mm, unit="mm", description="σ of depth/z_mm", **gzip)
        group = file.create_group("decoding")
        unit_dataset(group, "code", decoding.code, unit="1", description="decoded code value (−1: none)", **gzip)
        unit_dataset(
            group,
            "reason",
            decoding.reason,
            unit="1",
            description="0 decoded, 1 a bit not clear, 2 shading too low, 3 beyond the projector",
            **gzip,
        )
        unit_dataset(group, "shading_grey", decoding.shading_grey, unit="grey",
                     description="white − black (8-bit scale)", **gzip)  # fmt: skip
    return path


@dataclass(frozen=True, eq=False)
class StoredScan:
    """A scan file's contents (`read_scan`), arrays as stored."""

    points_cam_mm: np.ndarray
    sigma_mm: np.ndarray
    source: np.ndarray
    q_px: np.ndarray
    projector_px: np.ndarray
    depth_z_mm: np.ndarray
    depth_sigma_mm: np.ndarray
    code: np.ndarray
    reason: np.ndarray
    shading_grey: np.ndarray
    axis: str
    qa: dict[str, Any]
    provenance: dict[str, Any]


def is_scan_file(path: str | Path) -> bool:
    """Whether `path` is an HDF5 file of this schema (cheap: the attribute only)."""
    try:
        with h5py.File(path, "r") as file:
            return file.attrs.get("schema") == SCHEMA
    except OSError:
        return False


def read_scan(path: str | Path) -> StoredScan:
    """Read a scan file (ValueError naming it when it is not one)."""
    path = Path(path)
    try:
        file = h5py.File(path, "r")
    except OSError:
        raise ValueError(f"{path.name}: not an HDF5 file") from None
    with file:
        require_schema(file, SCHEMA, Path(path.name))
        return StoredScan(
            points_cam_mm=file["points/xyz_mm"][()], sigma_mm=file["points/sigma_mm"][()],
            source=file["points/source"][()], q_px=file["points/q_px"][()],
            projector_px=file["points/projector_px"][()], depth_z_mm=file["depth/z_mm"][()],
            depth_sigma_mm=file["depth/sigma_mm"][()], code=file["decoding/code"][()],
            reason=file["decoding/reason"][()], shading_grey=file["decoding/shading_grey"][()],
            axis=str(file.attrs["axis"]), qa=json.loads(file.attrs["qa"]),
            provenance=json.loads(file.attrs["provenance"]),
        )  # fmt: skip


PLY_COMMENT = "fringelab scan: camera frame (x right, y down, z along the optical axis), mm; sigma_mm along the ray"


def export_scan(path: str | Path, fmt: str, out: str | Path) -> Path:
    """Export a scan file: "points-csv" (x_mm,y_mm,z_mm,sigma_mm,source,u_px,v_px) or "ply" (binary little-endian
    PLY: float x, y, z, float sigma_mm, uchar source; readable by Open3D, MeshLab and ParaView)."""
    if fmt not in SCAN_EXPORT_FORMATS:
        raise ValueError(f"format: a scan exports as one of {SCAN_EXPORT_FORMATS}, got {fmt!r}")
    scan = read_scan(path)
    out = Path(out)
    with atomic_path(out) as partial:
        if fmt == "points-csv":
            with partial.open("w", newline="", encoding="utf-8") as handle:
                writer = csv.writer(handle)
                writer.writerow(["x_mm", "y_mm", "z_mm", "sigma_mm", "source", "u_px", "v_px"])
                for start in range(0, len(scan.sigma_mm), 100_000):
                    block = slice(start, start + 100_000)
                    xyz, sigma, q = scan.points_cam_mm[block], scan.sigma_mm[block], scan.q_px[block]
                    rows = zip(*(np.char.mod("%.5f", xyz[:, i]) for i in range(3)), np.char.mod("%.5f", sigma),
                               scan.source[block].astype(int), np.char.mod("%.3f", q[:, 0]),
                               np.char.mod("%.3f", q[:, 1]), strict=True)  # fmt: skip
                    writer.writerows(rows)
        else:
            vertices = np.empty(len(scan.sigma_mm), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                                            ("sigma_mm", "<f4"), ("source", "u1")])  # fmt: skip
            vertices["x"], vertices["y"], vertices["z"] = scan.points_cam_mm.T
            vertices["sigma_mm"] = scan.sigma_mm
            vertices["source"] = scan.source
            header = (
                "ply\nformat binary_little_endian 1.0\n"
                f"comment {PLY_COMMENT}\n"
                f"element vertex {len(vertices)}\n"
                "property float x\nproperty float y\nproperty float z\nproperty float sigma_mm\n"
                "property uchar source\nend_header\n"
            )
            with partial.open("wb") as handle:
                handle.write(header.encode("ascii"))
                handle.write(vertices.tobytes())
    return out


def read_ply_vertices(path: str | Path) -> np.ndarray:
    """The vertices of a binary little-endian PLY with float/double/uchar/int properties, as a structured array
    (to check an export; not a general PLY reader)."""
    types = {"float": "<f4", "float32": "<f4", "double": "<f8", "uchar": "u1", "uint8": "u1", "int": "<i4"}
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").splitlines()
    if lines[0] != "ply" or lines[1] != "format binary_little_endian 1.0":
        raise ValueError(f"{Path(path).name}: not a binary little-endian PLY")
    count, fields = 0, []
    for line in lines:
        parts = line.split()
        if parts[:2] == ["element", "vertex"]:
            count = int(parts[2])
        elif parts and parts[0] == "property":
            fields.append((parts[2], types[parts[1]]))
    return np.frombuffer(data, dtype=np.dtype(fields), count=count, offset=end)
