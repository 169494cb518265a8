"""A lab's day in the dashboard, on a demo experiment with two virtual cameras measured by the real worker: the
viewer's notices never move the page, the colour range follows the view on demand, every CSV names the grid it
holds, camera against camera shows the difference (map and curves, distinct line styles), the projector report's
sensitivity map lies on the image, and the small texts say what they mean (no stage on a finished job, yes/no
for the solver, no "No warnings" followed by something that reads like one).

One demo (both cameras, few frames; the `demo` fixture of conftest.py) is shared by every test; each test is one
or two page loads with several checks."""

from __future__ import annotations

import csv
import io
import math
import re

import httpx
import numpy as np
import pytest
from playwright.sync_api import expect

from tests.browser.conftest import DEMO_TIMEOUT_S, screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.slow]


def download_csv(page, button_name: str) -> tuple[str, list[dict[str, str]]]:  # type: ignore[no-untyped-def]
    with page.expect_download() as download:
        page.get_by_role("button", name=button_name).click()
    text = download.value.path().read_text()
    return download.value.suggested_filename, list(csv.DictReader(io.StringIO(text)))


TO_SCREEN = """async ([x, y]) => {
    const fields = await import("/plot_fields.js");
    return fields.screenPoint(document.querySelector("#field-map .plot-area"), x, y);
}"""


def test_viewer_keeps_still_colours_follow_the_view_csvs_name_their_grid(page, demo):
    job = demo["jobs"][("topography", "kodak")]
    grid = httpx.get(f"{demo['base']}/jobs/{job['id']}/topography", timeout=30).json()["grid"]
    page.goto(f"/#/jobs/{job['id']}/viewer")
    expect(page.get_by_role("slider", name="Frame")).to_be_visible(timeout=30_000)
    page.wait_for_function("() => window.fringelab.frameSwitchMs.length >= 1")
    the_map = page.get_by_role("img", name="Deflection map")
    the_map.scroll_into_view_if_needed()
    before = the_map.bounding_box()

    # A section line across the plate: its notice appears, and nothing under the pointer moves.
    x_mid, y_mid = (grid["x_min_mm"] + grid["x_max_mm"]) / 2, (grid["y_min_mm"] + grid["y_max_mm"]) / 2
    half = 0.4 * (grid["x_max_mm"] - grid["x_min_mm"])
    start = page.evaluate(TO_SCREEN, [x_mid - half, y_mid + 30])
    end = page.evaluate(TO_SCREEN, [x_mid + half, y_mid + 30])
    page.mouse.move(start["x"], start["y"])
    page.mouse.down()
    page.mouse.move(end["x"], end["y"], steps=6)
    page.mouse.up()
    expect(page.locator("#status")).to_contain_text("Section line A")
    assert the_map.bounding_box() == before, "the map moved when the notice appeared"
    # The next click lands where it was aimed: the point added is within one display cell of the aim.
    aim = (x_mid + 40.0, y_mid - 50.0)
    target = page.evaluate(TO_SCREEN, list(aim))
    page.mouse.click(target["x"], target["y"])
    expect(page.get_by_role("list", name="Points")).to_contain_text("P1")
    point = page.evaluate("() => window.fringelab.viewer.points[0]")
    cell_mm = 2 * grid["step_mm"] * 2  # a display node is a block of result nodes; a screen pixel is far less
    assert math.hypot(point["x"] - aim[0], point["y"] - aim[1]) < cell_mm, (point, aim)
    expect(page.locator("#status")).to_contain_text("Point P1")
    assert the_map.bounding_box() == before

    # Zoom into a 60 mm square off the centre; with the switch on, the colours span what is in view.
    page.evaluate(
        """async ([x0, x1, y0, y1]) => {
            await Plotly.relayout(document.querySelector("#field-map .plot-area"),
                {"xaxis.range": [x0, x1], "yaxis.range": [y0, y1]});
        }""",
        [x_mid + 100, x_mid + 160, y_mid - 30, y_mid + 30],
    )
    whole = page.evaluate("() => window.fringelab.viewer.shownColorRange")
    page.get_by_label("Colour range of this view").check()
    page.wait_for_function("() => window.fringelab.viewer.shownColorRange[1] < window.fringelab.viewer.colorRange[1]")
    in_view = page.evaluate(
        """([x0, x1, y0, y1]) => {
            const trace = document.querySelector("#field-map .plot-area").data[0];
            const values = [];
            trace.z.forEach((row, j) => row.forEach((w, i) => {
                const x = trace.x[i], y = trace.y[j];
                if (x >= x0 && x <= x1 && y >= y0 && y <= y1 && Number.isFinite(w)) values.push(w);
            }));
            const [lo, hi] = [Math.min(...values), Math.max(...values)];
            return { lo, hi, zmin: trace.zmin, zmax: trace.zmax, n: values.length };
        }""",
        [x_mid + 100, x_mid + 160, y_mid - 30, y_mid + 30],
    )
    assert in_view["n"] > 20
    # Exact: the range is the extremes of the values shown (float32 in the page either way).
    assert in_view["zmin"] == pytest.approx(in_view["lo"], abs=1e-6)
    assert in_view["zmax"] == pytest.approx(in_view["hi"], abs=1e-6)
    assert in_view["zmax"] - in_view["zmin"] < 0.5 * (whole[1] - whole[0]), (in_view, whole)
    screenshot(page, "viewer-colour-range-of-this-view")

    # The map's CSV is the display grid and says so (name and columns); the profile CSV is the result grid.
    name, rows = download_csv(page, "Download Deflection map CSV")
    display_step = float(rows[0]["grid_step_mm"])
    assert display_step > grid["step_mm"], "the map is block-averaged for display"
    assert f"display-grid-{display_step:.2f}mm" in name, name
    assert rows[0]["grid"].startswith("display") and f"{grid['step_mm']:.2f} mm result grid" in rows[0]["grid"]
    xs = sorted({float(row["x_mm"]) for row in rows})
    assert xs[1] - xs[0] == pytest.approx(display_step, rel=1e-9)
    _, profile_rows = download_csv(page, "Download Section profiles CSV")
    assert {row["grid"] for row in profile_rows} == {"result"}
    assert {float(row["grid_step_mm"]) for row in profile_rows} == {grid["step_mm"]}
    _, history_rows = download_csv(page, "Download Point histories CSV")
    assert history_rows and {row["grid"] for row in history_rows} == {"result"}
    _, peak_rows = download_csv(page, "Download Peak deflection and force CSV")
    assert {row["grid"] for row in peak_rows} == {"result"}


