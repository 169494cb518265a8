"""`fringelab calibrate-procam` and `fringelab scan`: rigs with a digital projector on the command line
(docs/procam.md).

Thin: parse arguments, call `fringelab.pipelines.scan`, print a summary. numpy, OpenCV and the measurement package
are imported inside the handlers so registering the commands stays instant. Scan files are exported by
`fringelab export` (commands/topography.py), which recognises them.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from fringelab.commands.output import emit, fail, floats, integers, progress_bar
from fringelab.commands.tables import write_projector_table


def _size(text: str) -> tuple[int, int]:
    width, height = integers(text.lower().replace("x", ","), 2, "WIDTH,HEIGHT in pixels")
    if width < 1 or height < 1:
        raise argparse.ArgumentTypeError(f"expected positive WIDTH,HEIGHT, got {text!r}")
    return width, height


def _scale(text: str) -> tuple[float, float]:
    sx, sy = floats(text, 2, "SX,SY (e.g. 1,0.5)")
    if not (sx > 0 and sy > 0):
        raise argparse.ArgumentTypeError(f"expected positive SX,SY, got {text!r}")
    return sx, sy


def _offset(text: str) -> tuple[float, float]:
    dx, dy = floats(text, 2, "finite DX,DY (e.g. -57,0)")
    return dx, dy


def register(subparsers: Any) -> None:
    """Add `calibrate-procam` and `scan` to the CLI's subparsers."""
    from fringelab.commands.output import add_output_options

    calibrate = subparsers.add_parser(
        "calibrate-procam",
        help="calibrate a camera–projector pair from chessboard poses under Gray code",
        description="Calibrate a camera and a digital projector (docs/procam.md §1) from one recording per "
        "chessboard pose, each with an all-white and an all-black frame and Gray codes along projector columns and "
        "rows, described by patterns-columns.json and patterns-rows.json beside its frames (or --columns/--rows).",
    )
    calibrate.add_argument("poses", nargs="+", help="folders or ZIPs of frames, one per chessboard pose")
    calibrate.add_argument("--board-cols", type=int, required=True, help="inner corners along a row of the board")
    calibrate.add_argument("--board-rows", type=int, required=True, help="inner corners along a column of the board")
    calibrate.add_argument("--square-mm", type=float, required=True, help="side of a board square in mm")
    calibrate.add_argument("--columns", help="patterns.json of the columns sequence (default: beside each pose)")
    calibrate.add_argument("--rows", help="patterns.json of the rows sequence (default: beside each pose)")
    calibrate.add_argument("--white-frame", type=int, help="frame for the board's corners (default: the white one)")
    calibrate.add_argument("-o", "--output", required=True, help="calibration JSON to write")
    calibrate.add_argument("--opencv-yaml", help="also write the pair as OpenCV FileStorage (OpenCV's stereo names)")
    add_output_options(calibrate)
    calibrate.set_defaults(handler=calibrate_procam_command)

    scan = subparsers.add_parser(
        "scan",
        help="3-D points of a Gray-code recording with a camera–projector calibration",
        description="Scan a surface (docs/procam.md §3): decode the coded sequence, locate and name its stripe edges "
        "and triangulate them against the projector; points in the camera frame in mm, with σ, a depth map and the "
        "decoding's QA. patterns.json is read from beside the frames unless --patterns is given.",
    )
    scan.add_argument("recording", help="folder or ZIP of the coded sequence's frames")
    scan.add_argument("--calibration", required=True,
                      help="fringelab procam JSON, or OpenCV FileStorage (XML/YAML) under SLStudio's or "
                      "OpenCV's names")  # fmt: skip
    scan.add_argument("--patterns", help="the sequence's patterns.json (default: the one beside the frames)")
    scan.add_argument("--camera-size", type=_size, metavar="W,H", help="camera size when the calibration has none")
    scan.add_argument("--projector-size", type=_size, metavar="W,H",
                      help="projector size when the calibration has none")  # fmt: skip
    scan.add_argument("--projector-scale", type=_scale, metavar="SX,SY", default=(1.0, 1.0),
                      help="patterns' projector pixels → the calibration's (1,0.5: a diamond-pixel DLP calibrated in "
                      "square pixels; default 1,1)")  # fmt: skip
    scan.add_argument("--projector-offset", type=_offset, metavar="DX,DY", default=(0.0, 0.0),
                      help="then added, in the calibration's projector pixels: where the patterns' pixel 0 lies in "
                      "the calibration's (default 0,0)")  # fmt: skip
    scan.add_argument("--no-code-points", action="store_true",
                      help="leave out the per-pixel code points (a band wide); keep the stripe edges and the "
                      "phase")  # fmt: skip
    scan.add_argument("-o", "--output", required=True, help="scan result (.h5) to write")
    add_output_options(scan)
    scan.set_defaults(handler=scan_command)
    register_table(subparsers)


