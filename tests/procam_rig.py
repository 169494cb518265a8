"""The virtual digital-projector rig the camera–projector tests share (docs/procam.md §6): the rig itself, the Gray
code a scan records, the two sequences a chessboard pose records, a ball in front of a screen rendered under the
scan's code, and four chessboard poses rendered under the pose sequences.

Used by tests/science/procam/, tests/worker/test_scan_jobs.py and the browser tests of the procam views.
"""

from __future__ import annotations

import cv2
import numpy as np

from fringelab.science.graycode import PatternSequence, WhiteBlack
from fringelab.science.virtual_procam import (
    ChessboardPose,
    Plane,
    ProcamImaging,
    ProcamRenderer,
    Sphere,
    gray_code_patterns,
    in_frame_order,
    virtual_procam_rig,
)

RIG = virtual_procam_rig()
# A scan's code: 8 bits of 2 projector px along the columns (the finest bit left out), white and black first.
SCAN_COLUMNS = PatternSequence(axis="columns", projector_size_wh_px=(320, 200), gray_frames=tuple(range(2, 10)),
                               band_px=2.0, threshold=WhiteBlack(0, 1))  # fmt: skip
# A chessboard pose's codes: white and black, then 9 bits of 1 px along the columns and 8 along the rows.
POSE_COLUMNS = PatternSequence(axis="columns", projector_size_wh_px=(320, 200), gray_frames=tuple(range(2, 11)),
                               band_px=1.0, threshold=WhiteBlack(0, 1))  # fmt: skip
POSE_ROWS = PatternSequence(axis="rows", projector_size_wh_px=(320, 200), gray_frames=tuple(range(11, 19)),
                            band_px=1.0, threshold=WhiteBlack(0, 1))  # fmt: skip
# The ball and the screen behind it, in the camera frame.
BALL = Sphere((0.0, 0.0, 300.0), 20.0)
SCREEN = Plane((0.0, 0.0, -1.0), -340.0)
# The chessboard the poses show: 9 × 7 inner corners of 8 mm.
BOARD_COLS, BOARD_ROWS, BOARD_SQUARE_MM = 9, 7, 8.0


def ball_frames(*, supersample: int, seed: int) -> list[np.ndarray]:
    """The ball in front of the screen under the scan's code (SCAN_COLUMNS), in recording order."""
    renderer = ProcamRenderer(RIG, imaging=ProcamImaging(supersample=supersample))
    return renderer.render([BALL, SCREEN], in_frame_order(gray_code_patterns(SCAN_COLUMNS)),
                           rng=np.random.default_rng(seed))  # fmt: skip


def pose_recordings(*, seed: int) -> list[list[np.ndarray]]:
    """Four chessboard poses (tilted 22° about x, about y, and 18° about both) 295–310 mm away, each under
    POSE_COLUMNS then POSE_ROWS: the frames of each, in recording order."""
    patterns = in_frame_order(gray_code_patterns(POSE_COLUMNS), gray_code_patterns(POSE_ROWS))
    renderer = ProcamRenderer(RIG, imaging=ProcamImaging(supersample=2))
    rng = np.random.default_rng(seed)
    out = []
    for i, (ax, ay) in enumerate([(0, 0), (22, 0), (0, 22), (-18, -18)]):
        rotation = cv2.Rodrigues(np.deg2rad(np.array([ax, ay, 2.0 * i])))[0]
        centre = np.array([(BOARD_COLS - 1) * BOARD_SQUARE_MM / 2, (BOARD_ROWS - 1) * BOARD_SQUARE_MM / 2, 0.0])
        tvec = np.array([0.0, 0.0, 295.0 + 5 * i]) - rotation @ centre
        pose = ChessboardPose(BOARD_COLS, BOARD_ROWS, BOARD_SQUARE_MM, tuple(cv2.Rodrigues(rotation)[0].ravel()),
                              tuple(tvec))  # fmt: skip
        out.append(renderer.render([pose], patterns, rng=rng))
    return out