def test_camera_against_camera_difference_map_and_curves(page, demo):
    job = demo["jobs"][("topography", "kodak")]
    page.goto(f"/#/jobs/{job['id']}/viewer")
    section = page.get_by_role("region", name="Camera against camera")
    expect(section.get_by_label("Compare with the topography of")).to_contain_text("camera phantom", timeout=30_000)
    figure = section.get_by_role("img", name="Camera against camera")
    expect(section.get_by_label("Difference between the cameras")).to_contain_text("Compared:", timeout=30_000)
    expect(figure.locator(".scatterlayer .trace").nth(2)).to_be_attached()
    # The three curves; the marks of frames a camera did not measure the peak of come after them, when there are any.
    styles = page.evaluate(
        """() => document.querySelector("#view section[aria-label='Camera against camera'] .plot-area").data
            .filter((t) => !/peak not measured/.test(t.name)).map((t) => [t.name, t.line.dash, t.yaxis])"""
    )
    assert len(styles) == 3, styles
    assert len({dash for _, dash, _ in styles}) == 3, f"three distinct line styles: {styles}"
    assert styles[2][0].startswith("difference") and styles[2][2] == "y2"
    expect(section.get_by_label("Difference between the cameras")).to_contain_text("RMS")
    screenshot(page, "camera-against-camera-curves")

    section.get_by_label("Compare", exact=True).select_option(label="difference map, this frame")
    expect(section.get_by_label("Difference between the cameras")).to_contain_text("Difference map")
    difference = page.evaluate(
        """() => {
            const section = document.querySelector("#view section[aria-label='Camera against camera']");
            const trace = section.querySelector(".plot-area").data[0];
            const values = trace.z.flatMap((row) => Array.from(row).filter(Number.isFinite));
            return { type: trace.type, n: values.length,
                     rms: Math.sqrt(values.reduce((a, d) => a + d * d, 0) / values.length) };
        }"""
    )
    assert difference["type"] == "heatmap" and difference["n"] > 1000, difference
    # Both cameras measure the same simulated plate: METHOD.md's accuracy target is 0.10 mm RMS over the dome for
    # each camera, so their difference stays within 2 × 0.10 mm.
    assert difference["rms"] < 0.2, difference
    name, rows = download_csv(page, "Download Camera against camera CSV")
    assert "difference" in name and "display-grid" in name
    row = next(r for r in rows if r["difference_w_mm"])
    assert float(row["difference_w_mm"]) == pytest.approx(float(row["w_mm"]) - float(row["other_w_mm"]), abs=1e-5)
    section.scroll_into_view_if_needed()
    screenshot(page, "camera-against-camera-difference-map")


