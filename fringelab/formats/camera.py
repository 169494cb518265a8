"""Readers and writers of camera-calibration files: the versioned fringelab JSON and OpenCV FileStorage YAML.

Belongs here: converting a `CameraCalibration` to and from its JSON document, and writing files atomically
(temp file + rename, so no reader ever sees half a result). Not here: computing the calibration
(`calibration.py`). The backend reads results through `read_camera_json` or plain `json`: the document is
self-describing, with units in every name.

Document (schema "fringelab.camera-calibration", version 1), angles in degrees as at every interface:
  schema, schema_version, mode, image_size_wh_px {width, height},
  sensor {du_px_per_mm, dv_px_per_mm, pixel_pitch_um [u, v] | null, scale_on},
  parameters {name: {value, unit, standard_error}} for su, f_mm, u0_px, v0_px, k1_per_mm2, k2_per_mm4,
      p1_per_mm, p2_per_mm, x0_mm, y0_mm, z0_mm, omega_deg, phi_deg, kappa_deg,
  pose {object_origin_in_camera_mm [x, y, z] (= x0, y0, z0), camera_centre_in_object_mm [X, Y, Z]} (derived; absent
      in files written before it was added),
  correlation: 14 × 14 in that order,
  opencv {camera_matrix 3×3, dist_coeffs [k1, k2, p1, p2, k3], rvec_rad, tvec_mm (OpenCV's pose: plate -> camera),
         standard_errors {...}},
  inverse_model {a1..a8, residual_px, approximation_residual_px},
  rms_px (per corner, as cv2.calibrateCamera), residual_std_px (per coordinate), n_points, converged,
  frames [{frame, status, reason, z_mm, n_corners, rms_px, max_px, r_cam_from_obj_rad, t_cam_from_obj_mm}],
  residuals {frame_index, x_mm, y_mm, z_mm, u_px, v_px, du_px, dv_px} (observed − model),
  residual_map {cells_u, cells_v, count, mean_du_px, mean_dv_px, rms_px, systematic_px, coverage},
  verdict {level, reasons, checks [{name, value, unit, good_limit, bad_limit, higher_is_better, level, message}]},
  board {cols, rows, square_mm, origin} | null, provenance {...}.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from fringelab.formats.atomic import atomic_write
from fringelab.science.calibration import (
    CAMERA_PARAMETERS,
    CameraCalibration,
    FrameResult,
    ResidualMap,
    ResidualVectors,
    Verdict,
    VerdictCheck,
)
from fringelab.science.camera import Camera, InverseModel, camera_centre_obj_mm
from fringelab.science.chessboard import Board

SCHEMA = "fringelab.camera-calibration"
SCHEMA_VERSION = 1

_ANGLES = ("omega_rad", "phi_rad", "kappa_rad")
_UNITS = {
    "su": "1", "f_mm": "mm", "u0_px": "px", "v0_px": "px", "k1_per_mm2": "mm^-2", "k2_per_mm4": "mm^-4",
    "p1_per_mm": "mm^-1", "p2_per_mm": "mm^-1", "x0_mm": "mm", "y0_mm": "mm", "z0_mm": "mm",
    "omega_deg": "deg", "phi_deg": "deg", "kappa_deg": "deg",
}  # fmt: skip


def _json_name(name: str) -> str:
    return name.replace("_rad", "_deg") if name in _ANGLES else name


def _finite_or_none(value: float | None) -> float | None:
    # JSON has no NaN; a missing number is null.
    return None if value is None or not math.isfinite(value) else float(value)


def _nested(array: np.ndarray) -> Any:
    return [_nested(row) for row in array] if array.ndim > 1 else [_finite_or_none(float(v)) for v in array]


def calibration_as_dict(calibration: CameraCalibration) -> dict[str, Any]:
    """The JSON document of a calibration (see the module docstring)."""
    camera = calibration.camera
    parameters = {}
    for name in CAMERA_PARAMETERS:
        value, error = getattr(camera, name), calibration.standard_errors[name]
        if name in _ANGLES:
            value, error = math.degrees(value), math.degrees(error)
        parameters[_json_name(name)] = {"value": value, "unit": _UNITS[_json_name(name)], "standard_error": error}
    opencv = calibration.opencv
    rmap = calibration.residual_map
    residuals = calibration.residuals
    return {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "mode": calibration.mode,
        "image_size_px": {"width": camera.image_width_px, "height": camera.image_height_px},
        "sensor": {
            "du_px_per_mm": camera.du_px_per_mm,
            "dv_px_per_mm": camera.dv_px_per_mm,
            "pixel_pitch_um": None if calibration.pixel_pitch_um is None else list(calibration.pixel_pitch_um),
            "scale_on": camera.scale_on,
        },
        "parameters": parameters,
        # The pose read both ways: x0, y0, z0 are where the plate's origin lies in the camera frame; the camera's
        # projection centre in the plate frame is C = −Mᵀ·[x0, y0, z0] (derived; no standard error given).
        "pose": {
            "object_origin_in_camera_mm": [float(v) for v in camera.translation_mm],
            "camera_centre_in_object_mm": [float(v) for v in camera_centre_obj_mm(camera)],
        },
        "correlation": _nested(calibration.correlation),
        "opencv": {
            "camera_matrix": opencv.camera_matrix.tolist(),
            "dist_coeffs": opencv.dist_coeffs.tolist(),
            "rvec_rad": list(opencv.r_cam_from_obj_rad),
            "tvec_mm": list(opencv.t_cam_from_obj_mm),
            "standard_errors": dict(calibration.opencv_standard_errors),
        },
        "inverse_model": {
            **{f"a{i}": a for i, a in enumerate(calibration.inverse.coefficients, start=1)},
            "residual_px": calibration.inverse.residual_px,
            "approximation_residual_px": calibration.inverse.approximation_residual_px,
        },
        "rms_px": calibration.rms_px,
        "residual_std_px": calibration.residual_std_px,
        "n_points": calibration.n_points,
        "converged": calibration.converged,
        "frames": [
            {
                "frame": f.frame,
                "status": f.status,
                "reason": f.reason,
                "z_mm": f.z_mm,
                "n_corners": f.n_corners,
                "rms_px": f.rms_px,
                "max_px": f.max_px,
                "rvec_rad": None if f.r_cam_from_obj_rad is None else list(f.r_cam_from_obj_rad),
                "tvec_mm": None if f.t_cam_from_obj_mm is None else list(f.t_cam_from_obj_mm),
            }  # fmt: skip
            for f in calibration.frames
        ],
        "residuals": {
            "frame_index": residuals.frame_index.astype(int).tolist(),
            "x_mm": residuals.points_obj_mm[:, 0].tolist(),
            "y_mm": residuals.points_obj_mm[:, 1].tolist(),
            "z_mm": residuals.points_obj_mm[:, 2].tolist(),
            "u_px": residuals.q_px[:, 0].tolist(),
            "v_px": residuals.q_px[:, 1].tolist(),
            "du_px": residuals.residual_px[:, 0].tolist(),
            "dv_px": residuals.residual_px[:, 1].tolist(),
        },
        "residual_map": {
            "cells_u": rmap.cells_u,
            "cells_v": rmap.cells_v,
            "count": rmap.count.astype(int).tolist(),
            "mean_du_px": _nested(rmap.mean_px[..., 0]),
            "mean_dv_px": _nested(rmap.mean_px[..., 1]),
            "rms_px": _nested(rmap.rms_px),
            "systematic_px": _finite_or_none(rmap.systematic_px),
            "coverage": rmap.coverage,
        },
        "verdict": {
            "level": calibration.verdict.level,
            "reasons": list(calibration.verdict.reasons),
            "checks": [vars(check) for check in calibration.verdict.checks],
        },
        "board": None
        if calibration.board is None
        else {
            "cols": calibration.board.cols,
            "rows": calibration.board.rows,
            "square_mm": calibration.board.square_mm,
            "origin": None if calibration.board.origin is None else list(calibration.board.origin),
        },
        "provenance": calibration.provenance,
    }


def _array(values: Any) -> np.ndarray:
    return np.array(values, dtype=np.float64) if values is not None else np.array([], dtype=np.float64)


def calibration_from_dict(document: dict[str, Any], *, name: str = "camera.json") -> CameraCalibration:
    """Rebuild a calibration from its JSON document. Raises ValueError naming what is missing or unsupported."""
    if document.get("schema") != SCHEMA:
        raise ValueError(f"{name}: not a fringelab camera calibration (schema {document.get('schema')!r})")
    if document.get("schema_version") != SCHEMA_VERSION:
        raise ValueError(f"{name}: schema version {document.get('schema_version')} is not supported (expected 1)")
    try:
        parameters = document["parameters"]
        values: dict[str, float] = {}
        errors: dict[str, float] = {}
        for field in CAMERA_PARAMETERS:
            entry = parameters[_json_name(field)]
            value, error = float(entry["value"]), float(entry["standard_error"])
            if field in _ANGLES:
                value, error = math.radians(value), math.radians(error)
            values[field], errors[field] = value, error
        sensor = document["sensor"]
        camera = Camera(
            image_width_px=int(document["image_size_px"]["width"]),
            image_height_px=int(document["image_size_px"]["height"]),
            du_px_per_mm=float(sensor["du_px_per_mm"]),
            dv_px_per_mm=float(sensor["dv_px_per_mm"]),
            scale_on=sensor["scale_on"],  # Camera checks it is "u" or "v"
            **values,
        )
        inverse_doc = document["inverse_model"]
        inverse = InverseModel(
            **{f"a{i}": float(inverse_doc[f"a{i}"]) for i in range(1, 9)},
            residual_px=float(inverse_doc["residual_px"]),
            approximation_residual_px=float(inverse_doc["approximation_residual_px"]),
        )
        frames = tuple(
            FrameResult(
                frame=f["frame"],
                status=f["status"],
                reason=f["reason"],
                z_mm=f["z_mm"],
                n_corners=f["n_corners"],
                rms_px=f["rms_px"],
                max_px=f["max_px"],
                r_cam_from_obj_rad=None if f["rvec_rad"] is None else tuple(f["rvec_rad"]),
                t_cam_from_obj_mm=None if f["tvec_mm"] is None else tuple(f["tvec_mm"]),
            )  # fmt: skip
            for f in document["frames"]
        )
        res = document["residuals"]
        residuals = ResidualVectors(
            frame_index=np.array(res["frame_index"], dtype=int),
            points_obj_mm=np.column_stack([_array(res["x_mm"]), _array(res["y_mm"]), _array(res["z_mm"])]),
            q_px=np.column_stack([_array(res["u_px"]), _array(res["v_px"])]),
            residual_px=np.column_stack([_array(res["du_px"]), _array(res["dv_px"])]),
        )
        rm = document["residual_map"]
        rmap = ResidualMap(
            cells_u=int(rm["cells_u"]), cells_v=int(rm["cells_v"]), count=np.array(rm["count"], dtype=int),
            mean_px=np.stack([_nan_array(rm["mean_du_px"]), _nan_array(rm["mean_dv_px"])], axis=-1),
            rms_px=_nan_array(rm["rms_px"]),
            systematic_px=float("nan") if rm["systematic_px"] is None else float(rm["systematic_px"]),
            coverage=float(rm["coverage"]),
        )  # fmt: skip
        verdict_doc = document["verdict"]
        verdict = Verdict(
            level=verdict_doc["level"],
            reasons=tuple(verdict_doc["reasons"]),
            checks=tuple(VerdictCheck(**check) for check in verdict_doc["checks"]),
        )
        board_doc = document.get("board")
        board = None
        if board_doc is not None:
            origin = board_doc.get("origin")
            board = Board(
                cols=int(board_doc["cols"]), rows=int(board_doc["rows"]), square_mm=float(board_doc["square_mm"]),
                origin=None if origin is None else (int(origin[0]), int(origin[1])),
            )  # fmt: skip
        pitch = sensor.get("pixel_pitch_um")
        return CameraCalibration(
            camera=camera,
            inverse=inverse,
            mode=document["mode"],
            rms_px=float(document["rms_px"]),
            residual_std_px=float(document["residual_std_px"]),
            n_points=int(document["n_points"]),
            standard_errors=errors,
            opencv_standard_errors={k: float(v) for k, v in document["opencv"]["standard_errors"].items()},
            correlation=_nan_array(document["correlation"]),
            frames=frames,
            residuals=residuals,
            residual_map=rmap,
            verdict=verdict,
            board=board,
            pixel_pitch_um=None if pitch is None else (float(pitch[0]), float(pitch[1])),
            converged=bool(document["converged"]),
            provenance=dict(document.get("provenance") or {}),
        )
    except (KeyError, TypeError, IndexError) as error:
        raise ValueError(f"{name}: malformed camera calibration ({type(error).__name__}: {error})") from None


def _nan_array(values: Any) -> np.ndarray:
    return np.array(values, dtype=np.float64)  # None → nan under dtype float64


def write_camera_json(calibration: CameraCalibration, path: str | Path) -> Path:
    """Write the calibration's JSON document to `path` atomically; returns the path."""
    path = Path(path)
    atomic_write(path, json.dumps(calibration_as_dict(calibration), indent=1, allow_nan=False) + "\n")
    return path


