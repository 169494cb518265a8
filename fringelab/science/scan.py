"""A structured-light scan: one coded sequence and a camera–projector model → points in the camera frame with σ
(docs/procam.md §3).

Belongs here: checking that the recording, the sequence and the calibration belong together, decoding, the points
of the coded stripe edges (sub-pixel, σ from the edge and the calibration), of the unwrapped phase where the
sequence has one, and of the per-pixel code where neither is near (σ of a whole band), and the depth map on the
camera grid. Not here: decoding (`graycode.py`), triangulating (`procam.py`), files (`fringelab.formats.scan`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import MeasurementError
from .fringes import EdgeSettings
from .graycode import REASON_LABELS, CodedEdges, DecodeSettings, Decoding, PatternSequence, coded_edges, decode
from .procam import ProcamModel, point_sigma_mm

# Where each point came from (`ScanResult.source`).
SOURCE_EDGE = 0
SOURCE_PHASE = 1
SOURCE_CODE = 2
SOURCE_LABELS = {SOURCE_EDGE: "stripe edge", SOURCE_PHASE: "phase", SOURCE_CODE: "per-pixel code"}


class ScanMismatchError(MeasurementError):
    """The recording, its pattern sequence and the calibration do not belong together."""


@dataclass(frozen=True)
class ScanSettings:
    """decode: the decoding's settings; edges: the edge locator's (None: `graycode.GRAY_EDGE_SETTINGS`);
    code_points: add a point from the per-pixel code at every decoded pixel that holds no edge point and has
    no phase (σ of a whole band: they show the shape, the edges measure it).

    projector_scale_xy, projector_offset_xy_px: how the patterns' projector pixels map to the calibration's, per
    axis: x_calibration = (x_patterns + ½)·scale − ½ + offset (pixel centres at integers in both). A calibration
    may count a projector's pixels otherwise than its patterns do: a diamond-pixel DLP calibrated in square
    pixels (scale 0.5 along its rows), or patterns whose bands start elsewhere than the calibration's pixel 0
    (docs/procam.md §8)."""

    decode: DecodeSettings = field(default_factory=DecodeSettings)
    edges: EdgeSettings | None = None
    code_points: bool = True
    projector_scale_xy: tuple[float, float] = (1.0, 1.0)
    projector_offset_xy_px: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if len(self.projector_scale_xy) != 2 or not all(v > 0 for v in self.projector_scale_xy):
            raise ValueError(f"projector_scale_xy: expected two positive factors, got {self.projector_scale_xy}")
        if len(self.projector_offset_xy_px) != 2 or not all(np.isfinite(v) for v in self.projector_offset_xy_px):
            raise ValueError(f"projector_offset_xy_px: expected two finite offsets, got {self.projector_offset_xy_px}")


@dataclass(frozen=True, eq=False)
class ScanResult:
    """Points in the camera frame (mm) and the decoding's QA.

    points_cam_mm: (N, 3); sigma_mm: (N,) σ along the camera ray; source: (N,) uint8 SOURCE_*; q_px: (N, 2) camera
    pixel of each; projector_px: (N,) projector coordinate along the code's axis.
    depth_z_mm, depth_sigma_mm: (H, W) float32 camera-frame z and its σ of the best point at each pixel (NaN: none).
    decoding: the per-pixel decoding (code, reason, shading); edges: the coded edges.
    calibration_sigma: whether the calibration's own σ is in sigma_mm (False: the calibration file gave no RMS).
    """

    points_cam_mm: np.ndarray
    sigma_mm: np.ndarray
    source: np.ndarray
    q_px: np.ndarray
    projector_px: np.ndarray
    depth_z_mm: np.ndarray
    depth_sigma_mm: np.ndarray
    decoding: Decoding
    edges: CodedEdges
    calibration_sigma: bool

    def __len__(self) -> int:
        return len(self.sigma_mm)


def check_scan_inputs(
    image_shape_hw_px: tuple[int, int],
    sequence: PatternSequence,
    model: ProcamModel,
    *,
    recording: str = "the recording",
) -> None:
    """ScanMismatchError when the frames are not the calibration's camera size, or the sequence's projector is not
    the calibration's projector."""
    height, width = image_shape_hw_px
    if (width, height) != tuple(model.camera_size_wh_px):
        cw, ch = model.camera_size_wh_px
        raise ScanMismatchError(
            f"{recording} has frames of {width} × {height} px but the calibration's camera is {cw} × {ch} px: use "
            "the calibration of this camera (or give the calibration's image size if the file has none)"
        )
    if tuple(sequence.projector_size_wh_px) != tuple(model.projector_size_wh_px):
        pw, ph = model.projector_size_wh_px
        sw, sh = sequence.projector_size_wh_px
        raise ScanMismatchError(
            f"patterns.json: projector_size_px [{sw}, {sh}] differs from the calibration's projector ({pw} × {ph} px)"
        )


