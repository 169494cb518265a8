"""What the two commands that make a projector table have in common: writing the table and reporting it.

`calibrate-projector` (commands/topography.py) builds the table from a flat-plate Z-stack, `projector-table`
(commands/procam.py) from a camera–projector model; both end the same way, here, so the file is written by one
call and a table is described by one line and one JSON object whichever way it was made. Not here: how either
table is built (the pipelines and the science) or the commands' arguments.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import TYPE_CHECKING

from fringelab.commands.output import emit, fail

if TYPE_CHECKING:
    from fringelab.science.projector import ProjectorCalibration


def write_projector_table(args: argparse.Namespace, build: Callable[[], ProjectorCalibration]) -> int:
    """Build a projector table with `build()`, write it to `args.output` and print its summary (text, or JSON with
    --json). An error a user must act on (ValueError, MeasurementError, OSError) is reported with exit status 2,
    and nothing is written."""
    from fringelab.formats.projector import write_projector_calibration
    from fringelab.science import MeasurementError

    try:
        table = build()
        write_projector_calibration(table, args.output)
    except (ValueError, MeasurementError, OSError) as error:
        return fail(args, error)
    qa = table.qa
    low, median, high = qa.sensitivity_px_per_mm
    text = (
        f"{args.output}: {qa.n_edges} edges over {table.n_lines} lines (scan along image {table.axis}, stripe period "
        f"{table.period_px:.2f} px), {qa.n_entries} table entries; Z {qa.z_range_mm[0]:g} … {qa.z_range_mm[1]:g} mm "
        f"in {len(table.z_mm)} steps; coverage {qa.coverage:.1%}; sensitivity {median:.3f} px/mm (5–95 %: "
        f"{low:.3f}–{high:.3f}); fit RMS {qa.fit_rms_mm:.3g} mm; {qa.n_non_monotonic} non-monotonic, "
        f"{qa.n_insensitive} insensitive entries left out"
    )
    result = {
        "path": args.output, "axis": table.axis, "n_lines": table.n_lines, "period_px": table.period_px,
        "n_edges": qa.n_edges, "n_entries": qa.n_entries, "z_steps": len(table.z_mm), "qa": qa,
    }  # fmt: skip
    return emit(args, result, [text])
