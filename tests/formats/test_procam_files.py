"""Camera–projector calibration files, patterns.json and scan files (docs/file-formats.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fringelab.formats.patterns import patterns_json_text, read_patterns_json
from fringelab.formats.procam import read_procam_calibration, write_opencv_procam, write_procam_json
from fringelab.formats.scan import export_scan, read_ply_vertices, read_scan, write_scan
from fringelab.science.graycode import InverseFrames, MeanOf, PatternSequence, PhaseFrames, WhiteBlack
from fringelab.science.procam import ProcamModel
from fringelab.science.scan import scan, scan_qa
from fringelab.science.virtual_procam import (
    Plane,
    ProcamRenderer,
    gray_code_patterns,
    in_frame_order,
    virtual_procam_rig,
)

RIG = virtual_procam_rig()


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_both_naming_schemes_read_to_identical_models(tmp_path: Path, suffix: str) -> None:
    write_opencv_procam(tmp_path / f"slstudio{suffix}", RIG, naming="slstudio")
    write_opencv_procam(tmp_path / f"opencv{suffix}", RIG, naming="opencv")
    slstudio = read_procam_calibration(tmp_path / f"slstudio{suffix}")
    opencv = read_procam_calibration(tmp_path / f"opencv{suffix}")
    assert slstudio.same_as(opencv)
    assert slstudio.same_as(RIG)  # FileStorage writes doubles with 17 digits: exact
    assert "Kc" in (tmp_path / f"slstudio{suffix}").read_text() and "M1" in (tmp_path / f"opencv{suffix}").read_text()


def test_the_own_file_round_trips_exactly(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    model = ProcamModel(
        camera_matrix=RIG.camera_matrix + np.diag(rng.normal(size=3) * [1e-7, 1e-7, 0]),
        camera_dist=RIG.camera_dist / 3,
        camera_size_wh_px=RIG.camera_size_wh_px, projector_matrix=RIG.projector_matrix * (1 + 1e-13),
        projector_dist=RIG.projector_dist, projector_size_wh_px=RIG.projector_size_wh_px,
        r_proj_from_cam=RIG.r_proj_from_cam, t_proj_from_cam_mm=RIG.t_proj_from_cam_mm + 1 / 3,
        camera_rms_px=0.0312345678901234, projector_rms_px=float("nan"), n_observations=1260,
    )  # fmt: skip
    write_procam_json(tmp_path / "procam.json", model)
    back = read_procam_calibration(tmp_path / "procam.json")
    assert back.same_as(model)
    assert np.isnan(back.projector_rms_px)


def test_sizes_come_from_options_when_the_file_has_none(tmp_path: Path) -> None:
    path = tmp_path / "stereo.yml"
    write_opencv_procam(path, RIG, naming="opencv")
    text = path.read_text()
    cut = text[: text.index("camera_size")]
    (tmp_path / "nosize.yml").write_text(cut)
    with pytest.raises(ValueError, match=r"nosize.yml: no camera image size \(key camera_size\): give it as an option"):
        read_procam_calibration(tmp_path / "nosize.yml")
    model = read_procam_calibration(
        tmp_path / "nosize.yml", camera_size_wh_px=(360, 270), projector_size_wh_px=(320, 200)
    )
    assert model.same_as(RIG)
    with pytest.raises(ValueError, match=r"stereo.yml: the file's camera size is 360 × 270 px but 640 × 480 px"):
        read_procam_calibration(path, camera_size_wh_px=(640, 480))


def test_a_missing_key_is_named(tmp_path: Path) -> None:
    path = tmp_path / "stereo.yml"
    write_opencv_procam(path, RIG, naming="opencv")
    lines = path.read_text().split("\nD2:")
    (tmp_path / "broken.yml").write_text(lines[0] + "\nX2:" + lines[1])
    with pytest.raises(ValueError, match=r"broken.yml: missing key 'D2' \(opencv names\)"):
        read_procam_calibration(tmp_path / "broken.yml")
    (tmp_path / "other.yml").write_text("%YAML:1.0\n---\nfoo: 1\n")
    with pytest.raises(ValueError, match="other.yml: neither SLStudio's names"):
        read_procam_calibration(tmp_path / "other.yml")
    (tmp_path / "junk.yml").write_text("not a calibration at all {")
    with pytest.raises(ValueError, match="junk.yml"):
        read_procam_calibration(tmp_path / "junk.yml")


@pytest.mark.parametrize(
    "threshold",
    [WhiteBlack(0, 1), InverseFrames((6, 7, 8, 9)), MeanOf((0, 1, 10))],
)
def test_patterns_json_round_trips(threshold) -> None:
    sequence = PatternSequence(axis="rows", projector_size_wh_px=(912, 1140), gray_frames=(2, 3, 4, 5), band_px=71.25,
                               threshold=threshold, phase=PhaseFrames((10, 11, 12), 114.0))  # fmt: skip
    assert read_patterns_json(patterns_json_text(sequence), n_frames=13) == sequence


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('{"axis": "columns"}', "patterns.json: missing projector_size_px, gray_frames, band_px, threshold"),
        (
            '{"axis": "diagonal", "projector_size_px": [9, 9], "gray_frames": [0], "band_px": 1, '
            '"threshold": {"white": 1, "black": 2}}',
            "patterns.json: axis must be one of",
        ),
        (
            '{"axis": "rows", "projector_size_px": [9, 9], "gray_frames": [0, 1], "band_px": 1, '
            '"threshold": {"white": 2, "black": 3}}',
            "patterns.json: threshold.black names frame 3 but the recording has 3 frames",
        ),
        (
            '{"axis": "rows", "projector_size_px": [9, 9], "gray_frames": [0, 7], "band_px": 1, '
            '"threshold": {"mean_of": [1, 2]}}',
            "patterns.json: gray_frames names frame 7",
        ),
        (
            '{"axis": "rows", "projector_size_px": [9, 9], "gray_frames": [0], "band_px": 1, '
            '"threshold": {"white": 1}}',
            "patterns.json: threshold must hold exactly",
        ),
        (
            '{"axis": "rows", "projector_size_px": [9, 9], "gray_frames": [0], "band_px": -2, '
            '"threshold": {"white": 1, "black": 2}}',
            "patterns.json: band_px must be a positive number",
        ),
        (
            '{"axis": "rows", "projector_size_px": [9, 9], "gray_frames": [0], "band_px": 1, "extra": 1, '
            '"threshold": {"white": 1, "black": 2}}',
            r"patterns.json: unknown keys \['extra'\]",
        ),
    ],
)
def test_patterns_json_errors_name_the_key(text: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        read_patterns_json(text, n_frames=3)


def test_a_scan_file_and_its_exports(tmp_path: Path) -> None:
    sequence = PatternSequence(axis="columns", projector_size_wh_px=(320, 200), gray_frames=tuple(range(2, 10)),
                               band_px=2.0, threshold=WhiteBlack(0, 1))  # fmt: skip
    frames = ProcamRenderer(RIG).render([Plane((0.0, 0.0, -1.0), -300.0)], in_frame_order(gray_code_patterns(sequence)),
                                        rng=np.random.default_rng(0))  # fmt: skip
    result = scan(frames, sequence, RIG)
    path = write_scan(tmp_path / "scan.h5", result, qa=scan_qa(result), provenance={"recording": "plane"})
    stored = read_scan(path)
    assert np.allclose(stored.points_cam_mm, result.points_cam_mm, atol=1e-4)  # float32 at 300 mm
    assert stored.qa["n_points"] == len(result) and stored.qa["calibration_sigma"] is False
    assert 0.5 < stored.qa["valid_share"] <= 1.0
    csv_path = export_scan(path, "points-csv", tmp_path / "scan.csv")
    header = csv_path.read_text().splitlines()[0]
    assert header.startswith("x_mm,y_mm,z_mm,sigma_mm")
    table = np.loadtxt(csv_path, delimiter=",", skiprows=1)
    assert table.shape == (len(result), 7)
    assert np.allclose(table[:, :3], result.points_cam_mm, atol=1e-4)
    ply_path = export_scan(path, "ply", tmp_path / "scan.ply")
    vertices = read_ply_vertices(ply_path)
    assert len(vertices) == len(result)
    assert np.allclose(vertices["z"], result.points_cam_mm[:, 2], atol=1e-4)
    assert np.allclose(vertices["sigma_mm"], result.sigma_mm, rtol=1e-6)
    meshio = pytest.importorskip("meshio", reason="meshio not installed: the PLY is checked by our own reader only")
    mesh = meshio.read(ply_path)
    assert len(mesh.points) == len(result) and "sigma_mm" in mesh.point_data
    with pytest.raises(ValueError, match="scan.csv: not an HDF5 file"):
        read_scan(csv_path)
