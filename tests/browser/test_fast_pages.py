"""Fast pages: plotly.js (4.8 MB) is loaded only by a page that draws a plot, after its content; pages without a
plot never ask for it (their first content does not wait for it). bench/bench_pages.py times first content."""

from __future__ import annotations

import httpx
import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration]


def test_pages_without_a_plot_load_no_plotly_and_a_plot_loads_it_once(page, live_server):
    made = httpx.post(f"{live_server.base_url}/api/v1/experiments", json={"name": "Nothing measured yet"}, timeout=30)
    assert made.status_code == 201, made.text
    plotly_requests: list[str] = []
    page.on("request", lambda request: plotly_requests.append(request.url) if "plotly" in request.url else None)
    experiment_path = f"/#/experiments/{made.json()['id']}"
    pages = {
        "/#/experiments": "Experiments",
        experiment_path: "Nothing measured yet",
        "/#/jobs": "Jobs",
        "/#/queue": "Queue",
        "/#/tokens": "API tokens",
        "/#/system": "System health",
        "/#/help": "Help",
    }
    for path, heading in pages.items():
        page.goto(path)
        expect(page.get_by_role("heading", name=heading, level=1)).to_be_visible()
        page.wait_for_load_state("networkidle")  # every request the page makes has been made
    # An empty experiment says what a comparison needs instead of showing its form with an empty plot.
    page.goto(experiment_path)
    expect(page.get_by_text("Comparisons open here once this experiment has a succeeded topography")).to_be_visible()
    expect(page.get_by_role("form", name="Compare with a simulation")).to_have_count(0)
    page.wait_for_load_state("networkidle")
    screenshot(page, "empty-experiment")
    assert plotly_requests == [], f"a page without a plot asked for plotly.js: {plotly_requests}"

    # The first figure drawn loads it, once, however many figures ask at the same time.
    page.evaluate(
        """async () => {
        const plots = await import("/plots.js");
        const figures = [1, 2].map((i) => new plots.Figure({ name: `Figure ${i}`, filename: "f", csv: () => ({}) }));
        document.querySelector("main").append(...figures.map((f) => f.element));
        await Promise.all(figures.map((f) => f.react([{ x: [0, 1], y: [0, 1] }], plots.layout())));
    }"""
    )
    expect(page.get_by_role("img", name="Figure 2").locator(".main-svg").first).to_be_visible()
    assert len(plotly_requests) == 1 and plotly_requests[0].endswith(".min.js"), plotly_requests
