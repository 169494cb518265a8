"""`fringelab calibrate-camera` and `fringelab camera-export`: camera calibration from the command line.

Thin: parse arguments, call `fringelab.science.calibration.calibrate_camera_recording`, write the result with
`fringelab.formats.camera`. numpy, OpenCV and the measurement package are imported inside the handlers
so registering the commands stays instant.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from fringelab.commands.output import emit, fail, integers, progress_bar


def _pair_of_ints(text: str) -> tuple[int, int]:
    i, j = integers(text, 2, "two integers I,J")
    return i, j


def _pitch(text: str) -> tuple[float, float]:
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (1, 2) or min(values) <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive pixel pitch P or PU,PV in µm, got {text!r}")
    return (values[0], values[-1])


def register(subparsers: Any) -> None:
    """Add `calibrate-camera` and `camera-export` to the CLI's subparsers."""
    from fringelab.commands.output import add_output_options

    calibrate = subparsers.add_parser(
        "calibrate-camera",
        help="calibrate a camera from a chessboard recording (Z-stack or free poses)",
        description="Calibrate a camera (Heikkilä model, docs/method.md §3) from a folder or ZIP of chessboard frames. "
        "zstack: the board moved along Z, with z.csv (frame,z_mm); poses: free views of the board. "
        "board.json in the recording may replace the board flags.",
    )
    calibrate.add_argument("recording", help="folder or ZIP of frames (with z.csv for zstack)")
    calibrate.add_argument("--board-cols", type=int, help="inner corners along a row of the board")
    calibrate.add_argument("--board-rows", type=int, help="inner corners along a column of the board")
    calibrate.add_argument("--square-mm", type=float, help="side of a board square in mm")
    calibrate.add_argument(
        "--origin",
        type=_pair_of_ints,
        metavar="I,J",
        help="origin inner corner, counted along +X, +Y from the lower-left (default: centre)",
    )
    calibrate.add_argument("--mode", choices=("zstack", "poses"), default="zstack")
    sensor = calibrate.add_mutually_exclusive_group()
    sensor.add_argument("--pixel-pitch-um", type=_pitch, metavar="P[,PV]", help="pixel pitch in µm (D = 1000 / P)")
    sensor.add_argument("--du", type=float, metavar="PX_PER_MM", help="D_u in px/mm (with --dv)")
    calibrate.add_argument("--dv", type=float, metavar="PX_PER_MM", help="D_v in px/mm (with --du)")
    calibrate.add_argument(
        "--scale-on",
        choices=("u", "v"),
        default="u",
        help="axis carrying the scale factor: u (Heikkilä) or v (the paper's sV)",
    )
    calibrate.add_argument(
        "--reject-outliers",
        action="store_true",
        help="drop frames whose RMS exceeds 3 × the median frame RMS (and 0.2 px)",
    )
    calibrate.add_argument(
        "--detector",
        choices=("auto", "classic"),
        default="auto",
        help="auto: findChessboardCornersSB, falling back to findChessboardCorners",
    )
    calibrate.add_argument(
        "--subpix-window",
        type=int,
        metavar="PX",
        help="cornerSubPix half-window in px (default: 0.4 × square side, 3..15)",
    )
    calibrate.add_argument("-o", "--output", required=True, help="calibration JSON to write")
    calibrate.add_argument("--opencv-yaml", help="also write the camera as OpenCV FileStorage YAML")
    add_output_options(calibrate)
    calibrate.set_defaults(handler=calibrate_camera_command)

    export = subparsers.add_parser("camera-export", help="export a camera calibration to another format")
    export.add_argument("calibration", help="camera.json written by calibrate-camera")
    export.add_argument("--opencv-yaml", required=True, metavar="OUT", help="OpenCV FileStorage YAML to write")
    add_output_options(export)
    export.set_defaults(handler=camera_export_command)