def test_reports_and_small_texts(page, demo):
    from fringelab.science.camera import camera_centre_obj_mm
    from fringelab.science.virtual_test import preset

    camera_job = demo["jobs"][("camera_calibration", "kodak")]
    page.goto(f"/#/jobs/{camera_job['id']}/report")
    checks = page.get_by_role("table", name="Verdict checks")
    solver = checks.get_by_role("row").filter(has_text=re.compile(r"^solver"))
    expect(solver).to_contain_text("yes")
    expect(solver).not_to_contain_text("1.000")
    # The pose both ways, each labelled: the camera centre in plate coordinates is the simulated camera's.
    calibration_id = camera_job["result"]["calibration_id"]
    pose = httpx.get(f"{demo['base']}/calibrations/{calibration_id}/report", timeout=30).json()["report"]["pose"]
    truth = camera_centre_obj_mm(preset("kodak").camera)
    # 1 % of the 2 m camera distance: the calibrated distance moves with f, whose standard error the verdict
    # accepts up to 0.5 %.
    distance = float(np.linalg.norm(truth))
    assert np.linalg.norm(np.array(pose["camera_centre_in_object_mm"]) - truth) < 0.01 * distance, (pose, truth)
    shown = ", ".join("0.0" if f"{v:.1f}" == "-0.0" else f"{v:.1f}" for v in pose["camera_centre_in_object_mm"])
    expect(page.locator("dl.facts")).to_contain_text(f"Camera centre in plate coordinates({shown}) mm")
    expect(page.locator("dl.facts")).to_contain_text("Plate origin in camera coordinates(")
    screenshot(page, "camera-report-pose")
    # A check's name leads to where the method documentation explains it, marked.
    checks.get_by_role("link", name="residual_std").click()
    expect(page.get_by_role("heading", name="The measurement method")).to_be_visible()
    found = page.locator("article.doc .found")
    expect(found).to_contain_text("residual_std")
    expect(found).to_be_in_viewport()
    screenshot(page, "help-residual-std", full_page=False)

    projector_job = demo["jobs"][("projector_calibration", "kodak")]
    page.goto(f"/#/jobs/{projector_job['id']}/report")
    verdict = page.get_by_role("region", name="Verdict")
    expect(verdict).to_contain_text("Verdict: ", timeout=60_000)
    expect(verdict.get_by_role("table", name="Verdict checks")).to_contain_text("z_resolution_mm")
    note = page.get_by_label("About the sensitivity map")
    expect(note).to_contain_text("Z resolution")
    recording = httpx.get(f"{demo['base']}/recordings/{projector_job['spec']['recording_id']}", timeout=30).json()
    width, height = recording["width_px"], recording["height_px"]
    the_map = page.evaluate(
        """() => {
            const figures = [...document.querySelectorAll("figure")];
            const figure = figures.find((f) => f.textContent.includes("Sensitivity map"));
            const t = figure.querySelector(".plot-area").data[0];
            const values = t.z.flat().filter(Number.isFinite);
            return { type: t.type, u: Array.from(t.x), v: Array.from(t.y), n: values.length, cells: t.z.flat().length };
        }"""
    )
    # The whole image: cell centres span it from edge to edge, inside it, and most cells hold entries.
    assert the_map["type"] == "heatmap"
    assert all(0 <= u <= width for u in the_map["u"]) and all(0 <= v <= height for v in the_map["v"])
    assert min(the_map["u"]) < 0.05 * width and max(the_map["u"]) > 0.95 * width
    assert min(the_map["v"]) < 0.05 * height and max(the_map["v"]) > 0.95 * height
    assert the_map["n"] > 0.5 * the_map["cells"], the_map
    page.get_by_label("Map of").select_option("coverage")
    expect(page.get_by_role("img", name="Coverage over Z")).to_be_visible()
    screenshot(page, "projector-report")

    page.goto(f"/#/experiments/{demo['experiment_id']}")
    jobs = page.get_by_role("table", name="Jobs of this experiment")
    succeeded = jobs.get_by_role("row").filter(has_text="succeeded")
    expect(succeeded.first).to_be_visible(timeout=30_000)
    for text in succeeded.all_inner_texts():
        assert "writing" not in text and "checking frames" not in text, text

    test_recording = demo["jobs"][("topography", "kodak")]["spec"]["recording_id"]
    page.goto(f"/#/recordings/{test_recording}")
    expect(page.get_by_role("heading", name="QA warnings")).to_be_visible(timeout=30_000)
    notes = page.get_by_role("list", name="Notes")
    if notes.count():
        # Notes come under their own heading, never right after "No QA warnings." as if they were one.
        expect(page.get_by_role("heading", name="Notes")).to_be_visible()
    screenshot(page, "recording-notes")


