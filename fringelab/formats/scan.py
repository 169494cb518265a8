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
from operator import attrgetter
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import h5py
import numpy as np

from fringelab.formats import SCAN_EXPORT_FORMATS
from fringelab.formats.atomic import atomic_path
from fringelab.formats.hdf5 import json_text, require_schema, unit_dataset

if TYPE_CHECKING:
    from fringelab.science.scan import ScanResult

SCHEMA = "fringelab.scan"


@dataclass(frozen=True)
class ScanDataset:
    """One dataset of a scan file, declared: where it is, its dtype (None: as computed), unit and description, the
    `ScanResult` attribute it stores (dotted for the decoding's) and how it is stored: "point", one row a point
    (compressed when there are more than 1000), or "pixel", one camera image (always compressed). It is read
    back into the `StoredScan` field of the attribute's last name."""

    path: str
    dtype: Any
    unit: str
    description: str
    attribute: str
    per: Literal["point", "pixel"]

    @property
    def field(self) -> str:
        return self.attribute.rsplit(".", 1)[-1]


def scan_layout() -> tuple[ScanDataset, ...]:
    """Every dataset of a scan file in the order they are made (the module docstring describes them)."""
    f32, u8 = np.float32, np.uint8
    return (
        ScanDataset("points/xyz_mm", f32, "mm",
                    "points in the camera frame (x right, y down, z along the optical axis)", "points_cam_mm", "point"),
        ScanDataset("points/sigma_mm", f32, "mm",
                    "σ of each point along its camera ray (edge or code, and the calibration)", "sigma_mm", "point"),
        ScanDataset("points/source", u8, "1", "0 stripe edge, 1 phase, 2 per-pixel code", "source", "point"),
        ScanDataset("points/q_px", f32, "px", "camera pixel (u, v) of each point", "q_px", "point"),
        ScanDataset("points/projector_px", f32, "px", "projector coordinate along the code's axis", "projector_px",
                    "point"),
        ScanDataset("depth/z_mm", None, "mm", "camera-frame z per camera pixel (NaN: none)", "depth_z_mm", "pixel"),
        ScanDataset("depth/sigma_mm", None, "mm", "σ of depth/z_mm", "depth_sigma_mm", "pixel"),
        ScanDataset("decoding/code", None, "1", "decoded code value (−1: none)", "decoding.code", "pixel"),
        ScanDataset("decoding/reason", None, "1",
                    "0 decoded, 1 a bit not clear, 2 shading too low, 3 beyond the projector", "decoding.reason",
                    "pixel"),
        ScanDataset("decoding/shading_grey", None, "grey", "white − black (8-bit scale)", "decoding.shading_grey",
                    "pixel"),
    )  # fmt: skip


def write_scan(path: str | Path, result: ScanResult, *, qa: dict[str, Any], patterns: dict[str, Any] | None = None,
               provenance: dict[str, Any] | None = None) -> Path:  # fmt: skip
    """Write a scan result file atomically (nothing under `path` until it is whole); qa: `science.scan.scan_qa`."""
    path = Path(path)
    decoding = result.decoding
    gzip = {"compression": "gzip", "compression_opts": 4, "shuffle": True}
    storage = {"point": gzip if len(result) > 1000 else {}, "pixel": gzip}
    with atomic_path(path) as partial, h5py.File(partial, "w") as file:
        file.attrs["schema"] = SCHEMA
        file.attrs["schema_version"] = 1
        file.attrs["axis"] = decoding.sequence.axis
        file.attrs["scan_axis"] = result.edges.scan_axis
        file.attrs["calibration_sigma"] = bool(result.calibration_sigma)
        file.attrs["qa"] = json_text(qa)
        file.attrs["provenance"] = json_text(provenance or {})
        file.attrs["patterns"] = json_text(patterns or {})
        for dataset in scan_layout():
            group_name, name = dataset.path.split("/")
            value = attrgetter(dataset.attribute)(result)
            if dataset.dtype is not None:
                value = value.astype(dataset.dtype)
            unit_dataset(file.require_group(group_name), name, value, unit=dataset.unit,
                         description=dataset.description, **storage[dataset.per])  # fmt: skip
    return path


@dataclass(frozen=True, eq=False)
class StoredScan:
    """A scan file's contents (`read_scan`), arrays as stored, each under the name of the `ScanResult` attribute
    it stores (`scan_layout`), and the file's axis, QA and provenance."""

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
        arrays = {dataset.field: file[dataset.path][()] for dataset in scan_layout()}
        return StoredScan(**arrays, axis=str(file.attrs["axis"]), qa=json.loads(file.attrs["qa"]),
                          provenance=json.loads(file.attrs["provenance"]))  # fmt: skip


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
