"""The projector table judged and mapped: a verdict with thresholds and what each means, and maps over the whole
image of the table's sensitivity (px of edge shift per mm of Z), the Z resolution that sensitivity gives at the
measured edge noise, and the table's coverage over the image and over Z.

Arrays in, arrays and a `Verdict` out; no OpenCV (the API judges stored tables with it). The table itself is
built in `projector.py`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .arrays import checked_array
from .verdict import Verdict, check, verdict_of

# Thresholds: METHOD.md's accuracy target is w within 0.05 mm RMS on the flat plate, so the table's own errors
# must stay well inside it; a stripe moving more than half a period between two heights cannot be tracked.
PROJECTOR_LIMITS: dict[str, tuple[float, float]] = {
    "coverage": (0.9, 0.6),
    "fit_rms_mm": (0.02, 0.05),
    "fit_p95_mm": (0.05, 0.1),
    "non_monotonic_pct": (0.1, 1.0),
    "insensitive_pct": (0.5, 5.0),
    "max_step_shift_periods": (0.25, 0.45),
    "z_resolution_mm": (0.02, 0.05),
}


def judge_projector(qa: Mapping[str, Any]) -> Verdict:
    """The projector table's verdict from its QA numbers (the fields of `ProjectorQA`, as stored)."""
    limits = PROJECTOR_LIMITS
    entries = max(int(qa["n_entries"]), 1)
    weakest = float(qa["sensitivity_px_per_mm"][0])  # 5th percentile of |dt/dZ|
    noise = float(qa["edge_noise_px"])
    resolution = noise / weakest if weakest > 0 else float("nan")
    checks = [
        check("coverage", float(qa["coverage"]), "of edges", good=limits["coverage"][0], bad=limits["coverage"][1],
              higher_is_better=True,
              what="share of the edges seen on the flat plate that have a table entry (elsewhere no height is "
              "measured)"),
        check("fit_rms_mm", float(qa["fit_rms_mm"]), "mm", good=limits["fit_rms_mm"][0],
              bad=limits["fit_rms_mm"][1],
              what="RMS error in Z of the table's polynomial fits (it adds to every measured height)"),
        check("fit_p95_mm", float(qa["fit_p95_mm"]), "mm", good=limits["fit_p95_mm"][0],
              bad=limits["fit_p95_mm"][1], what="95th percentile of the fits' Z errors (the worst places)"),
        check("non_monotonic", 100.0 * int(qa["n_non_monotonic"]) / entries, "% of entries",
              good=limits["non_monotonic_pct"][0], bad=limits["non_monotonic_pct"][1],
              what="entries left out because the edge moved back and forth with Z (ambiguous heights: a "
              "reflection, a defect or a wrong match)"),
        check("insensitive", 100.0 * int(qa["n_insensitive"]) / entries, "% of entries",
              good=limits["insensitive_pct"][0], bad=limits["insensitive_pct"][1],
              what="entries left out because the edge hardly moved with Z (no height can be read there)"),
        check("max_step_shift_periods", float(qa["max_step_shift_periods"]), "periods",
              good=limits["max_step_shift_periods"][0], bad=limits["max_step_shift_periods"][1],
              what="largest stripe shift between two calibration heights (beyond half a period stripes are "
              "confused: take smaller Z steps)"),
        check("z_resolution_mm", resolution, "mm", good=limits["z_resolution_mm"][0],
              bad=limits["z_resolution_mm"][1],
              what=f"Z resolution at the least sensitive edges: edge noise {noise:.3g} px / {weakest:.3g} px/mm"),
    ]  # fmt: skip
    return verdict_of(checks)


