"""Stripe edges of a real scan's Gray-code bit frames (../shared/data/real_structured_light_sphere: a ball in front
of a screen, 8-bit, dim, on a dark background), against a reference the locator does not see (issue 29).

Reference: every crossing of a bit frame with the mean of the scan's three sinusoidal frames (the threshold its
patterns.json names), along the scan lines, where the sinusoids are well lit (≥ 30 grey of shading, 2√2 times
their standard deviation, and 20 px from any pixel below that) and the crossing is a clean step (no other within
3 px). The locator sees the bit frame alone, with the bit's period fixed as a recording's pipeline fixes it: the
code's band width in the camera (measured from the decoded code on the screen: 284 px for the columns, 144 px for
the rows) times 2^(bit + 2), 576–4608 px, far beyond the periods a frame's own spectrum can give.

An edge is found when one of its polarity lies on its line within 8 px: the frame's own mid-level is not the
sinusoids' mean (the projector's gamma; on the rows' blurred edges, 2 grey per px, they sit up to 6 px apart), and
the stripes are at least 290 px wide, so no other edge is that near. Agreement: the median and the 95th percentile
of the found edges' offsets from the reference, which are mostly that difference of levels, not the locator's
error.

The data have no licence and live beside the checkout only: skipped, saying so, when absent.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import cv2
import numpy as np
import pytest

from fringelab.science.fringes import EdgeSettings, locate_edges

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "real_structured_light_sphere"
if not DATA.is_dir():
    print(f"skipping the real scan's edge tests: {DATA.resolve()} not found (it ships only beside the repo)")
    pytestmark = pytest.mark.skip(reason=f"{DATA} not found")

BAND_CAMERA_PX = {"columns": 284.0, "rows": 144.0}
# The code's stripes run across the image's columns for "columns" (scanned along image rows) and along them for
# "rows"; bit frames are given finest first (frame 03 is bit 0).
SCAN_AXIS = {"columns": "rows", "rows": "cols"}
SHADING_GREY, INTERIOR_PX, CLEAN_PX, MATCH_PX = 30.0, 20.0, 3, 8.0
# (set, bit): recall floor (%), |median| and 95th-percentile |offset| ceilings (px). Measured (issue 29): columns
# bits 0/1/2 recall 94.7 / 77.7 / 78.3 %, rows bits 0/1/2/3 95.5 / 95.5 / 90.4 / 99.5 % with curves linked across
# one lost crossing (EdgeSettings.link_across_lost_crossing; 92.1 / 75.1 / 76.3 and 95.5 / 94.6 / 89.7 / 99.5 %
# without); offsets below. The
# floors are 4–5 points under what was measured; the columns' bits 1 and 2 lose their edges on the ball where
# its silhouette's own transitions make stripes a tenth as wide as their neighbours (`_without_slivers`).
EXPECTED = {
    ("columns", 0): (90.0, 0.5, 1.0),  # median −0.28, p95 0.72 px
    ("columns", 1): (73.0, 0.6, 1.0),  # +0.34, 0.67
    ("columns", 2): (74.0, 1.2, 2.0),  # +0.94, 1.68
    ("rows", 0): (90.0, 2.5, 3.2),  # +2.07, 2.75
    ("rows", 1): (91.0, 2.6, 3.2),  # −2.27, 2.71
    ("rows", 2): (86.0, 3.3, 6.0),  # +2.91, 5.33
    ("rows", 3): (95.0, 2.5, 3.0),  # +2.13, 2.47
}


@cache
def _frames(name: str) -> tuple[np.ndarray, ...]:
    return tuple(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((DATA / name).glob("*.png")))


def reference_crossings(name: str, bit: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """line, t (px) and polarity of the bit frame's clean crossings with the sinusoids' mean in the lit interior,
    in the locator's scan frame."""
    frames = _frames(name)
    sinusoids = np.stack([f.astype(np.float64) for f in frames[:3]])
    shading = 2.0 * np.sqrt(2.0) * sinusoids.std(axis=0)
    interior = cv2.distanceTransform((shading >= SHADING_GREY).astype(np.uint8), cv2.DIST_L2, 5) >= INTERIOR_PX
    above = frames[3 + bit].astype(np.float64) - sinusoids.mean(axis=0)
    if SCAN_AXIS[name] == "cols":
        above, interior = above.T, interior.T
    flips = (above[:, 1:] > 0) != (above[:, :-1] > 0)
    line, j = np.nonzero(flips)
    n = above.shape[1]
    ok = (j >= CLEAN_PX) & (j < n - CLEAN_PX - 2)
    line, j = line[ok], j[ok]
    clean = np.ones(len(j), bool)
    for k in range(-CLEAN_PX, CLEAN_PX + 2):
        clean &= interior[line, j + k]
    for k in range(-CLEAN_PX, CLEAN_PX + 1):
        if k:
            clean &= ~flips[line, j + k]
    line, j = line[clean], j[clean]
    d0, d1 = above[line, j], above[line, j + 1]
    return line, j + d0 / (d0 - d1), np.where(d1 > d0, 1, -1)


def recall_and_offsets(name: str, bit: int) -> tuple[float, np.ndarray]:
    period_px = BAND_CAMERA_PX[name] * 2.0 ** (bit + 2)
    settings = EdgeSettings(axis=SCAN_AXIS[name], period_px=period_px, mid_level="envelopes",
                            link_across_lost_crossing=True)  # fmt: skip
    edges = locate_edges(_frames(name)[3 + bit], settings)
    line, t, polarity = reference_crossings(name, bit)
    offsets = np.full(len(line), np.nan)
    for i in range(len(line)):
        mine = (edges.line == line[i]) & (edges.polarity == polarity[i])
        if np.any(mine):
            nearest = edges.t_px[mine][np.argmin(np.abs(edges.t_px[mine] - t[i]))] - t[i]
            offsets[i] = nearest if abs(nearest) <= MATCH_PX else np.nan
    found = np.isfinite(offsets)
    return float(np.mean(found)), offsets[found]


@pytest.mark.parametrize(("name", "bit"), sorted(EXPECTED))
def test_the_bit_frames_edges_are_found_where_their_crossings_with_the_sinusoids_mean_are(name: str, bit: int):
    recall, offsets = recall_and_offsets(name, bit)
    median, p95 = float(np.median(offsets)), float(np.percentile(np.abs(offsets), 95))
    print(f"{name} bit {bit}: recall {100 * recall:.1f} %, offset median {median:+.2f} px, |offset| p95 {p95:.2f} px")
    floor, median_ceiling, p95_ceiling = EXPECTED[(name, bit)]
    assert 100 * recall >= floor
    assert abs(median) <= median_ceiling and p95 <= p95_ceiling
