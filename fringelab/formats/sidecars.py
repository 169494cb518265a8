"""The sidecars of a recording: z.csv (stage Z per frame), frames.csv (the test log), board.json (the chessboard).

One reader and one parser per sidecar, used wherever the sidecar comes from (inside a ZIP, beside the frames,
uploaded on its own): `check_sidecar_size` refuses a sidecar over MAX_SIDECAR_BYTES before a byte of it is read,
`sidecar_text` decodes it, and the parsers refuse cells over MAX_FIELD_CHARS, frame ids outside int64, non-finite
numbers and JSON nested deeper than MAX_JSON_DEPTH. Errors are ValueError naming the file and the line."""

from __future__ import annotations

import csv
import io
import json
import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.formats.container_common import MAX_SIDECAR_BYTES, check_sidecar_size
from fringelab.science.chessboard import Board

FRAMES_CSV_COLUMNS = ("time_s", "punch_displacement_mm", "force_kN")
MAX_FIELD_CHARS = 64  # a number or a frame id; longer is not a cell of these files
MAX_JSON_DEPTH = 8  # board.json is one object holding one list
_INT64_MAX = (1 << 63) - 1


def sidecar_text(data: bytes, *, name: str) -> str:
    """The text of a sidecar's bytes (UTF-8, a BOM allowed), size-checked."""
    check_sidecar_size(len(data), name=name)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{name}: not UTF-8 text") from None


def read_sidecar_file(path: Path) -> str:
    """The text of a sidecar file on disk; its size is checked before it is read."""
    check_sidecar_size(path.stat().st_size, name=path.name)
    with path.open("rb") as handle:
        return sidecar_text(handle.read(MAX_SIDECAR_BYTES + 1), name=path.name)


@dataclass(frozen=True, eq=False)
class FrameTable:
    """The test log (frames.csv): frame ids and, per frame, time, punch displacement and force, each (N,).

    A column the file does not have is None; an empty cell of a column it has is NaN (not logged for that frame).
    """

    frame: np.ndarray
    time_s: np.ndarray | None = None
    punch_displacement_mm: np.ndarray | None = None
    force_kN: np.ndarray | None = None

    COLUMNS = FRAMES_CSV_COLUMNS

    @classmethod
    def empty(cls) -> FrameTable:
        """A log with no rows (every frame gets NaN)."""
        return cls(frame=np.zeros(0, np.int64))

    def columns(self) -> list[str]:
        """The columns the log has, in file order."""
        return [c for c in FRAMES_CSV_COLUMNS if getattr(self, c) is not None]

    def rows(self, frames: Sequence[int]) -> dict[str, np.ndarray]:
        """Every column for the given frame indices (NaN for frames or columns not in the log)."""
        out = {name: np.full(len(frames), np.nan) for name in FRAMES_CSV_COLUMNS}
        position = {int(f): i for i, f in enumerate(self.frame)}
        for j, f in enumerate(frames):
            i = position.get(int(f))
            if i is not None:
                for name in self.columns():
                    out[name][j] = getattr(self, name)[i]
        return out


def read_frames_csv(text: str, *, name: str = "frames.csv") -> FrameTable:
    """Parse `frame,time_s,punch_displacement_mm,force_kN` (frame and any subset of the others).

    The rule, for every caller: frame ids are unique integers (a bad one is an error naming the line); an empty
    cell of an optional column is a missing value (NaN); any other cell must be a finite number; time_s, where
    given, increases with the frame id.
    """
    allowed = {"frame", *FRAMES_CSV_COLUMNS}
    rows = list(_rows(text, name=name, required=("frame",), allowed=allowed))
    if not rows:
        raise ValueError(f"{name}: no rows")
    present = [c for c in FRAMES_CSV_COLUMNS if c in rows[0][1]]
    if not present:
        raise ValueError(f"{name}: needs at least one of {', '.join(FRAMES_CSV_COLUMNS)} besides frame")
    frames: list[int] = []
    values: dict[str, list[float]] = {c: [] for c in present}
    seen: set[int] = set()
    for line_no, row in rows:
        frame = _frame_id(row, name=name, line_no=line_no)
        if frame in seen:
            raise ValueError(f"{name} line {line_no}: frame {frame} appears twice")
        seen.add(frame)
        frames.append(frame)
        for column in present:
            empty = row[column] == ""
            values[column].append(math.nan if empty else _number(row, column, name=name, line_no=line_no))
    frame_ids = np.asarray(frames, dtype=np.int64)
    table = {c: np.asarray(v, dtype=np.float64) for c, v in values.items()}
    if "time_s" in table:
        times = table["time_s"][np.argsort(frame_ids)]
        if (np.diff(times[np.isfinite(times)]) <= 0).any():
            raise ValueError(f"{name}: time_s must increase with the frame number")
    return FrameTable(frame=frame_ids, **table)


