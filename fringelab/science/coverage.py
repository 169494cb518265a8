"""What of the plate a frame measured, and why the rest is missing (docs/method.md §6).

Belongs here: the list of reasons and the per-frame record, shared by the science (which fills it,
`topography.frame_coverage`) and the result file (which stores it). Pure Python, no OpenCV: the API reads it.
"""

from __future__ import annotations

from dataclasses import dataclass

# The order is that of the codes `topography.frame_coverage` gives (their index here); a new reason goes last.
MISSING_REASONS = (
    "hole", "shadow", "low_contrast", "order_unresolved", "order_conflict", "out_of_range", "uneven_light",
)  # fmt: skip
MISSING_DESCRIPTIONS = {
    "hole": "as black as the background (a hole, a crack, the punch in front, the clamp ring beside the rim)",
    "shadow": "dark but lit by the room (no projected light)",
    "low_contrast": "faint or clipped stripes, or no edge located",
    "order_unresolved": (
        "edges whose fringe order no anchor reaches through sure links (a dim region, a stray group, the lit edge "
        "beside a hole or the clamp ring)"
    ),
    "order_conflict": "edges masked for a conflict between the sources of their order",
    "out_of_range": "outside the calibrated Z range (never extrapolated)",
    "uneven_light": "stripes where the light changes too fast for their edges to be placed (a soft shadow's rim)",
}
# How plots and tables name each reason in a few words: "hole" is every region as black as the background, which
# before a perforation is the punch in front or the clamp ring, not a hole in the plate.
MISSING_LABELS = {
    "hole": "black: hole, punch, clamp",
    "shadow": "shadow",
    "low_contrast": "low contrast",
    "order_unresolved": "order unresolved",
    "order_conflict": "order conflict",
    "out_of_range": "outside the Z range",
    "uneven_light": "uneven light",
}


@dataclass(frozen=True)
class FrameCoverage:
    """What of the plate one frame measured, and what it did not, by reason (docs/method.md §6).

    Areas are of the plate as the reference frame sees it (each reference (edge, line) point stands for its share
    of the plate, `OrderReference.cell_area_mm2`); a point of the reference that this frame does not measure is
    missing for one reason: hole (as black as the background: a hole, a crack, the punch in front), shadow (dark
    but lit by the room: no projected light), low_contrast (faint or clipped stripes, or no edge located there),
    order_unresolved (edges whose order no anchor reaches through sure links, and the edges kept beside a dark
    area, which are never ordered), order_conflict (edges masked for a conflict of sources), out_of_range
    (ordered, but outside the calibrated Z range), uneven_light (stripes there, but the light changes too fast for
    their edges to be placed: a soft shadow's rim). n_order_conflicts: conflicts found.
    """

    visible_area_mm2: float
    measured_area_mm2: float
    missing_mm2: dict[str, float]
    n_order_conflicts: int

    @property
    def measured_fraction(self) -> float:
        return self.measured_area_mm2 / self.visible_area_mm2 if self.visible_area_mm2 > 0 else float("nan")
