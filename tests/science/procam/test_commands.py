"""`fringelab calibrate-procam`, `fringelab scan` and `fringelab export` of a scan, on the virtual rig."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from fringelab.commands import procam as procam_commands
from fringelab.commands import topography as topography_commands
from fringelab.formats.patterns import patterns_json_text
from fringelab.formats.procam import read_procam_calibration, write_opencv_procam
from fringelab.formats.recordings import write_recording
from fringelab.formats.scan import StoredScan, read_ply_vertices, read_scan, scan_layout
from fringelab.science.graycode import PatternSequence, WhiteBlack
from tests.procam_rig import BALL, POSE_COLUMNS, POSE_ROWS, RIG, SCAN_COLUMNS, ball_frames, pose_recordings

SEQUENCE = SCAN_COLUMNS
SPHERE = BALL


def run_cli(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="fringelab")
    subparsers = parser.add_subparsers()
    procam_commands.register(subparsers)
    topography_commands.register(subparsers)
    args = parser.parse_args(list(argv))
    return args.handler(args)


@pytest.fixture(scope="module")
def scanned(tmp_path_factory) -> tuple[Path, Path]:
    """A folder of the sphere in front of a screen with its patterns.json, and the rig's calibration (SLStudio)."""
    root = tmp_path_factory.mktemp("scan")
    frames = ball_frames(supersample=2, seed=7)
    recording = write_recording(root / "sphere", frames, sidecars={"patterns.json": patterns_json_text(SEQUENCE)})
    calibration = write_opencv_procam(root / "calibration.yml", RIG, naming="slstudio")
    return recording, calibration


def test_scan_and_export_on_the_command_line(scanned, tmp_path: Path, capsys) -> None:
    recording, calibration = scanned
    out = tmp_path / "scan.h5"
    assert run_cli("scan", str(recording), "--calibration", str(calibration), "-o", str(out), "--json") == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["qa"]["points_by_source"]["stripe edge"] > 1000
    stored = read_scan(out)
    # Every stored array is declared once (scan_layout) and read back under its ScanResult attribute's name.
    assert {d.field for d in scan_layout()} | {"axis", "qa", "provenance"} == set(StoredScan.__dataclass_fields__)
    edge = stored.source == 0
    radial = np.linalg.norm(stored.points_cam_mm[edge] - np.asarray(SPHERE.centre_cam_mm), axis=1) - SPHERE.radius_mm
    on_sphere = np.abs(radial) < 1.0
    assert np.count_nonzero(on_sphere) > 500
    assert np.sqrt(np.mean(radial[on_sphere] ** 2)) < 0.05  # supersample 2 here; the science test holds 0.05 too
    assert run_cli("export", str(out), "--format", "ply", "-o", str(tmp_path / "scan.ply")) == 0
    assert len(read_ply_vertices(tmp_path / "scan.ply")) == len(stored.sigma_mm)
    assert run_cli("export", str(out), "--format", "points-csv", "-o", str(tmp_path / "scan.csv")) == 0
    assert (tmp_path / "scan.csv").read_text().startswith("x_mm,y_mm,z_mm,sigma_mm")


