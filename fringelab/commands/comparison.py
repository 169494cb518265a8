"""`fringelab compare` and `fringelab export-comparison`: a measurement against a finite-element simulation.

Thin: parse arguments, call `fringelab.pipelines.comparison.compare_result`, print a summary (or JSON). Heavy
imports stay inside the handlers so registering the commands stays instant.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from fringelab.commands.output import floats, line_mm
from fringelab.formats import COMPARISON_EXPORTS


def _pair(text: str) -> tuple[float, float]:
    x, y = floats(text, 2, "X,Y in mm")
    return x, y


def register(subparsers: Any) -> None:
    """Add `compare` and `export-comparison` to the CLI's subparsers."""
    parser = subparsers.add_parser(
        "compare",
        help="compare a topography result with a finite-element simulation",
        description="Map a simulation (d3plot family, .pvd/.vtu series, Exodus, nodal CSV; with nodout, rcforc or "
        "a punch CSV beside it) onto the plate, pair every test frame with it and write the differences. "
        "Every mapping choice left out is detected and reported; the model's own punch axis goes on the measured "
        "one (--origin 0,0 keeps it in plate coordinates); a simulation in mm whose punch displacement covers "
        "the test's needs no option.",
    )
    parser.add_argument("result", help="topography result (.h5)")
    parser.add_argument("simulation", help="simulation file or folder")
    parser.add_argument("-o", "--output", required=True, help="comparison file to write (.h5)")
    parser.add_argument("--align", choices=("displacement", "time", "peak"), default="displacement",
                        help="pair frames with states by punch displacement (default), time or peak")  # fmt: skip
    parser.add_argument("--units", choices=("mm", "m"), help="the model's length unit (default: detect)")
    parser.add_argument("--symmetry", choices=("none", "half-x", "half-y", "quarter"),
                        help="unfold a half or quarter model about X = 0 / Y = 0 (default: detect)")  # fmt: skip
    parser.add_argument(
        "--normal-axis", choices=("x", "y", "z"), help="the model axis out of the plate (default: detect)"
    )
    parser.add_argument("--w-sign", type=int, choices=(1, -1), help="+1 or -1: the sign that makes deflection "
                        "toward the cameras positive (default: detect)")  # fmt: skip
    parser.add_argument(
        "--origin",
        type=_pair,
        metavar="X,Y",
        help="where the model's origin lies on the plate, mm (default: its punch axis on the measured one; "
        "0,0 keeps a model in plate coordinates)",
    )
    parser.add_argument("--rotation", type=float, default=0.0, metavar="DEG", help="model rotation about Z")
    parser.add_argument("--surface", choices=("toward-cameras", "away", "mid"), default="toward-cameras",
                        help="the model surface the cameras see (default: the one facing them)")  # fmt: skip
    parser.add_argument("--shell-thickness", type=float, metavar="MM", help="shell thickness (default: the file's)")
    parser.add_argument("--punch-node", type=int, metavar="ID", help="node whose travel is the punch displacement")
    parser.add_argument("--contact", type=int, metavar="ID", help="rcforc interface of the punch force")
    parser.add_argument("--time-unit-s", type=float, metavar="S", help="seconds per model time unit (e.g. 0.001)")
    parser.add_argument("--time-offset", type=float, default=0.0, metavar="S", help="added to the model's times")
    parser.add_argument("--json", action="store_true", help='print {"frames": [{"frame", "rms_diff_mm", '
                        '"max_diff_mm"}, …]} to stdout')  # fmt: skip
    parser.set_defaults(handler=compare_command)

    export = subparsers.add_parser("export-comparison", help="export a comparison file")
    export.add_argument("comparison", help="comparison file (.h5)")
    export.add_argument("--format", required=True, choices=COMPARISON_EXPORTS)
    export.add_argument("-o", "--output", required=True, help="file to write (.csv, .h5, .mat, .pvd, .csv)")
    export.add_argument("--line", type=line_mm, metavar="X0,Y0,X1,Y1",
                        help="profile-csv: the line in mm (default along X through the punch axis)")  # fmt: skip
    export.set_defaults(handler=export_command)


def compare_command(args: argparse.Namespace) -> int:
    from fringelab.pipelines.comparison import compare_result
    from fringelab.science import MeasurementError
    from fringelab.science.compare import MappingSettings

    try:
        settings = MappingSettings(
            length_unit=args.units, symmetry=args.symmetry, normal_axis=args.normal_axis, w_sign=args.w_sign,
            origin_xy_mm=args.origin, rotation_deg=args.rotation, surface=args.surface,
            shell_thickness_mm=args.shell_thickness, time_unit_s=args.time_unit_s, time_offset_s=args.time_offset,
        )  # fmt: skip
        summary = compare_result(args.result, args.simulation, args.output, align=args.align, mapping=settings,
                                 punch_node=args.punch_node, contact_interface=args.contact)  # fmt: skip
    except (ValueError, MeasurementError, OSError) as error:  # ComparisonError: a message naming what to set
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(summary.as_json()))
        return 0
    mapping = summary.mapping
    print(f"wrote {summary.path}")
    print(f"mapping: {mapping['length_unit']}, symmetry {mapping['symmetry']}, normal {mapping['normal_axis']}, "
          f"w sign {mapping['w_sign']:+d}, origin {tuple(round(v, 2) for v in mapping['origin_xy_mm'])} mm "
          f"(detected: {', '.join(mapping['detected']) or 'none'})")  # fmt: skip
    for note in mapping["notes"]:
        print(f"  note: {note}")
    for row in summary.frames:
        rms, peak = row["rms_diff_mm"], row["max_diff_mm"]
        text = "not compared" if rms != rms else f"RMS {rms:.3f} mm, max {peak:.3f} mm"
        print(f"frame {row['frame']}: {text}")
    return 0


def export_command(args: argparse.Namespace) -> int:
    from fringelab.formats.exports import export_comparison

    try:
        path = export_comparison(args.comparison, args.format, args.output, line=args.line)
    except (ValueError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0