def test_demo_shows_its_progress_from_the_first_second(page, demo):
    """Last in this module (it starts a second demo): the steps show at once after the click, and end done."""
    page.goto("/#/experiments")
    page.get_by_label("Virtual cameras").select_option(label="Kodak only (under a minute)")
    page.get_by_role("button", name="Load demo experiment").click()
    steps = page.get_by_role("list", name="Demo progress")
    # At once: the page has the step list before the worker has made anything (no request is waited for).
    expect(steps).to_be_visible(timeout=3_000)
    expect(steps).to_contain_text("Camera kodak")
    expect(page.get_by_role("heading", name=re.compile(r"^Demo in progress"))).to_contain_text("since the click")
    expect(steps.locator("[data-status='doing']")).to_have_count(1)
    screenshot(page, "demo-progress-at-once")
    expect(page.get_by_role("heading", name=re.compile(r"^Demo done"))).to_be_visible(timeout=DEMO_TIMEOUT_S * 1000)
    expect(steps.locator("[data-status='done']")).to_have_count(6)
    screenshot(page, "demo-progress-done")


def test_exports_from_the_viewer_and_their_downloads_in_the_jobs_list(page, demo):
    """Every format of the API's list, started from the viewer for a frame range; the profile CSV follows the
    lines drawn; each export job gets its download link in the form and in the jobs list."""
    job = demo["jobs"][("topography", "kodak")]
    page.goto(f"/#/jobs/{job['id']}/viewer")
    expect(page.get_by_role("slider", name="Frame")).to_be_visible(timeout=30_000)
    page.get_by_text("Type a section line").click()
    for name, value in (("x₀", "-150"), ("y₀", "0"), ("x₁", "150"), ("y₁", "0")):
        page.get_by_label(f"Line {name} (mm)").fill(value)
    page.get_by_role("button", name="Add line").click()
    expect(page.get_by_role("list", name="Section lines")).to_contain_text("A")
    form = page.get_by_role("form", name="Export the result")
    options = form.get_by_label("Export format").locator("option")
    expected = ["points-csv", "grid-npz", "mat", "vtk", "profile-csv"]  # EXPORT_FORMATS, in its order
    expect(options).to_have_count(len(expected))  # the list comes from the API after the form is drawn
    formats = options.evaluate_all("(os) => os.map((o) => o.value)")
    assert formats == expected
    form.get_by_label("First frame").fill("2")
    form.get_by_label("Last frame").fill("4")
    for fmt in formats:
        form.get_by_label("Export format").select_option(fmt)
        form.get_by_role("button", name="Export", exact=True).click()
    started = form.get_by_role("list", name="Exports started here")
    expect(started.get_by_role("link", name=re.compile(r"^Download "))).to_have_count(len(formats), timeout=120_000)
    form.scroll_into_view_if_needed()
    screenshot(page, "viewer-exports")

    links = started.get_by_role("link", name=re.compile(r"^Download ")).evaluate_all("(as) => as.map((a) => a.href)")
    by_name = {link.rsplit("/", 1)[-1]: link for link in links}
    profile = httpx.get(next(link for name, link in by_name.items() if "profile" in name), timeout=30).text
    rows = list(csv.DictReader(io.StringIO(profile)))
    assert {row["line"] for row in rows} == {"A"} and {row["frame"] for row in rows} == {"2", "3", "4"}
    assert all(float(row["y_mm"]) == pytest.approx(0.0, abs=1e-3) for row in rows)  # along the line typed
    npz_url = next(link for name, link in by_name.items() if name.endswith(".npz"))
    npz = np.load(io.BytesIO(httpx.get(npz_url, timeout=30).content))
    np.testing.assert_array_equal(npz["frames"], [2, 3, 4])

    page.goto("/#/jobs")
    # The jobs started here, by the job id in their download links (other tests on this server export too).
    export_ids = {re.search(r"/jobs/([0-9a-f-]+)/files/", link).group(1) for link in links}  # type: ignore[union-attr]
    assert len(export_ids) == len(formats)
    rows = page.get_by_role("table", name="All jobs").get_by_role("row")
    for export_id in export_ids:
        row = rows.filter(has_text=f"Export {export_id[:8]}")
        expect(row).to_have_count(1, timeout=30_000)
        expect(row.get_by_role("link", name=re.compile(r"^Download ")).first).to_be_visible()
    screenshot(page, "jobs-list-export-downloads")


