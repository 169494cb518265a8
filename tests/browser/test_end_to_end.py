"""The whole path in real Chromium against a real server and prefork worker: create an experiment, upload the
simulated recordings of a virtual test through the page's own upload control, run the camera calibration,
projector calibration and topography jobs from the form and watch each reach 100 %, read the calibration report,
then open the topography viewer: move the slider, draw a section line, download the profile CSV and check its
numbers against the API; and time frame switches (fetch + Plotly.react of a 250 × 250 field)."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import httpx
import numpy as np
import pytest
from playwright.sync_api import expect

from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.slow]
PRESET = "kodak"  # 512 × 480 px: the quicker of the two virtual cameras
FRAMES = 12
SWITCHES = 20


@pytest.fixture(scope="module")
def virtual_test(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """The recordings of a virtual punch test (the `virtual-test` command's output), as ZIP files."""
    from fringelab.pipelines.virtual_test import write_virtual_test
    from fringelab.science.virtual_test import preset

    # Fewer calibration frames than the command's defaults keep the test quick: the board at 7 heights, the flat
    # plate every 4 mm (edges move ~0.6 px/mm on this camera: 4 mm is a quarter period, well inside what the
    # projector calibration accepts).
    made = write_virtual_test(
        tmp_path_factory.mktemp("virtual"),
        PRESET,
        n_test_frames=FRAMES,
        camera_z_mm=np.linspace(-20.0, 100.0, 7),
        calibration_z_mm=np.arange(0.0, 80.0 + 1e-9, 4.0),
        as_zip=True,
    )
    return made, preset(PRESET).camera


def upload(page, camera: str, kind_label: str, path: Path) -> None:
    region = page.get_by_role("region", name=f"Camera {camera}")
    region.get_by_label(f"Kind of the recordings to upload to {camera}").select_option(label=kind_label)
    region.get_by_label("Choose files").set_input_files([path])
    bar = region.get_by_role("progressbar", name=f"Upload progress of {path.name}")
    expect(bar).to_have_js_property("value", 100, timeout=60_000)


def start_job(page, kind_label: str) -> str:
    """Start a job from the experiment page's form with its defaults; wait until its bar shows 100 %."""
    form = page.get_by_role("form", name="Start a job")
    form.get_by_label("Job kind").select_option(label=kind_label)
    pickers = {"Camera calibration": ["Recording"], "Projector calibration": ["Recording", "Camera calibration"]}
    for label in pickers.get(kind_label, ["Recording", "Camera calibration", "Projector calibration"]):
        expect(form.get_by_label(label, exact=True)).not_to_have_value("")  # its choices have come
    expect(form.get_by_role("button", name="Start job")).to_be_enabled()
    with page.expect_response(lambda r: r.url.endswith("/api/v1/jobs") and r.request.method == "POST") as answer:
        form.get_by_role("button", name="Start job").click()
    job = answer.value.json()
    assert answer.value.status == 201, job
    bar = page.get_by_role("progressbar", name=f"Progress of {kind_label} {job['id'][:8]}")
    expect(bar).to_have_js_property("value", 1, timeout=240_000)
    row = page.get_by_role("table", name="Jobs of this experiment").get_by_role("row").filter(has=bar)
    expect(row).to_contain_text("100 %")
    expect(row).to_contain_text("succeeded")
    return job["id"]


def test_upload_calibrate_measure_and_explore(page, live_server, virtual_test):
    made, camera = virtual_test
    page.goto("/#/experiments")
    form = page.get_by_role("form", name="New experiment")
    form.get_by_label("Name").fill("Virtual punch test")
    form.get_by_label("Plate").fill("virtual plate, clamped at R = 50 mm")
    form.get_by_role("button", name="Create experiment").click()
    cameras = page.get_by_role("form", name="Add a camera")
    cameras.get_by_label("Camera name").fill(PRESET)
    cameras.get_by_label("Image width (px)").fill(str(camera.image_width_px))
    cameras.get_by_label("Image height (px)").fill(str(camera.image_height_px))
    cameras.get_by_label("Pixel pitch u (µm)").fill(f"{1000 / camera.du_px_per_mm:.6f}")
    cameras.get_by_role("button", name="Add camera").click()
    expect(page.get_by_role("region", name=f"Camera {PRESET}")).to_be_visible()

    upload(page, PRESET, "Camera calibration", made.camera_calibration)
    upload(page, PRESET, "Projector calibration", made.projector_calibration)
    upload(page, PRESET, "Test", made.test)
    table = page.get_by_role("table", name=f"Recordings of {PRESET}")
    for name in ("camera_calibration.zip", "projector_calibration.zip", "test.zip"):
        expect(table.get_by_role("row").filter(has_text=name)).to_contain_text("ready", timeout=120_000)

    camera_job = start_job(page, "Camera calibration")
    screenshot(page, "experiment-jobs")
    start_job(page, "Projector calibration")
    topography_job = start_job(page, "Topography")
    screenshot(page, "experiment-done")

    page.goto(f"/#/jobs/{camera_job}/report")
    expect(page.get_by_role("region", name="Verdict")).to_be_visible(timeout=30_000)
    expect(page.get_by_role("table", name="Camera parameters")).to_contain_text("±")
    expect(page.get_by_role("img", name="Residual vectors over the image")).to_be_visible()
    screenshot(page, "calibration-report")

    page.goto(f"/#/jobs/{topography_job}/viewer")
    slider = page.get_by_role("slider", name="Frame")
    expect(slider).to_be_visible(timeout=30_000)
    page.wait_for_function("() => window.fringelab.frameSwitchMs.length >= 1")
    slider.focus()
    last = FRAMES - 1
    slider.press("End")
    expect(page.get_by_role("spinbutton", name="Frame number")).to_have_value(str(last))

    # Draw a section line across the middle of the measured area, over 80 % of its width.
    grid = httpx.get(f"{live_server.base_url}/api/v1/jobs/{topography_job}/topography", timeout=30).json()["grid"]
    x_mid, y_mid = (grid["x_min_mm"] + grid["x_max_mm"]) / 2, (grid["y_min_mm"] + grid["y_max_mm"]) / 2
    half = 0.4 * (grid["x_max_mm"] - grid["x_min_mm"])
    to_screen = """async ([x, y]) => {
        const fields = await import("/plot_fields.js");
        return fields.screenPoint(document.querySelector("#field-map .plot-area"), x, y);
    }"""
    page.get_by_role("img", name="Deflection map").scroll_into_view_if_needed()
    start = page.evaluate(to_screen, [x_mid - half, y_mid])
    end = page.evaluate(to_screen, [x_mid + half, y_mid])
    page.mouse.move(start["x"], start["y"])
    page.mouse.down()
    page.mouse.move(end["x"], end["y"], steps=6)
    page.mouse.up()
    expect(page.get_by_role("list", name="Section lines")).to_contain_text("A")
    profiles = page.get_by_role("img", name="Section profiles")
    expect(profiles.locator(".scatterlayer .trace")).to_have_count(2)  # the profile and its ±2σ_w band

    screenshot(page, "viewer")
    with page.expect_download() as download:
        page.get_by_role("button", name="Download Section profiles CSV").click()
    rows = list(csv.DictReader(io.StringIO(download.value.path().read_text())))
    assert {row["frame"] for row in rows} == {str(last)}
    line = page.evaluate("() => window.fringelab.viewer.lines[0]")
    answer = httpx.get(
        f"{live_server.base_url}/api/v1/jobs/{topography_job}/topography/profile",
        params={
            "x0_mm": line["x0"],
            "y0_mm": line["y0"],
            "x1_mm": line["x1"],
            "y1_mm": line["y1"],
            "frames": [last],
            "n_points": 300,
        },
        timeout=30,
    ).json()
    api_w = answer["profiles"][0]["w_mm"]
    assert len(rows) == len(api_w)
    for row, s_mm, w_mm in zip(rows, answer["s_mm"], api_w, strict=True):
        assert float(row["s_mm"]) == pytest.approx(s_mm, abs=1e-9)
        if w_mm is None:
            assert row["w_mm"] in ("", "NaN")
        else:
            assert float(row["w_mm"]) == pytest.approx(w_mm, abs=1e-9)  # the same numbers, not a resampling
    assert any(w is not None and w > 1.0 for w in api_w), f"the last frame's profile shows the punch's dome: {api_w}"

    # What each frame measured: the coverage plot, its CSV equal to the API's numbers, every frame of the virtual
    # test measured almost whole and no order conflict.
    coverage = page.get_by_role("img", name="Coverage over time")
    coverage.scroll_into_view_if_needed()
    expect(coverage).to_be_visible()
    with page.expect_download() as download:
        page.get_by_role("button", name="Download Coverage over time CSV").click()
    coverage_rows = list(csv.DictReader(io.StringIO(download.value.path().read_text())))
    overview = httpx.get(f"{live_server.base_url}/api/v1/jobs/{topography_job}/topography", timeout=30).json()
    assert [float(row["measured_fraction"]) for row in coverage_rows] == pytest.approx(overview["measured_fraction"])
    assert min(overview["measured_fraction"]) > 0.9 and not any(overview["n_order_conflicts"])
    # The peak is measured while the dome's top is; from the perforation on, the maximum lies on the hole's rim:
    # a lower bound, never counted as measured (docs/method.md §8).
    perforation = json.loads(made.truth_json.read_text())["perforation_frame"]
    assert all(overview["peak_measured"][: FRAMES // 2]) and not any(overview["peak_measured"][perforation:])

    # Frame switches: each move of the slider fetches, decodes and draws the field and the profile (its timing is
    # bench/bench_pages.py's).
    page.evaluate("() => { window.fringelab.frameSwitchMs = []; }")
    for i in range(SWITCHES):
        slider.press("ArrowLeft" if (i // last) % 2 == 0 else "ArrowRight")
        page.wait_for_function(f"() => window.fringelab.frameSwitchMs.length >= {i + 1}")

    # Playback moves the frames on by itself until paused.
    frame_number = page.get_by_role("spinbutton", name="Frame number")
    shown = frame_number.input_value()
    page.get_by_role("button", name="Play").click()
    expect(frame_number).not_to_have_value(shown)
    page.get_by_role("button", name="Pause").click()
    expect(page.get_by_role("button", name="Play")).to_be_visible()
    page.get_by_role("tab", name="3-D surface").click()
    expect(page.get_by_role("img", name="Deflection surface")).to_be_visible()
    screenshot(page, "viewer-surface")