def scan(
    frames: Sequence[np.ndarray],
    sequence: PatternSequence,
    model: ProcamModel,
    *,
    settings: ScanSettings | None = None,
    recording: str = "the recording",
) -> ScanResult:
    """Points of one coded sequence (see the module docstring)."""
    settings = ScanSettings() if settings is None else settings
    shape = np.asarray(frames[0]).shape[:2]
    check_scan_inputs((int(shape[0]), int(shape[1])), sequence, model, recording=recording)
    decoding = decode(frames, sequence, settings=settings.decode)
    edges = coded_edges(decoding, edge_settings=settings.edges)
    calibration_sigma = bool(np.isfinite(model.camera_sigma_px) and np.isfinite(model.projector_sigma_px))
    cam_cal = model.camera_sigma_px if calibration_sigma else 0.0
    proj_cal = model.projector_sigma_px if calibration_sigma else 0.0
    axis = sequence.axis
    parts_q, parts_x, parts_sp, parts_sc, parts_src = [], [], [], [], []
    if len(edges):
        parts_q.append(edges.q_px)
        parts_x.append(edges.projector_px)
        parts_sp.append(np.zeros(len(edges)))
        parts_sc.append(np.hypot(edges.sigma_t_px, cam_cal))
        parts_src.append(np.full(len(edges), SOURCE_EDGE, np.uint8))
    height, width = decoding.code.shape
    near_edge = np.zeros((height, width), bool)
    if len(edges):
        iu, iv = np.rint(edges.q_px).astype(np.int64).T
        inside = (iu >= 0) & (iu < width) & (iv >= 0) & (iv < height)
        near_edge[iv[inside], iu[inside]] = True
    if decoding.phase_px is not None and decoding.phase_sigma_px is not None:
        vv, uu = np.nonzero(np.isfinite(decoding.phase_px))
        parts_q.append(np.column_stack([uu, vv]).astype(np.float64))
        parts_x.append(decoding.phase_px[vv, uu])
        parts_sp.append(decoding.phase_sigma_px[vv, uu])
        parts_sc.append(np.full(len(vv), cam_cal))
        parts_src.append(np.full(len(vv), SOURCE_PHASE, np.uint8))
    elif settings.code_points:
        vv, uu = np.nonzero(decoding.valid & ~near_edge)
        parts_q.append(np.column_stack([uu, vv]).astype(np.float64))
        parts_x.append(decoding.code_centre_px()[vv, uu])
        parts_sp.append(decoding.code_sigma_px()[vv, uu])
        parts_sc.append(np.full(len(vv), cam_cal))
        parts_src.append(np.full(len(vv), SOURCE_CODE, np.uint8))
    q = np.vstack(parts_q) if parts_q else np.zeros((0, 2))
    x = np.concatenate(parts_x) if parts_x else np.zeros(0)
    index = 0 if axis == "columns" else 1
    factor = settings.projector_scale_xy[index]
    x_model = (x + 0.5) * factor - 0.5 + settings.projector_offset_xy_px[index]
    # The decoding's σ is in the patterns' projector pixels, the calibration's in the model's.
    sigma_pattern = np.concatenate(parts_sp) if parts_sp else np.zeros(0)
    sigma_projector = np.hypot(sigma_pattern * factor, proj_cal)
    points, sigma = point_sigma_mm(
        model, q, x_model, axis=axis, sigma_projector_px=sigma_projector,
        sigma_camera_px=np.concatenate(parts_sc) if parts_sc else np.zeros(0), scan_axis=edges.scan_axis,
    )  # fmt: skip
    source = np.concatenate(parts_src) if parts_src else np.zeros(0, np.uint8)
    good = np.isfinite(points).all(axis=1) & np.isfinite(sigma)
    points, sigma, source, q, x = points[good], sigma[good], source[good], q[good], x[good]
    depth, depth_sigma = _depth_map(points, sigma, q, (height, width))
    return ScanResult(
        points_cam_mm=points, sigma_mm=sigma, source=source, q_px=q, projector_px=x, depth_z_mm=depth,
        depth_sigma_mm=depth_sigma, decoding=decoding, edges=edges, calibration_sigma=calibration_sigma,
    )  # fmt: skip


