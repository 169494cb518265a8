"""Readers and writers of recordings and sidecars: the only place in `measurement` that touches files.

A recording is opened lazily: `open_recording(path)` returns a `FrameSource` whose frames are decoded one at a
time on access, so a multi-GB sequence is never held in memory. Sidecars (`z.csv`, `frames.csv`,
`board.json`) are parsed and validated here with errors that name the file, line and column.
"""

from __future__ import annotations

import csv
import io
import json
import re
import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from .chessboard import Board

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg")


def natural_key(name: str) -> list[object]:
    """Sort key that orders frame2 before frame10."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def decode_grey(data: bytes, *, name: str) -> np.ndarray:
    """Decode image bytes to a 2-D grey array (uint8 or uint16), keeping the bit depth."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if image is None:
        raise ValueError(f"{name}: not a readable image (corrupt, truncated or unsupported format)")
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        image = cv2.cvtColor(image, code)
    return image


@dataclass(frozen=True)
class FrameSource(Sequence[np.ndarray]):
    """Frames of a folder or ZIP of images, in natural name order, decoded on access."""

    path: Path
    frame_names: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.frame_names)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        name = self.frame_names[index]
        return decode_grey(self.read_bytes(name), name=name)

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(len(self)):
            yield self[i]

    def read_bytes(self, name: str) -> bytes:
        if self.path.is_dir():
            return (self.path / name).read_bytes()
        with zipfile.ZipFile(self.path) as archive:
            return archive.read(name)

    def sidecar_text(self, name: str) -> str | None:
        """Text of a sidecar file (`z.csv`, `frames.csv`, `board.json`) stored with the frames, if any."""
        if self.path.is_dir():
            candidate = self.path / name
            return candidate.read_text() if candidate.is_file() else None
        with zipfile.ZipFile(self.path) as archive:
            for entry in archive.namelist():
                if Path(entry).name == name:
                    return archive.read(entry).decode()
        return None


def open_recording(path: str | Path) -> FrameSource:
    """Open a folder or ZIP of frames. Raises ValueError when it holds no image."""
    path = Path(path)
    if path.is_dir():
        names = [p.name for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
    elif zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as archive:
            names = [n for n in archive.namelist() if Path(n).suffix.lower() in IMAGE_SUFFIXES]
    else:
        raise ValueError(f"{path}: not a folder or ZIP of frames")
    if not names:
        raise ValueError(f"{path}: no image frames found (accepted: {', '.join(IMAGE_SUFFIXES)})")
    return FrameSource(path=path, frame_names=tuple(sorted(names, key=natural_key)))


def read_z_csv(text: str, *, name: str = "z.csv") -> dict[int, float]:
    """Parse `frame,z_mm` rows into {frame: z_mm}; errors name the line."""
    reader = csv.DictReader(io.StringIO(text))
    if reader.fieldnames is None or not {"frame", "z_mm"} <= {f.strip() for f in reader.fieldnames}:
        raise ValueError(f"{name}: expected columns 'frame,z_mm', got {reader.fieldnames}")
    z_by_frame: dict[int, float] = {}
    for line_no, row in enumerate(reader, start=2):
        row = {k.strip(): (v or "").strip() for k, v in row.items() if k is not None}
        try:
            frame = int(row["frame"])
            z_mm = float(row["z_mm"])
        except ValueError:
            raise ValueError(f"{name} line {line_no}: 'frame' must be an integer and 'z_mm' a number") from None
        if not np.isfinite(z_mm):
            raise ValueError(f"{name} line {line_no}: z_mm is not finite")
        if frame in z_by_frame:
            raise ValueError(f"{name} line {line_no}: frame {frame} appears twice")
        z_by_frame[frame] = z_mm
    if not z_by_frame:
        raise ValueError(f"{name}: no rows")
    return z_by_frame


def read_board_json(text: str, *, name: str = "board.json") -> Board:
    """Parse a chessboard description: {"cols": 9, "rows": 6, "square_mm": 25.0, "origin": [4, 2] or null}.

    cols × rows count inner corners; `"inner_corners": [cols, rows]` may replace cols and rows.
    """
    from .chessboard import Board

    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"{name}: not valid JSON ({error})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{name}: expected a JSON object, got {type(data).__name__}")
    if "inner_corners" in data:
        data = {**data, "cols": data["inner_corners"][0], "rows": data["inner_corners"][1]}
    missing = [key for key in ("cols", "rows", "square_mm") if key not in data]
    if missing:
        raise ValueError(f"{name}: missing {', '.join(missing)} (expected cols, rows, square_mm, optional origin)")
    try:
        origin = data.get("origin")
        return Board(
            cols=int(data["cols"]),
            rows=int(data["rows"]),
            square_mm=float(data["square_mm"]),
            origin=None if origin is None else (int(origin[0]), int(origin[1])),
        )
    except (TypeError, ValueError, IndexError) as error:
        raise ValueError(f"{name}: {error}") from None


def write_frame_folder(
    path: str | Path, frames: Sequence[np.ndarray], *, sidecars: dict[str, str] | None = None
) -> Path:
    """Write frames as frame0000.png, frame0001.png, ... and sidecar texts (e.g. {"z.csv": ...}) into a folder.

    For synthetic recordings and tests; the folder is readable with `open_recording`.
    """
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    for index, frame in enumerate(frames):
        if not cv2.imwrite(str(path / f"frame{index:04d}.png"), frame):
            raise ValueError(f"{path}: could not write frame {index} (dtype {frame.dtype}, shape {frame.shape})")
    for name, text in (sidecars or {}).items():
        (path / name).write_text(text)
    return path


def z_csv_text(z_mm: Sequence[float], *, first_frame: int = 0) -> str:
    """The text of a `z.csv` sidecar for frames numbered from `first_frame`."""
    return "frame,z_mm\n" + "".join(f"{first_frame + i},{z!r}\n" for i, z in enumerate(map(float, z_mm)))
