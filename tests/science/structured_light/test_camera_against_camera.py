"""Camera against camera on the hard demo (issue 27): no difference for a frame either camera did not measure.

The dashboard's hard demo films one virtual test ("hard": fast motion, an 18 mm hole with springback, petals, a
highlight and the punch's shadow) with both virtual cameras. Before, the comparison drew the frames after the
perforation, whose peaks are lower bounds on the hole's rim, as a 59 → 39 mm drop and reported "largest 5.899
mm". Here the test is shortened to 8 frames (the hard scenario needs 6) and rendered one sample per pixel.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fringelab.formats.sidecars import FrameTable, frames_csv_text
from fringelab.formats.topography import TopographyResult
from fringelab.pipelines.topography import topography_recording
from fringelab.science.camera_against_camera import NOT_MEASURED_HERE, PeakSeries, peaks_against
from fringelab.science.projector import build_projector_calibration, exact_camera_model
from fringelab.science.virtual_test import FringeRenderer, Imaging, preset, scenario

from .conftest import MemorySource

N_FRAMES = 8
# Both cameras see the same surface: their measured peaks agree to their own accuracy (each within ~0.5 mm of
# the truth on this grid, docs/method.md §7), so 1.5 mm is room for both errors and far below the 15–20 mm drop
# a lower bound after the perforation would show.
AGREEMENT_MM = 1.5


def hard_demo_peaks(name: str, z_max_mm: float, tmp_path: Path) -> tuple[PeakSeries, int]:
    setup, timeline = scenario("hard", preset(name, imaging=Imaging(supersample=1)), N_FRAMES)
    renderer = FringeRenderer(setup)
    rng = np.random.default_rng(17)
    z_mm = np.arange(0.0, z_max_mm + 1e-9, 2.0)
    camera = exact_camera_model(setup.camera)
    projector = build_projector_calibration([renderer.render_flat(z, rng=rng) for z in z_mm], z_mm, camera)
    table = FrameTable(frame=np.arange(N_FRAMES), time_s=timeline.time_s, force_kN=timeline.force_kN,
                       punch_displacement_mm=timeline.punch_displacement_mm)  # fmt: skip
    frames = [renderer.render_test(state, rng=rng) for state in timeline.states]
    path = topography_recording(MemorySource(frames, {"frames.csv": frames_csv_text(table)}), camera, projector,
                                out_path=tmp_path / f"{name}.h5").path  # fmt: skip
    with TopographyResult(path) as result:
        series = PeakSeries(frames=result.frames, time_s=result.column("frames/time_s"),
                            peak_w_mm=result.column("peak/w_mm"), measured=result.peak_measured())  # fmt: skip
    return series, timeline.perforation_frame


@pytest.mark.slow
def test_the_hard_demo_compares_only_frames_both_cameras_measured(tmp_path: Path) -> None:
    kodak, perforation = hard_demo_peaks("kodak", 80.0, tmp_path)
    phantom, _ = hard_demo_peaks("phantom", 64.0, tmp_path)
    against = peaks_against(kodak, phantom)
    assert against.aligned_by == "time"
    for i, reason in enumerate(against.left_out):
        if kodak.measured[i] == 0.0 or phantom.measured[i] == 0.0:
            assert reason and np.isnan(against.difference_w_mm[i]), f"frame {i} drawn as a difference"
    # The perforated frames are lower bounds for both cameras: left out, with the reason.
    assert all(reason == NOT_MEASURED_HERE for reason in against.left_out[perforation:])
    assert np.count_nonzero(against.compared) >= perforation - 2  # the loaded frames are compared
    assert against.largest_difference_mm < AGREEMENT_MM
    assert against.largest_difference_mm == np.nanmax(np.abs(against.difference_w_mm))


def test_a_gap_in_either_camera_is_left_out_never_a_difference() -> None:
    time = np.arange(6) * 1e-3
    mine = PeakSeries(frames=np.arange(6), time_s=time, peak_w_mm=np.array([0.0, 10, 20, 30, 40, 30]),
                      measured=np.array([1.0, 1, 1, 1, 1, 0]))  # fmt: skip
    # The other camera runs at twice the rate, its frame 5 (t = 2.5 ms) not measured, and stops at 4 ms.
    other_time = np.arange(9) * 0.5e-3
    other = PeakSeries(frames=np.arange(9), time_s=other_time, peak_w_mm=5.0 * np.arange(9) + 0.25,
                       measured=np.array([1.0, 1, 1, 1, 1, 0, 1, 1, 1]))  # fmt: skip
    against = peaks_against(mine, other)
    # frame 0: other's frame 0; frame 1: its frame 2; frame 2 (t = 2 ms): its frame 4, measured; frame 3
    # (t = 3 ms): its frame 6; frame 4 (4 ms): its frame 8; frame 5 not measured here (and beyond the other's end).
    np.testing.assert_allclose(against.difference_w_mm[:5], -0.25)
    assert against.left_out[5] in (NOT_MEASURED_HERE, "the other camera has no frame at this instant")
    # An instant between the other's frames 4 and 5 needs both measured: shifted by 0.25 ms it is left out.
    shifted = PeakSeries(frames=mine.frames, time_s=time + 0.25e-3, peak_w_mm=mine.peak_w_mm, measured=mine.measured)
    later = peaks_against(shifted, other)
    assert later.left_out[2] == "the other camera did not measure the peak at this instant"
    assert np.isnan(later.difference_w_mm[2]) and later.compared.sum() == 4
    assert later.largest_difference_mm == pytest.approx(np.nanmax(np.abs(later.difference_w_mm)))
