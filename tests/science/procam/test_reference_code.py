"""A Gray code recorded with the plate at rest gives the reference frame's stripe order (docs/procam.md §5), on the
virtual test's rig taken as a digital projector (`digital_projector_of`), against the truth.

Lean renders: the kodak preset at 512 × 480 px, one sample per pixel, a 9-bit code (band 2 projector px) with white
and black frames at rest, and a 5-frame test to 30 mm (the last frame perforated). The projector table comes from
the camera–projector model over Z = −10 … 40 mm (no Z-stack to render).
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from fringelab.commands import topography as topography_commands
from fringelab.formats.camera import read_camera_json, write_camera_json
from fringelab.formats.patterns import patterns_json_text
from fringelab.formats.projector import write_projector_calibration
from fringelab.formats.recordings import write_recording
from fringelab.formats.topography import TopographyResult
from fringelab.science.calibration import CameraCalibration
from fringelab.science.fringes import FrameEdges
from fringelab.science.graycode import Decoding, PatternSequence, WhiteBlack, decode
from fringelab.science.order import OrderSettings, ReferenceCodeError, ReferenceFrameError, RimNotVisibleError
from fringelab.science.procam_table import projector_table_from_model
from fringelab.science.projector import (
    PatternEdges,
    ProjectorCalibration,
    ProjectorSettings,
)
from fringelab.science.topography import (
    FrameMeasurement,
    TopographySettings,
    locate_test_edges,
    reference_for,
    track_and_measure,
)
from fringelab.science.virtual_procam import digital_projector_of, gray_code_on_plate
from fringelab.science.virtual_test import (
    FringeRenderer,
    Imaging,
    PlateState,
    Preset,
    PunchTimeline,
    preset,
    punch_timeline,
    true_camera_calibration,
    true_deflection_mm,
)

TABLE_Z_MM = list(np.arange(-10.0, 40.0 + 1e-9, 2.0))
MAX_DEFLECTION_MM = 30.0
# docs/method.md §7: RMS of w below 0.05 mm on the flat plate and 0.10 mm over the deforming one, 15 mm from the
# punch and the clamp excluded.
FLAT_RMS_MM, DEFORMED_RMS_MM, EXCLUDED_MM = 0.05, 0.10, 15.0
# Where the clamp ring is out of view the lab names the clamp circle it knows (centre, Ø500 mm).
CLAMP_RADIUS_MM = 250.0


@dataclass(frozen=True, eq=False)
class Rig:
    setup: Preset
    camera: CameraCalibration
    table: ProjectorCalibration
    sequence: PatternSequence
    code_frames: list[np.ndarray]
    decoding: Decoding
    timeline: PunchTimeline
    frames: list[np.ndarray]
    edges: list[FrameEdges]


def render_rig(f_mm: float, seed: int) -> Rig:
    setup = preset("kodak", imaging=Imaging(supersample=1))
    setup = replace(setup, camera=replace(setup.camera, f_mm=f_mm))
    # The camera's calibration as a lab's file holds it (what the CLI and the job read, and the table is made with).
    with tempfile.TemporaryDirectory() as folder:
        camera = read_camera_json(write_camera_json(true_camera_calibration(setup.camera), Path(folder) / "c.json"))
    model, pattern = digital_projector_of(setup.camera, setup.projector)
    table = projector_table_from_model(model, camera, pattern, TABLE_Z_MM)
    n_codes = int(np.ceil(model.projector_size_wh_px[0] / 2.0))
    n_bits = int(np.ceil(np.log2(n_codes)))
    sequence = PatternSequence(
        axis="columns", projector_size_wh_px=model.projector_size_wh_px, gray_frames=tuple(range(2, 2 + n_bits)),
        band_px=2.0, threshold=WhiteBlack(0, 1),
    )  # fmt: skip
    rng = np.random.default_rng(seed)
    code_frames = gray_code_on_plate(setup, model, sequence, state=PlateState(0.0), rng=rng)
    timeline = punch_timeline(5, max_deflection_mm=MAX_DEFLECTION_MM)
    renderer = FringeRenderer(setup)
    frames = [renderer.render_test(state, rng=rng) for state in timeline.states]
    return Rig(setup, camera, table, sequence, code_frames, decode(code_frames, sequence), timeline, frames,
               list(locate_test_edges(frames, table)))  # fmt: skip


@pytest.fixture(scope="module")
def rim_in_view() -> Rig:
    return render_rig(17.0, seed=41)  # the preset's lens: the whole plate and part of the clamp ring


@pytest.fixture(scope="module")
def rim_hidden() -> Rig:
    # A longer lens: the plate runs into the image border on most scan lines; the clamp ring shows only in the
    # image's corners.
    return render_rig(25.0, seed=42)


def errors_mm(rig: Rig, measurement: FrameMeasurement) -> np.ndarray:
    """Z measured − true w at the measured points, 15 mm from the punch axis, the clamp and the hole excluded."""
    scene, state = rig.setup.scene, rig.timeline.states[measurement.frame]
    points = measurement.points_obj_mm
    truth = true_deflection_mm(scene, state, points[:, 0], points[:, 1])
    r = scene.radius_mm(points[:, 0], points[:, 1])
    keep = (np.isfinite(truth) & np.isfinite(points[:, 2]) & (r > max(EXCLUDED_MM, state.hole_radius_mm + EXCLUDED_MM))
            & (r < scene.clamp_radius_mm - EXCLUDED_MM))  # fmt: skip
    return points[keep, 2] - truth[keep]


def assert_within_targets(
    rig: Rig, measurements: list[FrameMeasurement], *, edges: list[FrameEdges] | None = None
) -> list[float]:
    """edges: those the measurements were made from (the rig's by default)."""
    edges = rig.edges if edges is None else edges
    assert [m.frame for m in measurements] == list(range(len(rig.frames)))
    rms = []
    for measurement in measurements:
        error = errors_mm(rig, measurement)
        assert len(error) > 10_000, f"frame {measurement.frame}: {len(error)} points"
        rms.append(float(np.sqrt(np.mean(error**2))))
        limit = FLAT_RMS_MM if measurement.frame == 0 else DEFORMED_RMS_MM
        assert rms[-1] < limit, f"frame {measurement.frame}: {rms[-1]:.3f} mm RMS"
        # An order error is a whole stripe's Z step (~17 mm here): none anywhere, not even near the punch.
        assert np.max(np.abs(error)) < 2.0, f"frame {measurement.frame}"
        assert measurement.n_order_conflicts == 0
        # Unresolved only where edges are kept beside a dark area (the clamp ring), which are never ordered
        # (docs/method.md §5), and the odd piece of a curve of fewer than 3 lines between two stretches of them
        # (too short for a sure link): at most a tenth more.
        beside = edges[measurement.frame].beside_dark
        assert beside is not None and measurement.n_order_unresolved <= 1.1 * np.count_nonzero(beside)
    return rms


def test_the_code_decodes_on_the_plate_at_rest(rim_in_view: Rig) -> None:
    # The clamp ring and the background are too dark to decode; the plate decodes but for the pixels beside a
    # code edge (about half of them with bands of 2.5 camera px).
    assert 0.4 < rim_in_view.decoding.valid_share < 0.7


def test_where_the_rim_shows_the_code_and_the_table_agree(rim_in_view: Rig) -> None:
    rig = rim_in_view
    settings = TopographySettings()
    by_table = reference_for(rig.edges[0], rig.table, rig.camera, settings)
    by_code = reference_for(rig.edges[0], rig.table, rig.camera, settings, code=rig.decoding)
    # Every point the code names, the table's match names the same (measured: 25 375 of 25 375).
    assert by_code.code_points > 20_000 and by_code.code_compared == by_code.code_points
    assert by_code.code_agreement == 1.0
    np.testing.assert_array_equal(by_code.reference_t_px, by_table.reference_t_px)
    np.testing.assert_array_equal(by_code.rim, by_table.rim)
    assert by_table.code_points == 0 and np.isnan(by_table.code_agreement)
    measured = list(track_and_measure(rig.edges, rig.table, rig.camera, settings=settings, reference=by_code))
    rms = assert_within_targets(rig, measured)
    assert max(rms) < 0.03  # measured 0.015 mm in every frame


def test_where_the_rim_is_hidden_the_code_orders_the_reference_and_the_named_clamp_anchors(rim_hidden: Rig) -> None:
    rig = rim_hidden
    # Today's route refuses, and so does the code alone: the order of every later frame still needs a part of the
    # plate that stays still, and no clamp ring in view says where that is.
    with pytest.raises(RimNotVisibleError, match="rim_circle_mm"):
        reference_for(rig.edges[0], rig.table, rig.camera, TopographySettings())
    with pytest.raises(RimNotVisibleError, match="rim_circle_mm"):
        reference_for(rig.edges[0], rig.table, rig.camera, TopographySettings(), code=rig.decoding)
    clamp = (*rig.setup.scene.centre_xy_mm, CLAMP_RADIUS_MM)
    settings = TopographySettings(order=OrderSettings(rim_circle_mm=clamp))
    reference = reference_for(rig.edges[0], rig.table, rig.camera, settings, code=rig.decoding)
    assert reference.code_agreement == 1.0 and reference.code_points > 20_000
    assert np.count_nonzero(reference.rim) > 500  # the corners of the image (measured: 910 points)
    measured = list(track_and_measure(rig.edges, rig.table, rig.camera, settings=settings, reference=reference))
    rms = assert_within_targets(rig, measured)
    assert max(rms) < 0.03  # measured 0.010 mm


def test_a_plate_resting_off_the_tables_reference_z_is_ordered_by_the_code(rim_in_view: Rig) -> None:
    # The table made for a plate at rest at Z = −8 mm (half a stripe's Z step from where it rests): the table's
    # match at −8 mm names too few edges and refuses; the code names every edge and finds the plate at Z = 0.
    rig = rim_in_view
    model, pattern = digital_projector_of(rig.setup.camera, rig.setup.projector)
    table = projector_table_from_model(model, rig.camera, pattern, TABLE_Z_MM,
                                       settings=ProjectorSettings(reference_z_mm=-8.0))  # fmt: skip
    assert table.reference_z_mm == -8.0
    edges = list(locate_test_edges(rig.frames, table))
    settings = TopographySettings()
    with pytest.raises(ReferenceFrameError, match="match the projector calibration's edges"):
        reference_for(edges[0], table, rig.camera, settings)
    reference = reference_for(edges[0], table, rig.camera, settings, code=rig.decoding)
    assert reference.code_compared == 0 and np.isnan(reference.code_agreement)  # no second answer to check against
    measured = list(track_and_measure(edges, table, rig.camera, settings=settings, reference=reference))
    assert abs(float(np.median(measured[0].points_obj_mm[:, 2]))) < 0.01  # the plate rests at Z = 0
    assert_within_targets(rig, measured, edges=edges)


def test_a_code_that_disagrees_with_the_table_is_refused_naming_both(rim_in_view: Rig) -> None:
    # The projector's pattern moved by one stripe period (8 px) since the table was made: the code names every edge
    # two over, which puts the plate at rest a stripe's Z step (~17 mm) above where the table's match finds it flat.
    rig = rim_in_view
    assert rig.table.pattern_edges is not None
    shifted = PatternEdges(axis="columns", projector_px=rig.table.pattern_edges.projector_px - 8.0)
    table = replace(rig.table, pattern_edges=shifted)
    with pytest.raises(ReferenceCodeError, match=r"disagree.*[+-]2, 1 stripe periods.*reference Z = 0 mm"):
        reference_for(rig.edges[0], table, rig.camera, TopographySettings(), code=rig.decoding)


def test_a_code_along_the_other_axis_is_refused_naming_the_key(rim_in_view: Rig) -> None:
    rig = rim_in_view
    rows = replace(rig.decoding, sequence=replace(rig.sequence, axis="rows"))
    with pytest.raises(ReferenceCodeError, match=r'projector rows \(patterns.json "axis"\).*projector columns'):
        reference_for(rig.edges[0], rig.table, rig.camera, TopographySettings(), code=rows)


def test_a_code_with_no_decoded_pixels_at_the_edges_is_refused(rim_in_view: Rig) -> None:
    rig = rim_in_view
    # Decoded only in a 20 px square in a corner, on the clamp ring: no stripe edge of the plate has a code beside it.
    code = np.full_like(rig.decoding.code, -1)
    code[:20, :20] = 3
    lost = replace(rig.decoding, code=code)
    with pytest.raises(ReferenceCodeError, match=r"names only 0 of the reference frame's \d+ stripe-edge points"):
        reference_for(rig.edges[0], rig.table, rig.camera, TopographySettings(), code=lost)


def test_a_table_that_does_not_know_its_projector_edges_is_refused(rim_in_view: Rig) -> None:
    rig = rim_in_view
    zstack_like = replace(rig.table, pattern_edges=None)
    with pytest.raises(ReferenceCodeError, match="Z-stack's table.*fringelab projector-table"):
        reference_for(rig.edges[0], zstack_like, rig.camera, TopographySettings(), code=rig.decoding)


@pytest.fixture(scope="module")
def rig_files(rim_in_view: Rig, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The rig as a lab has it on disk: the test and the code at rest as folders of frames (the code with its
    patterns.json), the camera's calibration and the projector table made from the camera–projector model."""
    rig = rim_in_view
    root = tmp_path_factory.mktemp("rig")
    write_camera_json(rig.camera, root / "camera.json")
    write_projector_calibration(rig.table, root / "projector.h5")
    return {
        "test": write_recording(root / "test", rig.frames),
        "code": write_recording(
            root / "code", rig.code_frames, sidecars={"patterns.json": patterns_json_text(rig.sequence)}
        ),  # fmt: skip
        "camera": root / "camera.json",
        "projector": root / "projector.h5",
    }


def run_topography(files: dict[str, Path], out: Path, *extra: str) -> int:
    parser = argparse.ArgumentParser(prog="fringelab")
    topography_commands.register(parser.add_subparsers())
    args = parser.parse_args(["topography", str(files["test"]), "--camera", str(files["camera"]), "--projector",
                              str(files["projector"]), "-o", str(out), "--json", *extra])  # fmt: skip
    return int(args.handler(args))


def test_the_command_line_takes_the_code_at_rest(rim_in_view: Rig, rig_files, tmp_path: Path, capsys) -> None:
    out = tmp_path / "result.h5"
    assert run_topography(rig_files, out, "--reference-code", str(rig_files["code"])) == 0, capsys.readouterr().err
    with TopographyResult(out) as result:
        summary = result.summary()
        coverage = result.coverage()
        assert summary["reference_order_from"] == "gray code at rest"
        assert summary["reference_code_agreement"] == 1.0 and summary["reference_code_points"] > 20_000
        assert np.all(coverage["measured_fraction"] > 0.95)  # per frame (the last one has its hole)
        assert result.sigma_grid(len(rim_in_view.frames) - 1) is not None
        for i in range(len(rim_in_view.frames)):
            points = result.points(i)
            truth = true_deflection_mm(rim_in_view.setup.scene, rim_in_view.timeline.states[i], points[:, 0],
                                       points[:, 1])  # fmt: skip
            error = points[:, 2] - truth
            assert np.nanmedian(np.abs(error)) < 0.05, f"frame {i}"
    plain = tmp_path / "plain.h5"
    assert run_topography(rig_files, plain) == 0
    with TopographyResult(plain) as result:
        assert result.summary()["reference_order_from"] == "projector table"


def test_the_command_line_refuses_a_bad_code_naming_the_file_and_key(rim_in_view: Rig, rig_files, tmp_path: Path,
                                                                      capsys) -> None:  # fmt: skip
    rig = rim_in_view
    missing = replace(rig.sequence, gray_frames=(*rig.sequence.gray_frames, len(rig.code_frames)))
    (tmp_path / "missing.json").write_text(patterns_json_text(missing), encoding="utf-8")
    out = tmp_path / "result.h5"
    assert run_topography(rig_files, out, "--reference-code", str(rig_files["code"]), "--reference-code-patterns",
                          str(tmp_path / "missing.json")) != 0  # fmt: skip
    error = capsys.readouterr().err
    assert f"missing.json: gray_frames names frame {len(rig.code_frames)} but the recording has" in error
    rows = replace(rig.sequence, axis="rows")
    (tmp_path / "rows.json").write_text(patterns_json_text(rows), encoding="utf-8")
    assert run_topography(rig_files, out, "--reference-code", str(rig_files["code"]), "--reference-code-patterns",
                          str(tmp_path / "rows.json")) != 0  # fmt: skip
    assert 'projector rows (patterns.json "axis")' in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob("*.h5*"))  # nothing half-written