def frames_csv_text(table: FrameTable) -> str:
    """The text of a frames.csv for a table (its columns; NaN written as an empty cell)."""
    columns = table.columns()
    lines = [",".join(["frame", *columns])]
    for i, frame in enumerate(table.frame):
        values = [getattr(table, c)[i] for c in columns]
        lines.append(",".join([str(int(frame)), *("" if not np.isfinite(v) else repr(float(v)) for v in values)]))
    return "\n".join(lines) + "\n"


def _rows(
    text: str, *, name: str, required: tuple[str, ...], allowed: set[str]
) -> Iterator[tuple[int, dict[str, str]]]:
    reader = csv.DictReader(io.StringIO(text))
    try:
        yield from _checked_rows(reader, name=name, required=required, allowed=allowed)
    except csv.Error as error:  # a NUL byte, a field over csv's own limit: malformed input, not a crash
        raise ValueError(f"{name} line {reader.line_num}: not a CSV row ({error})") from None


def _checked_rows(
    reader: csv.DictReader[str], *, name: str, required: tuple[str, ...], allowed: set[str]
) -> Iterator[tuple[int, dict[str, str]]]:
    columns = [f.strip() for f in reader.fieldnames or []]
    if not set(required) <= set(columns):
        raise ValueError(f"{name}: expected columns '{','.join(required)}', got {reader.fieldnames}")
    unknown = [c for c in columns if c not in allowed]
    if unknown:
        raise ValueError(f"{name}: unknown column {unknown[0]!r} (accepted: {', '.join(sorted(allowed))})")
    for line_no, row in enumerate(reader, start=2):
        if None in row or any(value is None for value in row.values()):
            raise ValueError(f"{name} line {line_no}: expected {len(columns)} values")
        cells = {k.strip(): (v or "").strip() for k, v in row.items()}
        for column, value in cells.items():
            if len(value) > MAX_FIELD_CHARS:
                raise ValueError(
                    f"{name} line {line_no}, column {column}: {len(value)} characters; a cell holds one number"
                )
        yield line_no, cells


def _number(row: dict[str, str], column: str, *, name: str, line_no: int) -> float:
    try:
        value = float(row[column])
    except ValueError:
        raise ValueError(f"{name} line {line_no}, column {column}: {row[column]!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{name} line {line_no}, column {column}: not finite")
    return value


def _frame_id(row: dict[str, str], *, name: str, line_no: int) -> int:
    try:
        frame = int(row["frame"])
    except ValueError:
        raise ValueError(f"{name} line {line_no}, column frame: {row['frame']!r} is not an integer") from None
    if not 0 <= frame <= _INT64_MAX:
        raise ValueError(f"{name} line {line_no}, column frame: {frame} is not a frame number (0 or more)")
    return frame


def read_z_csv(text: str, *, name: str = "z.csv") -> dict[int, float]:
    """Parse `frame,z_mm` rows into {frame: z_mm}; errors name the line."""
    z_by_frame: dict[int, float] = {}
    for line_no, row in _rows(text, name=name, required=("frame", "z_mm"), allowed={"frame", "z_mm"}):
        frame = _frame_id(row, name=name, line_no=line_no)
        z_mm = _number(row, "z_mm", name=name, line_no=line_no)
        if frame in z_by_frame:
            raise ValueError(f"{name} line {line_no}: frame {frame} appears twice")
        z_by_frame[frame] = z_mm
    if not z_by_frame:
        raise ValueError(f"{name}: no rows")
    return z_by_frame


