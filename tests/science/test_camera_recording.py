"""A calibration recording end to end: the CLI, the JSON and YAML files, and every kind of bad input."""

from __future__ import annotations

import argparse
import json
import shutil

import cv2
import numpy as np
import pytest

from fringelab.commands import camera as camera_commands
from fringelab.formats.camera import read_camera_json, write_camera_json
from fringelab.formats.recordings import open_recording, write_recording
from fringelab.formats.sidecars import z_csv_text
from fringelab.pipelines.camera_calibration import calibrate_camera_recording
from fringelab.science import Cancelled
from fringelab.science.calibration import CalibrationError
from fringelab.science.camera import project_points
from fringelab.science.chessboard import Board, BoardNotFoundError

from .conftest import render_zstack


def run_cli(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="fringelab")
    camera_commands.register(parser.add_subparsers())
    args = parser.parse_args(list(argv))
    return args.handler(args)


@pytest.fixture(scope="module")
def small_stack(tmp_path_factory):
    """Five 512 × 480 frames from −20 to +60 mm: enough for a zstack calibration, quick to copy and break."""
    return render_zstack(tmp_path_factory.mktemp("small") / "stack", "512x480", np.linspace(-20, 60, 5), seed=31)


def copy_of(stack, tmp_path):
    return shutil.copytree(stack.path, tmp_path / "recording")


def board_flags(stack) -> list[str]:
    board = stack.board
    return ["--board-cols", str(board.cols), "--board-rows", str(board.rows), "--square-mm", str(board.square_mm)]


def test_cli_calibrates_and_exports(zstack_recordings, tmp_path, capsys):
    stack = zstack_recordings["512x480"]
    out = tmp_path / "camera.json"
    code = run_cli("calibrate-camera", str(stack.path), *board_flags(stack), "--mode", "zstack",
                   "--du", "96", "--dv", "96", "--scale-on", "v", "-o", str(out))  # fmt: skip
    assert code == 0
    assert "verdict good" in capsys.readouterr().out

    calibration = read_camera_json(out)
    document = json.loads(out.read_text())
    assert document["schema"] == "fringelab.camera-calibration" and document["schema_version"] == 1
    assert document["parameters"]["omega_deg"]["unit"] == "deg"
    assert document["verdict"]["level"] == "good"
    assert len(document["frames"]) == 20 and len(document["residuals"]["du_px"]) == calibration.n_points
    # Read back, the camera projects like the truth to the noise level of the calibration.
    points = calibration.residuals.points_obj_mm
    assert np.max(np.abs(project_points(calibration.camera, points) - project_points(stack.camera, points))) < 0.05

    yaml_path = tmp_path / "camera.yaml"
    assert run_cli("camera-export", str(out), "--opencv-yaml", str(yaml_path)) == 0
    storage = cv2.FileStorage(str(yaml_path), cv2.FILE_STORAGE_READ)
    camera_matrix = storage.getNode("camera_matrix").mat()
    dist = storage.getNode("distortion_coefficients").mat().ravel()
    rvec, tvec = storage.getNode("rvec").mat().ravel(), storage.getNode("tvec").mat().ravel()
    q_yaml, _ = cv2.projectPoints(points, rvec, tvec, camera_matrix, dist)
    # FileStorage keeps 16 significant digits: the YAML camera is the JSON camera to round-off.
    assert np.max(np.abs(q_yaml.reshape(-1, 2) - project_points(calibration.camera, points))) < 1e-9
    assert storage.getNode("image_width").real() == 512


def test_json_round_trip_is_exact(calibrations, tmp_path):
    calibration = calibrations["1024x1024"]
    back = read_camera_json(write_camera_json(calibration, tmp_path / "c.json"))
    points = calibration.residuals.points_obj_mm
    # Angles go through degrees in the file: a 1-ulp change, ~1e-12 px.
    assert np.max(np.abs(project_points(back.camera, points) - project_points(calibration.camera, points))) < 1e-9
    assert back.inverse == calibration.inverse
    assert back.verdict == calibration.verdict
    assert back.frames == calibration.frames
    np.testing.assert_array_equal(back.residuals.residual_px, calibration.residuals.residual_px)
    assert back.standard_errors == pytest.approx(calibration.standard_errors, rel=1e-12)


def test_progress_and_board_json(small_stack, tmp_path):
    path = copy_of(small_stack, tmp_path)
    board = small_stack.board
    (path / "board.json").write_text(json.dumps({"cols": board.cols, "rows": board.rows, "square_mm": 25.0}))
    calls = []
    calibration = calibrate_camera_recording(
        open_recording(path), du_px_per_mm=96, dv_px_per_mm=96, scale_on="v",
        progress=lambda done, total, stage: calls.append((done, total, stage)),
    )  # fmt: skip
    assert calibration.board == board
    assert calls[0] == (1, 7, "corners") and calls[-2] == (6, 7, "solving") and calls[-1] == (7, 7, "done")
    with pytest.raises(Cancelled):
        calibrate_camera_recording(open_recording(path), du_px_per_mm=96, dv_px_per_mm=96, should_cancel=lambda: True)


