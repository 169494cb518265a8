"""A measured virtual test, made once per session: the Kodak preset, an 8-frame test (perforation at frame
6), the projector calibrated over 0 … 80 mm in 4 mm steps, the topography of the whole test (about 20 s)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fringelab.formats.camera import read_camera_json
from fringelab.formats.recordings import open_recording
from fringelab.pipelines.projector_calibration import calibrate_projector_recording
from fringelab.pipelines.topography import topography_recording
from fringelab.pipelines.virtual_test import write_virtual_test
from fringelab.science.virtual_test import PlateScene, PlateState, true_deflection_mm


@dataclass(frozen=True)
class MeasuredExperiment:
    root: Path
    result: Path
    truth_json: Path
    truth: dict[str, Any]

    @property
    def scene(self) -> PlateScene:
        fields = {k: tuple(v) if isinstance(v, list) else v for k, v in self.truth["scene"].items()}
        return PlateScene(**fields)

    def true_w_mm(self, frame: int, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        state = self.truth["frames"][frame]
        return true_deflection_mm(self.scene, PlateState(state["w0_mm"], state["hole_radius_mm"]), x_mm, y_mm)


@pytest.fixture(scope="session")
def measured(tmp_path_factory: pytest.TempPathFactory) -> MeasuredExperiment:
    root = tmp_path_factory.mktemp("measured") / "kodak"
    experiment = write_virtual_test(root, "kodak", n_test_frames=8, calibration_z_mm=np.arange(0.0, 80.0 + 1e-9, 4.0),
                                     camera_z_mm=(-20.0, 40.0, 100.0), seed=3)  # fmt: skip
    camera = read_camera_json(experiment.camera_json)
    projector = calibrate_projector_recording(open_recording(experiment.projector_calibration), camera)
    result = topography_recording(open_recording(experiment.test), camera, projector, out_path=root / "result.h5")
    truth = json.loads(experiment.truth_json.read_text())
    return MeasuredExperiment(root=root, result=result.path, truth_json=experiment.truth_json, truth=truth)
