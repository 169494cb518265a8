"""The projector table's verdict and maps, on small tables with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.science.projector_quality import judge_projector, projector_maps

GOOD_QA = {
    "coverage": 0.98, "n_entries": 10_000, "n_edges": 100, "sensitivity_px_per_mm": [0.6, 0.65, 0.7],
    "fit_rms_mm": 0.015, "fit_p95_mm": 0.03, "n_non_monotonic": 0, "n_insensitive": 0,
    "max_step_shift_periods": 0.12, "edge_noise_px": 0.009, "z_range_mm": [0, 80], "xy_extent_mm": [0, 1, 0, 1],
}  # fmt: skip


def test_verdict_levels_follow_the_thresholds_and_say_what_they_mean():
    verdict = judge_projector(GOOD_QA)
    assert verdict.level == "good", verdict.reasons
    by_name = {c.name: c for c in verdict.checks}
    # Z resolution at the least sensitive edges: 0.009 px / 0.6 px/mm = 0.015 mm (exact arithmetic).
    assert by_name["z_resolution_mm"].value == pytest.approx(0.015, rel=1e-12)
    assert "Z resolution at the least sensitive edges" in by_name["z_resolution_mm"].message
    # 8 of 10 000 entries non-monotonic is 0.08 %: good; 80 is 0.8 %: to check; 200 is 2 %: bad.
    levels = [judge_projector({**GOOD_QA, "n_non_monotonic": n}).level for n in (8, 80, 200)]
    assert levels == ["good", "check", "bad"]
    shifted = judge_projector({**GOOD_QA, "max_step_shift_periods": 0.5})
    assert shifted.level == "bad" and "take smaller Z steps" in shifted.reasons[0]
    unmeasured = judge_projector({**GOOD_QA, "edge_noise_px": float("nan")})
    assert unmeasured.level == "bad" and any("not measured" in r for r in unmeasured.reasons)


def test_maps_cover_the_whole_image_with_the_median_sensitivity_of_each_cell():
    # Scan lines are the 32 rows of a 64 × 32 px image ("rows"); 4 edges at columns 8, 24, 40, 56 on every line.
    edges, lines = 4, 32
    t_px = np.tile(np.array([8.0, 24.0, 40.0, 56.0])[:, None], (1, lines))
    sensitivity = np.tile(np.array([0.5, 0.6, 0.7, 0.8])[:, None], (1, lines))
    sensitivity[3, 16:] = np.nan  # edge 3 has no entry on the lower half: coverage 0 there
    z_lo = np.zeros((edges, lines))
    z_hi = np.full((edges, lines), 40.0)
    maps = projector_maps(image_shape=(32, 64), axis="rows", reference_t_px=t_px, sensitivity_px_per_mm=sensitivity,
                          z_mm=np.array([0.0, 20.0, 40.0, 60.0]), z_lo_mm=z_lo, z_hi_mm=z_hi, edge_noise_px=0.01,
                          cell_px=16)  # fmt: skip
    assert (maps.cells_u, maps.cells_v) == (4, 2)
    np.testing.assert_allclose(maps.sensitivity_px_per_mm[0], [0.5, 0.6, 0.7, 0.8])
    np.testing.assert_allclose(maps.sensitivity_px_per_mm[1], [0.5, 0.6, 0.7, np.nan])
    np.testing.assert_allclose(maps.z_resolution_mm[0], 0.01 / np.array([0.5, 0.6, 0.7, 0.8]))
    np.testing.assert_allclose(maps.coverage, [[1, 1, 1, 1], [1, 1, 1, 0]])
    np.testing.assert_allclose(maps.coverage_z, [1, 1, 1, 0])  # every entry spans 0…40 mm, none reaches 60
    # The same table with scan lines as columns ("cols") maps onto the transpose.
    cols = projector_maps(image_shape=(64, 32), axis="cols", reference_t_px=t_px, sensitivity_px_per_mm=sensitivity,
                          z_mm=np.array([0.0]), z_lo_mm=z_lo, z_hi_mm=z_hi, edge_noise_px=0.01, cell_px=16)  # fmt: skip
    np.testing.assert_allclose(cols.sensitivity_px_per_mm, maps.sensitivity_px_per_mm.T)
    with pytest.raises(ValueError, match="axis"):
        projector_maps(image_shape=(32, 64), axis="diagonal", reference_t_px=t_px, sensitivity_px_per_mm=sensitivity,
                       z_mm=np.array([0.0]), z_lo_mm=z_lo, z_hi_mm=z_hi, edge_noise_px=0.01)  # fmt: skip
