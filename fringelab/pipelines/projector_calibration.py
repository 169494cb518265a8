"""Projector calibration of a whole recording: a flat-plate Z-stack in, the look-up table out (docs/method.md §4).

What the command line and the worker's projector-calibration job call; the table itself is built by
`fringelab.science.projector.build_projector_calibration`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import asdict, replace
from typing import Any

import numpy as np

from fringelab.formats.sidecars import read_z_csv
from fringelab.pipelines.provenance import code_versions
from fringelab.science.calibration import ProgressCallback, zstack_heights_mm
from fringelab.science.projector import (
    CameraModel,
    ProjectorCalibration,
    ProjectorSettings,
    build_projector_calibration,
)


def calibrate_projector_recording(
    source: Any,
    camera_model: CameraModel,
    *,
    settings: ProjectorSettings | None = None,
    progress: ProgressCallback | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> ProjectorCalibration:
    """Calibrate the projector from a recording of the flat plate moved along Z: what the CLI and tasks call.

    source: a frame source from `formats.recordings.open_recording` (a sequence of grey frames with
    `sidecar_text`), with `z.csv` (frame,z_mm). camera_model: the camera calibration
    (`formats.camera.read_camera_json` gives one) of the camera that took the frames. progress(done, total,
    stage) is called after each frame ("edges") and at the end ("done"); should_cancel() is polled between frames
    (Cancelled).

    Raises ValueError for malformed input (z.csv), CalibrationMismatchError for frames of another size than the
    camera's, NoStripesError, ProjectorCalibrationError for a table that cannot be built.
    """

    where = str(getattr(source, "path", "recording"))
    z_text = source.sidecar_text("z.csv")
    if z_text is None:
        raise ValueError(f"{where}: z.csv missing; the projector calibration needs the stage Z of every frame")
    z_mm = zstack_heights_mm(read_z_csv(z_text), len(source))
    digest = hashlib.sha256(z_text.encode())

    class _Hashed(Sequence[np.ndarray]):
        """The recording's frames, hashed as they are read (for provenance)."""

        def __len__(self) -> int:
            return len(source)

        def __getitem__(self, index):
            image = source[index]
            digest.update(np.ascontiguousarray(image).data)
            return image

    settings = ProjectorSettings() if settings is None else settings
    calibration = build_projector_calibration(
        _Hashed(), z_mm, camera_model, settings=settings, progress=progress, should_cancel=should_cancel
    )
    provenance = {
        "input": where,
        "input_sha256": digest.hexdigest(),
        "n_frames": len(source),
        "camera_fingerprint": calibration.camera_fingerprint,
        "camera_provenance": dict(getattr(camera_model, "provenance", {}) or {}),
        "settings": {**asdict(settings), "edges": asdict(calibration.edges)},
        **code_versions(),
    }
    return replace(calibration, provenance=provenance)
