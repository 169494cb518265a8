"""The experiment page's job form for a camera–projector calibration in real Chromium against a real `fringelab up`:
the chessboard poses are picked from the experiment's ready coded recordings (one box each), fewer than three are
refused before anything is sent, and the job it starts carries exactly the poses and the board that were chosen."""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from playwright.sync_api import expect

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Recording
from fringelab.core.settings import Settings
from fringelab.formats.patterns import patterns_json_text
from fringelab.formats.recordings import write_recording
from tests.browser.conftest import screenshot
from tests.procam_rig import POSE_COLUMNS, POSE_ROWS

pytestmark = [pytest.mark.browser, pytest.mark.integration]


def add_pose_recordings(data_dir: Path, camera_id: int, names: list[str]) -> dict[str, int]:
    """Ready coded recordings of the camera, one per name, each a folder of frames with its two patterns files
    (the frames are blank: the form is tested here, not the calibration)."""
    frames = [np.zeros((270, 360), np.uint8)] * 19
    sidecars = {
        "patterns-columns.json": patterns_json_text(POSE_COLUMNS),
        "patterns-rows.json": patterns_json_text(POSE_ROWS),
    }
    settings = Settings(_env_file=None, data_dir=data_dir)  # type: ignore[call-arg]
    engine = make_engine(settings.resolved_database_url)
    ids = {}
    with make_sessionmaker(engine)() as session:
        for name in names:
            relative = Path("recordings") / f"camera-{camera_id}" / name
            write_recording(data_dir / relative, frames, sidecars=sidecars)
            row = Recording(camera_id=camera_id, kind="coded", state="ready", filename=name, path=str(relative),
                            frame_count=len(frames), width_px=360, height_px=270,
                            sha256=f"{len(ids):02d}" * 32)  # fmt: skip
            session.add(row)
            session.flush()
            ids[name] = row.id
        session.commit()
    engine.dispose()
    return ids


def test_the_job_form_picks_the_chessboard_poses(page, live_server) -> None:  # type: ignore[no-untyped-def]
    base = f"{live_server.base_url}/api/v1"
    experiment = httpx.post(f"{base}/experiments", json={"name": "procam rig"}, timeout=30).json()
    camera = httpx.post(f"{base}/experiments/{experiment['id']}/cameras",
                        json={"name": "left", "image_width_px": 360, "image_height_px": 270, "pixel_pitch_um": 5.0},
                        timeout=30)  # fmt: skip
    assert camera.status_code == 201, camera.text
    ids = add_pose_recordings(live_server.data_dir, camera.json()["id"], ["pose-a", "pose-b", "pose-c", "pose-d"])

    page.goto(f"/#/experiments/{experiment['id']}")
    form = page.get_by_role("form", name="Start a job")
    form.get_by_label("Job kind").select_option(label="Camera–projector calibration")
    poses = form.get_by_role("group", name="Chessboard poses")
    expect(poses).to_be_visible(timeout=30_000)
    # One box per ready coded recording, none ticked.
    for name, recording_id in ids.items():
        expect(poses.get_by_label(f"#{recording_id} {name}", exact=False)).not_to_be_checked()
    board = form.get_by_role("group", name="Board")
    board.get_by_label("Cols").fill("9")
    board.get_by_label("Rows").fill("7")
    board.get_by_label("Square (mm)").fill("8")

    # Two poses are refused in the browser: nothing is sent.
    poses.get_by_label(f"#{ids['pose-a']} pose-a", exact=False).check()
    poses.get_by_label(f"#{ids['pose-c']} pose-c", exact=False).check()
    expect(poses).to_contain_text("2 poses ticked; at least 3")
    form.get_by_role("button", name="Start job").click()
    time.sleep(1.0)
    listed = httpx.get(f"{base}/jobs", params={"experiment_id": experiment["id"], "limit": 100}, timeout=30).json()
    assert [job for job in listed["items"] if job["kind"] == "procam_calibration"] == []

    poses.get_by_label(f"#{ids['pose-d']} pose-d", exact=False).check()
    expect(poses).to_contain_text("3 poses ticked")
    expect(form.get_by_label("Job spec (JSON)")).to_contain_text('"recording_ids"')
    screenshot(page, "procam-calibration-form")
    form.get_by_role("button", name="Start job").click()
    expect(page.get_by_text("started.")).to_be_visible(timeout=30_000)
    deadline = time.monotonic() + 30
    while True:
        listed = httpx.get(f"{base}/jobs", params={"experiment_id": experiment["id"], "limit": 100}, timeout=30).json()
        started = [job for job in listed["items"] if job["kind"] == "procam_calibration"]
        if started or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    [job] = started
    assert job["spec"]["recording_ids"] == [ids["pose-a"], ids["pose-c"], ids["pose-d"]]
    assert job["spec"]["board"] == {"cols": 9, "rows": 7, "square_mm": 8.0, "origin": None}
    # The job is in the experiment's list under its kind's name.
    expect(page.get_by_role("table", name="Jobs of this experiment")).to_contain_text("Camera–projector calibration")