def scan_qa(result: ScanResult) -> dict[str, Any]:
    """The decoding's and the points' quality numbers, as stored and shown."""
    decoding = result.decoding
    counts = np.bincount(decoding.reason.ravel(), minlength=len(REASON_LABELS))
    total = decoding.reason.size
    by_source = np.bincount(result.source, minlength=len(SOURCE_LABELS)) if len(result) else np.zeros(3, int)
    return {
        "valid_share": decoding.valid_share,
        "pixels_by_reason": {REASON_LABELS[i]: int(counts[i]) for i in REASON_LABELS},
        "share_by_reason": {REASON_LABELS[i]: float(counts[i] / total) for i in REASON_LABELS},
        "n_points": len(result),
        "points_by_source": {SOURCE_LABELS[i]: int(by_source[i]) for i in SOURCE_LABELS},
        "n_edge_points": len(result.edges),
        "n_rejected_edge_points": result.edges.n_rejected,
        "median_sigma_mm_by_source": {
            SOURCE_LABELS[i]: float(np.median(result.sigma_mm[result.source == i])) if by_source[i] else None
            for i in SOURCE_LABELS
        },
        "phase_offset_px": decoding.phase_offset_px,
        "calibration_sigma": result.calibration_sigma,
        "calibration_sigma_note": None if result.calibration_sigma else (
            "the calibration file gives no reprojection RMS: σ holds the decoding's part only"),
    }  # fmt: skip


def _depth_map(
    points: np.ndarray, sigma: np.ndarray, q: np.ndarray, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """z and σ of the point with the smallest σ at each camera pixel (the pixel its q rounds to)."""
    height, width = shape
    depth = np.full(shape, np.nan, np.float32)
    depth_sigma = np.full(shape, np.nan, np.float32)
    if len(points) == 0:
        return depth, depth_sigma
    iu, iv = np.rint(q).astype(np.int64).T
    inside = (iu >= 0) & (iu < width) & (iv >= 0) & (iv < height)
    index = np.flatnonzero(inside)
    # Largest σ first, so the smallest is written last and stays.
    index = index[np.argsort(-sigma[index], kind="stable")]
    depth[iv[index], iu[index]] = points[index, 2]
    depth_sigma[iv[index], iu[index]] = sigma[index]
    return depth, depth_sigma


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Least-squares plane of points (N, 3): unit normal (3,), offset d (n·p = d), signed distances (N,)."""
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    normal = vt[-1]
    distance = (points - centre) @ normal
    return normal, float(normal @ centre), distance


def fit_sphere(points: np.ndarray, *, weights: np.ndarray | None = None) -> tuple[np.ndarray, float, np.ndarray]:
    """Least-squares sphere of points (N, 3): centre (3,), radius, signed radial distances (N,). An algebraic fit
    (|p|² = 2c·p + k) starts Gauss–Newton on the geometric distances."""
    w = np.ones(len(points)) if weights is None else np.asarray(weights, np.float64)
    a = np.column_stack([2.0 * points, np.ones(len(points))]) * np.sqrt(w)[:, None]
    b = np.sum(points**2, axis=1) * np.sqrt(w)
    solution, *_ = np.linalg.lstsq(a, b, rcond=None)
    centre = solution[:3]
    radius = float(np.sqrt(solution[3] + centre @ centre))
    for _ in range(20):
        offset = points - centre
        distance = np.linalg.norm(offset, axis=1)
        residual = distance - radius
        jacobian = np.column_stack([-offset / distance[:, None], -np.ones(len(points))]) * np.sqrt(w)[:, None]
        step, *_ = np.linalg.lstsq(jacobian, -residual * np.sqrt(w), rcond=None)
        centre = centre + step[:3]
        radius += float(step[3])
        if np.max(np.abs(step)) < 1e-10:
            break
    residual = np.linalg.norm(points - centre, axis=1) - radius
    return centre, radius, residual