def calibrate_procam_command(args: argparse.Namespace) -> int:
    from fringelab.formats.procam import write_opencv_procam
    from fringelab.pipelines.scan import calibrate_procam_recordings
    from fringelab.science import MeasurementError
    from fringelab.science.chessboard import Board

    try:
        board = Board(cols=args.board_cols, rows=args.board_rows, square_mm=args.square_mm)
        with progress_bar(args, "calibrate-procam") as progress:
            calibration = calibrate_procam_recordings(
                args.poses, args.output, board=board, columns=args.columns, rows=args.rows,
                white_frame=args.white_frame, progress=progress,
            )  # fmt: skip
        if args.opencv_yaml:
            write_opencv_procam(args.opencv_yaml, calibration.model, naming="opencv")
    except (ValueError, MeasurementError, OSError) as error:
        return fail(args, error)
    lines = [
        f"{args.output}: verdict {calibration.verdict.level}; RMS camera {calibration.camera_rms_px:.3f} px, "
        f"projector {calibration.projector_rms_px:.3f} px, stereo {calibration.stereo_rms_px:.3f} px over "
        f"{len(calibration.poses)} poses ({calibration.n_corners} corners)"
    ]
    lines += [f"  {p.pose}: camera {p.camera_rms_px:.3f} px, projector {p.projector_rms_px:.3f} px"
              for p in calibration.poses]  # fmt: skip
    lines += [f"  {reason}" for reason in (calibration.verdict.reasons if calibration.verdict.level != "good" else ())]
    result = {
        "path": args.output, "verdict": calibration.verdict.level, "camera_rms_px": calibration.camera_rms_px,
        "projector_rms_px": calibration.projector_rms_px, "stereo_rms_px": calibration.stereo_rms_px,
        "poses": [{"pose": p.pose, "camera_rms_px": p.camera_rms_px, "projector_rms_px": p.projector_rms_px}
                  for p in calibration.poses],
    }  # fmt: skip
    return emit(args, result, lines)


def scan_command(args: argparse.Namespace) -> int:
    from fringelab.pipelines.scan import scan_recording
    from fringelab.science import MeasurementError
    from fringelab.science.scan import ScanSettings, scan_qa

    try:
        settings = ScanSettings(code_points=not args.no_code_points, projector_scale_xy=args.projector_scale,
                                projector_offset_xy_px=args.projector_offset)  # fmt: skip
        with progress_bar(args, "scan") as progress:
            result = scan_recording(
                args.recording, args.calibration, args.output, patterns=args.patterns, settings=settings,
                camera_size_wh_px=args.camera_size, projector_size_wh_px=args.projector_size, progress=progress,
            )  # fmt: skip
    except (ValueError, MeasurementError, OSError) as error:
        return fail(args, error)
    qa = scan_qa(result)
    lines = [
        f"{args.output}: {qa['n_points']} points ({qa['points_by_source']['stripe edge']} on stripe edges); "
        f"{100 * qa['valid_share']:.1f} % of the pixels decoded",
    ]
    if not result.calibration_sigma:
        lines.append(f"  note: {qa['calibration_sigma_note']}")
    return emit(args, {"path": args.output, "qa": qa}, lines)


def _z_range(text: str) -> list[float]:
    try:
        start, stop, step = (float(part) for part in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected FIRST:LAST:STEP in mm, got {text!r}") from None
    if not (step > 0 and stop > start) or (stop - start) / step > 1000:
        raise argparse.ArgumentTypeError(f"expected FIRST < LAST and 0 < STEP (at most 1000 heights), got {text!r}")
    import numpy as np

    return [float(z) for z in np.arange(start, stop + 0.5 * step, step)]


def register_table(subparsers: Any) -> None:
    """Add `projector-table`: the topography's projector table from a camera–projector calibration."""
    from fringelab.commands.output import add_output_options

    table = subparsers.add_parser(
        "projector-table",
        help="the topography's projector table from a camera–projector calibration (no Z stage)",
        description="Generate the projector look-up table of docs/method.md §4 for the stripes a digital projector "
        "shows during a deformation test, from the camera–projector calibration and the camera's calibration (which "
        "fixes the plate's frame), over the Z range the test needs (docs/procam.md §5). The result is what "
        "`calibrate-projector` writes from a Z-stack: `topography --projector` takes either.",
    )
    table.add_argument("--procam", required=True, help="camera–projector calibration (procam.json or OpenCV file)")
    table.add_argument("--camera", required=True, help="camera.json of the same camera (the plate's frame)")
    table.add_argument("--stripe-period-px", type=float, required=True, help="stripe period in projector pixels")
    table.add_argument("--stripe-axis", choices=("columns", "rows"), default="columns",
                       help="columns: vertical stripes (bright where x mod period < period/2); rows: "
                       "horizontal")  # fmt: skip
    table.add_argument("--stripe-offset-px", type=float, default=-0.5,
                       help="projector coordinate of a rising edge (default −0.5: pixel 0 starts bright)")  # fmt: skip
    table.add_argument("--z-mm", type=_z_range, required=True, metavar="FIRST:LAST:STEP", help="heights, mm")
    table.add_argument("--scan-axis", choices=("auto", "rows", "cols"), default="auto",
                       help="image axis to scan along (auto: the one the stripes cross most)")  # fmt: skip
    table.add_argument("-o", "--output", required=True, help="projector calibration to write (.h5)")
    add_output_options(table)
    table.set_defaults(handler=projector_table_command)


def projector_table_command(args: argparse.Namespace) -> int:
    from fringelab.formats.camera import read_camera_json
    from fringelab.formats.procam import read_procam_calibration
    from fringelab.science.procam_table import StripePattern, projector_table_from_model
    from fringelab.science.projector import ProjectorCalibration

    def build() -> ProjectorCalibration:
        pattern = StripePattern(args.stripe_axis, period_px=args.stripe_period_px, offset_px=args.stripe_offset_px)
        return projector_table_from_model(
            read_procam_calibration(args.procam), read_camera_json(args.camera), pattern, args.z_mm,
            scan_axis=None if args.scan_axis == "auto" else args.scan_axis,
            provenance={"procam": Path(args.procam).name, "camera": Path(args.camera).name},
        )  # fmt: skip

    return write_projector_table(args, build)
