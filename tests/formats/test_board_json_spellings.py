"""board.json as labs write it: the common spellings of the chessboard's inner corners and square size all read as
the same board, units are converted, and what cannot be read says what was expected."""

from __future__ import annotations

import pytest

from fringelab.formats.sidecars import board_json_text, read_board_json
from fringelab.science.chessboard import Board

NINE_BY_SIX = Board(9, 6, 25.0)


@pytest.mark.parametrize(
    "text",
    [
        '{"cols": 9, "rows": 6, "square_mm": 25}',
        '{"columns": 9, "rows": 6, "square_size_mm": 25.0}',
        '{"nx": 9, "ny": 6, "square_size": 25}',  # no unit: mm
        '{"boardWidth": 9, "boardHeight": 6, "squareSize": 25}',  # camelCase (OpenCV's sample arguments)
        '{"Board-Width": 9, "board height": 6, "Square Size mm": 25}',
        '{"inner_corners": [9, 6], "square_mm": 25}',
        '{"pattern_size": [9, 6], "square_size": 0.025, "unit": "m"}',
        '{"patternSize": {"width": 9, "height": 6}, "square_size_m": 0.025}',
        '{"squares_x": 10, "squares_y": 7, "square_size": 2.5, "units": "cm"}',  # squares: one more than corners
        '{"corners_x": 9, "corners_y": 6, "square_cm": 2.5}',
    ],
)
def test_common_spellings_read_as_the_same_board(text):
    assert read_board_json(text) == NINE_BY_SIX


def test_origin_spellings_and_round_trip():
    board = read_board_json('{"cols": 9, "rows": 6, "square_mm": 25, "originCorner": [4, 2]}')
    assert board == Board(9, 6, 25.0, (4, 2))
    assert read_board_json(board_json_text(board)) == board
    assert read_board_json(board_json_text(NINE_BY_SIX)) == NINE_BY_SIX


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('{"cols": 9, "rows": 6}', r"missing square_mm \(none of the keys \['cols', 'rows'\]"),
        ('{"width_mm": 250, "height_mm": 180}', "missing cols, rows, square_mm"),
        ('{"cols": 9.5, "rows": 6, "square_mm": 25}', "at least 2 × 2 inner corners"),
        ('{"cols": 9, "rows": 6, "square_size": 25, "unit": "furlong"}', "unit must be one of"),
        ('{"pattern_size": [9], "square_mm": 25}', r"pattern_size must be \[cols, rows\]"),
        ("[9, 6, 25]", "expected a JSON object like"),
    ],
)
def test_what_cannot_be_read_says_what_was_expected(text, message):
    with pytest.raises(ValueError, match=message):
        read_board_json(text)
