"""What a result is of, said where it is shown (issue 27): the viewer's title names the camera and the recording,
and the list of all jobs has experiment and camera columns and marks a calibration whose verdict is bad. The result
is a small synthetic topography file (the results API's test file, 4 frames) registered as a succeeded job of a
real experiment, camera and recording."""

from __future__ import annotations

import uuid

import httpx
import pytest
from playwright.sync_api import expect

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Job, Recording, utcnow
from fringelab.core.settings import Settings
from tests.browser.conftest import screenshot
from tests.worker.test_results_api import write_result

pytestmark = [pytest.mark.browser, pytest.mark.integration]


def test_the_viewer_and_the_jobs_list_name_the_camera_and_the_experiment(page, live_server):
    base = f"{live_server.base_url}/api/v1"
    experiment = httpx.post(f"{base}/experiments", json={"name": "plate 7"}, timeout=30).json()
    camera = {"name": "kodak", "image_width_px": 64, "image_height_px": 48, "pixel_pitch_um": 20}
    camera_id = httpx.post(f"{base}/experiments/{experiment['id']}/cameras", json=camera, timeout=30).json()["id"]
    job_id = str(uuid.uuid4())
    data_dir = live_server.data_dir
    target = data_dir / "results" / "jobs" / job_id / "topography.h5"
    target.parent.mkdir(parents=True)
    write_result(target)
    entry = {"name": "topography.h5", "path": str(target.relative_to(data_dir)), "size_bytes": target.stat().st_size,
             "sha256": "", "media_type": "application/x-hdf5"}  # fmt: skip
    engine = make_engine(Settings(_env_file=None, data_dir=data_dir).resolved_database_url)  # type: ignore[call-arg]
    # Measured with a bad calibration, by consent: the result carries the warning wherever it is shown.
    used = {"calibrations": [{"id": 1, "warning": "camera calibration #1 has the verdict bad: f = 21.7 mm"}]}
    with make_sessionmaker(engine)() as session:
        recording = Recording(camera_id=camera_id, kind="test", state="ready", filename="punch.zip")
        session.add(recording)
        session.flush()
        recording_id = recording.id
        session.add(Job(id=job_id, kind="topography", state="succeeded", experiment_id=experiment["id"],
                        files=[entry], spec={"kind": "topography", "recording_id": recording_id}, provenance=used,
                        result={"frames": [10, 13]}, finished_at=utcnow()))  # fmt: skip
        # A camera calibration whose verdict is bad: marked so in every jobs list.
        spec = {"kind": "camera_calibration", "recording_id": recording_id}
        session.add(Job(id=str(uuid.uuid4()), kind="camera_calibration", state="succeeded",
                        experiment_id=experiment["id"], spec=spec,
                        result={"verdict": "bad", "reasons": ["f = 21.7 mm"]}, finished_at=utcnow()))  # fmt: skip
        session.commit()
    engine.dispose()

    page.goto(f"/#/jobs/{job_id}/viewer")
    expect(page.get_by_role("heading", name=f"Topography of camera kodak, recording {recording_id}")).to_be_visible()
    expect(page.get_by_role("link", name="experiment plate 7")).to_be_visible()
    warnings = page.get_by_role("list", name="Warnings about this result")
    expect(warnings).to_have_text("⚠ camera calibration #1 has the verdict bad: f = 21.7 mm")
    page.goto("/#/jobs")
    jobs = page.get_by_role("table", name="All jobs")
    expect(jobs.get_by_role("columnheader")).to_contain_text(["Job", "Experiment", "Camera"])
    row = jobs.get_by_role("row").filter(has_text=job_id[:8])
    expect(row.get_by_role("cell").nth(1)).to_have_text("plate 7")
    expect(row.get_by_role("cell").nth(2)).to_have_text("kodak")
    expect(row).to_contain_text("⚠ camera calibration #1 has the verdict bad")
    calibration = jobs.get_by_role("row").filter(has_text="Camera calibration")
    expect(calibration.get_by_text("verdict: bad")).to_be_visible()
    screenshot(page, "jobs-with-experiment-and-camera", full_page=False)
