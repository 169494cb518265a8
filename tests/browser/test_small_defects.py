"""Small defects of the dashboard (issue 27), each checked where a person meets it: passing messages go away,
Help's table of contents is readable, "Add a camera" holds no made-up values, the scale factor names its axis."""

from __future__ import annotations

import httpx
import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration]
ACCENT = "rgb(31, 95, 174)"  # --accent: the links' colour on a light page


def test_a_passing_message_goes_and_an_error_stays(page):
    page.clock.install()
    page.goto("/#/system")
    expect(page.get_by_role("heading", name="System health")).to_be_visible()
    page.evaluate(
        """async () => {
        const ui = await import("/ui.js");
        ui.say("Camera left added.");
        ui.showError("the server is away", "list the jobs");
    }"""
    )
    expect(page.get_by_role("status")).to_have_text("Camera left added.")
    page.clock.fast_forward(7_000)
    expect(page.get_by_role("status")).to_have_text("Camera left added.")
    page.clock.fast_forward(2_000)  # past SAY_MS (8 s): off the plots it covered
    expect(page.get_by_role("status")).to_be_hidden()
    expect(page.get_by_role("alert")).to_contain_text("Could not list the jobs")  # an error waits to be dismissed


def test_help_contents_are_readable_and_add_a_camera_has_placeholders(page, live_server):
    page.goto("/#/help/method")
    contents = page.get_by_role("navigation", name="Sections")
    expect(contents.get_by_role("heading", name="Contents")).to_be_visible()
    link = contents.get_by_role("link", name="2. Conventions")
    expect(link).to_have_css("color", ACCENT)  # not the top bar's pale grey
    expect(link).to_have_css("font-size", "13px")
    screenshot(page, "help-contents", full_page=False)

    made = httpx.post(f"{live_server.base_url}/api/v1/experiments", json={"name": "Cameras"}, timeout=30).json()
    page.goto(f"/#/experiments/{made['id']}")
    form = page.get_by_role("form", name="Add a camera")
    for label, example in [
        ("Image width (px)", "e.g. 1024"),
        ("Image height (px)", "e.g. 1024"),
        ("Pixel pitch u (µm)", "e.g. 20"),
    ]:
        expect(form.get_by_label(label)).to_have_value("")
        expect(form.get_by_label(label)).to_have_attribute("placeholder", example)
    form.get_by_label("Camera name").fill("left")
    form.get_by_role("button", name="Add camera").click()  # the browser asks for the missing size and pitch
    assert form.get_by_label("Image width (px)").evaluate("(input) => input.validity.valueMissing")


def test_the_scale_factor_names_the_axis_it_scales(page):
    page.goto("/#/system")
    names = page.evaluate(
        """async () => {
        const { parameterName } = await import("/views/calibration.js");
        return [parameterName("su", { scale_on: "u" }), parameterName("su", { scale_on: "v" }),
                parameterName("f_mm", {})];
    }"""
    )
    assert names == ["scale factor s_u", "scale factor s_v", "focal length f"]


def test_a_gap_present_from_the_first_frame_is_outlined_but_not_the_area_off_the_plate(page):
    """The hard demo's highlight: missing in every frame, the first too; it is outlined as the hole is."""
    page.goto("/#/system")
    mask = page.evaluate(
        """async () => {
        const { missingOutlineTraces } = await import("/plot_fields.js");
        const rows = (values) => values.map((row) => Float32Array.from(row, (v) => (v === null ? NaN : v)));
        const x = [0, 1, 2, 3, 4];
        const y = [0, 1, 2];
        // Off the plate: columns 0 and 4; a highlight at (2, 1) from the first frame on; a hole at (3, 0) later.
        const reference = { x, y, z: rows([[null, 1, 1, 1, null], [null, 1, null, 1, null], [null, 1, 1, 1, null]]) };
        const frame = { x, y, z: rows([[null, 1, 1, null, null], [null, 1, null, 1, null], [null, 1, 1, 1, null]]) };
        return missingOutlineTraces(frame, reference)[0].z;
    }"""
    )
    assert mask == [[0, 0, 0, 1, 0], [0, 0, 1, 0, 0], [0, 0, 0, 0, 0]]
