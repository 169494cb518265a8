"""The projector look-up table of docs/method.md §4 generated from a camera–projector model instead of a Z-stack
(docs/procam.md §5).

Belongs here: where each stripe edge of the pattern a digital projector shows during a deformation test falls on
each scan line for a flat plate at each height Z, computed from the camera's calibration (which fixes the plate's
frame) and the camera–projector model, then fitted exactly as a Z-stack's table is (`projector.
calibration_from_positions`), so a lab without a Z stage runs the same topography. Not here: the table's fits and
look-up (`projector.py`), the model (`procam.py`).

Frames. The camera calibration (Heikkilä, `camera.py`) gives the plate's object frame: p_cam = M·p_obj + t. The
model's camera frame is the same camera's; the two must describe one camera (same size; the intrinsics the
camera calibration's, since the table's rays are its rays). p_proj = R·p_cam + T.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from .camera import rays_from_pixels
from .fringes import EdgeSettings
from .procam import ProcamModel, project_to_projector, rigid_transform
from .projector import (
    CalibrationMismatchError,
    CameraModel,
    PatternEdges,
    ProjectorCalibration,
    ProjectorSettings,
    calibration_from_positions,
)


@dataclass(frozen=True)
class StripePattern:
    """The binary stripes a digital projector shows during the test: bright where
    (x − offset_px) mod period_px < period_px / 2, x the projector coordinate along `axis` ("columns": x, vertical
    stripes; "rows": y), so edges lie at x = offset_px + m·period_px/2, rising (dark → bright along +x) for even m."""

    axis: Literal["columns", "rows"]
    period_px: float
    offset_px: float = -0.5

    def __post_init__(self) -> None:
        if not self.period_px >= 2.0:
            raise ValueError(f"period_px: expected ≥ 2 projector pixels, got {self.period_px}")

    def edges(self, extent_px: int) -> tuple[np.ndarray, np.ndarray]:
        """Projector coordinates (M,) of the edges within the projector (−½ .. extent − ½, exclusive) and their
        polarity along +x (M,) (+1 rising)."""
        half = 0.5 * self.period_px
        m = np.arange(np.ceil((-0.5 - self.offset_px) / half), np.floor((extent_px - 0.5 - self.offset_px) / half) + 1)
        x = self.offset_px + m * half
        inside = (x > -0.5) & (x < extent_px - 0.5)
        m, x = m[inside], x[inside]
        return x, np.where(m % 2 == 0, 1, -1).astype(np.int8)


def procam_table_positions(
    model: ProcamModel,
    camera_model: CameraModel,
    pattern: StripePattern,
    z_mm: Sequence[float],
    *,
    scan_axis: Literal["rows", "cols"],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edge positions (K, S, J) (NaN where an edge is not on a line at a height) in stripe order along +t, each
    edge's polarity along +t (K,) and its projector coordinate along the pattern's axis (K,). Every pixel centre of
    a scan line is intersected with each plane Z; its projector coordinate follows (distortion included), and each
    edge's t is interpolated linearly between the two pixels it falls between (the coordinate's curvature over one
    pixel is far below 0.001 px)."""
    camera = camera_model.camera
    width, height = camera.image_width_px, camera.image_height_px
    if (width, height) != tuple(model.camera_size_wh_px):
        cw, ch = model.camera_size_wh_px
        raise CalibrationMismatchError(
            f"the camera calibration is for {width} × {height} px but the camera–projector calibration's camera is "
            f"{cw} × {ch} px: they must describe one camera"
        )
    n_lines, n_samples = (height, width) if scan_axis == "rows" else (width, height)
    t = np.arange(n_samples, dtype=np.float64)
    s = np.arange(n_lines, dtype=np.float64)
    tt, ss = np.meshgrid(t, s)
    q = np.column_stack([tt.ravel(), ss.ravel()] if scan_axis == "rows" else [ss.ravel(), tt.ravel()])
    centre_obj, directions_obj = rays_from_pixels(camera, q, inverse=camera_model.inverse)
    rotation, translation = camera.rotation, camera.translation_mm
    index = 0 if pattern.axis == "columns" else 1
    extent = model.projector_size_wh_px[index]
    edge_x, edge_polarity = pattern.edges(extent)
    z = np.asarray(z_mm, np.float64)
    lut = np.full((len(edge_x), n_lines, len(z)), np.nan)
    direction_sign = 0.0
    for j, height_mm in enumerate(z):
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = (height_mm - centre_obj[2]) / directions_obj[:, 2]
        points_obj = centre_obj + lam[:, None] * directions_obj
        points_cam = rigid_transform(rotation, translation, points_obj)
        coordinate = project_to_projector(model, points_cam)[:, index].reshape(n_lines, n_samples)
        rising = np.nanmedian(np.diff(coordinate, axis=1)) > 0
        direction_sign = direction_sign or (1.0 if rising else -1.0)
        rows, ts = (coordinate, t) if rising else (coordinate[:, ::-1], t[::-1])
        # Lines with a gap or a fold (the distortion beyond its range) get no entry rather than a wrong one.
        usable = np.all(np.isfinite(rows), axis=1) & np.all(np.diff(rows, axis=1) > 0, axis=1)
        if not np.any(usable):
            continue
        # One search for every (line, edge): each line shifted past the one before, so the whole is increasing.
        lo, hi = float(np.min(rows[usable])), float(np.max(rows[usable]))
        stride = hi - lo + 10.0
        shifted = (rows[usable] - lo + stride * np.arange(np.count_nonzero(usable))[:, None]).ravel()
        line_index = np.flatnonzero(usable)
        queries = (edge_x[None, :] - lo) + stride * np.arange(len(line_index))[:, None]  # (L, K)
        position = np.searchsorted(shifted, queries.ravel()).reshape(queries.shape)
        base = np.arange(len(line_index))[:, None] * n_samples
        inside = (edge_x[None, :] >= rows[usable][:, :1]) & (edge_x[None, :] <= rows[usable][:, -1:])
        right = np.clip(position, base + 1, base + n_samples - 1)
        left = right - 1
        x_left, x_right = shifted[left], shifted[right]
        fraction = (queries - x_left) / (x_right - x_left)
        t_left = ts[left - base]
        t_right = ts[right - base]
        values = t_left + fraction * (t_right - t_left)
        lut[:, line_index, j] = np.where(inside, values, np.nan).T
    order = np.arange(len(edge_x)) if direction_sign > 0 else np.arange(len(edge_x))[::-1]
    seen = np.any(np.isfinite(lut), axis=(1, 2))
    order = order[seen[order]]
    return lut[order], (edge_polarity[order] * int(direction_sign)).astype(np.int8), edge_x[order]


