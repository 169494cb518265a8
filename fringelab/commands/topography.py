"""`fringelab calibrate-projector`, `topography` and `export`: the structured-light side on the CLI.

Thin: parse arguments, call the pipelines (projector calibration, topography) and the exports, print a summary.
numpy and the measurement package are imported inside the handlers so registering the commands stays instant.
"""

from __future__ import annotations

import argparse
from typing import Any

from fringelab.commands.output import emit, fail, floats, line_mm, progress_bar
from fringelab.commands.tables import write_projector_table
from fringelab.formats import EXPORT_FORMATS, SCAN_EXPORT_FORMATS


def _frames(text: str) -> slice:
    try:
        start, stop = text.split(":")
        return slice(int(start) if start else None, int(stop) if stop else None)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected A:B (frames A to B−1; either may be left out), got {text!r}"
        ) from None


def _circle(text: str) -> tuple[float, float, float]:
    x, y, r = floats(text, 3, "X,Y,R in mm (three numbers)")
    if not r > 0:
        raise argparse.ArgumentTypeError(f"expected a radius R > 0, got {r:g}")
    return x, y, r


def register(subparsers: Any) -> None:
    """Add `calibrate-projector`, `topography` and `export` to the CLI's subparsers."""
    from fringelab.commands.output import add_output_options

    calibrate = subparsers.add_parser(
        "calibrate-projector",
        help="build the projector look-up table from a flat-plate Z-stack",
        description="Projector calibration (docs/method.md §4): the position of every stripe edge against Z, from a "
        "folder or ZIP of frames of the flat plate moved along Z, with z.csv (frame,z_mm).",
    )
    calibrate.add_argument("recording", help="folder or ZIP of frames with z.csv")
    calibrate.add_argument("--camera", required=True, help="camera.json of the camera that took the frames")
    calibrate.add_argument("-o", "--output", required=True, help="projector calibration to write (.h5)")
    calibrate.add_argument(
        "--reference-z",
        type=float,
        default=0.0,
        metavar="MM",
        help="Z of the flat test plate at rest, where edges are counted (default 0)",
    )
    calibrate.add_argument(
        "--axis",
        choices=("auto", "rows", "cols"),
        default="auto",
        help="scan along image rows (vertical stripes) or columns; default: detect",
    )
    calibrate.add_argument("--poly-degree", type=int, default=3, help="degree of Z(t) per edge and line (default 3)")
    add_output_options(calibrate)
    calibrate.set_defaults(handler=calibrate_projector_command)

    topography = subparsers.add_parser(
        "topography",
        help="measure the deflection of every frame of a test",
        description="Topography (docs/method.md §5–6): edges of every frame, identity from the flat first frame, "
        "Z from the projector table, X and Y by back-projection, the gridded deflection field; written as HDF5.",
    )
    topography.add_argument("recording", help="folder or ZIP of test frames (frames.csv beside them is kept)")
    topography.add_argument("--camera", required=True, help="camera.json")
    topography.add_argument("--projector", required=True, help="projector calibration (.h5)")
    topography.add_argument("-o", "--output", required=True, help="result file to write (.h5)")
    topography.add_argument(
        "--frames", type=_frames, metavar="A:B", help="write frames A to B−1 only (tracking still starts at frame 0)"
    )
    topography.add_argument("--grid-step", type=float, default=2.0, metavar="MM", help="grid spacing (default 2)")
    topography.add_argument(
        "--temporal-smoothing",
        type=int,
        default=0,
        metavar="H",
        help="smooth edge positions over 2H+1 frames (default 0: off)",
    )
    topography.add_argument(
        "--reference-code",
        metavar="FOLDER_OR_ZIP",
        help="a Gray code recorded with the plate at rest before the test (its patterns.json beside the frames): it "
        "gives the reference frame's stripe order, checked against the projector table's match (docs/procam.md §5; "
        "needs a table made by `fringelab projector-table`)",
    )
    topography.add_argument(
        "--reference-code-patterns", metavar="JSON", help="the code's patterns.json, when not beside its frames"
    )
    topography.add_argument(
        "--rim-circle",
        type=_circle,
        metavar="X,Y,R",
        help="centre and radius (mm, plate frame) of the clamp circle, when the clamp ring is not in view: the band "
        "inside it that the camera sees anchors the fringe order of every frame (default: found from the ring)",
    )
    add_output_options(topography)
    topography.set_defaults(handler=topography_command)

    export = subparsers.add_parser(
        "export",
        help="export a topography result (CSV, NPZ, MATLAB, VTK) or a scan (CSV, PLY)",
        description="Export a topography result: points-csv (frame,x_mm,y_mm,z_mm), grid-npz, mat (MATLAB), vtk "
        "(a .pvd time series of .vtu surfaces for ParaView) or profile-csv (a section along --line); a scan file "
        "(`fringelab scan`): points-csv (x_mm,y_mm,z_mm,sigma_mm,...) or ply (binary, sigma_mm per vertex).",
    )
    export.add_argument("result", help="result .h5 written by `fringelab topography` or `fringelab scan`")
    export.add_argument("--format", required=True, choices=sorted(set(EXPORT_FORMATS) | set(SCAN_EXPORT_FORMATS)),
                        help="a scan: points-csv or ply")  # fmt: skip
    export.add_argument(
        "-o", "--output", required=True, help="file to write (.csv, .npz, .mat, .pvd; a folder with --per-frame)"
    )
    export.add_argument(
        "--per-frame",
        action="store_true",
        help="points-csv: one CSV per frame into the folder --output (each fits a spreadsheet)",
    )
    export.add_argument(
        "--mat-version",
        choices=("auto", "5", "7.3"),
        default="auto",
        help="mat: v5 while every variable fits its 2 GB limit, else v7.3 (HDF5) (default: auto)",
    )
    export.add_argument(
        "--line",
        type=line_mm,
        metavar="X0,Y0,X1,Y1",
        help="profile line in mm (profile-csv; default: along X through the punch axis); "
        "write --line=X0,... when X0 is negative",
    )
    add_output_options(export)
    export.set_defaults(handler=export_command)


