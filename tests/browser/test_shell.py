"""The app shell in real Chromium: navigation, health, errors in the status region, nothing from the internet;
and the plot helpers (section lines drawn by dragging on the map, points by clicking, CSV and PNG downloads)."""

from __future__ import annotations

import csv
import io

import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration]


def test_system_page_shows_every_part_up_without_internet(page, live_server):
    requested: list[str] = []
    page.on("request", lambda request: requested.append(request.url))
    page.goto("/#/system")
    expect(page.get_by_role("heading", name="System health")).to_be_visible()
    health = page.get_by_role("table", name="Health of each part")
    expect(health.get_by_role("row", name="Database up")).to_be_visible(timeout=15_000)
    expect(health.get_by_role("row", name="Redis up")).to_be_visible()
    expect(page.get_by_role("contentinfo")).to_contain_text("All parts are up")
    expect(page.get_by_role("link", name="System", exact=True)).to_have_attribute("aria-current", "page")
    assert page.evaluate("typeof window.Plotly") == "undefined"  # no plot here: plotly.js is not loaded
    assert page.evaluate("typeof window.tus.Upload") == "function"
    assert all(url.startswith(live_server.base_url) for url in requested), requested
    screenshot(page, "system")


def test_an_api_error_is_shown_in_the_alert_region(page, expected_console_errors):
    expected_console_errors.append(r"^404 GET .*/api/v1/jobs/no-such-job$")
    page.goto("/#/jobs/no-such-job")
    expect(page.get_by_role("alert")).to_contain_text("Could not open the job")
    page.get_by_role("button", name="Dismiss the error").click()
    expect(page.get_by_role("alert")).to_be_hidden()
    page.goto("/#/no/such/page")
    expect(page.get_by_role("heading", name="Not found")).to_be_visible()


def test_map_turns_drags_into_section_lines_and_clicks_into_points(page, tmp_path):
    """Mouse gestures on a real Plotly heatmap give back data coordinates (mm) within half a pixel's worth."""
    page.goto("/#/system")
    page.evaluate(
        """async () => {
        const plots = await import("/plots.js");
        const fields = await import("/plot_fields.js");
        const x = Array.from({ length: 101 }, (_, i) => i * 0.5);      // 0 .. 50 mm
        const y = Array.from({ length: 81 }, (_, j) => -20 + j * 0.5);   // -20 .. 20 mm
        const z = y.map((yy) => Float32Array.from(x, (xx) => xx * 0.01 + yy * 0.1));
        const figure = new plots.Figure({
            name: "Test map", filename: "test-map",
            csv: () => ({ columns: ["x_mm", "y_mm", "w_mm"], rows: fields.fieldRows({ x, y, z }) }),
        });
        document.querySelector("main").append(figure.element);
        window.gestures = { lines: [], points: [] };
        window.testFigure = figure;
        window.fields = fields;
        await figure.react(fields.mapTraces({ x, y, z }), fields.mapLayout());
        fields.listenToMap(figure, {
            onLine: (line) => window.gestures.lines.push(line),
            onPoint: (point) => window.gestures.points.push(point),
        });
    }"""
    )
    page.get_by_role("img", name="Test map").scroll_into_view_if_needed()
    to_screen = "([x, y]) => window.fields.screenPoint(window.testFigure.plot, x, y)"
    start = page.evaluate(to_screen, [10.0, -10.0])
    end = page.evaluate(to_screen, [40.0, 15.0])
    page.mouse.move(start["x"], start["y"])
    page.mouse.down()
    page.mouse.move((start["x"] + end["x"]) / 2, (start["y"] + end["y"]) / 2, steps=4)
    page.mouse.move(end["x"], end["y"], steps=4)
    page.mouse.up()
    click = page.evaluate(to_screen, [25.0, 5.0])
    page.mouse.click(click["x"], click["y"])
    page.wait_for_function("window.gestures.lines.length === 1 && window.gestures.points.length === 1", timeout=5000)
    gestures = page.evaluate("window.gestures")
    mm_per_px = page.evaluate(
        "() => 50 / window.testFigure.plot.querySelector('.nsewdrag').getBoundingClientRect().width"
    )
    tolerance = 1.5 * mm_per_px  # the mouse lands on whole pixels; Plotly rounds once more when drawing
    line = gestures["lines"][0]
    assert line["x0"] == pytest.approx(10, abs=tolerance) and line["y0"] == pytest.approx(-10, abs=tolerance)
    assert line["x1"] == pytest.approx(40, abs=tolerance) and line["y1"] == pytest.approx(15, abs=tolerance)
    point = gestures["points"][0]
    assert point["x"] == pytest.approx(25, abs=tolerance) and point["y"] == pytest.approx(5, abs=tolerance)

    with page.expect_download() as csv_download:
        page.get_by_role("button", name="Download Test map CSV").click()
    rows = list(csv.reader(io.StringIO(csv_download.value.path().read_text())))
    assert rows[0] == ["x_mm", "y_mm", "w_mm"]
    assert len(rows) == 1 + 101 * 81
    x_mm, y_mm, w_mm = map(float, rows[1 + 101 * 3 + 7])  # row j=3, column i=7
    assert (x_mm, y_mm) == (3.5, -18.5)
    assert w_mm == pytest.approx(3.5 * 0.01 - 18.5 * 0.1, abs=1e-6)  # float32 rounding of the field
    with page.expect_download() as png_download:
        page.get_by_role("button", name="Download Test map PNG").click()
    assert png_download.value.suggested_filename == "test-map.png"
    assert png_download.value.path().read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    screenshot(page, "plot-helpers")
