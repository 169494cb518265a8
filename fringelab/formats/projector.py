"""The projector calibration file (HDF5, schema "fringelab.projector-calibration"): the look-up table and its QA."""

from __future__ import annotations

import json
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

from fringelab.formats.atomic import atomic_path
from fringelab.formats.hdf5 import SCHEMA_VERSION, json_text, require_schema, unit_dataset
from fringelab.science.fringes import EdgeSettings
from fringelab.science.projector import PatternEdges, ProjectorCalibration, ProjectorQA

if TYPE_CHECKING:
    pass


PROJECTOR_SCHEMA = "fringelab.projector-calibration"


_PROJECTOR_ARRAYS = {
    "reference_t_px": ("px", "position of edge k on scan line s at the reference Z"),
    "t_centre_px": ("px", "centre of the polynomial's variable τ = (t − t_centre)/t_scale"),
    "t_scale_px": ("px", "scale of the polynomial's variable"),
    "t_lo_px": ("px", "lowest position looked up (sampled range plus noise margin)"),
    "t_hi_px": ("px", "highest position looked up (sampled range plus noise margin)"),
    "z_lo_mm": ("mm", "lowest Z sampled for the entry"),
    "z_hi_mm": ("mm", "highest Z sampled for the entry"),
    "sensitivity_px_per_mm": ("px/mm", "dt/dZ of the entry (linear fit)"),
    "fit_rms_mm": ("mm", "RMS residual in Z of the entry's polynomial fit"),
}


def write_projector_calibration(calibration: ProjectorCalibration, path: str | Path) -> Path:
    """Write a projector calibration as HDF5 (arrays (K, S[, J]) with NaN where there is no entry)."""
    path = Path(path)
    with atomic_path(path) as temp, h5py.File(temp, "w") as file:
        file.attrs["schema"] = PROJECTOR_SCHEMA
        file.attrs["schema_version"] = SCHEMA_VERSION
        file.attrs["created_utc"] = datetime.now(UTC).isoformat(timespec="seconds")
        file.attrs["image_height_px"], file.attrs["image_width_px"] = calibration.image_shape_hw_px
        file.attrs["axis"] = calibration.axis
        file.attrs["period_px"] = calibration.period_px
        file.attrs["reference_z_mm"] = calibration.reference_z_mm
        file.attrs["camera_fingerprint"] = calibration.camera_fingerprint
        file.attrs["edge_settings_json"] = json_text(asdict(calibration.edges))
        file.attrs["qa_json"] = json_text(asdict(calibration.qa))
        file.attrs["provenance_json"] = json_text(calibration.provenance)
        file.attrs["description"] = (
            "Projector look-up table (docs/method.md §4): lut_t_px[k, s, j] is the position (px, along scan line s) of "
            "stripe edge k on the flat plate at Z = z_mm[j]; Z(t) = Σ_i coefficients[k, s, i]·τ^i with "
            "τ = (t − t_centre_px)/t_scale_px for t_lo_px ≤ t ≤ t_hi_px. axis 'rows': scan lines are image rows and "
            "t the column; 'cols': scan lines are columns and t the row."
        )
        n_lines = calibration.n_lines
        chunk = (1, n_lines, len(calibration.z_mm))
        unit_dataset(file, "z_mm", calibration.z_mm, unit="mm", description="calibration heights, increasing")
        unit_dataset(
            file, "polarity", calibration.polarity, unit="1", description="+1 dark→bright along +t, −1 falling"
        )
        unit_dataset(
            file,
            "lut_t_px",
            calibration.lut_t_px,
            unit="px",
            description="the table, NaN where not seen",
            chunks=chunk,
            compression="gzip",
            compression_opts=4,
            shuffle=True,
        )
        unit_dataset(
            file,
            "coefficients",
            calibration.coefficients,
            unit="mm",
            description="Z(τ) polynomial coefficients, lowest power first",
            compression="gzip",
        )
        for name, (unit, description) in _PROJECTOR_ARRAYS.items():
            unit_dataset(file, name, getattr(calibration, name), unit=unit, description=description, compression="gzip")
        if calibration.pattern_edges is not None:
            dataset = unit_dataset(
                file, "pattern_edge_projector_px", calibration.pattern_edges.projector_px, unit="px",
                description="projector coordinate of each edge k along pattern_axis (a table from a camera–projector "
                "model; what a Gray code at rest names the edges by)",
            )  # fmt: skip
            dataset.attrs["pattern_axis"] = calibration.pattern_edges.axis
    return path


def read_projector_calibration(path: str | Path) -> ProjectorCalibration:
    """Read a projector calibration written by `write_projector_calibration`. ValueError for anything else."""
    path = Path(path)
    try:
        file = h5py.File(path, "r")
    except OSError as error:
        raise ValueError(f"{path}: not a readable HDF5 file ({error})") from None
    with file:
        require_schema(file, PROJECTOR_SCHEMA, path)
        try:
            qa: dict[str, Any] = {
                key: tuple(np.nan if v is None else v for v in value)
                if isinstance(value, list)
                else (np.nan if value is None else value)
                for key, value in json.loads(file.attrs["qa_json"]).items()
            }
            arrays = {name: file[name][()] for name in _PROJECTOR_ARRAYS}
            pattern_edges = None
            if "pattern_edge_projector_px" in file:  # only tables from a camera–projector model have it
                dataset = file["pattern_edge_projector_px"]
                axis = str(dataset.attrs["pattern_axis"])
                if axis not in ("columns", "rows"):
                    raise ValueError(
                        f"{path}: pattern_edge_projector_px's pattern_axis must be columns or rows, got {axis!r}"
                    )
                pattern_edges = PatternEdges(axis="columns" if axis == "columns" else "rows", projector_px=dataset[()])
            return ProjectorCalibration(
                image_shape_hw_px=(int(file.attrs["image_height_px"]), int(file.attrs["image_width_px"])),
                edges=EdgeSettings.from_dict(json.loads(file.attrs["edge_settings_json"])),
                reference_z_mm=float(file.attrs["reference_z_mm"]),
                z_mm=file["z_mm"][()],
                polarity=file["polarity"][()],
                lut_t_px=file["lut_t_px"][()],
                coefficients=file["coefficients"][()],
                qa=ProjectorQA(**qa),
                camera_fingerprint=str(file.attrs["camera_fingerprint"]),
                provenance=json.loads(file.attrs["provenance_json"]),
                pattern_edges=pattern_edges,
                **arrays,
            )
        except (KeyError, TypeError) as error:
            raise ValueError(f"{path}: malformed projector calibration ({type(error).__name__}: {error})") from None