@dataclass(frozen=True, eq=False)
class ProjectorMaps:
    """A projector table mapped over its image in square cells of `cell_px` pixels.

    sensitivity_px_per_mm: (cells_v, cells_u) median |dt/dZ| of the entries whose reference position lies in the
    cell; z_resolution_mm: (cells_v, cells_u) the Z step the measured edge noise amounts to there (noise /
    sensitivity); coverage: (cells_v, cells_u) the share of the edges seen at the reference Z in the cell that
    have a table entry; NaN where no edge was seen. z_mm (J,), coverage_z (J,): the share of the entries whose
    fitted Z range holds each calibration height.
    """

    cell_px: int
    cells_u: int
    cells_v: int
    sensitivity_px_per_mm: np.ndarray
    z_resolution_mm: np.ndarray
    coverage: np.ndarray
    z_mm: np.ndarray
    coverage_z: np.ndarray


def projector_maps(
    *,
    image_shape: tuple[int, int],
    axis: str,
    reference_t_px: np.ndarray,
    sensitivity_px_per_mm: np.ndarray,
    z_mm: np.ndarray,
    z_lo_mm: np.ndarray,
    z_hi_mm: np.ndarray,
    edge_noise_px: float,
    cell_px: int = 16,
) -> ProjectorMaps:
    """Maps over the whole image (height, width = image_shape) of a table whose arrays are (K, S): K edges, S scan
    lines (`axis` "rows": scan lines are image rows and t the column; "cols": the transpose)."""
    if cell_px < 1:
        raise ValueError(f"cell_px must be ≥ 1, got {cell_px}")
    if axis not in ("rows", "cols"):
        raise ValueError(f"axis: expected 'rows' or 'cols', got {axis!r}")
    t_px = checked_array(reference_t_px, shape=(None, None), name="reference_t_px").astype(np.float64)
    shape = t_px.shape
    sensitivity = np.abs(checked_array(sensitivity_px_per_mm, shape=shape, name="sensitivity_px_per_mm"))
    z_lo = checked_array(z_lo_mm, shape=shape, name="z_lo_mm")
    z_hi = checked_array(z_hi_mm, shape=shape, name="z_hi_mm")
    height, width = image_shape
    cells_u, cells_v = -(-width // cell_px), -(-height // cell_px)
    line = np.broadcast_to(np.arange(shape[1], dtype=np.float64), shape)
    u_px, v_px = (t_px, line) if axis == "rows" else (line, t_px)
    seen = np.isfinite(u_px) & (u_px >= -0.5) & (u_px < width - 0.5) & (v_px >= -0.5) & (v_px < height - 0.5)
    entry = seen & np.isfinite(sensitivity)
    cell = ((v_px[seen] + 0.5) // cell_px).astype(int) * cells_u + ((u_px[seen] + 0.5) // cell_px).astype(int)
    n_cells = cells_u * cells_v
    n_seen = np.bincount(cell, minlength=n_cells)
    has = entry[seen]
    n_entry = np.bincount(cell, weights=has.astype(float), minlength=n_cells)
    coverage = np.where(n_seen > 0, n_entry / np.maximum(n_seen, 1), np.nan).reshape(cells_v, cells_u)
    median = np.full(n_cells, np.nan)
    order = np.argsort(cell[has], kind="stable")
    sorted_cells = cell[has][order]
    if sorted_cells.size:
        cells_with, starts = np.unique(sorted_cells, return_index=True)
        for index, chunk in zip(cells_with, np.split(sensitivity[seen][has][order], starts[1:]), strict=True):
            median[index] = np.median(chunk)
    sensitivity_map = median.reshape(cells_v, cells_u)
    with np.errstate(divide="ignore", invalid="ignore"):
        resolution = np.where(sensitivity_map > 0, edge_noise_px / sensitivity_map, np.nan)
    heights = np.asarray(z_mm, dtype=np.float64)
    lo, hi = z_lo[entry], z_hi[entry]
    count = max(int(entry.sum()), 1)
    coverage_z = np.array([np.count_nonzero((lo <= z + 1e-9) & (hi >= z - 1e-9)) / count for z in heights])
    return ProjectorMaps(
        cell_px=cell_px,
        cells_u=cells_u,
        cells_v=cells_v,
        sensitivity_px_per_mm=sensitivity_map,
        z_resolution_mm=resolution,
        coverage=coverage,
        z_mm=heights,
        coverage_z=coverage_z,
    )
