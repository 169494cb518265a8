"""Camera calibration of a whole recording: frames and sidecars in, a `CameraCalibration` out (docs/method.md §3).

What the command line and the worker's camera-calibration job call. The science stages (corner detection, the
solver) live in `fringelab.science`; the sidecars are parsed by `fringelab.formats.recordings`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.formats.sidecars import read_board_json, read_z_csv
from fringelab.pipelines.provenance import code_versions
from fringelab.science import Cancelled
from fringelab.science.calibration import (
    MODES,
    CalibrationMode,
    CameraCalibration,
    CornerView,
    FrameResult,
    ProgressCallback,
    calibrate_from_views,
    zstack_heights_mm,
)
from fringelab.science.camera import ScaleAxis
from fringelab.science.chessboard import Board, BoardNotFoundError, Detector, detect_board


def calibrate_camera_recording(
    source: Any,
    *,
    board: Board | None = None,
    mode: CalibrationMode = "zstack",
    du_px_per_mm: float,
    dv_px_per_mm: float,
    scale_on: ScaleAxis = "u",
    origin: tuple[int, int] | None = None,
    reject_outliers: bool = False,
    pixel_pitch_um: tuple[float, float] | None = None,
    detector: Detector = "auto",
    subpix_half_window_px: int | None = None,
    progress: ProgressCallback | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> CameraCalibration:
    """Calibrate a camera from a recording of a chessboard: the function the CLI and the Celery task call.

    source: a frame source from `formats.recordings.open_recording` (a sequence of grey frames with `frame_names` and
    `sidecar_text(name)`). board: the chessboard; None reads `board.json` from the recording. origin overrides
    the board's origin corner. mode: "zstack" (frames with `z.csv`, one shared pose) or "poses" (free views).
    detector and subpix_half_window_px are passed to `chessboard.detect_board` ("classic" and 11 reproduce
    OpenCV's calibration sample). progress(done, total, stage) is called with stage "corners" after each
    frame, "solving" before the solver and "done" at the end (total = frames + 2); should_cancel() is polled
    between frames and before the solver, and Cancelled is raised when it returns True.

    Frames without the board are skipped and listed with the reason. Raises ValueError for malformed input
    (z.csv, board.json, mixed image sizes) and BoardNotFoundError / CalibrationError for what the user must fix.
    """
    if mode not in MODES:
        raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
    # Messages name the recording by its file name only (never a server path); the provenance keeps the path.
    path_text = str(getattr(source, "path", "recording"))
    where = Path(path_text).name or path_text
    n_frames = len(source)
    names = list(getattr(source, "frame_names", [f"frame {i}" for i in range(n_frames)]))
    board_text = source.sidecar_text("board.json")
    if board is None:
        if board_text is None:
            raise ValueError(f"{where}: no board given and no board.json in the recording")
        board = read_board_json(board_text)
    if origin is not None:
        board = Board(board.cols, board.rows, board.square_mm, origin=tuple(origin))  # type: ignore[arg-type]
    z_text = source.sidecar_text("z.csv")
    heights: list[float] | None = None
    if mode == "zstack":
        if z_text is None:
            raise ValueError(f"{where}: z.csv missing; a zstack calibration needs the stage Z of every frame")
        heights = zstack_heights_mm(read_z_csv(z_text), n_frames)

    digest = hashlib.sha256()
    for text in (z_text, board_text):
        digest.update((text or "").encode())
    total = n_frames + 2
    views: list[CornerView] = []
    skipped: list[FrameResult] = []
    found_sizes: list[tuple[int, int] | None] = []
    image_size: tuple[int, int] | None = None
    for i, name in enumerate(names):
        if should_cancel is not None and should_cancel():
            raise Cancelled(f"cancelled after {i} of {n_frames} frames")
        image = source[i]
        digest.update(f"{name}:{image.shape}:{image.dtype}".encode())
        digest.update(np.ascontiguousarray(image).data)
        size = (int(image.shape[1]), int(image.shape[0]))
        if image_size is None:
            image_size = size
        elif size != image_size:
            raise ValueError(
                f"{name}: image size {size[0]} × {size[1]} differs from {image_size[0]} × {image_size[1]} of {names[0]}"
            )
        z_mm = None if heights is None else heights[i]
        try:
            corners = detect_board(
                image, board=board, frame=name, detector=detector, subpix_half_window_px=subpix_half_window_px
            )
        except BoardNotFoundError as error:
            found_sizes.append(error.found_size)
            skipped.append(FrameResult(frame=name, status="skipped", reason=str(error), z_mm=z_mm))
        else:
            z_column = np.full(len(corners.q_px), 0.0 if z_mm is None else z_mm)
            views.append(CornerView(name, np.column_stack([corners.points_board_mm, z_column]), corners.q_px, z_mm))
        if progress is not None:
            progress(i + 1, total, "corners")
    sizes = [f for f in found_sizes if f is not None]
    if sizes and (not views or len(sizes) >= len(views)):
        # The board is another size than declared: one sentence with both sizes, whether or not a few frames
        # matched the declared one (never a calibration on a sub-board). The detector may stop short of a board's
        # outer corners, so the largest size any frame showed is the best lower bound.
        cols, rows = max(sizes, key=lambda size: size[0] * size[1])
        full = "" if len(set(sizes)) == 1 else "at least "
        raise BoardNotFoundError(
            f"{where}: the chessboard has {full}{cols} × {rows} inner corners, {board.cols} × {board.rows} declared: "
            "declare its full size",
            found_size=(cols, rows),
        )
    if not views:
        raise BoardNotFoundError(
            f"{where}: no {board.cols} × {board.rows} chessboard found in any of the {n_frames} frames"
        )
    assert image_size is not None  # at least one frame was read
    if should_cancel is not None and should_cancel():
        raise Cancelled(f"cancelled after corner extraction of {n_frames} frames")
    if progress is not None:
        progress(n_frames + 1, total, "solving")
    settings = {
        "mode": mode, "board": {"cols": board.cols, "rows": board.rows, "square_mm": board.square_mm,
                                "origin": None if board.origin is None else list(board.origin)},
        "du_px_per_mm": du_px_per_mm, "dv_px_per_mm": dv_px_per_mm, "scale_on": scale_on,
        "reject_outliers": reject_outliers, "detector": detector, "subpix_half_window_px": subpix_half_window_px,
        "pixel_pitch_um": None if pixel_pitch_um is None else list(pixel_pitch_um),
    }  # fmt: skip
    calibration = calibrate_from_views(
        views, image_size_wh_px=image_size, mode=mode, du_px_per_mm=du_px_per_mm, dv_px_per_mm=dv_px_per_mm,
        scale_on=scale_on, reject_outliers=reject_outliers, skipped=skipped, board=board,
        pixel_pitch_um=pixel_pitch_um,
        provenance={"input": path_text, "input_sha256": digest.hexdigest(), "n_frames": n_frames, "settings": settings,
                    **code_versions()},
    )  # fmt: skip
    if progress is not None:
        progress(total, total, "done")
    return calibration
