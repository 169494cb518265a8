"""The projector calibration report of the shared demo (conftest.py): it names the camera calibration the table
was built on, and its coverage-over-Z plot shows its whole axis title (it was clipped)."""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.slow]


def test_the_projector_report_names_its_camera_calibration_and_shows_its_axis_titles(page, demo):
    job = demo["jobs"][("projector_calibration", "kodak")]
    page.goto(f"/#/jobs/{job['id']}/report")
    heading = page.get_by_role("heading", name=f"Projector calibration {job['result']['calibration_id']} ")
    expect(heading).to_be_visible(timeout=30_000)
    expect(page.get_by_text(f"Built on camera calibration #{job['spec']['camera_calibration_id']}.")).to_be_visible()
    coverage = page.get_by_role("img", name="Coverage over Z")
    title = coverage.locator("text.ytitle")
    expect(title).to_have_text("entries (%)", timeout=60_000)  # drawn after the curves and the maps
    title.scroll_into_view_if_needed()
    plot, box = coverage.bounding_box(), title.bounding_box()
    assert plot and box and box["y"] >= plot["y"] and box["y"] + box["height"] <= plot["y"] + plot["height"]
    screenshot(page, "projector-report")
