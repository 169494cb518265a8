"""Camera–projector calibration files: fringelab's own JSON (exact round trip) and OpenCV FileStorage (XML or YAML)
under the names other tools write (docs/file-formats.md "Camera–projector calibration").

Belongs here: reading a `ProcamModel` from any of these files (`read_procam_calibration`), writing fringelab's own
document with the calibration's report (`write_procam_json`) and writing FileStorage files under either naming
scheme (`write_opencv_procam`). Not here: computing a calibration (`science/procam_calibration.py`).

FileStorage names (R, T take camera coordinates to projector coordinates, in mm):
- SLStudio: Kc, kc (camera K and distortion), Kp, kp (projector), Rp, Tp, frameWidth, frameHeight (camera size),
  screenResX, screenResY (projector size);
- OpenCV's stereo samples: M1, D1 (camera), M2, D2 (projector), R, T; sizes under camera_size / projector_size
  ([width, height]) when the file has them, else from the options.

Own document (schema "fringelab.procam-calibration", version 1): camera {size_wh_px, camera_matrix, dist_coeffs},
projector {same}, stereo {r_proj_from_cam, t_proj_from_cam_mm}, rms {camera_px, projector_px, stereo_px},
n_observations, poses [{pose, camera_rms_px, projector_rms_px, share_from_edges, camera_q_px, camera_residual_px,
projector_q_px, projector_residual_px}], verdict {level, reasons, checks}, provenance. Numbers are written as
Python's shortest round-trip decimal, so reading gives back the very same floats; unknown numbers are null.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from fringelab.formats.atomic import atomic_path, atomic_write
from fringelab.science.procam import ProcamModel
from fringelab.science.procam_calibration import ProcamCalibration

SCHEMA = "fringelab.procam-calibration"
SCHEMA_VERSION = 1
Naming = Literal["opencv", "slstudio"]
NAMINGS: tuple[str, ...] = ("opencv", "slstudio")
_NAMES = {
    "slstudio": {"K1": "Kc", "D1": "kc", "K2": "Kp", "D2": "kp", "R": "Rp", "T": "Tp"},
    "opencv": {"K1": "M1", "D1": "D1", "K2": "M2", "D2": "D2", "R": "R", "T": "T"},
}


def _number(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _unnumber(value: Any) -> float:
    return float("nan") if value is None else float(value)


def procam_document(model: ProcamModel, calibration: ProcamCalibration | None = None,
                    provenance: dict[str, Any] | None = None) -> dict[str, Any]:  # fmt: skip
    """The JSON document of a model, with its calibration's report when there is one."""
    document: dict[str, Any] = {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "camera": {"size_wh_px": list(model.camera_size_wh_px), "camera_matrix": model.camera_matrix.tolist(),
                   "dist_coeffs": model.camera_dist.tolist()},
        "projector": {"size_wh_px": list(model.projector_size_wh_px), "camera_matrix": model.projector_matrix.tolist(),
                      "dist_coeffs": model.projector_dist.tolist()},
        "stereo": {"r_proj_from_cam": model.r_proj_from_cam.tolist(),
                   "t_proj_from_cam_mm": model.t_proj_from_cam_mm.tolist()},
        "rms": {"camera_px": _number(model.camera_rms_px), "projector_px": _number(model.projector_rms_px),
                "stereo_px": _number(calibration.stereo_rms_px) if calibration else None},
        "n_observations": int(model.n_observations),
        "poses": [],
        "verdict": None,
        "provenance": dict(provenance or {}),
    }  # fmt: skip
    if calibration is not None:
        document["poses"] = [
            {"pose": p.pose, "camera_rms_px": p.camera_rms_px, "projector_rms_px": p.projector_rms_px,
             "share_from_edges": p.share_from_edges, "camera_q_px": p.camera_q_px.tolist(),
             "camera_residual_px": p.camera_residual_px.tolist(), "projector_q_px": p.projector_q_px.tolist(),
             "projector_residual_px": p.projector_residual_px.tolist()}
            for p in calibration.poses
        ]  # fmt: skip
        verdict = calibration.verdict
        document["verdict"] = {"level": verdict.level, "reasons": list(verdict.reasons),
                               "checks": [asdict(c) for c in verdict.checks]}  # fmt: skip
        document["rms"]["camera_calibration_px"] = calibration.camera_rms_px
        document["rms"]["projector_calibration_px"] = calibration.projector_rms_px
    return document


