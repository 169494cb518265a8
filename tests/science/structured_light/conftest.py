"""Virtual tests for the structured-light tests, rendered once per session and kept in memory.

Sizes (the default suite must stay fast on two shared cores). Both render one sample per pixel: the stripes'
optical blur and pixel integration are analytic in the renderer, so this does not bias the edges;
`fringelab virtual-test` supersamples 2 × 2, which adds the pixel integration of shading and texture.
- kodak: otherwise full size, as `fringelab virtual-test --preset kodak` writes it: 512 × 480 px, projector
  calibration at 0 … 80 mm in 2 mm steps (41 frames), a 40-frame test (perforation at frame 30).
- phantom: the full 1024 × 1024 px image but a reduced recording: the projector calibration only over the
  0 … 64 mm the test needs (2 mm steps, 33 frames) and a 24-frame test (perforation at frame 18; edges move up
  to ~5 px between frames instead of ~3 px).
- kodak_full (slow tests only): exactly what `fringelab virtual-test` writes (supersampled).
- phantom_full (slow tests only): the same, supersampled, in the reduced recording of `phantom` (0 … 64 mm, a
  24-frame test; edges move further per frame, so the tracking is not made easier). The 40-frame test took
  ~45 s of CPU, the most of any science test.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from fringelab.formats.sidecars import FrameTable, frames_csv_text
from fringelab.science.fringes import FrameEdges
from fringelab.science.projector import (
    ExactCamera,
    ProjectorCalibration,
    build_projector_calibration,
    exact_camera_model,
)
from fringelab.science.topography import locate_test_edges
from fringelab.science.virtual_test import FringeRenderer, Imaging, Preset, PunchTimeline, preset, punch_timeline


@dataclass(frozen=True, eq=False)
class RenderedExperiment:
    preset: Preset
    camera: ExactCamera
    calibration_frames: list[np.ndarray]
    calibration_z_mm: np.ndarray
    timeline: PunchTimeline
    test_frames: list[np.ndarray]
    projector: ProjectorCalibration
    test_edges: list[FrameEdges]


def render_experiment(
    name: str, *, z_step_mm: float, n_test_frames: int, seed: int, supersample: int, z_max_mm: float = 80.0
) -> RenderedExperiment:
    setup = preset(name, imaging=Imaging(supersample=supersample))
    renderer = FringeRenderer(setup)
    rng = np.random.default_rng(seed)
    z_mm = np.arange(0.0, z_max_mm + 1e-9, z_step_mm)
    calibration_frames = [renderer.render_flat(z, rng=rng) for z in z_mm]
    timeline = punch_timeline(n_test_frames, max_deflection_mm=setup.max_deflection_mm)
    test_frames = [renderer.render_test(state, rng=rng) for state in timeline.states]
    camera = exact_camera_model(setup.camera)
    projector = build_projector_calibration(calibration_frames, z_mm, camera)
    return RenderedExperiment(
        preset=setup,
        camera=camera,
        calibration_frames=calibration_frames,
        calibration_z_mm=z_mm,
        timeline=timeline,
        test_frames=test_frames,
        projector=projector,
        test_edges=list(locate_test_edges(test_frames, projector)),
    )


@dataclass(frozen=True)
class MemorySource:
    """A recording held in memory, with the interface of `fringelab.formats.recordings.open_recording`'s FrameSource."""

    frames: list[np.ndarray]
    sidecars: dict[str, str]

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index: int) -> np.ndarray:
        return self.frames[index]

    def sidecar_text(self, name: str) -> str | None:
        return self.sidecars.get(name)


def recorded_test(experiment: RenderedExperiment, n_frames: int) -> MemorySource:
    """The first n_frames of an experiment's test, with its frames.csv."""
    timeline = experiment.timeline
    table = FrameTable(
        frame=np.arange(n_frames),
        time_s=timeline.time_s[:n_frames],
        punch_displacement_mm=timeline.punch_displacement_mm[:n_frames],
        force_kN=timeline.force_kN[:n_frames],
    )
    return MemorySource(list(experiment.test_frames[:n_frames]), {"frames.csv": frames_csv_text(table)})


@pytest.fixture(scope="session")
def kodak() -> RenderedExperiment:
    return render_experiment("kodak", z_step_mm=2.0, n_test_frames=40, seed=21, supersample=1)


@pytest.fixture(scope="session")
def phantom() -> RenderedExperiment:
    return render_experiment("phantom", z_step_mm=2.0, z_max_mm=64.0, n_test_frames=24, seed=22, supersample=1)


@pytest.fixture(scope="session")
def kodak_full() -> RenderedExperiment:
    return render_experiment("kodak", z_step_mm=2.0, n_test_frames=40, seed=23, supersample=2)


@pytest.fixture(scope="session")
def phantom_full() -> RenderedExperiment:
    return render_experiment("phantom", z_step_mm=2.0, z_max_mm=64.0, n_test_frames=24, seed=24, supersample=2)