# The spellings of board.json keys met in the wild (OpenCV samples, MATLAB's Camera Calibrator, lab scripts), each
# mapped onto ours after normalising (camelCase → snake_case, lower case, "-" and " " → "_"). Counts of squares
# are one more than counts of inner corners.
_BOARD_COLS = ("cols", "columns", "n_cols", "num_cols", "inner_cols", "corners_x", "inner_corners_x", "nx",
               "board_width", "width", "pattern_width")  # fmt: skip
_BOARD_ROWS = ("rows", "n_rows", "num_rows", "inner_rows", "corners_y", "inner_corners_y", "ny", "board_height",
               "height", "pattern_height")  # fmt: skip
_BOARD_SQUARES_X = ("squares_x", "n_squares_x", "squares_cols", "square_cols")
_BOARD_SQUARES_Y = ("squares_y", "n_squares_y", "squares_rows", "square_rows")
_BOARD_PAIRS = ("inner_corners", "pattern_size", "board_size", "corners", "size")  # [cols, rows] of inner corners
_BOARD_SQUARE_UNITS = {  # key → factor to mm
    **dict.fromkeys(("square_mm", "square_size_mm", "square_length_mm", "square_side_mm", "size_mm"), 1.0),
    **dict.fromkeys(("square_size", "square_length", "square", "square_side", "checker_size", "spacing"), None),
    **dict.fromkeys(("square_m", "square_size_m", "square_length_m"), 1000.0),
    **dict.fromkeys(("square_cm", "square_size_cm", "square_length_cm"), 10.0),
}
_UNIT_TO_MM = {"mm": 1.0, "millimeter": 1.0, "millimeters": 1.0, "millimetre": 1.0, "millimetres": 1.0,
               "cm": 10.0, "m": 1000.0, "meter": 1000.0, "meters": 1000.0, "metre": 1000.0, "metres": 1000.0,
               "in": 25.4, "inch": 25.4, "inches": 25.4}  # fmt: skip
_BOARD_ORIGIN = ("origin", "origin_corner", "origin_ij", "origin_index")
BOARD_JSON_EXAMPLE = '{"cols": 9, "rows": 6, "square_mm": 25.0, "origin": null}'


def _normal_key(key: str) -> str:
    snake = re.sub(r"(?<=[a-z0-9])([A-Z])", r"_\1", key.strip())
    return re.sub(r"[\s\-]+", "_", snake).lower()


def _first(data: dict[str, Any], keys: Sequence[str]) -> tuple[str, Any] | None:
    for key in keys:
        if key in data:
            return key, data[key]
    return None