def test_frames_without_board_are_skipped_and_listed(small_stack, tmp_path):
    path = copy_of(small_stack, tmp_path)
    cv2.imwrite(str(path / "frame0002.png"), np.full((480, 512), 90, np.uint8))
    calibration = calibrate_camera_recording(
        open_recording(path), board=small_stack.board, du_px_per_mm=96, dv_px_per_mm=96, scale_on="v"
    )
    skipped = [f for f in calibration.frames if f.status == "skipped"]
    assert [f.frame for f in skipped] == ["frame0002.png"]
    assert "no 14 × 9 chessboard found" in skipped[0].reason
    assert [f.frame for f in calibration.frames] == [f"frame{i:04d}.png" for i in range(5)]
    back = read_camera_json(write_camera_json(calibration, tmp_path / "camera.json"))
    assert back.frames == calibration.frames
    np.testing.assert_array_equal(back.residuals.frame_index, calibration.residuals.frame_index)
    assert 2 not in set(back.residuals.frame_index)  # the skipped frame has no residuals


def test_too_few_frames_after_skipping(small_stack, tmp_path):
    path = copy_of(small_stack, tmp_path)
    for i in (1, 2, 3):
        cv2.imwrite(str(path / f"frame{i:04d}.png"), np.full((480, 512), 90, np.uint8))
    # one short sentence: each reason once, with how many frames it cost
    with pytest.raises(CalibrationError, match=r"at least 3 frames with the board, got 2 \(3 skipped: 3 × no 14 × 9"):
        calibrate_camera_recording(open_recording(path), board=small_stack.board, du_px_per_mm=96, dv_px_per_mm=96)


def test_no_board_anywhere(tmp_path):
    path = write_recording(
        tmp_path / "blank", [np.full((48, 64), 90, np.uint8)] * 3, sidecars={"z.csv": z_csv_text([0, 1, 2])}
    )
    with pytest.raises(BoardNotFoundError, match=r"blank: no 9 × 6 chessboard found in any of the 3 frames$"):
        calibrate_camera_recording(open_recording(path), board=Board(9, 6, 25.0), du_px_per_mm=1, dv_px_per_mm=1)


def test_wrong_board_size_is_reported(small_stack, tmp_path):
    # One short sentence naming both sizes, the recording by its name (never a server path). The detector stops
    # short of this 14 × 9 board's outer columns in some frames: the largest size found, as a lower bound.
    with pytest.raises(BoardNotFoundError, match=r"^stack: the chessboard has at least 1[2-4] × 9 inner corners, 9 × 6 "
                       r"declared: declare its full size$"):  # fmt: skip
        calibrate_camera_recording(open_recording(small_stack.path), board=Board(9, 6, 25.0), du_px_per_mm=96,
                                   dv_px_per_mm=96)  # fmt: skip


@pytest.mark.parametrize(
    ("z_csv", "message"),
    [
        (None, "z.csv missing"),
        ("frame,height\n0,1\n", "expected columns 'frame,z_mm'"),
        ("frame,z_mm\n0,abc\n", "z.csv line 2"),
        ("frame,z_mm\n0,1\n1,2\n", "2 rows, but the recording has 5 frames"),
        ("frame,z_mm\n0,1\n1,2\n2,3\n3,2.5\n4,5\n", "not monotonic: frame 3"),
        ("frame,z_mm\n0,1\n1,2\n2,2\n3,4\n4,5\n", "frames 1 and 2 repeat Z = 2.0 mm"),
        ("frame,z_mm\n0,7\n1,7\n2,7\n3,7\n4,7\n", "all 5 frames are at Z = 7.0 mm"),
    ],
)
def test_bad_z_csv(z_csv, message, small_stack, tmp_path):
    path = copy_of(small_stack, tmp_path)
    (path / "z.csv").unlink()
    if z_csv is not None:
        (path / "z.csv").write_text(z_csv)
    with pytest.raises(ValueError, match=message):
        calibrate_camera_recording(open_recording(path), board=small_stack.board, du_px_per_mm=96, dv_px_per_mm=96)


def test_mixed_image_sizes(small_stack, tmp_path):
    path = copy_of(small_stack, tmp_path)
    cv2.imwrite(str(path / "frame0003.png"), np.full((400, 512), 90, np.uint8))
    mixed = r"^frame0003.png: 512 × 400 px, but frame 0 is 512 × 480 px \(mixed frame sizes"
    with pytest.raises(ValueError, match=mixed):
        calibrate_camera_recording(open_recording(path), board=small_stack.board, du_px_per_mm=96, dv_px_per_mm=96)


def test_cli_errors_are_one_line_and_leave_no_file(small_stack, tmp_path, capsys):
    path = copy_of(small_stack, tmp_path)
    (path / "z.csv").write_text("frame,z_mm\n0,1\n")
    out = tmp_path / "camera.json"
    assert run_cli("calibrate-camera", str(path), *board_flags(small_stack), "-o", str(out)) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert error[-1].startswith("error: z.csv: 1 rows, but the recording has 5 frames")
    assert not out.exists() and list(tmp_path.glob("*.partial")) == []
    assert run_cli("calibrate-camera", str(path), "--board-cols", "9", "-o", str(out)) == 2
    assert "give all of --board-cols" in capsys.readouterr().err
    assert run_cli("camera-export", str(tmp_path / "missing.json"), "--opencv-yaml", str(tmp_path / "x.yaml")) == 2
    assert run_cli("calibrate-camera", str(path), "--pixel-pitch-um", "10", "--dv", "3", "-o", str(out)) == 2
    assert "not both" in capsys.readouterr().err


def test_failed_write_keeps_the_old_file(calibrations, tmp_path, monkeypatch):
    from fringelab.formats import atomic

    out = tmp_path / "camera.json"
    out.write_text("old")
    calibration = calibrations["512x480"]

    def broken_write(text_file, *args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(atomic.os, "replace", broken_write)
    with pytest.raises(OSError, match="disk full"):
        write_camera_json(calibration, out)
    assert out.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["camera.json"]
