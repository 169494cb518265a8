"""Whether a frame's peak deflection was measured: the one rule every file, API, plot and export reads.

Belongs here: the rule (`peak_measurement`) and its reasons. Not here: finding the peak (`fields.field_peak`) or
storing the flag (`fringelab.formats.topography`, dataset peak/measured).

The rule (docs/method.md §8, "A measured peak"): the largest deflection of a frame counts as measured only where
the surface around it is measured on all sides over at least the punch radius, i.e. every grid node of the plate
within that radius of the maximum has data. A maximum on the rim of a missing area (a shadow, a hole, points out
of the calibrated range) is a lower bound: the plate may rise higher where nothing was measured.

"The plate" is what the reference (first, flat) frame measured: a node that the reference frame never saw (the
clamp ring, the image border) is not a gap of this frame, so a maximum near the edge of the view is not
flagged for what no frame could have measured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .arrays import checked_array
from .fields import Grid

# The punch of the paper's rig (Grytten et al. 2007: a 20 mm diameter punch), the default radius of the rule.
PUNCH_RADIUS_MM = 10.0
# A gap at most this wide between measured nodes (a lost edge or two, a streak) cannot hide a higher maximum: the
# plate bends no tighter than the punch, so over a gap g it rises at most g² / (8 R) = 0.2 mm above the chord
# for g = 4 mm and R = 10 mm. Such gaps are bridged (a morphological closing) before the rule looks for missing
# nodes; wider ones (a shadow, a hole) are not.
BRIDGED_GAP_MM = 4.0


@dataclass(frozen=True)
class PeakMeasurement:
    """Whether a frame's peak was measured (the module's rule). missing_nodes: plate nodes within radius_mm of the
    maximum without data (−1: the frame has no data at all); the peak is measured when there is none."""

    missing_nodes: int
    radius_mm: float = PUNCH_RADIUS_MM

    @property
    def measured(self) -> bool:
        return self.missing_nodes == 0

    @property
    def reason(self) -> str:
        """One short sentence why the peak is not measured ("" when it is)."""
        if self.missing_nodes < 0:
            return "no data in this frame"
        if self.missing_nodes > 0:
            return (
                f"data missing within {self.radius_mm:g} mm of the maximum ({self.missing_nodes} grid nodes): "
                "the value is a lower bound"
            )
        return ""


def peak_measurement(
    measured_nodes: np.ndarray,
    grid: Grid,
    peak_xy_mm: tuple[float, float],
    *,
    plate_nodes: np.ndarray | None = None,
    radius_mm: float = PUNCH_RADIUS_MM,
    bridged_gap_mm: float = BRIDGED_GAP_MM,
) -> PeakMeasurement:
    """Whether the maximum at peak_xy_mm is measured on all sides over radius_mm (the module's rule).

    measured_nodes: (ny, nx) bool, the grid nodes with data in this frame. plate_nodes: (ny, nx) bool, the nodes
    of the plate (what the reference frame measured); None: every node of the grid. peak_xy_mm: where the
    maximum is (`fields.Peak.x_mm, y_mm`); NaN: no data, not measured. Gaps no wider than bridged_gap_mm
    between measured nodes are not counted (see BRIDGED_GAP_MM).
    """
    measured = checked_array(measured_nodes, shape=grid.shape, name="measured_nodes").astype(bool)
    plate = (
        np.ones(grid.shape, bool)
        if plate_nodes is None
        else checked_array(plate_nodes, shape=grid.shape, name="plate_nodes").astype(bool)
    )
    if not radius_mm > 0:
        raise ValueError(f"radius_mm: expected > 0, got {radius_mm}")
    px, py = peak_xy_mm
    if not (np.isfinite(px) and np.isfinite(py)) or not measured.any():
        return PeakMeasurement(-1, radius_mm)
    # Only a window around the disc is looked at (a frame's grid can be 1000² nodes).
    step = grid.step_mm if np.isfinite(grid.step_mm) else radius_mm
    bridge = int(bridged_gap_mm // (2.0 * step))  # the closing's radius in nodes: it fills gaps of 2 × that
    reach = radius_mm + (bridge + 0.5) * step
    ix = np.flatnonzero(np.abs(grid.x_mm - px) <= reach)
    iy = np.flatnonzero(np.abs(grid.y_mm - py) <= reach)
    window = np.ix_(iy, ix)
    seen = measured[window]
    if bridge > 0:
        # Closed within the window (padded as measured, so a gap open to the window's edge is still closed
        # only between measured nodes inside it), then only what was a gap among measured nodes is filled.
        size = 2 * bridge + 1
        closed = ndimage.binary_closing(np.pad(seen, bridge, constant_values=True), np.ones((size, size), bool))
        seen = seen | closed[bridge:-bridge, bridge:-bridge]
    gx, gy = np.meshgrid(grid.x_mm[ix], grid.y_mm[iy])
    disc = np.hypot(gx - px, gy - py) <= radius_mm + 1e-9
    # A node of the disc counts when it belongs to the plate, or has data anyway (the plate grew into view); the
    # grid covers the reference frame's points with a margin, so what lies beyond it is no plate that frame saw.
    considered = disc & (plate[window] | measured[window])
    return PeakMeasurement(int(np.count_nonzero(considered & ~seen)), radius_mm)