def read_board_json(text: str, *, name: str = "board.json") -> Board:
    """Parse a chessboard description: {"cols": 9, "rows": 6, "square_mm": 25.0, "origin": [4, 2] or null}.

    cols × rows count inner corners. Common other spellings are accepted: `columns`, `nx`, `width`, camelCase
    (`squareSize`), a pair `"inner_corners"` or `"pattern_size": [cols, rows]`, counts of squares (`squares_x`,
    `squares_y`: one more than inner corners), the square in m or cm (`square_size_m`) or with a `"unit"`
    (`"square_size": 0.025, "unit": "m"`; without one, mm). Errors say what was expected.
    """
    if _json_depth(text) > MAX_JSON_DEPTH:
        raise ValueError(f"{name}: nested deeper than {MAX_JSON_DEPTH} levels; expected one flat object")
    try:
        raw: Any = json.loads(text, parse_constant=_no_constant)
    except ValueError as error:  # JSONDecodeError, or NaN/Infinity
        raise ValueError(f"{name}: not valid JSON ({error})") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{name}: expected a JSON object like {BOARD_JSON_EXAMPLE}, got {type(raw).__name__}")
    data = {_normal_key(str(key)): value for key, value in raw.items()}
    cols = _first(data, _BOARD_COLS)
    rows = _first(data, _BOARD_ROWS)
    if cols is None and rows is None:
        pair = _first(data, _BOARD_PAIRS)
        squares_x, squares_y = _first(data, _BOARD_SQUARES_X), _first(data, _BOARD_SQUARES_Y)
        if pair is not None:
            if not (isinstance(pair[1], list | dict) and len(pair[1]) == 2):
                raise ValueError(f"{name}: {pair[0]} must be [cols, rows] of inner corners, got {pair[1]!r}")
            values = list(pair[1].values()) if isinstance(pair[1], dict) else pair[1]
            cols, rows = (pair[0], values[0]), (pair[0], values[1])
        elif squares_x is not None and squares_y is not None:
            cols = (squares_x[0], squares_x[1] - 1 if _is_int(squares_x[1]) else squares_x[1])
            rows = (squares_y[0], squares_y[1] - 1 if _is_int(squares_y[1]) else squares_y[1])
    square = _first(data, tuple(_BOARD_SQUARE_UNITS))
    if cols is None or rows is None or square is None:
        missing = [what for what, found in (("cols", cols), ("rows", rows), ("square_mm", square)) if found is None]
        raise ValueError(
            f"{name}: missing {', '.join(missing)} (none of the keys {sorted(raw)} names it; expected e.g. "
            f"{BOARD_JSON_EXAMPLE}: cols × rows inner corners, the square's side in mm)"
        )
    if not (_is_int(cols[1]) and _is_int(rows[1]) and cols[1] >= 2 and rows[1] >= 2):
        raise ValueError(f"{name}: needs at least 2 × 2 inner corners (integers), got {cols[1]!r} × {rows[1]!r}")
    square_key, square_value = square
    if not _is_number(square_value) or not 0 < square_value < math.inf:
        raise ValueError(f"{name}: {square_key} must be a positive number, got {square_value!r}")
    factor = _BOARD_SQUARE_UNITS[square_key]
    if factor is None:
        unit = data.get("unit", data.get("units", data.get("square_unit", "mm")))
        if not isinstance(unit, str) or unit.strip().lower() not in _UNIT_TO_MM:
            raise ValueError(f"{name}: unit must be one of {', '.join(sorted(_UNIT_TO_MM))}, got {unit!r}")
        factor = _UNIT_TO_MM[unit.strip().lower()]
    origin_found = _first(data, _BOARD_ORIGIN)
    origin = origin_found[1] if origin_found else None
    if origin is not None:
        valid = isinstance(origin, list) and len(origin) == 2 and all(_is_int(v) and v >= 0 for v in origin)
        if not valid:
            raise ValueError(f"{name}: origin must be [i, j] corner indices ≥ 0 or null, got {origin!r}")
        origin = (origin[0], origin[1])
    return Board(cols=cols[1], rows=rows[1], square_mm=float(square_value) * factor, origin=origin)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def board_json_text(board: Board) -> str:
    """board.json in our own spelling (what `read_board_json` reads back to the same board)."""
    origin = list(board.origin) if board.origin is not None else None
    return json.dumps({"cols": board.cols, "rows": board.rows, "square_mm": board.square_mm, "origin": origin}) + "\n"


def _json_depth(text: str) -> int:
    """The deepest nesting of brackets outside strings (json.loads would recurse that deep)."""
    depth = deepest = 0
    in_string = escaped = False
    for char in text:
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth -= 1
    return deepest


def _no_constant(constant: str) -> Any:
    raise ValueError(f"{constant} is not a JSON number")


def frame_indices(frame_ids: Sequence[int] | np.ndarray, frame_count: int, *, name: str) -> np.ndarray:
    """0-based frame indices of a sidecar's frame ids, which number the frames 0..n−1 or 1..n.

    Ids are read as 1-based when none is 0 and the largest is n. Raises ValueError naming the first id that
    matches no frame.
    """
    ids = np.asarray(frame_ids, dtype=np.int64)
    one_based = ids.size > 0 and ids.min() >= 1 and ids.max() == frame_count
    indices = ids - 1 if one_based else ids
    outside = np.flatnonzero((indices < 0) | (indices >= frame_count))
    if outside.size:
        bad = int(ids[outside[0]])
        raise ValueError(
            f"{name}: frame {bad} matches no frame of the recording, which has {frame_count} frames "
            f"(numbered 0–{frame_count - 1} or 1–{frame_count})"
        )
    return indices


def z_csv_text(z_mm: Sequence[float], *, first_frame: int = 0) -> str:
    """The text of a `z.csv` sidecar for frames numbered from `first_frame`."""
    return "frame,z_mm\n" + "".join(f"{first_frame + i},{z!r}\n" for i, z in enumerate(map(float, z_mm)))
