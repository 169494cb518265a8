"""Science subcommands of the `fringelab` CLI (calibrate-camera, calibrate-projector, topography, export,
virtual-test, compare, export-comparison, calibrate-procam, scan).

Each module listed in COMMAND_MODULES defines `register(subparsers)`, which adds its subcommands to the
argparse tree built by `backend.cli`. Registration must stay cheap: import numpy, OpenCV and
`fringelab.science` inside the handlers, not at module level, so `fringelab version` stays instant.
"""

COMMAND_MODULES = (
    "fringelab.commands.camera",
    "fringelab.commands.topography",
    "fringelab.commands.virtual_test",
    "fringelab.commands.comparison",
    "fringelab.commands.procam",
)