def read_camera_json(path: str | Path) -> CameraCalibration:
    """Read a calibration written by `write_camera_json`. Raises ValueError for anything else."""
    path = Path(path)
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(document, dict):
        raise ValueError(f"{path}: expected a JSON object")
    return calibration_from_dict(document, name=str(path))


def write_opencv_yaml(calibration: CameraCalibration, path: str | Path) -> Path:
    """Write the camera in OpenCV FileStorage YAML (as OpenCV's calibration sample does), atomically.

    Nodes: image_width, image_height, camera_matrix, distortion_coefficients (k1, k2, p1, p2, k3), rvec, tvec
    (of the pose in the calibration: the object frame in zstack mode, the first view in poses mode),
    avg_reprojection_error, and the fringelab schema for the way back.
    """
    path = Path(path)
    opencv = calibration.opencv
    storage = cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    storage.write("image_width", opencv.image_width_px)
    storage.write("image_height", opencv.image_height_px)
    storage.write("camera_matrix", opencv.camera_matrix)
    storage.write("distortion_coefficients", opencv.dist_coeffs.reshape(-1, 1))
    storage.write("rvec", np.array(opencv.r_cam_from_obj_rad).reshape(3, 1))
    storage.write("tvec", np.array(opencv.t_cam_from_obj_mm).reshape(3, 1))
    storage.write("avg_reprojection_error", calibration.rms_px)
    storage.write("source", f"{SCHEMA} v{SCHEMA_VERSION}, mode {calibration.mode}, verdict {calibration.verdict.level}")
    atomic_write(path, storage.releaseAndGetString())
    return path
