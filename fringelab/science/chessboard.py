"""Chessboard inner corners: detection, sub-pixel refinement and consistent labelling (docs/method.md §3.1).

Belongs here: the `Board` description, finding its inner corners in one grey image with OpenCV
(findChessboardCornersSB, falling back to findChessboardCorners), refining them with cornerSubPix, and
labelling them by the rule of docs/method.md §3.1 so a board moved along Z keeps its origin in every frame.
Not here: reading frames (`fringelab.formats.recordings.py`) and using the corners (`calibration.py`).

Labelling rule: +X is the board direction closest to image right, +Y the one closest to image up, so +Z points
toward the camera. Corner (i, j) is counted along +X and +Y from the inner corner at the lower left of the
image; the origin is the centre inner corner ((n − 1) // 2 along each axis) unless the board names another.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import cv2
import numpy as np

from . import MeasurementError

# Boards are found on a copy no larger than this (long side, px): findChessboardCornersSB costs about the
# image area, and its corners are only a start for cornerSubPix at full resolution.
DETECTION_MAX_SIDE_PX = 800
# cornerSubPix half-window as a fraction of the square side: large enough to average noise over the edges,
# small enough (< 1/2 side) that the window never reaches the neighbouring corners.
SUBPIX_WINDOW_FRACTION = 0.4
SUBPIX_MIN_HALF_WINDOW_PX = 3
SUBPIX_MAX_HALF_WINDOW_PX = 15
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 1e-4)


class BoardNotFoundError(MeasurementError):
    """The chessboard was not found in a frame (or in any frame), or not with the declared size.

    found_size: (cols, rows) of a board of another size seen in the image, as a lower bound (the detector may
    not grow it to its full extent), or None.
    """

    def __init__(self, message: str, *, found_size: tuple[int, int] | None = None) -> None:
        super().__init__(message)
        self.found_size = found_size


@dataclass(frozen=True)
class Board:
    """A chessboard: inner corners per row and per column, square side, optional origin corner (i, j)."""

    cols: int
    rows: int
    square_mm: float
    origin: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.cols < 2 or self.rows < 2:
            raise ValueError(f"board: needs at least 2 × 2 inner corners, got {self.cols} × {self.rows}")
        if not self.square_mm > 0:
            raise ValueError(f"board: square size must be positive mm, got {self.square_mm}")
        if self.origin is not None and min(self.origin) < 0:
            raise ValueError(f"board: origin corner indices must be ≥ 0, got {self.origin}")


@dataclass(frozen=True, eq=False)
class BoardCorners:
    """Labelled inner corners of one image.

    q_px: shape (N, 2) pixels; ij: shape (N, 2) integer corner indices along +X, +Y from the lower-left corner;
    points_board_mm: shape (N, 2) board coordinates (X, Y) relative to the origin corner.
    """

    q_px: np.ndarray
    ij: np.ndarray
    points_board_mm: np.ndarray
    detector: str


def _as_uint8(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    # 16-bit or float frames: stretch the 0.1..99.9 percentiles so the detector sees full contrast.
    low, high = np.percentile(image, [0.1, 99.9])
    scaled = (image.astype(np.float32) - low) * (255.0 / max(float(high - low), 1e-9))
    return np.clip(scaled, 0, 255).astype(np.uint8)


Detector = Literal["auto", "classic"]
DETECTORS: tuple[str, ...] = get_args(Detector)


def _detect_grid(image_u8: np.ndarray, pattern: tuple[int, int], detector: str) -> tuple[np.ndarray | None, str]:
    """Raw corners (n_a, n_b, 2) in detector order and the detector's name, or (None, "")."""
    cols, rows = pattern
    if detector == "classic":
        return _detect_classic(image_u8, pattern)
    height, width = image_u8.shape
    scale = min(1.0, DETECTION_MAX_SIDE_PX / max(height, width))
    small = image_u8 if scale == 1.0 else cv2.resize(image_u8, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_LARGER
    found, corners, meta = cv2.findChessboardCornersSBWithMeta(small, pattern, flags)
    if not found and scale != 1.0:
        small, scale = image_u8, 1.0
        found, corners, meta = cv2.findChessboardCornersSBWithMeta(small, pattern, flags)
    if found:
        # The SB detector returns pixel centres at integer coordinates, as we do; a resize by s maps
        # u to (u + 0.5)·s − 0.5.
        grid = (corners.reshape(meta.shape[0], meta.shape[1], 2).astype(np.float64) + 0.5) / scale - 0.5
        return grid, "findChessboardCornersSB"
    return _detect_classic(image_u8, pattern)


def _detect_classic(image_u8: np.ndarray, pattern: tuple[int, int]) -> tuple[np.ndarray | None, str]:
    cols, rows = pattern
    found, corners = cv2.findChessboardCorners(
        image_u8, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    )
    if found:
        return corners.reshape(rows, cols, 2).astype(np.float64), "findChessboardCorners"
    return None, ""


def _refine_subpixel(image_u8: np.ndarray, grid_px: np.ndarray, half_window_px: int | None) -> np.ndarray:
    steps = np.concatenate(
        [
            np.linalg.norm(np.diff(grid_px, axis=0), axis=2).ravel(),
            np.linalg.norm(np.diff(grid_px, axis=1), axis=2).ravel(),
        ]
    )
    half = int(np.clip(round(SUBPIX_WINDOW_FRACTION * float(np.min(steps))), SUBPIX_MIN_HALF_WINDOW_PX,
                       SUBPIX_MAX_HALF_WINDOW_PX)) if half_window_px is None else half_window_px  # fmt: skip
    corners = grid_px.reshape(-1, 1, 2).astype(np.float32)
    refined = cv2.cornerSubPix(image_u8, corners, (half, half), (-1, -1), SUBPIX_CRITERIA)
    return refined.reshape(grid_px.shape).astype(np.float64)


def find_board_corners(
    image: np.ndarray,
    *,
    board: Board,
    frame: str = "image",
    detector: Detector = "auto",
    subpix_half_window_px: int | None = None,
) -> tuple[np.ndarray, str]:
    """Sub-pixel inner corners of `board` in a grey image, shape (H, W): grid (n_a, n_b, 2) in detector order.

    detector: "auto" (findChessboardCornersSB, falling back to findChessboardCorners) or "classic"
    (findChessboardCorners only, as OpenCV's calibration sample). subpix_half_window_px: cornerSubPix half-window;
    None sizes it to 0.4 × the smallest square side seen (3..15 px), so it never reaches the next corner.
    OpenCV's sample uses 11, which on small squares pulls corners toward their neighbours.

    Raises BoardNotFoundError naming `frame`, with the size actually found when the board differs from the
    declared one.
    """
    if image.ndim != 2:
        raise ValueError(f"{frame}: expected a grey image of shape (H, W), got {image.shape}")
    if detector not in DETECTORS:
        raise ValueError(f"detector: expected one of {DETECTORS}, got {detector!r}")
    image_u8 = _as_uint8(image)
    declared = (board.cols, board.rows)
    grid, used = _detect_grid(image_u8, declared, detector)
    found = _found_size(image_u8, declared) if grid is None else (grid.shape[1], grid.shape[0])
    if grid is not None and used != "findChessboardCornersSB":
        # The classic detector finds the declared pattern inside a larger board too: never take a sub-board.
        whole = _found_size(image_u8, declared)
        if whole is not None and max(whole) * min(whole) > board.cols * board.rows:
            found = whole
    if found is not None and sorted(found) != sorted(declared):
        # Name the found size in the declared orientation (larger count first if declared so).
        big, small = max(found), min(found)
        found_cols, found_rows = (big, small) if board.cols >= board.rows else (small, big)
        raise BoardNotFoundError(
            f"{frame}: the chessboard has {found_cols} × {found_rows} inner corners, "
            f"{board.cols} × {board.rows} declared",
            found_size=(found_cols, found_rows),
        )
    if grid is None:
        raise BoardNotFoundError(f"{frame}: no {board.cols} × {board.rows} chessboard found")
    return _refine_subpixel(image_u8, grid, subpix_half_window_px), used


def _found_size(image_u8: np.ndarray, declared: tuple[int, int]) -> tuple[int, int] | None:
    """The inner-corner count (cols, rows) of whatever chessboard is in the image: the larger of the boards grown
    (CALIB_CB_LARGER) from the declared pattern and from the smallest (3 × 3); either may stop short of the board's
    full extent, so it is a lower bound."""
    height, width = image_u8.shape
    scale = min(1.0, DETECTION_MAX_SIDE_PX / max(height, width))
    small = cv2.resize(image_u8, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else image_u8
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_LARGER
    sizes = []
    for image in (small, image_u8) if scale < 1 else (image_u8,):
        for start in (declared, (3, 3)):
            found, _, meta = cv2.findChessboardCornersSBWithMeta(image, start, flags)
            if found:
                sizes.append((int(meta.shape[1]), int(meta.shape[0])))
        if sizes:
            break
    return max(sizes, key=lambda size: size[0] * size[1]) if sizes else None


def label_board_corners(grid_px: np.ndarray, *, board: Board) -> BoardCorners:
    """Label a corner grid, shape (n_a, n_b, 2), by the rule of docs/method.md §3.1 (see the module docstring)."""
    grid = np.asarray(grid_px, dtype=np.float64)
    if grid.ndim != 3 or grid.shape[2] != 2 or min(grid.shape[:2]) < 2:
        raise ValueError(f"grid_px: expected shape (n_a, n_b, 2) with n_a, n_b ≥ 2, got {grid.shape}")
    step_along_1 = np.mean(np.diff(grid, axis=1).reshape(-1, 2), axis=0)
    step_along_0 = np.mean(np.diff(grid, axis=0).reshape(-1, 2), axis=0)
    right = np.array([1.0, 0.0])
    # +X: of the four board directions, the one closest to image right.
    cos_1 = step_along_1 @ right / np.linalg.norm(step_along_1)
    cos_0 = step_along_0 @ right / np.linalg.norm(step_along_0)
    if abs(cos_0) > abs(cos_1):
        grid = grid.transpose(1, 0, 2)
        cos_1 = cos_0
    if cos_1 < 0:
        grid = grid[:, ::-1]
    # +Y: along the other axis, the sense closest to image up (−v).
    step_y = np.mean(np.diff(grid, axis=0).reshape(-1, 2), axis=0)
    if step_y[1] > 0:
        grid = grid[::-1]
    n_y, n_x = grid.shape[:2]
    if board.origin is None:
        i0, j0 = (n_x - 1) // 2, (n_y - 1) // 2
    else:
        i0, j0 = board.origin
        if i0 >= n_x or j0 >= n_y:
            raise ValueError(
                f"board origin ({i0}, {j0}) is outside the {n_x} × {n_y} inner corners as seen (i along +X, j along +Y)"
            )
    j_index, i_index = np.mgrid[0:n_y, 0:n_x]
    ij = np.column_stack([i_index.ravel(), j_index.ravel()])
    points_board_mm = (ij - np.array([i0, j0])) * board.square_mm
    return BoardCorners(
        q_px=grid.reshape(-1, 2), ij=ij, points_board_mm=points_board_mm.astype(np.float64), detector=""
    )


def detect_board(
    image: np.ndarray,
    *,
    board: Board,
    frame: str = "image",
    detector: Detector = "auto",
    subpix_half_window_px: int | None = None,
) -> BoardCorners:
    """Find, refine and label the inner corners of `board` in a grey image, shape (H, W) (see find_board_corners)."""
    grid, used = find_board_corners(
        image, board=board, frame=frame, detector=detector, subpix_half_window_px=subpix_half_window_px
    )
    labelled = label_board_corners(grid, board=board)
    return BoardCorners(labelled.q_px, labelled.ij, labelled.points_board_mm, used)