def calibrate_projector_command(args: argparse.Namespace) -> int:
    from fringelab.formats.camera import read_camera_json
    from fringelab.formats.recordings import open_recording
    from fringelab.pipelines.projector_calibration import calibrate_projector_recording
    from fringelab.science.fringes import EdgeSettings
    from fringelab.science.projector import ProjectorCalibration, ProjectorSettings

    def build() -> ProjectorCalibration:
        settings = ProjectorSettings(
            edges=EdgeSettings(axis=args.axis),
            reference_z_mm=args.reference_z,
            poly_degree=args.poly_degree,
            min_z_samples=max(6, args.poly_degree + 2),
        )
        with open_recording(args.recording) as source, progress_bar(args, "calibrate-projector") as progress:
            return calibrate_projector_recording(source, read_camera_json(args.camera), settings=settings,
                                                 progress=progress)  # fmt: skip

    return write_projector_table(args, build)


def topography_command(args: argparse.Namespace) -> int:
    import numpy as np

    from fringelab.formats.camera import read_camera_json
    from fringelab.formats.projector import read_projector_calibration
    from fringelab.formats.recordings import open_recording
    from fringelab.pipelines.topography import decode_reference_code, topography_recording
    from fringelab.science import MeasurementError
    from fringelab.science.order import OrderSettings
    from fringelab.science.topography import TopographySettings

    try:
        if args.reference_code_patterns and not args.reference_code:
            raise ValueError("--reference-code-patterns: give the code's frames with --reference-code")
        with open_recording(args.recording) as source, progress_bar(args, "topography") as progress:
            frames = None if args.frames is None else range(len(source))[args.frames]
            code = None
            if args.reference_code:
                shape = np.shape(source[0])[:2]
                code = decode_reference_code(
                    args.reference_code, patterns=args.reference_code_patterns, image_shape_hw_px=(shape[0], shape[1])
                )
            summary = topography_recording(
                source,
                read_camera_json(args.camera),
                read_projector_calibration(args.projector),
                out_path=args.output,
                frames=frames,
                settings=TopographySettings(
                    grid_step_mm=args.grid_step,
                    temporal_smoothing_frames=args.temporal_smoothing,
                    order=OrderSettings(rim_circle_mm=args.rim_circle),
                ),  # fmt: skip
                progress=progress,
                code=code,
            )
    except (ValueError, MeasurementError, OSError) as error:
        return fail(args, error)
    text = (
        f"{summary.path}: frames {summary.frames.start}–{summary.frames.stop - 1}; flat first frame RMS "
        f"{summary.flat_rms_mm:.3f} mm; peak deflection {summary.max_peak_w_mm:.2f} mm; punch axis at "
        f"({summary.punch_axis_xy_mm[0]:.1f}, {summary.punch_axis_xy_mm[1]:.1f}) mm; "
        f"{summary.n_out_of_range_total} points beyond the calibrated Z range masked"
    )
    return emit(args, {**vars(summary), "xdmf": summary.path.with_suffix(".xdmf")}, [text])


def export_command(args: argparse.Namespace) -> int:
    from fringelab.formats.exports import export_result
    from fringelab.formats.scan import export_scan, is_scan_file

    try:
        if is_scan_file(args.result):
            path = export_scan(args.result, args.format, args.output)
            return emit(args, {"path": path, "format": args.format}, [f"{path}: {args.format} written"])
        with progress_bar(args, "export") as progress:
            path = export_result(
                args.result, args.format, args.output, line=args.line, per_frame=args.per_frame,
                mat_version=args.mat_version, progress=progress,
            )  # fmt: skip
    except (ValueError, OSError) as error:
        return fail(args, error)
    return emit(args, {"path": path, "format": args.format}, [f"{path}: {args.format} written"])
