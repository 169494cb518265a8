"""Comparing a measurement with a finite-element simulation in real Chromium, against a real `fringelab up`.

The measurement is the virtual test's topography (tests/pipelines/conftest.py, `measured`: 8 frames, the
pipeline's own result), registered as a succeeded topography job of a new experiment. The simulation is that
experiment's true surface written as a quarter model in metres (a folder: a .pvd/.vtu series with nodout and
rcforc, over 1 MiB, packed into a ZIP by the browser) whose states reach only the punch travel of frame 5, at
displacements that are not the frames': so the units and the symmetry must be detected, the states interpolated,
and frames 6 and 7 are left uncompared, with their reason, as gaps. Through the dashboard: upload, the mapping
form's live preview (detected choices shown in the controls, a wrong unit and a model off the plate refused in the
form's own words), the comparison job, its view (map, field switch, frame slider, profile with ±σ, peak and force
curves, per-frame differences with the gaps) and an export.
"""

from __future__ import annotations

import re
import uuid
from pathlib import Path

import httpx
import numpy as np
import pytest
from playwright.sync_api import expect

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Job, utcnow
from fringelab.core.settings import Settings
from fringelab.formats.topography import TopographyResult
from fringelab.pipelines.virtual_test import write_true_simulation
from tests.browser.conftest import screenshot
from tests.pipelines.conftest import measured  # noqa: F401  (the session's measured virtual test)

pytestmark = [pytest.mark.browser, pytest.mark.integration]
LAST_SIMULATED_FRAME = 5
# The 422 the preview answers while the Units are set wrong (the test sets them so on purpose).
PREVIEW_REFUSED = r"^422 POST .*/api/v1/comparisons/preview$"


def register_topography(data_dir: Path, experiment_id: int, result: Path) -> str:
    """A succeeded topography job of the experiment holding `result` (as the worker writes one)."""
    job_id = str(uuid.uuid4())
    settings = Settings(_env_file=None, data_dir=data_dir)  # type: ignore[call-arg]
    target = data_dir / "results" / "jobs" / job_id / "topography.h5"
    target.parent.mkdir(parents=True)
    target.write_bytes(result.read_bytes())
    with TopographyResult(target) as opened:
        frames = [int(opened.frames[0]), int(opened.frames[-1])]
    entry = {"name": "topography.h5", "path": str(target.relative_to(data_dir)), "size_bytes": target.stat().st_size,
             "sha256": "", "media_type": "application/x-hdf5"}  # fmt: skip
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        session.add(Job(id=job_id, kind="topography", state="succeeded", experiment_id=experiment_id, files=[entry],
                        spec={"kind": "topography"}, result={"frames": frames}, finished_at=utcnow()))  # fmt: skip
        session.commit()
    engine.dispose()
    return job_id


def quarter_model_in_metres(measured, folder: Path) -> Path:  # type: ignore[no-untyped-def]  # noqa: F811
    """The true surface as a quarter model in metres (a folder), its states short of the test's last frames."""
    with TopographyResult(measured.result) as result:
        punch_mm = result.column("frames/punch_displacement_mm")
    states = np.linspace(0.0, punch_mm[LAST_SIMULATED_FRAME], 7)  # not the frames' displacements
    return write_true_simulation(measured.truth_json, folder / "plate-fe", kind="vtu", quarter=True,
                                 length_unit="m", state_punch_mm=states, resolution=0.03)  # fmt: skip