def _sensor_constants(args: argparse.Namespace) -> tuple[float, float, tuple[float, float] | None]:
    if args.pixel_pitch_um is not None:
        if args.dv is not None:
            raise ValueError("give either --pixel-pitch-um or --du/--dv, not both")
        pitch_u, pitch_v = args.pixel_pitch_um
        return 1000.0 / pitch_u, 1000.0 / pitch_v, (pitch_u, pitch_v)
    if (args.du is None) != (args.dv is None):
        raise ValueError("give both --du and --dv, or --pixel-pitch-um")
    if args.du is not None:
        if args.du <= 0 or args.dv <= 0:
            raise ValueError(f"--du and --dv must be positive px/mm, got {args.du}, {args.dv}")
        return args.du, args.dv, None
    print("note: no pixel pitch given; D_u = D_v = 1 px/mm, so f is in pixels", file=sys.stderr)
    return 1.0, 1.0, None


def calibrate_camera_command(args: argparse.Namespace) -> int:
    from fringelab.formats.camera import write_camera_json, write_opencv_yaml
    from fringelab.formats.recordings import open_recording
    from fringelab.pipelines.camera_calibration import calibrate_camera_recording
    from fringelab.science import MeasurementError
    from fringelab.science.chessboard import Board

    try:
        du, dv, pitch = _sensor_constants(args)
        board_flags = (args.board_cols, args.board_rows, args.square_mm)
        if all(flag is None for flag in board_flags):
            board = None  # board.json in the recording
        elif any(flag is None for flag in board_flags):
            raise ValueError("give all of --board-cols, --board-rows and --square-mm, or none (board.json)")
        else:
            board = Board(cols=args.board_cols, rows=args.board_rows, square_mm=args.square_mm)
        with open_recording(args.recording) as source, progress_bar(args, "calibrate-camera") as progress:
            calibration = calibrate_camera_recording(
                source,
                progress=progress,
                board=board,
                mode=args.mode,
                du_px_per_mm=du,
                dv_px_per_mm=dv,
                scale_on=args.scale_on,
                origin=args.origin,
                reject_outliers=args.reject_outliers,
                pixel_pitch_um=pitch,
                detector=args.detector,
                subpix_half_window_px=args.subpix_window,
            )
        write_camera_json(calibration, args.output)
        if args.opencv_yaml:
            write_opencv_yaml(calibration, args.opencv_yaml)
    except (ValueError, MeasurementError) as error:
        return fail(args, error)
    camera, opencv = calibration.camera, calibration.opencv
    used = sum(f.status == "used" for f in calibration.frames)
    lines = [
        f"{args.output}: verdict {calibration.verdict.level}; RMS {calibration.rms_px:.3f} px over "
        f"{calibration.n_points} corners in {used}/{len(calibration.frames)} frames; f = {camera.f_mm:.4f} mm "
        f"(fx {opencv.fx_px:.2f}, fy {opencv.fy_px:.2f} px), "
        f"principal point ({camera.u0_px:.2f}, {camera.v0_px:.2f}) px"
    ]
    lines += [f"  {reason}" for reason in (calibration.verdict.reasons if calibration.verdict.level != "good" else ())]
    lines += [
        f"  {frame.frame}: {frame.status}: {frame.reason}" for frame in calibration.frames if frame.status != "used"
    ]
    result = {
        "path": args.output, "verdict": calibration.verdict, "rms_px": calibration.rms_px,
        "n_points": calibration.n_points, "frames_used": used, "camera": camera, "opencv": opencv,
        "frames": [{"frame": f.frame, "status": f.status, "reason": f.reason} for f in calibration.frames],
    }  # fmt: skip
    return emit(args, result, lines)


def camera_export_command(args: argparse.Namespace) -> int:
    from fringelab.formats.camera import read_camera_json, write_opencv_yaml
    from fringelab.science import MeasurementError

    try:
        write_opencv_yaml(read_camera_json(args.calibration), args.opencv_yaml)
    except (ValueError, MeasurementError, OSError) as error:
        return fail(args, error)
    return emit(args, {"path": args.opencv_yaml}, [f"{args.opencv_yaml}: OpenCV FileStorage YAML written"])
