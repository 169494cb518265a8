"""The page shell in real Chromium: health shown, plotly.js served locally, nothing from the internet."""

from __future__ import annotations

import pytest

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration]


def test_health_page_shows_every_part_up_without_internet(page, live_server):
    requested: list[str] = []
    page.on("request", lambda request: requested.append(request.url))
    page.goto("/")
    status = page.get_by_role("status")
    status.filter(has_text="All parts are up.").wait_for(timeout=15_000)
    assert page.evaluate("typeof window.Plotly") == "object"
    assert int(page.locator("#health-workers").inner_text()) >= 1
    assert all(url.startswith(live_server.base_url) for url in requested), requested
    screenshot(page, "health")
