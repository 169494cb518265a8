"""The camera–projector calibration's report in real Chromium against a real `fringelab up`: a calibration made
from the virtual rig's true corners (with 0.03 px of noise), registered as a succeeded procam_calibration job with
its versioned calibration; the verdict, the RMS, per-pose bars and residual arrows in both images."""

from __future__ import annotations

import uuid
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
from playwright.sync_api import expect

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Calibration, Job, utcnow
from fringelab.core.settings import Settings
from fringelab.formats.procam import write_procam_json
from fringelab.science.procam import project_to_camera, project_to_projector
from fringelab.science.procam_calibration import PoseCorners, calibrate_procam
from fringelab.science.virtual_procam import ChessboardPose, virtual_procam_rig
from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration]


def register_calibration(data_dir: Path, experiment_id: int, camera_id: int) -> str:
    rig = virtual_procam_rig()
    rng = np.random.default_rng(9)
    poses = []
    for i, (ax, ay) in enumerate([(0, 0), (25, 0), (-25, 0), (0, 25), (0, -25), (15, 15)]):
        rotation = cv2.Rodrigues(np.deg2rad(np.array([ax, ay, 2.0 * i])))[0]
        tvec = np.array([0.0, 0.0, 300.0]) - rotation @ np.array([32.0, 24.0, 0.0])
        pose = ChessboardPose(9, 7, 8.0, tuple(cv2.Rodrigues(rotation)[0].ravel()), tuple(tvec))
        points = pose.inner_corners_cam_mm()
        poses.append(PoseCorners(f"pose {i}", pose.inner_corners_board_mm(),
                                 project_to_camera(rig, points) + rng.normal(0, 0.03, (len(points), 2)),
                                 project_to_projector(rig, points) + rng.normal(0, 0.03, (len(points), 2)),
                                 np.ones(len(points), bool)))  # fmt: skip
    calibration = calibrate_procam(poses, camera_size_wh_px=(360, 270), projector_size_wh_px=(320, 200))
    job_id = str(uuid.uuid4())
    target = data_dir / "results" / "jobs" / job_id / "procam.json"
    target.parent.mkdir(parents=True)
    write_procam_json(target, calibration.model, calibration=calibration)
    relative = str(target.relative_to(data_dir))
    entry = {"name": "procam.json", "path": relative, "size_bytes": target.stat().st_size, "sha256": "",
             "media_type": "application/json"}  # fmt: skip
    settings = Settings(_env_file=None, data_dir=data_dir)  # type: ignore[call-arg]
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        session.add(Job(id=job_id, kind="procam_calibration", state="succeeded", experiment_id=experiment_id,
                        files=[entry], spec={"kind": "procam_calibration"}, finished_at=utcnow()))  # fmt: skip
        session.flush()
        row = Calibration(kind="procam", camera_id=camera_id, job_id=job_id, version=1, path=relative,
                          image_width_px=360, image_height_px=270, sha256="ab" * 32,
                          summary={"verdict": calibration.verdict.level})  # fmt: skip
        session.add(row)
        session.flush()
        job = session.get(Job, job_id)
        assert job is not None
        job.result = {"calibration_id": row.id, "version": 1, "verdict": calibration.verdict.level}
        session.commit()
    engine.dispose()
    return job_id


def test_the_procam_report_shows_verdict_poses_and_residuals(page, live_server) -> None:  # type: ignore[no-untyped-def]
    base = f"{live_server.base_url}/api/v1"
    experiment = httpx.post(f"{base}/experiments", json={"name": "rig"}, timeout=30).json()
    camera = httpx.post(f"{base}/experiments/{experiment['id']}/cameras",
                        json={"name": "left", "image_width_px": 360, "image_height_px": 270, "pixel_pitch_um": 5.0},
                        timeout=30)  # fmt: skip
    assert camera.status_code == 201, camera.text
    job_id = register_calibration(live_server.data_dir, experiment["id"], camera.json()["id"])

    page.goto(f"/#/jobs/{job_id}")
    page.get_by_role("link", name="Calibration report").click()
    expect(page.get_by_role("heading", name="Camera–projector calibration")).to_be_visible(timeout=30_000)
    verdict = page.get_by_role("region", name="Verdict")
    expect(verdict).to_contain_text("Verdict: good")
    expect(page.get_by_role("table", name="Verdict checks")).to_contain_text("stereo_rms")
    expect(page.get_by_label("Calibration summary")).to_contain_text("Stereo (both together)")
    expect(page.get_by_role("img", name="Per-pose RMS")).to_be_visible()
    expect(page.get_by_text("Residual vectors in the camera image")).to_be_visible()
    expect(page.get_by_text("Residual vectors in the projector image")).to_be_visible()
    with page.expect_download() as download:
        page.get_by_role("button", name="Download Per-pose RMS CSV").click()
    assert Path(download.value.path()).read_text().splitlines()[0].startswith("pose,camera_rms_px,projector_rms_px")
    page.wait_for_function("() => window.fringelab.procamReport && window.fringelab.procamReport.drawn === 3",
                           timeout=60_000)  # fmt: skip
    expect(page.locator(".plot-area .main-svg").first).to_be_visible()
    assert page.locator(".plot-area .main-svg").count() >= 3
    screenshot(page, "procam-report")
