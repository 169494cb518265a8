"""What was not measured is drawn as not measured (issue 27), in real Chromium with the viewer's own panels fed a
small known result: a frame whose peak was not measured is a gap marked on the curve's line of missing values (the
value between its measured neighbours, never w = 0), its lower bound a lower bound; camera against camera draws
no difference for a frame either camera did not measure (the server's answer, GET .../against/{id}), and lists it
with why."""

from __future__ import annotations

import math

import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration]

LOWER_BOUND = "data missing within 10 mm of the maximum (12 grid nodes): the value is a lower bound"
# Six frames, 2 mm of punch travel apart; the peak of frames 3 and 4 not measured (3 has a lower bound, 4 nothing).
SETUP = """async ([lowerBoundReason]) => {
    const { PeakPanel } = await import("/views/viewer/peak.js");
    const { CamerasPanel } = await import("/views/viewer/cameras.js");
    const { HistoriesPanel } = await import("/views/viewer/histories.js");
    const { ProfilesPanel } = await import("/views/viewer/profiles.js");
    const meta = (peaks, reasons, lower) => ({
        grid: { step_mm: 2 },
        frames: { index: [0, 1, 2, 3, 4, 5], time_s: [0, 0.1, 0.2, 0.3, 0.4, 0.5],
                  punch_displacement_mm: [0, 2, 4, 6, 8, 10], force_kN: [0, 1, 2, 3, 4, 5], peak_w_mm: peaks,
                  peak_w_lower_bound_mm: lower, peak_reason: reasons },
        coverage: { peak_measured: peaks.map((w) => Number.isFinite(w)) },
    });
    const none = [NaN, NaN, NaN, NaN, NaN, NaN];
    const ours = meta([0, 2, 4, NaN, NaN, 10], [null, null, null, lowerBoundReason, "no data near the axis", null],
                      [NaN, NaN, NaN, 5.5, NaN, NaN]);
    const theirs = meta([0, 2.1, NaN, 6.1, 8.1, 10.1], [null, null, "shadow over the dome top", null, null, null],
                        none);
    const history = { frame: [0, 1, 2, 3, 4, 5], time_s: ours.frames.time_s, w: [0, 1, NaN, NaN, 4, 5],
                      sigma: [0.1, 0.1, NaN, NaN, 0.2, 0.2] };
    const points = [{ label: "P1", x: 0, y: 0, color: "#111111", history }];
    const viewer = { job: { id: "0123456789ab" }, meta: ours, frames: ours.frames.index, position: 5, lines: [],
                     points, context: { current: () => true } };
    // The server's camera against camera (GET .../against/{id}), as the API answers for these two results.
    viewer.source = { against: async (otherJobId) => (otherJobId !== "fedcba987654" ? null : {
        frames: [0, 1, 2, 3, 4, 5], difference_w_mm: [0, -0.1, NaN, NaN, NaN, -0.1], n_compared: 3,
        left_out_frames: [{ frame: 2, reason: "the other camera did not measure the peak at this instant" },
                          { frame: 3, reason: "this camera did not measure the peak (a lower bound)" },
                          { frame: 4, reason: "this camera did not measure the peak (a lower bound)" }] }) };
    const peak = new PeakPanel(viewer);
    const cameras = new CamerasPanel(viewer);
    cameras.label = "camera kodak";
    cameras.comparison = { label: "camera phantom", meta: theirs, source: { job: { id: "fedcba987654" } } };
    cameras.element.hidden = false;
    const histories = new HistoriesPanel(viewer);
    const profiles = new ProfilesPanel(viewer);
    ours.w_range_mm = [0, 10];
    document.querySelector("main").append(peak.figure.element, profiles.figure.element, histories.figure.element,
                                          cameras.element);
    await histories.draw();
    const profile = { s: [0, 10, 20, 30], x: [0, 10, 20, 30], y: [0, 0, 0, 0], w: [9, 8, NaN, 5],
                      sigma: [0.25, 0.5, 0.5, 0.5] };
    await profiles.draw([{ line: { label: "A", color: "#e6a100" }, frame: 5, profile }]);
    await peak.draw();
    await cameras.draw();
    // A recording without frames.csv: no punch travel, no force; the peak plot's title and note say so.
    const bare = meta([0, 2, 4, 6, 8, 10], [null, null, null, null, null, null], none);
    bare.frames.punch_displacement_mm = none;
    bare.frames.force_kN = none;
    bare.notes = ["no punch displacement or force for any frame: the recording has no frames.csv with those columns"];
    const withoutLog = new PeakPanel({ ...viewer, meta: bare });
    document.querySelector("main").append(withoutLog.figure.element);
    await withoutLog.draw();
    window.panels = { peak, cameras, histories, profiles, withoutLog };
}"""
TRACE = "([panel, name]) => { const t = window.panels[panel].figure.plot.data.find((d) => d.name === name); return t ? { x: Array.from(t.x), y: Array.from(t.y) } : null; }"  # noqa: E501


