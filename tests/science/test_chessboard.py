"""Chessboard corners: detection accuracy, the labelling rule of docs/method.md §3.1, wrong or missing boards."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.formats.sidecars import read_board_json
from fringelab.science.chessboard import Board, BoardNotFoundError, detect_board, label_board_corners
from fringelab.science.synthetic import ChessboardRenderer, board_pose_at_z, reference_camera


def ideal_grid(n_x: int, n_y: int, *, angle_deg: float = 0.0) -> np.ndarray:
    """Corners (n_y, n_x, 2) with +X to image right and +Y to image up, rotated by angle_deg in the image."""
    j, i = np.mgrid[0:n_y, 0:n_x]
    xy = np.stack([i * 30.0, -j * 30.0], axis=-1)  # image v grows downward, so +Y is −v
    angle = np.deg2rad(angle_deg)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return xy @ rotation.T + [300.0, 300.0]


@pytest.mark.parametrize("angle_deg", [0.0, 30.0, -40.0])
@pytest.mark.parametrize(
    "reorder",
    [lambda g: g, lambda g: g[::-1], lambda g: g[:, ::-1], lambda g: g[::-1, ::-1], lambda g: g.transpose(1, 0, 2),
     lambda g: g.transpose(1, 0, 2)[::-1, ::-1]],
)  # fmt: skip
def test_labels_do_not_depend_on_detector_order(angle_deg, reorder):
    grid = ideal_grid(6, 4, angle_deg=angle_deg)  # even × even: 180° symmetric, detectors may return it reversed
    labelled = label_board_corners(reorder(grid), board=Board(6, 4, 10.0))
    np.testing.assert_array_equal(labelled.q_px, grid.reshape(-1, 2))
    # Origin at the centre inner corner ((n − 1) // 2 along each axis), +X right, +Y up.
    np.testing.assert_array_equal(labelled.points_board_mm[0], [-20.0, -10.0])
    np.testing.assert_array_equal(labelled.points_board_mm[-1], [30.0, 20.0])


def test_board_turned_a_quarter_turn_in_the_image():
    # Declared 6 × 4, but seen with its 6-corner side vertical: X follows the image, so it has 4 corners.
    grid = ideal_grid(4, 6)
    labelled = label_board_corners(grid.transpose(1, 0, 2), board=Board(6, 4, 10.0))
    np.testing.assert_array_equal(labelled.q_px, grid.reshape(-1, 2))
    assert labelled.ij.max(axis=0).tolist() == [3, 5]


def test_origin_override_counts_from_lower_left():
    labelled = label_board_corners(ideal_grid(6, 4), board=Board(6, 4, 10.0, origin=(0, 0)))
    np.testing.assert_array_equal(labelled.points_board_mm[0], [0.0, 0.0])
    np.testing.assert_array_equal(labelled.q_px[0], [300.0, 300.0])  # lower-left inner corner
    with pytest.raises(ValueError, match=r"origin \(6, 0\) is outside the 6 × 4"):
        label_board_corners(ideal_grid(6, 4), board=Board(6, 4, 10.0, origin=(6, 0)))


@pytest.fixture(scope="module")
def even_board_renderer():
    return ChessboardRenderer(reference_camera("512x480"), Board(cols=12, rows=8, square_mm=25.0))


@pytest.mark.parametrize("z_mm", [-20.0, 40.0, 100.0])
def test_even_board_keeps_its_labels_along_z(z_mm, even_board_renderer):
    pose = board_pose_at_z(z_mm)
    image = even_board_renderer.render(pose, rng=np.random.default_rng(int(z_mm) + 100))
    corners = detect_board(image, board=even_board_renderer.board)
    error_px = np.hypot(*(corners.q_px - even_board_renderer.true_corners_px(pose)).T)
    # A flipped or shifted labelling would put corners a whole square (~27 px) off; 0.15 px is the detector's
    # worst case with 2 grey levels of noise.
    assert np.max(error_px) < 0.15


def test_sixteen_bit_frames_are_detected(even_board_renderer):
    pose = board_pose_at_z(0.0)
    image = even_board_renderer.render(pose, rng=np.random.default_rng(7)).astype(np.uint16) * 257
    corners = detect_board(image, board=even_board_renderer.board)
    assert np.max(np.hypot(*(corners.q_px - even_board_renderer.true_corners_px(pose)).T)) < 0.15


@pytest.mark.parametrize(("cols", "rows"), [(9, 7), (5, 4)])
def test_wrong_board_size_names_what_was_found(cols, rows, even_board_renderer):
    image = even_board_renderer.render(board_pose_at_z(0.0), rng=np.random.default_rng(8))
    with pytest.raises(
        BoardNotFoundError, match=rf"^frame7.png: the chessboard has 12 × 8 inner corners, {cols} × {rows} declared$"
    ):
        detect_board(image, board=Board(cols, rows, 25.0), frame="frame7.png")


def test_no_board():
    image = np.full((120, 160), 128, np.uint8)
    with pytest.raises(BoardNotFoundError, match="blank.png: no 9 × 6 chessboard found"):
        detect_board(image, board=Board(9, 6, 25.0), frame="blank.png")


def test_board_json():
    assert read_board_json('{"cols": 9, "rows": 6, "square_mm": 25, "origin": [0, 0]}') == Board(9, 6, 25.0, (0, 0))
    assert read_board_json('{"inner_corners": [9, 6], "square_mm": 25}') == Board(9, 6, 25.0)
    with pytest.raises(ValueError, match="board.json: missing square_mm"):
        read_board_json('{"cols": 9, "rows": 6}')
    with pytest.raises(ValueError, match="board.json: not valid JSON"):
        read_board_json("{cols: 9")
    with pytest.raises(ValueError, match="at least 2 × 2"):
        read_board_json('{"cols": 1, "rows": 6, "square_mm": 25}')


@pytest.mark.parametrize("detector", ["auto", "classic"])
def test_a_sub_board_of_a_larger_board_is_never_accepted(detector, even_board_renderer):
    """Declaring 9 × 6 on the 12 × 8 board: the classic detector finds a 9 × 6 pattern inside it, which would
    calibrate on a sub-board; it is refused in one sentence naming both sizes."""
    image = even_board_renderer.render(board_pose_at_z(0.0), rng=np.random.default_rng(9))
    sizes = r"^frame3.png: the chessboard has 12 × 8 inner corners, 9 × 6 declared$"
    with pytest.raises(BoardNotFoundError, match=sizes):
        detect_board(image, board=Board(9, 6, 25.0), frame="frame3.png", detector=detector)
