"""Benchmark of camera calibration: corner extraction and solver, ours beside cv2.calibrateCamera, on one core.

Run from the repository root:  .venv/bin/python bench/bench_camera_calibration.py [--repeats 5]

Cases: synthetic 20-frame Z-stacks at 512 × 480 and 1024 × 1024 (rendered here, not timed), 20 free views of a
tilted board at each size, and OpenCV's 13 left*.jpg images from ../shared/data/opencv_left when present. For
each case it prints the median time of
  corners   chessboard.detect_board on every frame,
  ours      our solver (zstack or poses mode) on those corners, with everything it reports (covariance,
            inverse model, residual map, verdict),
  opencv    cv2.calibrateCamera (CALIB_FIX_K3) on the same corners: the free views as they are; the Z-stack as one
            non-planar view with initCameraMatrix2D's camera as the starting guess (OpenCV needs one there),
and the ratio ours / opencv of the medians (and of the minima, steadier on a
loaded machine). Targets: a 20-frame 1024 × 1024 calibration (corners + solver) under 5 s on one
core; our solver within 2 × of OpenCV's time. It also prints the rate of backproject_to_z (target ≥ 1e6 points/s).
"""

from __future__ import annotations

import os

# One core: numpy's BLAS and OpenCV's thread pool both restricted before they start.
for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[variable] = "1"

import argparse  # noqa: E402
import contextlib  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scipy.spatial.transform import Rotation  # noqa: E402

from fringelab.formats.recordings import open_recording  # noqa: E402
from fringelab.science.calibration import CornerView, calibrate_from_views  # noqa: E402
from fringelab.science.camera import backproject_to_z, fit_inverse_model  # noqa: E402
from fringelab.science.chessboard import Board, BoardNotFoundError, detect_board  # noqa: E402
from fringelab.science.synthetic import (  # noqa: E402
    BoardPose,
    ChessboardRenderer,
    board_pose_at_z,
    reference_camera,
    zstack_board,
)

REAL_DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "opencv_left"