def test_upload_map_with_a_live_preview_compare_and_export(
    page,
    live_server,
    measured,  # noqa: F811
    tmp_path,
    expected_console_errors,
) -> None:  # type: ignore[no-untyped-def]
    expected_console_errors.append(PREVIEW_REFUSED)
    base = f"{live_server.base_url}/api/v1"
    experiment = httpx.post(f"{base}/experiments", json={"name": "plate vs LS-DYNA"}, timeout=30).json()
    topography = register_topography(live_server.data_dir, experiment["id"], measured.result)
    model = quarter_model_in_metres(measured, tmp_path)
    # over the JSON bodies' cap: the simulation's upload streams past it
    assert sum(path.stat().st_size for path in model.rglob("*")) > 2**20

    page.goto(f"/#/experiments/{experiment['id']}")
    section = page.get_by_role("region", name="Simulations and comparisons")
    upload = section.get_by_role("form", name="Upload a simulation")
    upload.get_by_label("Simulation folder").set_input_files(str(model))  # packed into a ZIP in the browser
    expect(section.get_by_role("table", name="Simulations")).to_contain_text("plate-fe.zip", timeout=60_000)
    expect(section.get_by_role("table", name="Simulations")).to_contain_text("7 states")

    # The live preview: the detected choices shown in the controls left on "detect"
    form = section.get_by_role("form", name="Compare with a simulation")
    expect(form.get_by_label("Topography result")).to_have_value(topography)
    state = form.get_by_label("Preview state")
    expect(state).to_contain_text("6 of 8 frames paired", timeout=60_000)
    expect(form.get_by_label("Units", exact=True).locator("option").first).to_have_text("detected: m")
    expect(form.get_by_label("Symmetry", exact=True).locator("option").first).to_have_text("detected: quarter")
    expect(form.get_by_label("Frames not compared")).to_contain_text("Frame 7 not compared: punch displacement")
    # the page's first plot: plotly.js (4.8 MB) is loaded and parsed only now, which takes seconds on a busy machine
    preview_plot = form.get_by_role("img", name="Mapping preview")
    expect(preview_plot.locator(".scatterlayer .trace")).to_have_count(3, timeout=30_000)
    screenshot(page, "comparison-mapping-preview")

    # A wrong unit is refused in the form's terms, and the preview comes back when it is undone
    form.get_by_label("Units", exact=True).select_option("mm")
    refused = form.get_by_role("alert")
    expect(refused).to_contain_text("“Units” mm or m", timeout=30_000)
    expect(refused).not_to_contain_text("--units")
    form.get_by_label("Units", exact=True).select_option("")
    expect(state).to_contain_text("6 of 8 frames paired", timeout=30_000)
    expect(refused).to_be_hidden()
    # a model put off the plate: the overlap is refused, naming the origin as the form does
    form.get_by_label("Origin x (mm)").fill("400")
    expect(refused).to_contain_text("“Origin x (mm)” and “Origin y (mm)”", timeout=30_000)
    expect(form.get_by_role("button", name="Start comparison")).to_be_disabled()
    form.get_by_label("Origin x (mm)").fill("")
    expect(state).to_contain_text("6 of 8 frames paired", timeout=30_000)

    # Detected units are confirmed before the comparison starts; the spec then names them
    start = form.get_by_role("button", name="Start comparison")
    confirm = form.get_by_label(re.compile(r"^The model's units are m "))
    expect(confirm).to_be_visible()
    confirm.check()
    start.click()
    link = form.get_by_role("list", name="Comparisons started here").get_by_role("link", name="comparison view")
    expect(link).to_be_visible()
    job_id = re.search(r"#/jobs/([0-9a-f-]+)/comparison", link.get_attribute("href")).group(1)  # type: ignore[union-attr, arg-type]
    job = httpx.get(f"{base}/jobs/{job_id}", timeout=30).json()
    assert job["spec"]["units"] == "m" and job["spec"].get("symmetry") is None, job["spec"]  # confirmed; detected
    jobs = page.get_by_role("table", name="Jobs of this experiment")
    expect(jobs.get_by_role("row").filter(has_text="Comparison")).to_contain_text("succeeded", timeout=90_000)
    link.click()

    # The comparison view
    expect(page.get_by_role("heading", name=re.compile(r"^Comparison: Comparison [0-9a-f]{8}$"))).to_be_visible()
    frame_facts = page.get_by_label("Current frame")
    # it opens on the deepest compared frame whose peak was measured (frame 5's dome top is in the punch's shadow:
    # its peak is only a lower bound, docs/method.md)
    with TopographyResult(measured.result) as result:
        peaks_mm = result.measured_peaks()[: LAST_SIMULATED_FRAME + 1]
    expect(frame_facts).to_contain_text(f"frame {int(np.nanargmax(peaks_mm))} ")
    expect(frame_facts).to_contain_text("RMS difference")
    expect(page.get_by_role("img", name="Comparison map").locator(".hm, .heatmaplayer image")).not_to_have_count(0)
    expect(page.get_by_label("Profile against the measurement's uncertainty")).to_contain_text("differ by more than 2σ")
    not_compared = page.get_by_role("list", name="Frames not compared")
    expect(not_compared).to_contain_text("Frame 6: punch displacement")
    expect(not_compared).to_contain_text("Frame 7: punch displacement")
    # the per-frame differences: a gap (null), never a drop to zero, and a "not compared" mark per missing frame
    differences = page.evaluate(
        "() => window.fringelab.comparison.differenceFigure.plot.data.map((t) => [t.name, t.y])"
    )
    rms = dict(differences)["RMS difference"]
    assert rms[6] is None and rms[7] is None and all(v is not None and v > 0 for v in rms[:6]), rms
    assert len(dict(differences)["not compared"]) == 2
    curves = page.evaluate("() => window.fringelab.comparison.curvesFigure.plot.data.map((t) => t.name)")
    assert {"peak w, measured", "peak w, simulated", "force, measured", "force, simulated"} <= set(curves), curves
    notes = page.get_by_role("definition").filter(has_text="shell thickness")
    expect(notes).to_contain_text("“Shell thickness (mm)”")  # the form's name of the setting, not the CLI's
    screenshot(page, "comparison-view")

    page.get_by_label("Field", exact=True).select_option("sigma_w_mm")
    expect(page.get_by_role("img", name="Comparison map")).to_contain_text("σ_w")
    page.get_by_role("slider", name="Frame").fill("7")
    expect(frame_facts).to_contain_text("not compared: punch displacement")
    expect(page.get_by_label("Profile against the measurement's uncertainty")).to_contain_text("not compared")
    page.get_by_label("Field", exact=True).select_option("diff_mm")
    expect(page.get_by_role("img", name="Comparison map")).to_contain_text("Frame 7 not compared")
    screenshot(page, "comparison-view-frame-not-compared")

    exports = page.get_by_role("form", name="Export the comparison")
    exports.get_by_label("Comparison export format").select_option("csv")
    exports.get_by_role("button", name="Export").click()
    download = exports.get_by_role("link", name="Download comparison.csv")
    expect(download).to_be_visible(timeout=60_000)
    text = httpx.get(f"{live_server.base_url}{download.get_attribute('href')}", timeout=30).text
    rows = text.splitlines()
    assert rows[0].startswith("frame,state_lo,") and len(rows) == 9
    assert rows[8].split(",")[1] == "-1" and "punch displacement" in rows[8]

    # The topography's own export form still offers the topography's formats (one form module serves both kinds)
    page.goto(f"/#/jobs/{topography}")
    formats = page.get_by_role("form", name="Export the result").get_by_label("Export format")
    expect(formats.locator("option")).to_have_count(5)
    expect(formats).to_contain_text("grid NPZ (numpy)")
    expect(formats).not_to_contain_text("HDF5")