def write_procam_json(
    path: str | Path,
    model: ProcamModel,
    *,
    calibration: ProcamCalibration | None = None,
    provenance: dict[str, Any] | None = None,
) -> Path:
    """Write fringelab's own camera–projector calibration file (atomically)."""
    document = procam_document(model, calibration, provenance)
    text = json.dumps(document, indent=1, allow_nan=False)
    return atomic_write(path, text + "\n")


def _model_from_document(document: dict[str, Any], name: str) -> ProcamModel:
    try:
        camera, projector, stereo = document["camera"], document["projector"], document["stereo"]
        rms = document.get("rms", {})
        return ProcamModel(
            camera_matrix=camera["camera_matrix"], camera_dist=camera["dist_coeffs"],
            camera_size_wh_px=tuple(camera["size_wh_px"]), projector_matrix=projector["camera_matrix"],
            projector_dist=projector["dist_coeffs"], projector_size_wh_px=tuple(projector["size_wh_px"]),
            r_proj_from_cam=stereo["r_proj_from_cam"], t_proj_from_cam_mm=stereo["t_proj_from_cam_mm"],
            camera_rms_px=_unnumber(rms.get("camera_px")), projector_rms_px=_unnumber(rms.get("projector_px")),
            n_observations=int(document.get("n_observations", 0)),
        )  # fmt: skip
    except KeyError as error:
        raise ValueError(f"{name}: missing key {error.args[0]!r} of a {SCHEMA} document") from None
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name}: {error}") from None


def read_procam_document(path: str | Path) -> dict[str, Any]:
    """The JSON document of fringelab's own file (ValueError naming the file when it is not one)."""
    path = Path(path)
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, ValueError) as error:
        raise ValueError(f"{path.name}: not a {SCHEMA} JSON file ({error})") from None
    found = document.get("schema") if isinstance(document, dict) else None
    if found != SCHEMA:
        raise ValueError(f"{path.name}: not a {SCHEMA} file (schema {found!r})")
    if document.get("schema_version") != SCHEMA_VERSION:
        raise ValueError(
            f"{path.name}: schema version {document.get('schema_version')} is not supported (expected {SCHEMA_VERSION})"
        )
    return document


def read_procam_calibration(
    path: str | Path,
    *,
    camera_size_wh_px: tuple[int, int] | None = None,
    projector_size_wh_px: tuple[int, int] | None = None,
) -> ProcamModel:
    """A camera–projector model from fringelab's JSON or an OpenCV FileStorage file (XML, YAML; see the module
    docstring). Sizes the file does not hold come from the options; sizes given both ways must agree.
    ValueError naming the file and the key for anything missing or malformed."""
    path = Path(path)
    head = path.read_bytes()[:64].lstrip()
    if head.startswith(b"{"):
        model = _model_from_document(read_procam_document(path), path.name)
        return _with_sizes(model, path.name, camera_size_wh_px, projector_size_wh_px)
    return _read_filestorage(path, camera_size_wh_px, projector_size_wh_px)


def _with_sizes(model: ProcamModel, name: str, camera: tuple[int, int] | None,
                projector: tuple[int, int] | None) -> ProcamModel:  # fmt: skip
    for what, given, held in (("camera", camera, model.camera_size_wh_px),
                              ("projector", projector, model.projector_size_wh_px)):  # fmt: skip
        if given is not None and tuple(given) != tuple(held):
            raise ValueError(
                f"{name}: the file's {what} is {held[0]} × {held[1]} px but {given[0]} × {given[1]} px was given"
            )
    return model


