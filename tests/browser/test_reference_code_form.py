"""The topography form offers a Gray code recorded at rest (docs/procam.md §5): the ready coded recordings of the
test recording's camera, or none, and the clamp circle for a view without the clamp ring; both come into the spec
as the server's schema names them. The form is the dashboard's own (jobForm, with the server's schema)."""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

pytestmark = [pytest.mark.browser, pytest.mark.integration]

SETUP = """async () => {
    const { jobForm } = await import("/views/jobs.js");
    const form = jobForm({
        recordings: () => [
            { id: 5, kind: "test", state: "ready", camera_id: 7, camera_name: "left", filename: "punch.zip",
              frame_count: 20 },
            { id: 8, kind: "coded", state: "ready", camera_id: 7, camera_name: "left", filename: "at-rest.zip",
              frame_count: 11 },
            { id: 9, kind: "coded", state: "ingesting", camera_id: 7, camera_name: "left", filename: "later.zip",
              frame_count: 11 },
            { id: 10, kind: "coded", state: "ready", camera_id: 6, camera_name: "right", filename: "other.zip",
              frame_count: 11 },
        ],
        calibrations: async () => [],
        onStarted: () => {},
    });
    document.querySelector("main").append(form.element);
}"""


def test_the_topography_form_offers_the_code_at_rest_of_the_tests_camera(page):
    page.goto("/#/system")
    expect(page.get_by_role("heading", name="System health")).to_be_visible()
    page.evaluate(SETUP)
    form = page.get_by_role("form", name="Start a job")
    form.get_by_label("Job kind").select_option(label="Topography")
    code = form.get_by_label("Gray code at rest")
    expect(code).to_be_visible(timeout=30_000)  # the form is built from the server's schema (slow when loaded)
    expect(code.get_by_role("option")).to_have_text(
        ["none (the projector table's match)", "#8 at-rest.zip (11 frames)"]
    )
    spec = form.get_by_label("Job spec (JSON)")
    expect(spec).not_to_contain_text("reference_code_recording_id")  # none: the server's default
    code.select_option("8")
    expect(spec).to_contain_text('"reference_code_recording_id": 8')
    circle = form.get_by_role("group", name="Rim circle (mm)")
    for i, value in enumerate(("8", "-5", "250")):
        circle.get_by_label(f"Rim circle (mm), value {i + 1}").fill(value)
    form.get_by_label("Job kind").focus()  # the spec view follows the inputs
    expect(spec).to_contain_text('"rim_circle_mm"')
