"""Calibrations in the job form (issue 27): the topography form offers only consistent pairs (the projector
calibrations built on the chosen camera calibration), names each calibration by id, camera and date with what a
projector calibration was built on, and marks a bad verdict. The form is the dashboard's own (jobForm, with the
server's schema of the topography spec), fed a camera's calibrations and pairs as GET /calibrations and
GET /calibrations/pairs list them."""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration]

SETUP = """async () => {
    const { jobForm, calibrationChoice, pairChoice } = await import("/views/jobs.js");
    const at = "2026-11-27T07:40:00Z";
    const listed = {
        camera: [
            { id: 2, kind: "camera", label: "camera calibration #2, camera 'left', 2026-11-27 07:40", verdict: "good",
              bad: false, summary: { rms_px: 0.051 }, created_at: at },
            { id: 1, kind: "camera", label: "camera calibration #1, camera 'left', 2026-11-27 07:20", verdict: "bad",
              bad: true, bad_reason: "f = 21.7 mm, far from the lens's", summary: { rms_px: 0.357 }, created_at: at },
        ],
        projector: [
            { id: 4, kind: "projector", label: "projector calibration #4, camera 'left', 2026-11-27 07:50",
              camera_calibration_id: 1, bad: true, bad_reason: "built on a bad camera calibration", summary: {},
              created_at: at },
            { id: 3, kind: "projector", label: "projector calibration #3, camera 'left', 2026-11-27 07:45",
              camera_calibration_id: 2, bad: false, summary: {}, created_at: at },
        ],
    };
    const form = jobForm({
        recordings: () => [{ id: 5, kind: "test", state: "ready", camera_id: 7, camera_name: "left",
                             filename: "punch.zip", frame_count: 20 }],
        // As GET /calibrations?camera_id=7&kind=... and GET /calibrations/pairs?camera_id=7 answer.
        calibrations: async (cameraId, kind) => {
            if (cameraId !== 7) return [];
            if (kind !== "pairs") return listed[kind].map(calibrationChoice);
            const byId = Object.fromEntries(listed.camera.map((c) => [c.id, c]));
            return listed.projector.map((p) => pairChoice({ camera_calibration: byId[p.camera_calibration_id],
                                                            projector_calibration: p, bad: p.bad }));
        },
        onStarted: () => {},
    });
    document.querySelector("main").append(form.element);
}"""


def test_the_topography_form_offers_only_consistent_pairs_and_marks_a_bad_verdict(page):
    page.goto("/#/system")
    expect(page.get_by_role("heading", name="System health")).to_be_visible()
    page.evaluate(SETUP)
    form = page.get_by_role("form", name="Start a job")
    form.get_by_label("Job kind").select_option(label="Topography")
    camera = form.get_by_label("Camera calibration")
    projector = form.get_by_label("Projector calibration")
    expect(camera.get_by_role("option")).to_have_text([
        "camera calibration #2, camera 'left', 2026-11-27 07:40 · RMS 0.051 px · good",
        "⚠ BAD: camera calibration #1, camera 'left', 2026-11-27 07:20 · RMS 0.357 px · f = 21.7 mm, far from the"
        " lens's",
    ])  # fmt: skip
    # The newest projector calibration (#4) is not offered with camera calibration #2: it was built on #1.
    expect(projector.get_by_role("option")).to_have_text([
        "projector calibration #3, camera 'left', 2026-11-27 07:45 · built on camera calibration #2",
    ])  # fmt: skip
    camera.select_option("1")
    expect(projector.get_by_role("option")).to_have_text([
        "⚠ BAD: projector calibration #4, camera 'left', 2026-11-27 07:50 · built on camera calibration #1 · built on"
        " a bad camera calibration",
    ])  # fmt: skip
    spec = form.get_by_label("Job spec (JSON)")
    expect(spec).to_contain_text('"projector_calibration_id": 4')
    # A bad calibration chosen: the job needs the person's explicit consent (the spec's accept_bad_calibration).
    consent = form.get_by_role("checkbox", name="Use it although its verdict is bad")
    expect(consent).to_be_visible()
    expect(consent).not_to_be_checked()
    assert consent.evaluate("(box) => box.required")
    expect(form).to_contain_text("⚠ BAD: camera calibration #1")  # which one, under the checkbox
    expect(spec).to_contain_text('"accept_bad_calibration": false')
    consent.check()
    expect(spec).to_contain_text('"accept_bad_calibration": true')
    screenshot(page, "calibration-pairs")
    camera.select_option("2")  # a good pair: no consent asked, none sent
    expect(consent).to_be_hidden()
    expect(spec).not_to_contain_text("accept_bad_calibration")
