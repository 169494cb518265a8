"""QA of recorded frames: statistics, the warnings they raise, the ingest's checks end to end, the preview store
and the PNG frames the API serves."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from fringelab.formats.previews import PREVIEW_FILE, encode_png, read_preview, read_qa, shrink
from fringelab.science.quality import (
    describe_frames,
    effective_bit_depth,
    exposure_warnings,
    frame_stats,
    saturated_pct,
)
from tests.formats.recording_files import stripe_frames, write_zip
from worker.jobs.ingest import inspect_recording


def chessboard(*, cols: int = 8, rows: int = 6, square: int = 16, margin: int = 24) -> np.ndarray:
    """A dark-on-light chessboard with cols × rows inner corners."""
    image = np.full(((rows + 1) * square + 2 * margin, (cols + 1) * square + 2 * margin), 230, np.uint8)
    for r in range(rows + 1):
        for c in range(cols + 1):
            if (r + c) % 2 == 0:
                image[
                    margin + r * square : margin + (r + 1) * square, margin + c * square : margin + (c + 1) * square
                ] = 25
    return image


def test_frame_statistics_are_exact_on_known_frames():
    frame = np.zeros((10, 10), np.uint8)
    frame[:, 5:] = 200
    frame[0, :3] = 255  # three clipped pixels
    stats = frame_stats(frame)
    assert stats.max == 255 and stats.at_max_pct == pytest.approx(3.0)
    assert stats.mean == pytest.approx((50 * 200 + 3 * 255) / 100)
    # p5 = 0 and p95 = 200 (only 3 % of the pixels are 255): Michelson contrast (200 − 0) / (200 + 0) = 1
    assert stats.contrast == pytest.approx(1.0)
    assert saturated_pct(stats, full_scale_dn=255) == pytest.approx(3.0)
    assert saturated_pct(stats, full_scale_dn=4095) == 0.0
    flat = frame_stats(np.full((8, 8), 100, np.uint16))
    assert flat.contrast == 0.0 and flat.at_max_pct == 100.0


def test_effective_bit_depth_of_16_bit_containers():
    assert effective_bit_depth(4095, stored_bits=16) == 12
    assert effective_bit_depth(4096, stored_bits=16) == 14
    assert effective_bit_depth(1000, stored_bits=16) == 10
    assert effective_bit_depth(65535, stored_bits=16) == 16
    assert effective_bit_depth(3, stored_bits=8) == 8


def test_warnings_name_the_frames():
    mean = np.array([0.5, 0.01, 0.5, 0.5])
    saturation = np.array([0.0, 0.0, 4.0, 0.0])
    contrast = np.array([0.7, 0.7, 0.7, 0.05])
    found = {w.code: w for w in exposure_warnings(mean, saturation, contrast, contrast_of="stripe")}
    assert found["saturated"].frames == (2,) and found["saturated"].message.startswith("frame 2: more than 1 %")
    assert found["dark"].frames == (1,)
    assert found["low_contrast"].message.startswith("frame 3: low stripe contrast")
    assert describe_frames([17]) == "frame 17"
    assert describe_frames([3, 5, 6, 7, 9]) == "frames 3, 5–7 and 9"
    assert describe_frames(range(0, 40, 2), limit=3) == "frames 0, 2, 4 and 17 more"


def inspect(path, settings, kind):  # type: ignore[no-untyped-def]
    probes = []
    found = inspect_recording(
        path,
        kind=kind,
        settings=settings,
        preview_path=path.parent / PREVIEW_FILE,
        progress=lambda done, total, stage: None,
        on_probe=probes.append,
    )
    assert probes and probes[0].frame_count == found.probe.frame_count
    return found


def test_the_ingest_finds_saturated_dark_and_flat_frames_and_missing_z(settings, tmp_path):
    frames = stripe_frames(6)
    frames[1] = np.full_like(frames[1], 3)  # dark (and flat)
    frames[2] = frames[2].copy()
    frames[2][:, :20] = 255  # a third of the frame clipped
    frames[4] = np.full_like(frames[4], 120)  # lit but without stripes
    z = "frame,z_mm\n" + "".join(f"{i},{i}\n" for i in (0, 1, 2, 3, 5))
    path = write_zip(tmp_path / "r.zip", frames, sidecars={"z.csv": z})
    found = inspect(path, settings, "projector_calibration")
    assert found.reasons == []
    warnings = {w.code: w.frames for w in found.warnings}
    assert warnings["saturated"] == (2,)
    assert warnings["dark"] == (1,)
    assert warnings["low_contrast"] == (1, 4)
    assert warnings["missing_z"] == (4,)
    assert found.sidecar["z.csv"]["rows"] == 5
    arrays, attrs = read_qa(tmp_path / PREVIEW_FILE)
    assert attrs["full_scale_dn"] == 255 and attrs["width_px"] == 64
    assert arrays["saturation_pct"][2] == pytest.approx(100 * 20 / 64, abs=0.1)
    assert list(arrays["board_found"]) == [-1] * 6


def test_the_ingest_looks_for_the_board_in_every_frame_of_a_camera_calibration(settings, tmp_path):
    frames = [chessboard() for _ in range(20)]
    frames[17] = np.full_like(frames[17], 128)  # the board left the field of view
    board = json.dumps({"cols": 8, "rows": 6, "square_mm": 10})
    path = write_zip(tmp_path / "cal.zip", frames, sidecars={"board.json": board})
    found = inspect(path, settings, "camera_calibration")
    by_code = {w.code: w for w in found.warnings}
    assert by_code["board_not_found"].message == "board (8 × 6 inner corners) not found in frame 17"
    assert by_code["board_not_found"].frames == (17,)
    assert by_code["low_contrast"].message.startswith("frame 17: low board contrast")
    assert "missing_z" in by_code  # a Z-stack calibration needs z.csv
    arrays, _attrs = read_qa(tmp_path / PREVIEW_FILE)
    assert list(arrays["board_found"]) == [1] * 17 + [0] + [1] * 2
    no_board = write_zip(tmp_path / "nb.zip", frames[:2])
    assert "no_board" in {w.code for w in inspect(no_board, settings, "camera_calibration").warnings}
    # Another lab's spelling is read as the same board; a file that cannot be read is one warning (not a second,
    # contradictory "no board.json"), and never a reason to refuse the recording.
    other_spelling = json.dumps({"boardWidth": 8, "boardHeight": 6, "squareSize": 0.01, "unit": "m"})
    spelled = inspect(write_zip(tmp_path / "os.zip", frames[:2], sidecars={"board.json": other_spelling}), settings,
                      "camera_calibration")  # fmt: skip
    assert spelled.reasons == [] and spelled.sidecar["board.json"]["square_mm"] == pytest.approx(10.0)
    odd = inspect(write_zip(tmp_path / "odd.zip", frames[:2], sidecars={"board.json": '{"pattern": "chess"}'}),
                  settings, "camera_calibration")  # fmt: skip
    codes = [w.code for w in odd.warnings]
    assert odd.reasons == [] and "board_unreadable" in codes and "no_board" not in codes
    assert "board.json: missing cols, rows, square_mm" in odd.sidecar["board.json"]["error"]


def test_previews_are_display_size_8_bit_with_thumbnails(settings, tmp_path):
    frames = stripe_frames(3, height=300, width=2000, dtype=np.uint16)
    found = inspect(write_zip(tmp_path / "r.zip", frames), settings, "test")
    assert found.probe.bit_depth == 12
    store = tmp_path / PREVIEW_FILE
    display = read_preview(store, 2)
    assert display.dtype == np.uint8 and display.shape == (120, 800)  # 2000 → FRINGELAB_PREVIEW_SIZE_PX
    # Scaled so that 12-bit full scale is 255: the stripes' 15 % and 80 % levels.
    assert np.percentile(display, 10) == pytest.approx(0.15 * 255, abs=6)
    assert np.percentile(display, 90) == pytest.approx(0.8 * 255, abs=6)
    thumb = read_preview(store, 2, max_px=100)
    assert max(thumb.shape) <= 100
    with pytest.raises(IndexError):
        read_preview(store, 3)


def test_png_encoding_round_trips_through_a_decoder():
    rng = np.random.default_rng(7)
    image = rng.integers(0, 256, (37, 53), dtype=np.uint8)
    decoded = cv2.imdecode(np.frombuffer(encode_png(image), np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(decoded, image)
    assert shrink(np.arange(16, dtype=np.uint8).reshape(4, 4), max_px=2).tolist() == [
        [3, 5],
        [11, 13],
    ]  # 2×2 means, rounded


def test_the_api_process_never_imports_opencv():
    code = "import sys, backend.app, backend.cli; print('cv2' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"


def test_a_test_recording_without_frames_csv_says_so(settings, tmp_path):
    """Nothing silent (issue 27): a test recording with no frames.csv has no punch travel or force to plot."""
    path = write_zip(tmp_path / "t.zip", stripe_frames(3))
    found = inspect(path, settings, "test")
    assert found.reasons == []
    (warning,) = [w for w in found.warnings if w.code == "no_test_log"]
    assert "no frames.csv" in warning.message and "force" in warning.message
    logged = write_zip(tmp_path / "l.zip", stripe_frames(3), sidecars={"frames.csv": "frame,time_s\n0,0\n1,1\n2,2\n"})
    assert "no_test_log" not in {w.code for w in inspect(logged, settings, "test").warnings}
