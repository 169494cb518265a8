"""What the topography job hands from one task to the next: the reference and each measured frame as typed records
(`as_record` / `from_record`), read back exactly (what the file stores: X, Y and σ of the points as float32)."""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from fringelab.pipelines.topography import FRAME_SCALARS, MeasuredFrame, PackedFrame, TopographyReference
from fringelab.science.coverage import MISSING_REASONS, FrameCoverage
from fringelab.science.fields import Grid, Peak
from fringelab.science.order import OrderReference
from fringelab.science.topography import FrameMeasurement


def _frame(rng: np.random.Generator) -> MeasuredFrame:
    n = 50
    coverage = FrameCoverage(visible_area_mm2=1234.5, measured_area_mm2=1000.25,
                             missing_mm2={reason: float(i) + 0.5 for i, reason in enumerate(MISSING_REASONS)},
                             n_order_conflicts=3)  # fmt: skip
    measurement = FrameMeasurement(
        frame=7, k=rng.integers(0, 40, n), line=rng.integers(0, 300, n), points_obj_mm=rng.normal(0, 30, (n, 3)),
        n_tracks=n, n_ended=0, n_out_of_range=2, n_unmatched=5, edge_noise_px=0.0375, n_order_unresolved=4,
        n_order_conflict_points=6, n_order_conflicts=3, coverage=coverage, sigma_z_mm=rng.random(n),
    )  # fmt: skip
    z_grid = rng.normal(0, 5, (6, 8))
    z_grid[0, :3] = np.nan
    peak = Peak(w_mm=12.5, x_mm=1.25, y_mm=-0.5, centre_x_mm=0.75, centre_y_mm=float("nan"))
    return MeasuredFrame(measurement, z_grid, rng.random((6, 8)), peak)


def test_a_measured_frame_crosses_the_hand_over_as_the_file_stores_it() -> None:
    original = PackedFrame.of(_frame(np.random.default_rng(1)))
    record = original.as_record()
    assert record["scalars"].dtype == FRAME_SCALARS and record["scalars"].shape == (1,)  # one header per frame
    back = PackedFrame.from_record(record, (6, 8))
    m, r = original.measurement, back.measurement
    for name in ("frame", "n_tracks", "n_ended", "n_out_of_range", "n_unmatched", "edge_noise_px",
                 "n_order_unresolved", "n_order_conflict_points", "n_order_conflicts", "coverage"):  # fmt: skip
        assert getattr(r, name) == getattr(m, name), name
    np.testing.assert_array_equal(r.k, m.k)
    np.testing.assert_array_equal(r.line, m.line)
    np.testing.assert_array_equal(r.points_obj_mm[:, 2], m.points_obj_mm[:, 2])  # Z in full: the cross-check reads it
    # X, Y and σ as the file stores them (float32)
    np.testing.assert_array_equal(r.points_obj_mm[:, :2], m.points_obj_mm[:, :2].astype(np.float32))
    np.testing.assert_array_equal(r.sigma_z_mm, np.asarray(m.sigma_z_mm, np.float32))
    for f in fields(Peak):
        np.testing.assert_equal(getattr(back.peak, f.name), getattr(original.peak, f.name))
    assert back.packed.z_mm == original.packed.z_mm and back.packed.sigma_w_mm == original.packed.sigma_w_mm
    np.testing.assert_array_equal(back.packed.z_finite, original.packed.z_finite)


def test_the_reference_crosses_the_hand_over_exactly() -> None:
    rng = np.random.default_rng(2)
    order = OrderReference(reference_t_px=rng.random((4, 9)), rim=rng.random((4, 9)) > 0.5,
                           rim_circle_mm=(1.5, -2.25, 80.0), cell_area_mm2=rng.random((4, 9)))  # fmt: skip
    reference = TopographyReference(
        order=order, grid=Grid(x_mm=np.arange(-10.0, 10.0, 2.0), y_mm=np.arange(-6.0, 6.0, 2.0)), max_edge_mm=3.5,
        z_flat_mm=0.0125, flat_rms_mm=0.03, clamp=(0.5, -0.25, 81.0), n_tracks_first_frame=1234,
        plate_nodes=rng.random((6, 10)) > 0.3,
    )  # fmt: skip
    back = TopographyReference.from_record(reference.as_record())
    for name in ("max_edge_mm", "z_flat_mm", "flat_rms_mm", "clamp", "n_tracks_first_frame"):
        assert getattr(back, name) == getattr(reference, name), name
    assert back.order.rim_circle_mm == order.rim_circle_mm
    for name in ("reference_t_px", "rim", "cell_area_mm2"):
        np.testing.assert_array_equal(getattr(back.order, name), getattr(order, name))
    np.testing.assert_array_equal(back.grid.x_mm, reference.grid.x_mm)
    np.testing.assert_array_equal(back.grid.y_mm, reference.grid.y_mm)
    np.testing.assert_array_equal(back.plate_nodes, reference.plate_nodes)