def _read_filestorage(
    path: Path, camera_size: tuple[int, int] | None, projector_size: tuple[int, int] | None
) -> ProcamModel:
    name = path.name
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_FORMAT_AUTO)
    except (cv2.error, SystemError):  # OpenCV's parser errors reach Python as either
        raise ValueError(f"{name}: not an OpenCV FileStorage file (XML or YAML) nor a {SCHEMA} JSON file") from None
    try:
        if not storage.isOpened():
            raise ValueError(f"{name}: not an OpenCV FileStorage file (XML or YAML) nor a {SCHEMA} JSON file")
        keys = set(storage.root().keys())
        naming = "slstudio" if "Kc" in keys else "opencv" if "M1" in keys else None
        if naming is None:
            raise ValueError(
                f"{name}: neither SLStudio's names (Kc, kc, Kp, kp, Rp, Tp) nor OpenCV's stereo names (M1, D1, M2, "
                f"D2, R, T); the file holds {sorted(keys)}"
            )
        names = _NAMES[naming]

        def matrix(key: str) -> np.ndarray:
            node = storage.getNode(key)
            if node.empty() or node.isNone():
                raise ValueError(f"{name}: missing key {key!r} ({naming} names)")
            value = node.mat()
            if value is None:
                raise ValueError(f"{name}: key {key!r} is not a matrix")
            return np.asarray(value, np.float64)

        def size(keys_wh: tuple[str, str] | str, given: tuple[int, int] | None, what: str) -> tuple[int, int]:
            if isinstance(keys_wh, str):
                node = storage.getNode(keys_wh)
                found = (
                    None if node.empty() or node.isNone() else tuple(int(v) for v in np.asarray(node.mat()).ravel()[:2])
                )
            else:
                nodes = [storage.getNode(k) for k in keys_wh]
                found = None if any(n.empty() or n.isNone() for n in nodes) else tuple(int(n.real()) for n in nodes)
            if found is not None and given is not None and tuple(given) != found:
                raise ValueError(f"{name}: the file's {what} size is {found[0]} × {found[1]} px but "
                                 f"{given[0]} × {given[1]} px was given")  # fmt: skip
            if found is None and given is None:
                keys_text = keys_wh if isinstance(keys_wh, str) else " and ".join(keys_wh)
                raise ValueError(f"{name}: no {what} image size (key {keys_text}): give it as an option")
            return (int(found[0]), int(found[1])) if found is not None else (int(given[0]), int(given[1]))  # type: ignore[index]

        if naming == "slstudio":
            cam_size = size(("frameWidth", "frameHeight"), camera_size, "camera")
            proj_size = size(("screenResX", "screenResY"), projector_size, "projector")
        else:
            cam_size = size("camera_size", camera_size, "camera")
            proj_size = size("projector_size", projector_size, "projector")
        try:
            return ProcamModel(
                camera_matrix=matrix(names["K1"]), camera_dist=matrix(names["D1"]).ravel(), camera_size_wh_px=cam_size,
                projector_matrix=matrix(names["K2"]), projector_dist=matrix(names["D2"]).ravel(),
                projector_size_wh_px=proj_size, r_proj_from_cam=matrix(names["R"]),
                t_proj_from_cam_mm=matrix(names["T"]).ravel(),
            )  # fmt: skip
        except ValueError as error:
            raise ValueError(f"{name}: {error}") from None
    finally:
        storage.release()


def write_opencv_procam(path: str | Path, model: ProcamModel, *, naming: Naming = "opencv") -> Path:
    """Write the model as an OpenCV FileStorage file (.yml/.yaml or .xml by the name) under `naming`'s names,
    with the sizes, atomically."""
    if naming not in NAMINGS:
        raise ValueError(f"naming: expected one of {NAMINGS}, got {naming!r}")
    path = Path(path)
    names = _NAMES[naming]
    with atomic_path(path) as partial:
        # FileStorage picks the format from the name's extension: keep it on the temporary name.
        target = partial.with_name(partial.name + path.suffix)
        storage = cv2.FileStorage(str(target), cv2.FILE_STORAGE_WRITE)
        try:
            storage.write(names["K1"], model.camera_matrix)
            storage.write(names["D1"], model.camera_dist.reshape(1, -1))
            storage.write(names["K2"], model.projector_matrix)
            storage.write(names["D2"], model.projector_dist.reshape(1, -1))
            storage.write(names["R"], model.r_proj_from_cam)
            storage.write(names["T"], model.t_proj_from_cam_mm.reshape(3, 1))
            if naming == "slstudio":
                storage.write("frameWidth", int(model.camera_size_wh_px[0]))
                storage.write("frameHeight", int(model.camera_size_wh_px[1]))
                storage.write("screenResX", int(model.projector_size_wh_px[0]))
                storage.write("screenResY", int(model.projector_size_wh_px[1]))
            else:
                storage.write("camera_size", np.array([model.camera_size_wh_px], np.float64))
                storage.write("projector_size", np.array([model.projector_size_wh_px], np.float64))
        finally:
            storage.release()
        target.replace(partial)
    return path
