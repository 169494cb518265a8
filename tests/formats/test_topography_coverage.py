"""What is missing per frame, in the topography result file: written by TopographyWriter, read back by
TopographyResult.coverage(); files written before it existed read as NaN (the layout only grew: schema 1)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np

from fringelab.formats.topography import TopographyResult, TopographyWriter
from fringelab.science.coverage import MISSING_REASONS, FrameCoverage
from fringelab.science.fields import Grid, Peak
from fringelab.science.topography import FrameMeasurement, TemporalCheck


def measurement(frame: int, coverage: FrameCoverage | None) -> FrameMeasurement:
    rng = np.random.default_rng(frame)
    points = rng.uniform(-10.0, 10.0, (5, 3))
    return FrameMeasurement(
        frame=frame, k=np.arange(5, dtype=np.int32), line=np.full(5, 3, np.int32), points_obj_mm=points,
        n_tracks=5, n_ended=0, n_out_of_range=1, n_unmatched=2, edge_noise_px=0.02, n_order_unresolved=7,
        n_order_conflicts=3 if coverage else 0, coverage=coverage,
    )  # fmt: skip


def write(path: Path, measurements: list[FrameMeasurement]) -> Path:
    grid = Grid(x_mm=np.linspace(-10.0, 10.0, 5), y_mm=np.linspace(-10.0, 10.0, 4))
    writer = TopographyWriter(path, grid=grid, max_edge_mm=6.0, z_flat_mm=0.0, axis="rows", attrs={},
                              calibration_attrs={})  # fmt: skip
    peak = Peak(w_mm=1.0, x_mm=0.0, y_mm=0.0, centre_x_mm=0.0, centre_y_mm=0.0)
    for m in measurements:
        writer.append(m, np.zeros(grid.shape), peak, log=(0.0, 0.0, 0.0))
    return writer.close({})


def test_coverage_round_trips_with_every_reason(tmp_path: Path) -> None:
    missing = {name: 10.0 * (i + 1) for i, name in enumerate(MISSING_REASONS)}
    coverage = FrameCoverage(visible_area_mm2=1000.0, measured_area_mm2=790.0, missing_mm2=missing, n_order_conflicts=3)
    checked = replace(measurement(1, None), temporal=TemporalCheck(n_checked=5, n_jumps=2))
    path = write(tmp_path / "r.h5", [measurement(0, coverage), checked])
    with TopographyResult(path) as result:
        read = result.coverage()
        assert result.file["qa/missing_shadow_mm2"].attrs["unit"] == "mm2"
        assert result.column("qa/n_order_unresolved").tolist() == [7, 7]
    assert read["measured_fraction"][0] == 0.79
    assert read["visible_area_mm2"][0] == 1000.0 and read["measured_area_mm2"][0] == 790.0
    for name, value in missing.items():
        assert read[f"missing_{name}_mm2"][0] == value
    assert read["n_order_conflicts"].tolist() == [3.0, 0.0]
    assert np.isnan(read["n_temporal_jumps"][0]) and read["n_temporal_jumps"][1] == 2.0  # not checked: NaN
    # A measurement without coverage (stored before it existed) is written as NaN, never as "all measured".
    assert np.isnan(read["measured_fraction"][1]) and np.isnan(read["missing_hole_mm2"][1])


def test_files_without_coverage_read_as_nan(tmp_path: Path) -> None:
    nothing = dict.fromkeys(MISSING_REASONS, 0.0)
    coverage = FrameCoverage(visible_area_mm2=1.0, measured_area_mm2=1.0, missing_mm2=nothing, n_order_conflicts=0)
    path = write(tmp_path / "old.h5", [measurement(0, coverage)])
    with h5py.File(path, "a") as file:  # as an older fringelab wrote it
        for name in list(file["qa"]):
            if name.startswith(("missing_", "measured_", "visible_", "n_order_")):
                del file["qa"][name]
    with TopographyResult(path) as result:
        read = result.coverage()
    assert set(read) >= {"measured_fraction", "n_order_conflicts", *(f"missing_{n}_mm2" for n in MISSING_REASONS)}
    assert all(np.isnan(values).all() and len(values) == 1 for values in read.values())