def gap(value: float | None) -> bool:
    return value is None or math.isnan(value)


def test_unmeasured_peaks_are_gaps_marked_on_the_line_and_cameras_compare_only_what_both_measured(page):
    page.goto("/#/system")
    expect(page.get_by_role("heading", name="System health")).to_be_visible()
    page.evaluate(SETUP, [LOWER_BOUND])
    expect(page.get_by_role("img", name="Camera against camera").locator(".main-svg").first).to_be_visible()

    marks = page.evaluate(TRACE, ["peak", "peak not measured"])
    # On the line between frame 2 (4 mm at 4 mm of travel) and frame 5 (10 mm at 10 mm): 6 and 8 mm, not 0.
    assert marks["x"] == [6, 8] and marks["y"] == pytest.approx([6, 8])
    lower = page.evaluate(TRACE, ["peak", "lower bound (peak not measured)"])
    assert lower == {"x": [6], "y": [5.5]}
    curve = page.evaluate(TRACE, ["peak", "peak deflection"])
    assert gap(curve["y"][3]) and gap(curve["y"][4])  # gaps, not drops

    # A point not measured in frames 2 and 3: marked on its line, between 1 mm (100 ms) and 4 mm (400 ms).
    history = page.evaluate(TRACE, ["histories", "P1 not measured"])
    assert history["x"] == pytest.approx([200, 300]) and history["y"] == pytest.approx([2, 3])

    # ±2σ_w bands: one closed polygon per run of known values (upper edge out, lower edge back), a gap kept a gap.
    band = page.evaluate(TRACE, ["profiles", "A, t = 500.000 ms ±2σ_w"])
    assert band["x"] == [0, 10, 10, 0, None]  # the lone sample after the gap makes no polygon
    assert band["y"][:4] == pytest.approx([9 + 0.5, 8 + 1, 8 - 1, 9 - 0.5])
    band = page.evaluate(TRACE, ["histories", "P1 ±2σ_w"])
    assert band["x"][:4] == pytest.approx([0, 100, 100, 0]) and band["x"][4] is None  # ms; a polygon per run
    assert band["y"][:4] == pytest.approx([0.2, 1.2, 0.8, -0.2])

    difference = page.evaluate(TRACE, ["cameras", "difference (this − other)"])["y"]
    assert difference[0] == pytest.approx(0) and difference[1] == pytest.approx(-0.1)
    assert all(gap(d) for d in difference[2:5]) and difference[5] == pytest.approx(-0.1)
    left_out = page.get_by_role("list", name="Frames left out of the difference").get_by_role("listitem")
    expect(left_out).to_have_text([
        "Frame 2: the other camera did not measure the peak at this instant",
        "Frame 3: this camera did not measure the peak (a lower bound)",
        "Frame 4: this camera did not measure the peak (a lower bound)",
    ])  # fmt: skip
    stats = page.get_by_label("Difference between the cameras")
    expect(stats).to_contain_text("largest 0.100 mm over 3 points where both measured")
    expect(stats).to_contain_text("Compared: 3 of 6 frames; left out: 3")
    # Without a test log: titled for what it shows (no "and force"), its x axis time, and a note why.
    bare = page.get_by_role("figure", name="Peak deflection", exact=True)
    expect(bare.get_by_role("button", name="Download Peak deflection CSV")).to_be_visible()
    expect(bare).to_contain_text("no punch displacement or force for any frame: the recording has no frames.csv")
    expect(bare).to_contain_text("time (ms)")
    screenshot(page, "peak-marks")