def timed(function, repeats: int) -> tuple[float, float, object]:
    """Median and minimum wall time of `repeats` calls, and the last result. The minimum is steadier when
    other work shares the machine."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return statistics.median(times), min(times), result


def detect_all(frames, names, board):
    views = []
    for frame, name in zip(frames, names, strict=True):
        # A tilted view that leaves the image is not part of the timing comparison.
        with contextlib.suppress(BoardNotFoundError):
            views.append((name, detect_board(frame, board=board, frame=name)))
    return views


def opencv_calibrate(views, size, *, intrinsic_guess=None):
    object_points = [v.points_obj_mm.astype(np.float32) for v in views]
    image_points = [v.q_px.astype(np.float32) for v in views]
    flags = cv2.CALIB_FIX_K3
    if intrinsic_guess is not None:
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    return cv2.calibrateCamera(object_points, image_points, size, intrinsic_guess, np.zeros(5), flags=flags)


def run_case(name, frames, names, board, *, mode, z_mm=None, du, dv, scale_on, repeats):
    height, width = frames[0].shape
    corners_s, _, detected = timed(lambda: detect_all(frames, names, board), repeats)
    z_of = dict(zip(names, z_mm, strict=True)) if z_mm is not None else {}
    views = [
        CornerView(n, np.column_stack([c.points_board_mm, np.full(len(c.q_px), z_of.get(n, 0.0))]), c.q_px, z_of.get(n))
        for n, c in detected
    ]
    ours_s, ours_min_s, ours = timed(
        lambda: calibrate_from_views(views, mode=mode, image_size_wh_px=(width, height), du_px_per_mm=du,
                                     dv_px_per_mm=dv, scale_on=scale_on), repeats)  # fmt: skip
    if mode == "zstack":
        # OpenCV's equivalent of the Z-stack: one non-planar view, which needs a starting camera matrix.
        planar = [[v.points_obj_mm * [1, 1, 0] for v in views], [v.q_px for v in views]]
        guess = cv2.initCameraMatrix2D([p.astype(np.float32) for p in planar[0]],
                                       [q.astype(np.float32) for q in planar[1]], (width, height))  # fmt: skip
        stacked = [CornerView("stack", np.vstack([v.points_obj_mm for v in views]), np.vstack([v.q_px for v in views]))]
        opencv_s, opencv_min_s, opencv = timed(
            lambda: opencv_calibrate(stacked, (width, height), intrinsic_guess=guess), repeats
        )
    else:
        opencv_s, opencv_min_s, opencv = timed(lambda: opencv_calibrate(views, (width, height)), repeats)
    return {
        "case": name, "mode": mode, "frames": len(views), "corners": sum(len(v.q_px) for v in views),
        "corners_s": corners_s, "ours_s": ours_s, "opencv_s": opencv_s, "ours_rms": ours.rms_px,
        "opencv_rms": opencv[0], "ours_min_s": ours_min_s, "opencv_min_s": opencv_min_s,
    }  # fmt: skip


def tilted_poses(n_views: int, rng: np.random.Generator) -> list[BoardPose]:
    """Free views for Zhang's method: the board tilted up to 25° about a random in-plane axis, shifted a little."""
    poses = []
    for _ in range(n_views):
        axis_angle = rng.uniform(0, 2 * np.pi)
        tilt = np.deg2rad(rng.uniform(10, 25))
        rotvec = tilt * np.array([np.cos(axis_angle), np.sin(axis_angle), 0.0])
        rotation = Rotation.from_rotvec(rotvec).as_matrix()
        poses.append(BoardPose(rotation, np.array([rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-20, 60)])))
    return poses


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    rows = []
    z_mm = np.linspace(-20.0, 100.0, 20)
    for size in ("512x480", "1024x1024"):
        camera = reference_camera(size)
        renderer = ChessboardRenderer(camera, zstack_board(camera))
        rng = np.random.default_rng(1)
        sensor = dict(du=camera.du_px_per_mm, dv=camera.dv_px_per_mm, scale_on=camera.scale_on, repeats=args.repeats)
        frames = [renderer.render(board_pose_at_z(z), rng=rng) for z in z_mm]
        names = [f"frame{i:04d}.png" for i in range(len(frames))]
        rows.append(run_case(f"synthetic {size}", frames, names, renderer.board, mode="zstack", z_mm=z_mm, **sensor))
        # Smaller board for free views, so tilted views stay inside the image.
        renderer = ChessboardRenderer(camera, Board(10, 7, 25.0))
        frames = [renderer.render(pose, rng=rng) for pose in tilted_poses(20, rng)]
        rows.append(run_case(f"synthetic {size}", frames, names, renderer.board, mode="poses", **sensor))
    if (REAL_DATA / "reference_opencv.json").is_file():
        source = open_recording(REAL_DATA)
        rows.append(run_case("opencv_left 640x480", list(source), list(source.frame_names), Board(9, 6, 25.0),
                             mode="poses", du=1.0, dv=1.0, scale_on="u", repeats=args.repeats))  # fmt: skip
    else:
        print(f"skipping real images: {REAL_DATA.resolve()} not found")

    for size in ("512x480", "1024x1024"):
        camera = reference_camera(size)
        inverse = fit_inverse_model(camera)
        q_px = np.random.default_rng(2).uniform(0, [camera.image_width_px, camera.image_height_px], (1_000_000, 2))
        backproject_s, _, _ = timed(
            lambda camera=camera, q_px=q_px, inverse=inverse: backproject_to_z(camera, q_px, 10.0, inverse=inverse),
            args.repeats,
        )
        print(f"backproject_to_z {size}: {1e-6 * len(q_px) / backproject_s:.2f} million points/s (median)")
    print(f"one core, median of {args.repeats} runs, times in seconds")
    print(
        f"{'case':22s} {'mode':6s} {'frames':>6s} {'corners':>7s} {'corners_s':>9s} {'ours_s':>7s} {'opencv_s':>8s} "
        f"{'ratio':>6s} {'total_s':>7s} {'min ratio':>9s}  rms ours / opencv (px)"
    )
    for row in rows:
        print(
            f"{row['case']:22s} {row['mode']:6s} {row['frames']:6d} {row['corners']:7d} {row['corners_s']:9.3f} "
            f"{row['ours_s']:7.3f} {row['opencv_s']:8.3f} {row['ours_s'] / row['opencv_s']:6.2f} "
            f"{row['corners_s'] + row['ours_s']:7.3f} {row['ours_min_s'] / row['opencv_min_s']:9.2f}  "
            f"{row['ours_rms']:.4f} / {row['opencv_rms']:.4f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
