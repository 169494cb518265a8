"""The projector table from a camera–projector model (docs/procam.md §5) against the Z-stack's on the virtual test,
and the deformation test measured both ways."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.science.procam_table import StripePattern, projector_table_from_model
from fringelab.science.projector import CalibrationMismatchError, ProjectorCalibration
from fringelab.science.topography import track_and_measure
from fringelab.science.virtual_procam import digital_projector_of, virtual_procam_rig

from .conftest import RenderedExperiment

N_FRAMES = 12  # flat, then up to ~15 mm of deflection


@pytest.fixture(scope="module")
def model_table(kodak: RenderedExperiment) -> ProjectorCalibration:
    model, pattern = digital_projector_of(kodak.preset.camera, kodak.preset.projector)
    return projector_table_from_model(model, kodak.camera, pattern, kodak.calibration_z_mm,
                                      scan_axis=kodak.projector.axis, edges=kodak.projector.edges)  # fmt: skip


def _edge_offset(zstack: ProjectorCalibration, model: ProjectorCalibration) -> int:
    """The model's edge index of the Z-stack's edge 0 (each counts from the first edge it sees)."""
    best: tuple[float, int] | None = None
    for offset in range(-zstack.n_edges, model.n_edges):
        k = np.arange(zstack.n_edges)
        ok = (k + offset >= 0) & (k + offset < model.n_edges)
        d = zstack.reference_t_px[k[ok]] - model.reference_t_px[k[ok] + offset]
        if np.count_nonzero(np.isfinite(d)) < 1000:
            continue
        score = float(np.nanmedian(np.abs(d)))
        if best is None or score < best[0]:
            best = (score, offset)
    assert best is not None
    return best[1]


def test_tables_from_the_model_and_the_zstack_agree_within_the_tables_sigma(
    kodak: RenderedExperiment, model_table: ProjectorCalibration
) -> None:
    zstack = kodak.projector
    offset = _edge_offset(zstack, model_table)
    k, s, j = np.nonzero(np.isfinite(zstack.lut_t_px))
    t = zstack.lut_t_px[k, s, j].astype(np.float64)
    z_zstack, status_zstack = zstack.z_from_t(k, s, t)
    inside = (k + offset >= 0) & (k + offset < model_table.n_edges)
    z_model, status_model = model_table.z_from_t(np.where(inside, k + offset, 0), s, t)
    both = inside & (status_zstack == 0) & (status_model == 0)
    assert np.count_nonzero(both) > 0.8 * len(k)
    dz = z_zstack[both] - z_model[both]
    sigma = zstack.table_sigma_z_mm[k[both], s[both]]
    # The model's table is exact (its fit RMS is ~1e-4 mm), so the difference is the Z-stack table's own error:
    # measured 0.0066 mm RMS against a median σ of 0.0051 mm, 90 % within 2σ and 98 % within 3σ.
    assert np.sqrt(np.mean(dz**2)) < 1.5 * np.median(sigma)
    assert np.mean(np.abs(dz) < 3.0 * sigma) > 0.95
    assert abs(np.median(dz)) < 0.2 * np.median(sigma)  # no bias between the two routes
    assert model_table.qa.fit_rms_mm < 1e-3


def test_a_deformation_test_measured_with_either_table_agrees(
    kodak: RenderedExperiment, model_table: ProjectorCalibration
) -> None:
    edges = kodak.test_edges[:N_FRAMES]
    by_zstack = list(track_and_measure(edges, kodak.projector, kodak.camera))
    by_model = list(track_and_measure(edges, model_table, kodak.camera))
    offset = _edge_offset(kodak.projector, model_table)
    differences, sigmas = [], []
    for a, b in zip(by_zstack, by_model, strict=True):
        za = dict(zip(zip(a.k.tolist(), a.line.tolist(), strict=True), a.points_obj_mm[:, 2], strict=True))
        for kk, line, z in zip(b.k.tolist(), b.line.tolist(), b.points_obj_mm[:, 2], strict=True):
            other = za.get((kk - offset, line))
            if other is not None and np.isfinite(other) and np.isfinite(z):
                differences.append(other - z)
        assert len(b.k) > 0.9 * len(a.k)  # the model's table orders as many points
        if a.sigma_z_mm is not None:
            sigmas.append(np.nanmedian(a.sigma_z_mm))
    differences_mm = np.asarray(differences)
    assert len(differences_mm) > 10_000
    # Same edges, two tables: they differ by the tables' difference only (well below the points' own σ_Z).
    assert np.sqrt(np.mean(differences_mm**2)) < 0.02
    assert abs(np.median(differences_mm)) < 0.005


def test_a_camera_of_another_size_is_refused(kodak: RenderedExperiment) -> None:
    rig = virtual_procam_rig()
    with pytest.raises(CalibrationMismatchError, match="must describe one camera"):
        projector_table_from_model(rig, kodak.camera, StripePattern("columns", 8.0), [0.0, 10.0], scan_axis="rows")


def test_projector_table_on_the_command_line(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    import argparse
    import json

    from fringelab.commands import procam as procam_commands
    from fringelab.formats.camera import write_camera_json
    from fringelab.formats.procam import write_procam_json
    from fringelab.formats.projector import read_projector_calibration
    from fringelab.science.projector import exact_camera_model
    from fringelab.science.virtual_test import Imaging, preset, true_camera_calibration

    setup = preset("kodak", imaging=Imaging(supersample=1))
    model, pattern = digital_projector_of(setup.camera, setup.projector)
    write_procam_json(tmp_path / "procam.json", model)
    write_camera_json(true_camera_calibration(setup.camera), tmp_path / "camera.json")
    parser = argparse.ArgumentParser(prog="fringelab")
    procam_commands.register(parser.add_subparsers())
    args_text = ["projector-table", "--procam", str(tmp_path / "procam.json"), "--camera",
                 str(tmp_path / "camera.json"), "--stripe-period-px", str(pattern.period_px),
                 "--stripe-offset-px", str(pattern.offset_px), "--z-mm", "0:20:2", "-o",
                 str(tmp_path / "projector.h5"), "--json"]  # fmt: skip
    args = parser.parse_args(args_text)
    assert args.handler(args) == 0, capsys.readouterr().err
    summary = json.loads(capsys.readouterr().out)
    assert summary["axis"] == "rows"  # the kodak preset's stripes run roughly vertically in the image
    # The same summary as `calibrate-projector` gives a Z-stack's table (one writer and reporter, commands/tables.py).
    assert set(summary) == {"path", "axis", "n_lines", "period_px", "n_edges", "n_entries", "z_steps", "qa"}
    assert summary["z_steps"] == 11 and summary["qa"]["z_range_mm"] == [0.0, 20.0]
    assert args.handler(parser.parse_args([a for a in args_text if a != "--json"])) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"{tmp_path / 'projector.h5'}: {summary['n_edges']} edges over {summary['n_lines']} lines")
    assert "Z 0 … 20 mm in 11 steps" in text and "stripe period" in text and "coverage" in text
    table = read_projector_calibration(tmp_path / "projector.h5")
    direct = projector_table_from_model(model, exact_camera_model(setup.camera), pattern, list(np.arange(0, 21, 2.0)))
    assert table.n_edges == direct.n_edges and table.period_px == pytest.approx(direct.period_px)
    assert np.allclose(table.lut_t_px, direct.lut_t_px, equal_nan=True, atol=1e-4)
    assert table.provenance["source"] == "camera–projector model"
    # The table says which projector stripe edge each of its edges is (what a Gray code at rest names them by):
    # the pattern's edges offset + m·period/2, read back exactly.
    assert table.pattern_edges is not None and direct.pattern_edges is not None
    assert table.pattern_edges.axis == "columns"
    np.testing.assert_array_equal(table.pattern_edges.projector_px, direct.pattern_edges.projector_px)
    m = (table.pattern_edges.projector_px - pattern.offset_px) / (0.5 * pattern.period_px)
    np.testing.assert_allclose(m, np.round(m), atol=1e-9)
    assert np.all(np.abs(np.diff(np.round(m))) == 1)  # consecutive edges of the pattern, in stripe order
