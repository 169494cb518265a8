"""The "Load demo experiment" button: a newcomer gets a virtual test whose recordings are simulated,
checked, calibrated and measured by the real worker, and reaches the topography viewer. It picks one of the hard
virtual tests (fast motion, springback at perforation), which the worker simulates as chosen; the quasi-static
default is the shared demo of the other browser tests (conftest.py)."""

from __future__ import annotations

import re
import time

import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.slow]


def test_load_demo_experiment_to_the_topography_viewer(page, capsys):
    page.goto("/#/experiments")
    page.get_by_label("Virtual cameras").select_option(label="Kodak only (under a minute)")
    page.get_by_label("Virtual test").select_option(value="fast")
    began = time.monotonic()
    page.get_by_role("button", name="Load demo experiment").click()
    expect(page.get_by_role("heading", name=re.compile(r"^Demo: virtual punch test, fast"))).to_be_visible()
    camera = page.get_by_role("region", name="Camera kodak")
    expect(camera).to_be_visible(timeout=30_000)  # the worker adds it, then simulates its recordings
    recordings = camera.get_by_role("table", name="Recordings of kodak")
    expect(recordings.get_by_role("row").filter(has_text="test.zip")).to_contain_text("ready", timeout=120_000)
    jobs = page.get_by_role("table", name="Jobs of this experiment")
    topography = jobs.get_by_role("row").filter(has_text="Topography")
    expect(topography).to_contain_text("succeeded", timeout=120_000)
    took_s = time.monotonic() - began
    expect(jobs.get_by_role("row").filter(has_text="Camera calibration")).to_contain_text("succeeded")
    expect(jobs.get_by_role("row").filter(has_text="Projector calibration")).to_contain_text("succeeded")
    screenshot(page, "demo-experiment")
    with capsys.disabled():
        print(f"\ndemo (kodak only, fast test): results {took_s:.0f} s after the click")

    topography.get_by_role("link", name="Topography viewer").click()
    expect(page.get_by_role("slider", name="Frame")).to_be_visible(timeout=30_000)
    expect(page.get_by_role("img", name="Peak deflection and force")).to_be_visible()
    screenshot(page, "demo-viewer")
