"""Synthetic Z-stack recordings with known truth, rendered once per test session (a few seconds each)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from fringelab.formats.recordings import open_recording, write_recording
from fringelab.formats.sidecars import z_csv_text
from fringelab.pipelines.camera_calibration import calibrate_camera_recording
from fringelab.science.camera import Camera
from fringelab.science.chessboard import Board
from fringelab.science.synthetic import reference_camera, render_zstack_frames, zstack_board

# 20 frames from −20 to +100 mm: the paper's stage range covers the plate's deflection (up to ~60 mm) with margin.
ZSTACK_Z_MM = np.linspace(-20.0, 100.0, 20)
NOISE_SIGMA_GREY = 2.0


@dataclass(frozen=True)
class SyntheticZStack:
    path: Path
    camera: Camera
    board: Board
    z_mm: np.ndarray


def render_zstack(path: Path, size: str, z_mm: np.ndarray, *, seed: int) -> SyntheticZStack:
    camera = reference_camera(size)
    board = zstack_board(camera)
    frames = render_zstack_frames(camera, board, z_mm, rng=np.random.default_rng(seed))
    write_recording(path, frames, sidecars={"z.csv": z_csv_text(z_mm)})
    return SyntheticZStack(path=path, camera=camera, board=board, z_mm=z_mm)


@pytest.fixture(scope="session")
def zstack_recordings(tmp_path_factory) -> dict[str, SyntheticZStack]:
    root = tmp_path_factory.mktemp("zstack")
    return {
        size: render_zstack(root / size, size, ZSTACK_Z_MM, seed=seed)
        for size, seed in (("512x480", 11), ("1024x1024", 12))
    }


@pytest.fixture(scope="session")
def calibrations(zstack_recordings):
    """The zstack calibration of each synthetic recording, as calibrate-camera would compute it."""
    results = {}
    for size, recording in zstack_recordings.items():
        camera = recording.camera
        results[size] = calibrate_camera_recording(
            open_recording(recording.path), board=recording.board, mode="zstack", du_px_per_mm=camera.du_px_per_mm,
            dv_px_per_mm=camera.dv_px_per_mm, scale_on=camera.scale_on,
        )  # fmt: skip
    return results
