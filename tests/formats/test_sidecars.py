"""The sidecars' one set of rules (fringelab.formats.sidecars), whatever the recording they come with."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.formats.sidecars import frame_indices, read_board_json, read_frames_csv, read_z_csv


def test_sidecars_are_validated_with_line_and_column():
    assert read_z_csv("frame,z_mm\n0,1.0\n1,2.5\n") == {0: 1.0, 1: 2.5}
    with pytest.raises(ValueError, match="line 3, column z_mm"):
        read_z_csv("frame,z_mm\n0,1\n1,abc\n")
    table = read_frames_csv("frame,time_s,force_kN\n1,0.0,0.5\n2,0.001,1.5\n")
    assert table.columns() == ["time_s", "force_kN"] and table.punch_displacement_mm is None
    np.testing.assert_array_equal(table.frame, [1, 2])
    with pytest.raises(ValueError, match="unknown column 'speed'"):
        read_frames_csv("frame,speed\n0,1\n")
    with pytest.raises(ValueError, match="time_s must increase"):
        read_frames_csv("frame,time_s\n0,0.1\n1,0.1\n")
    with pytest.raises(ValueError, match="line 2, column force_kN: 'nan'|line 2, column force_kN: not finite"):
        read_frames_csv("frame,force_kN\n0,nan\n")
    board = read_board_json('{"inner_corners": [9, 6], "square_mm": 25}')
    assert (board.cols, board.rows, board.square_mm, board.origin) == (9, 6, 25.0, None)
    with pytest.raises(ValueError, match="square_mm must be a positive number"):
        read_board_json('{"cols": 9, "rows": 6, "square_mm": -1}')
    with pytest.raises(ValueError, match="missing rows"):
        read_board_json('{"cols": 9, "square_mm": 3}')


def test_sidecar_frame_ids_must_match_the_frames():
    np.testing.assert_array_equal(frame_indices([0, 1, 2], 3, name="z.csv"), [0, 1, 2])
    np.testing.assert_array_equal(frame_indices([1, 2, 3], 3, name="z.csv"), [0, 1, 2])  # 1-based
    with pytest.raises(ValueError, match="frame 7 matches no frame of the recording, which has 3 frames"):
        frame_indices([0, 1, 7], 3, name="z.csv")


def test_frames_csv_an_empty_cell_is_a_missing_value_and_errors_name_the_line() -> None:
    table = read_frames_csv("frame,time_s,force_kN\n0,0.0,1.5\n1,0.5,\n")
    np.testing.assert_array_equal(table.frame, [0, 1])
    assert np.isnan(table.force_kN[1]) and table.punch_displacement_mm is None
    assert np.all(np.isnan(table.rows([0, 1])["punch_displacement_mm"]))  # an absent column reads as not logged
    with pytest.raises(ValueError, match="line 3, column time_s: .abc. is not a number"):
        read_frames_csv("frame,time_s\n0,0\n1,abc\n")
    with pytest.raises(ValueError, match="line 3: frame 0 appears twice"):
        read_frames_csv("frame,time_s\n0,0\n0,1\n")
    with pytest.raises(ValueError, match="unknown column"):
        read_frames_csv("frame,speed\n0,1\n")
