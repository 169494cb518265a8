"""The CLI's arguments made of numbers separated by commas (a line, a circle, a pair, a size) are read by one
rule (`commands.output.floats` / `integers`): the count, the kind and finiteness are checked, and a refusal names
what was expected and what came."""

from __future__ import annotations

import argparse
import importlib

import pytest

from fringelab.commands import COMMAND_MODULES


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fringelab")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


TOPOGRAPHY = ["topography", "r", "--camera", "c.json", "--projector", "p.h5", "-o", "o.h5"]
SCAN = ["scan", "r", "--calibration", "c.json", "-o", "o.h5"]
CAMERA = ["calibrate-camera", "r", "-o", "c.json"]
EXPORT = ["export", "r.h5", "--format", "profile-csv", "-o", "l.csv"]


@pytest.mark.parametrize(
    ("argv", "attribute", "value"),
    [
        ([*TOPOGRAPHY, "--rim-circle", "1,-2.5,240"], "rim_circle", (1.0, -2.5, 240.0)),
        ([*EXPORT, "--line=-100,0,100,0"], "line", (-100.0, 0.0, 100.0, 0.0)),
        ([*SCAN, "--camera-size", "1280x1024"], "camera_size", (1280, 1024)),
        ([*SCAN, "--projector-scale", "1,0.5"], "projector_scale", (1.0, 0.5)),
        ([*SCAN, "--projector-offset=-57,0"], "projector_offset", (-57.0, 0.0)),
        ([*CAMERA, "--origin", "3,4"], "origin", (3, 4)),
    ],
)
def test_numbers_are_read(argv: list[str], attribute: str, value: tuple[float, ...]) -> None:
    assert getattr(_parser().parse_args(argv), attribute) == value


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([*TOPOGRAPHY, "--rim-circle", "1,2"], "expected X,Y,R in mm (three numbers), got '1,2'"),
        ([*TOPOGRAPHY, "--rim-circle", "1,2,0"], "expected a radius R > 0, got 0"),
        ([*EXPORT, "--line", "1,2,3,x"], "expected X0,Y0,X1,Y1 in mm, got '1,2,3,x'"),
        ([*EXPORT, "--line", "0,0,inf,0"], "expected X0,Y0,X1,Y1 in mm, got '0,0,inf,0'"),
        ([*SCAN, "--camera-size", "1280.5,1024"], "expected WIDTH,HEIGHT in pixels, got '1280.5,1024'"),
        ([*SCAN, "--camera-size", "0,1024"], "expected positive WIDTH,HEIGHT, got '0,1024'"),
        ([*SCAN, "--projector-scale", "1,-1"], "expected positive SX,SY, got '1,-1'"),
        ([*SCAN, "--projector-offset", "nan,0"], "expected finite DX,DY (e.g. -57,0), got 'nan,0'"),
        ([*CAMERA, "--origin", "3"], "expected two integers I,J, got '3'"),
    ],
)
def test_a_refusal_names_what_was_expected(argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        _parser().parse_args(argv)
    assert message in capsys.readouterr().err