def stripe_scan_axis(
    model: ProcamModel, camera_model: CameraModel, pattern: StripePattern, *, reference_z_mm: float = 0.0
) -> Literal["rows", "cols"]:
    """ "rows" when the stripes cross the image's rows more than its columns at the reference height (the projector
    coordinate along the pattern's axis changes faster along u than along v at the image centre), else "cols"."""
    camera = camera_model.camera
    u, v = 0.5 * (camera.image_width_px - 1), 0.5 * (camera.image_height_px - 1)
    q = np.array([[u, v], [u + 10.0, v], [u, v + 10.0]])
    centre_obj, directions_obj = rays_from_pixels(camera, q, inverse=camera_model.inverse)
    lam = (reference_z_mm - centre_obj[2]) / directions_obj[:, 2]
    points_cam = rigid_transform(camera.rotation, camera.translation_mm, centre_obj + lam[:, None] * directions_obj)
    coordinate = project_to_projector(model, points_cam)[:, 0 if pattern.axis == "columns" else 1]
    return "rows" if abs(coordinate[1] - coordinate[0]) >= abs(coordinate[2] - coordinate[0]) else "cols"


def projector_table_from_model(
    model: ProcamModel,
    camera_model: CameraModel,
    pattern: StripePattern,
    z_mm: Sequence[float],
    *,
    scan_axis: Literal["rows", "cols"] | None = None,
    settings: ProjectorSettings | None = None,
    edges: EdgeSettings | None = None,
    provenance: dict[str, Any] | None = None,
) -> ProjectorCalibration:
    """The topography's projector table for heights z_mm (increasing; the Z range the test needs) from the model.

    edges: the edge settings the test's frames will be processed with (axis and period); None fixes them from the
    table: the scan axis given and the median stripe period in the image at the reference height.
    scan_axis: None takes the image axis along which the pattern's projector coordinate changes most."""
    settings = ProjectorSettings() if settings is None else settings
    if scan_axis is None:
        scan_axis = stripe_scan_axis(model, camera_model, pattern, reference_z_mm=settings.reference_z_mm)
    lut, polarity, edge_projector_px = procam_table_positions(model, camera_model, pattern, z_mm, scan_axis=scan_axis)
    z = np.asarray(z_mm, np.float64)
    j_ref = int(np.argmin(np.abs(z - settings.reference_z_mm)))
    if edges is None:
        spacing = np.diff(lut[:, :, j_ref], axis=0)
        period = 2.0 * float(np.nanmedian(np.abs(spacing)))
        edges = replace(settings.edges, axis=scan_axis, period_px=period)
    camera = camera_model.camera
    return calibration_from_positions(
        lut, z, polarity, camera_model, settings=replace(settings, edges=edges), edge_settings=edges,
        image_shape_hw_px=(camera.image_height_px, camera.image_width_px),
        provenance={"source": "camera–projector model", **(provenance or {})},
        pattern_edges=PatternEdges(axis=pattern.axis, projector_px=edge_projector_px),
    )  # fmt: skip