def test_delete_says_what_goes_with_it_and_removes_it(page, live_server, demo):
    """An experiment of its own (so the shared demo stays): the confirmation names what goes, "Keep it" keeps it,
    "Delete" removes it; then a finished export job of the demo is deleted from the jobs list."""
    base = demo["base"]
    experiment = httpx.post(f"{base}/experiments", json={"name": "Trial to delete"}, timeout=30).json()
    page.goto(f"/#/experiments/{experiment['id']}")
    # A camera with non-square pixels (11.5 × 12.0 µm), through the form; the hint says what a data sheet gives.
    cameras = page.get_by_role("form", name="Add a camera")
    cameras.get_by_label("Camera name").fill("spare")
    cameras.get_by_label("Image width (px)").fill("64")
    cameras.get_by_label("Image height (px)").fill("48")
    cameras.get_by_label("Pixel pitch u (µm)").fill("11.5")
    cameras.get_by_label("Pixel pitch v (µm)").fill("12")
    expect(cameras).to_contain_text("horizontal × vertical = u × v")
    cameras.get_by_role("button", name="Add camera").click()
    expect(page.get_by_role("region", name="Camera spare")).to_contain_text("pixel pitch 11.5 × 12 µm (u × v)")
    listed = httpx.get(f"{base}/experiments/{experiment['id']}/cameras", timeout=30).json()
    assert [(c["pixel_pitch_um"], c["pixel_pitch_v_um"]) for c in listed] == [(11.5, 12.0)]
    page.get_by_role("button", name="Delete experiment Trial to delete").click()
    dialog = page.get_by_role("dialog", name="Delete experiment Trial to delete?")
    expect(dialog).to_contain_text(f"Deletes experiment {experiment['id']} (Trial to delete) with 1 camera")
    expect(dialog).to_contain_text("This cannot be undone.")
    screenshot(page, "delete-confirmation", full_page=False)
    dialog.get_by_role("button", name="Keep it").click()
    expect(dialog).to_have_count(0)
    assert httpx.get(f"{base}/experiments/{experiment['id']}", timeout=30).status_code == 200
    page.get_by_role("button", name="Delete experiment Trial to delete").click()
    page.get_by_role("dialog").get_by_role("button", name="Delete", exact=True).click()
    expect(page).to_have_url(re.compile(r"#/experiments$"))
    expect(page.get_by_role("table", name="Experiments")).not_to_contain_text("Trial to delete")
    assert httpx.get(f"{base}/experiments/{experiment['id']}", timeout=30).status_code == 404

    export = httpx.post(f"{base}/jobs", json={"kind": "export", "job_id": demo["jobs"][("topography", "kodak")]["id"],
                                              "format": "grid-npz"}, timeout=30).json()  # fmt: skip
    page.goto(f"/#/jobs/{export['id']}")
    expect(page.get_by_role("link", name=re.compile(r"^Download topography"))).to_be_visible(timeout=120_000)
    page.goto("/#/jobs")
    row = page.get_by_role("row").filter(has=page.get_by_role("link", name=f"Export {export['id'][:8]}"))
    row.get_by_role("button", name=f"Delete Export {export['id'][:8]}").click()
    dialog = page.get_by_role("dialog")
    expect(dialog).to_contain_text(f"Deletes export job {export['id']} with 1 job")
    dialog.get_by_role("button", name="Delete", exact=True).click()
    expect(row).to_have_count(0)
    assert httpx.get(f"{base}/jobs/{export['id']}", timeout=30).status_code == 404


