"""`fringelab virtual-test`: a whole virtual test (calibrations, a punch test and its ground truth) written to disk.

Thin: parse arguments, call `fringelab.pipelines.virtual_test.write_virtual_test`, print the next commands. numpy
and the renderer are imported inside the handler so registering the command stays instant. `fringelab simulate` is
the command's former name, kept as a hidden alias for one release (it will go; "simulation" is the finite-element
results' word).
"""

from __future__ import annotations

import argparse
from typing import Any

from fringelab.commands.output import add_output_options, emit, fail, progress_bar
from fringelab.science.scenarios import SCENARIOS

DEPRECATED_NAME = "simulate"  # hidden alias of `virtual-test`, for one release


def register(subparsers: Any) -> None:
    """Add `virtual-test` (and its hidden former name `simulate`) to the CLI's subparsers."""
    description = (
        "Render a whole virtual test with stripes projected on a plate deflecting to 60 mm and perforating, "
        "through one of the paper's cameras, in the recording formats, with ground truth in OUT/truth."
    )
    command = subparsers.add_parser(
        "virtual-test",
        help="write a virtual test (camera and projector calibrations, a punch test, ground truth)",
        description=description,
    )
    _add_arguments(command)
    # No help= : argparse then leaves the alias out of the command list.
    _add_arguments(subparsers.add_parser(DEPRECATED_NAME, description=f"{description} (Former name of virtual-test.)"))


def _add_arguments(command: argparse.ArgumentParser) -> None:
    command.add_argument("out", help="folder to write into")
    command.add_argument(
        "--preset",
        choices=("kodak", "phantom"),
        default="kodak",
        help="kodak: 512 × 480 px, vertical stripes; phantom: 1024 × 1024 px, horizontal",
    )
    command.add_argument("--frames", type=int, default=40, help="test frames (default 40)")
    command.add_argument(
        "--z-step",
        type=float,
        default=2.0,
        metavar="MM",
        help="projector calibration step, from 2 steps below the plate's rest to 80 mm (default 2)",
    )
    command.add_argument(
        "--scenario",
        default="quasi-static",
        choices=SCENARIOS,
        help="quasi-static: the paper's test; fast: large motion per frame, an 18 mm hole and 6 mm springback in "
        "one frame; petals: fast, with radial cracks and petals; highlight: a specular highlight; shadow: the "
        "punch comes through and shadows the stripes; hard: all at once",
    )
    command.add_argument("--zip", action="store_true", help="write ZIPs instead of folders")
    command.add_argument("--seed", type=int, default=0, help="noise seed")
    add_output_options(command)
    command.set_defaults(handler=virtual_test_command)


def virtual_test_command(args: argparse.Namespace) -> int:
    from fringelab.pipelines.virtual_test import write_virtual_test
    from fringelab.science.virtual_test import calibration_heights_mm, preset

    if args.frames < 4:
        return fail(args, ValueError(f"--frames: expected at least 4, got {args.frames}"))
    if not 0 < args.z_step <= 10:
        return fail(args, ValueError(f"--z-step: expected 0 < step ≤ 10 mm, got {args.z_step}"))
    try:
        with progress_bar(args, "virtual test") as progress:
            experiment = write_virtual_test(
                args.out,
                args.preset,
                n_test_frames=args.frames,
                calibration_z_mm=calibration_heights_mm(args.z_step),
                as_zip=args.zip,
                seed=args.seed,
                scenario=args.scenario,
                progress=progress,
            )
    except (ValueError, OSError) as error:
        return fail(args, error)
    lines = [f"{experiment.root}: virtual {args.preset} test written; next:"]
    camera = preset(args.preset).camera
    lines.append(
        f"  fringelab calibrate-camera {experiment.camera_calibration} --du {camera.du_px_per_mm:g} "
        f"--dv {camera.dv_px_per_mm:g} --scale-on {camera.scale_on} -o {experiment.root / 'camera.json'}"
    )
    lines.append(f"  (or use the exact camera: {experiment.camera_json})")
    lines.append(
        f"  fringelab calibrate-projector {experiment.projector_calibration} --camera {experiment.camera_json} "
        f"-o {experiment.root / 'projector.h5'}"
    )
    lines.append(
        f"  fringelab topography {experiment.test} --camera {experiment.camera_json} --projector "
        f"{experiment.root / 'projector.h5'} -o {experiment.root / 'result.h5'}"
    )
    return emit(args, vars(experiment), lines)