def test_a_calibration_that_counts_projector_pixels_from_elsewhere_takes_an_offset(
    scanned, tmp_path: Path, capsys
) -> None:
    """The same frames against a calibration whose projector pixel 0 is the patterns' pixel −3 (its principal point
    3 px further): with --projector-offset 3,0 the sphere is the truth's again; without, it is not."""
    recording, calibration = scanned
    rig = read_procam_calibration(calibration)
    matrix = rig.projector_matrix.copy()
    matrix[0, 2] += 3.0
    shifted = write_opencv_procam(tmp_path / "shifted.yml", type(rig)(
        camera_matrix=rig.camera_matrix, camera_dist=rig.camera_dist, camera_size_wh_px=rig.camera_size_wh_px,
        projector_matrix=matrix, projector_dist=rig.projector_dist, projector_size_wh_px=rig.projector_size_wh_px,
        r_proj_from_cam=rig.r_proj_from_cam, t_proj_from_cam_mm=rig.t_proj_from_cam_mm), naming="opencv")  # fmt: skip
    radii = []
    for offset in ("3,0", "0,0"):
        out = tmp_path / f"scan-{offset}.h5"
        assert run_cli("scan", str(recording), "--calibration", str(shifted), "--projector-offset", offset,
                       "--no-code-points", "-o", str(out)) == 0  # fmt: skip
        stored = read_scan(out)
        radial = np.linalg.norm(stored.points_cam_mm - np.asarray(SPHERE.centre_cam_mm), axis=1) - SPHERE.radius_mm
        radii.append(np.median(np.abs(radial[np.abs(radial) < 5.0])))
    assert radii[0] < 0.05 and radii[1] > 0.2, radii
    with pytest.raises(SystemExit):
        run_cli("scan", str(recording), "--calibration", str(shifted), "--projector-offset", "nan,0", "-o",
                str(tmp_path / "x.h5"))  # fmt: skip
    assert "expected finite DX,DY (e.g. -57,0), got 'nan,0'" in capsys.readouterr().err


def test_bad_input_is_refused_in_a_sentence_and_nothing_is_written(scanned, tmp_path: Path, capsys) -> None:
    recording, calibration = scanned
    out = tmp_path / "scan.h5"
    # A calibration whose camera is another size than the recording's.
    other = read_procam_calibration(calibration)
    small = write_opencv_procam(tmp_path / "small.yml", type(other)(
        camera_matrix=other.camera_matrix, camera_dist=other.camera_dist, camera_size_wh_px=(640, 480),
        projector_matrix=other.projector_matrix, projector_dist=other.projector_dist,
        projector_size_wh_px=other.projector_size_wh_px, r_proj_from_cam=other.r_proj_from_cam,
        t_proj_from_cam_mm=other.t_proj_from_cam_mm), naming="opencv")  # fmt: skip
    assert run_cli("scan", str(recording), "--calibration", str(small), "-o", str(out)) == 2
    assert "sphere has frames of 360 × 270 px but the calibration's camera is 640 × 480 px" in capsys.readouterr().err
    # A patterns.json naming frames the recording lacks.
    wrong = tmp_path / "patterns.json"
    wrong.write_text(patterns_json_text(PatternSequence(axis="columns", projector_size_wh_px=(320, 200),
                                                        gray_frames=tuple(range(2, 12)), band_px=1.0,
                                                        threshold=WhiteBlack(0, 1))))  # fmt: skip
    assert run_cli("scan", str(recording), "--calibration", str(calibration), "--patterns", str(wrong), "-o",
                   str(out)) == 2  # fmt: skip
    assert "patterns.json: gray_frames names frames 10, 11 but the recording has 10 frames" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob(".scan.h5*"))


def test_calibrate_procam_on_the_command_line(tmp_path: Path, capsys) -> None:
    sidecars = {"patterns-columns.json": patterns_json_text(POSE_COLUMNS),
                "patterns-rows.json": patterns_json_text(POSE_ROWS)}  # fmt: skip
    poses = [str(write_recording(tmp_path / f"pose{i}", frames, sidecars=sidecars))
             for i, frames in enumerate(pose_recordings(seed=11))]  # fmt: skip
    out = tmp_path / "procam.json"
    code = run_cli("calibrate-procam", *poses, "--board-cols", "9", "--board-rows", "7", "--square-mm", "8", "-o",
                   str(out), "--opencv-yaml", str(tmp_path / "procam.yml"), "--json")  # fmt: skip
    assert code == 0, capsys.readouterr().err
    summary = json.loads(capsys.readouterr().out)
    assert summary["stereo_rms_px"] < 0.2 and len(summary["poses"]) == 4
    document = json.loads(out.read_text())
    assert len(document["poses"]) == 4 and document["verdict"]["level"] in ("good", "check")
    assert read_procam_calibration(out).same_as(read_procam_calibration(out))
    assert np.allclose(read_procam_calibration(tmp_path / "procam.yml").t_proj_from_cam_mm, RIG.t_proj_from_cam_mm,
                       atol=1.5)  # fmt: skip