def test_board_in_the_calibration_form_and_sidecars_replaced_from_the_recording_page(page, demo, tmp_path):
    """The camera calibration form is prefilled from the recording's board.json; on the recording page an odd
    board.json is replaced: another lab's spelling reads as the same board, an unreadable one is one warning (the
    recording stays ready), and the original goes back."""
    base = demo["base"]
    recording_id = demo["jobs"][("camera_calibration", "kodak")]["spec"]["recording_id"]
    recording = httpx.get(f"{base}/recordings/{recording_id}", timeout=30).json()
    board = recording["sidecars"]["board.json"]
    page.goto(f"/#/experiments/{demo['experiment_id']}")
    form = page.get_by_role("form", name="Start a job")
    form.get_by_label("Job kind").select_option(label="Camera calibration")
    form.get_by_label("Recording", exact=True).select_option(str(recording_id))
    expect(form.get_by_label("Where the board comes from")).to_contain_text("Board from the recording's board.json")
    expect(form.get_by_label("Cols", exact=True)).to_have_value(str(board["cols"]))
    expect(form.get_by_label("Rows", exact=True)).to_have_value(str(board["rows"]))
    expect(form.get_by_label("Square (mm)")).to_have_value(f"{board['square_mm']:g}")
    spec = page.get_by_label("Job spec (JSON)").text_content()
    assert f'"cols": {board["cols"]}' in spec
    form.scroll_into_view_if_needed()
    screenshot(page, "calibration-form-board")

    def replace(text: str) -> None:
        path = tmp_path / "board.json"
        path.write_text(text)
        sidecars = page.get_by_role("form", name="Replace a sidecar")
        sidecars.get_by_label("Sidecar", exact=True).select_option("board.json")
        sidecars.get_by_label("Sidecar file").set_input_files(str(path))
        page.evaluate("() => { document.getElementById('status').textContent = ''; }")  # the last outcome said
        sidecars.get_by_role("button", name="Replace the sidecar").click()
        expect(page.locator("#status")).to_contain_text("board.json replaced: the recording is ready", timeout=120_000)

    page.goto(f"/#/recordings/{recording_id}")
    square_m = board["square_mm"] / 1000
    replace(f'{{"boardWidth": {board["cols"]}, "boardHeight": {board["rows"]}, "squareSize": {square_m}, "unit": "m"}}')
    again = httpx.get(f"{base}/recordings/{recording_id}", timeout=30).json()
    assert again["state"] == "ready" and again["sidecars"]["board.json"]["cols"] == board["cols"]
    assert again["sidecars"]["board.json"]["square_mm"] == pytest.approx(board["square_mm"])
    replace('{"pattern": "chessboard"}')
    warnings = page.get_by_role("list", name="QA warnings")
    expect(warnings).to_contain_text("board.json: missing cols, rows, square_mm")
    expect(warnings).not_to_contain_text("no board.json")
    expect(page.get_by_role("heading", name="QA warnings")).to_be_visible()
    screenshot(page, "recording-board-unreadable")
    origin = board["origin"]
    replace(f'{{"cols": {board["cols"]}, "rows": {board["rows"]}, "square_mm": {board["square_mm"]}, '
            f'"origin": {"null" if origin is None else origin}}}')  # fmt: skip
    assert httpx.get(f"{base}/recordings/{recording_id}", timeout=30).json()["sidecars"]["board.json"] == board


def test_queue_shows_what_runs_on_which_worker_and_updates_from_events(page, demo):
    """A self-test of the workers (many frames, so that it is seen running) appears on the queue page with its
    worker, and leaves it when it ends, with no reload and no polling: the page reads the queue again only when
    the jobs' event stream says something changed. Storage is listed per user."""
    requests: list[str] = []
    page.on("request", lambda request: requests.append(request.url))
    page.goto("/#/queue")
    expect(page.get_by_role("table", name="Storage per user")).to_contain_text("local")
    started = httpx.post(f"{demo['base']}/jobs", json={"kind": "selftest", "frames": 400, "frame_size_px": 256},
                         timeout=30).json()  # fmt: skip
    running = page.get_by_role("table", name="Running jobs")
    row = running.get_by_role("row").filter(has=page.get_by_role("link", name=f"Self-test {started['id'][:8]}"))
    expect(row).to_be_visible(timeout=60_000)
    worker = httpx.get(f"{demo['base']}/jobs/{started['id']}", timeout=30).json()["worker"]
    expect(row).to_contain_text(worker)
    screenshot(page, "queue-running")
    expect(row).to_have_count(0, timeout=240_000)
    assert httpx.get(f"{demo['base']}/jobs/{started['id']}", timeout=30).json()["state"] == "succeeded"
    assert any(url.endswith("/api/v1/jobs/events") for url in requests), "the page does not follow the events"
    # Idle now: a poll would read the queue again within a few seconds; events do not come, so neither do reads.
    page.wait_for_timeout(1_000)
    before = sum("/api/v1/queue" in url for url in requests)
    page.wait_for_timeout(6_000)
    assert sum("/api/v1/queue" in url for url in requests) == before, "the queue page polls"
