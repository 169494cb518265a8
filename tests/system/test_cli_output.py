"""The science commands for people and for scripts: a progress bar on stderr while they run, `--json` on stdout."""

from __future__ import annotations

import json
import math

import h5py

from tests.system.test_cli import run_cli


def test_virtual_test_calibrate_topography_export_with_progress_and_json(tmp_path):
    root = tmp_path / "sim"
    # A 4 mm projector Z-step: 10 mm steps move kodak's stripes ~0.66 period, which the calibration reads as
    # 0.34 back (aliased): the projector calibration refuses them, naming the step it needs (≤ ~4.3 mm).
    simulated = run_cli("virtual-test", str(root), "--frames", "4", "--z-step", "4", "--json", timeout=300)
    assert simulated.returncode == 0, simulated.stderr
    experiment = json.loads(simulated.stdout)  # stdout is the JSON object and nothing else
    assert experiment["root"] == str(root) and "%|" not in simulated.stderr  # --json: no bar

    projector = tmp_path / "projector.h5"
    calibrated = run_cli("calibrate-projector", experiment["projector_calibration"], "--camera",
                         experiment["camera_json"], "-o", str(projector), "--progress", "always")  # fmt: skip
    assert calibrated.returncode == 0, calibrated.stderr
    bar = calibrated.stderr.replace("\r", "\n")
    assert "calibrate-projector: edges" in bar and "100%|" in bar  # the bar went to stderr and finished
    assert calibrated.stdout.startswith(f"{projector}: ") and "%|" not in calibrated.stdout

    result = tmp_path / "result.h5"
    topography = run_cli("topography", experiment["test"], "--camera", experiment["camera_json"], "--projector",
                         str(projector), "-o", str(result), "--json", timeout=300)  # fmt: skip
    assert topography.returncode == 0, topography.stderr
    summary = json.loads(topography.stdout)
    assert summary["path"] == str(result) and summary["frames"] == {"start": 0, "stop": 4}
    assert summary["xdmf"] == str(result.with_suffix(".xdmf"))
    assert all(v is None or math.isfinite(v) for v in summary["punch_axis_xy_mm"])  # NaN is null, never NaN
    with h5py.File(result, "r") as file:
        assert file.attrs["n_frames"] == 4

    exported = run_cli("export", str(result), "--format", "mat", "--mat-version", "7.3", "-o",
                       str(tmp_path / "r.mat"), "--json")  # fmt: skip
    assert json.loads(exported.stdout) == {"path": str(tmp_path / "r.mat"), "format": "mat"}


def test_an_error_is_json_too(tmp_path):
    failed = run_cli("topography", str(tmp_path / "missing"), "--camera", "c.json", "--projector", "p.h5",
                     "-o", str(tmp_path / "r.h5"), "--json")  # fmt: skip
    assert failed.returncode == 2
    error = json.loads(failed.stdout)
    assert "missing" in error["error"] and error["type"]
    assert failed.stderr.startswith("error: ")


def test_the_readme_command_line_run_works_as_written(tmp_path):
    """The README's "as written" block as one script (only `make install` is skipped), run from a folder standing
    for the checkout: it works, and leaves nothing there."""
    import os
    import re
    import subprocess
    import sys
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    block = re.search(r"A whole\s+run on a virtual test, as written:\n\n```sh\n(.*?)```", readme, re.S)
    assert block, "the README lost its command-line walk-through"
    script = Path(sys.executable).parent / "fringelab"
    lines = [line for line in block.group(1).splitlines() if line and line != "make install"]
    assert len(lines) >= 4
    commands = [line.replace(".venv/bin/fringelab", str(script)).replace("python3", sys.executable) for line in lines]
    checkout = tmp_path / "checkout"
    checkout.mkdir()
    scratch = tmp_path / "scratch"  # where `mktemp -d` makes its folder
    scratch.mkdir()
    done = subprocess.run(
        ["bash", "-euo", "pipefail", "-c", "\n".join(commands)],
        cwd=checkout, env={**os.environ, "TMPDIR": str(scratch)}, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert list(checkout.iterdir()) == [], "the walk-through left files in the checkout"
    (made,) = scratch.iterdir()
    assert (made / "result.mat").is_file() and (made / "result.xdmf").is_file()
