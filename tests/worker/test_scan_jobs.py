"""Scan jobs through the API with a real worker, on the virtual digital-projector rig (docs/procam.md §3)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Calibration, Camera, Experiment, Recording
from fringelab.formats.patterns import patterns_json_text
from fringelab.formats.procam import write_procam_json
from fringelab.formats.recordings import write_recording
from fringelab.formats.scan import read_scan
from fringelab.science.graycode import PatternSequence, WhiteBlack
from tests.procam_rig import POSE_COLUMNS, POSE_ROWS, RIG, SCAN_COLUMNS, ball_frames, pose_recordings
from tests.worker.conftest import log_messages, wait_job

pytestmark = pytest.mark.integration
SEQUENCE = SCAN_COLUMNS


@pytest.fixture(scope="module")
def frames() -> list[np.ndarray]:
    return ball_frames(supersample=1, seed=3)


def add_scan_rows(settings, frames, *, calibration_size=(360, 270), patterns: str | None = None,
                  model=RIG) -> dict[str, int]:  # fmt: skip
    """A ready coded recording of a camera and a procam calibration of it (the rig's truth unless `model`)."""
    relative = Path("recordings") / "sphere"
    text = patterns_json_text(SEQUENCE) if patterns is None else patterns
    write_recording(settings.data_path / relative, frames, sidecars={"patterns.json": text})
    calibration_path = Path("calibrations") / "procam.json"
    write_procam_json(settings.data_path / calibration_path, model)
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        experiment = Experiment(name="ball")
        camera = Camera(experiment=experiment, name="left", image_width_px=360, image_height_px=270,
                        pixel_pitch_um=5.0)  # fmt: skip
        recording = Recording(camera=camera, kind="coded", state="ready", path=str(relative),
                              frame_count=len(frames), width_px=360, height_px=270, sha256="ef" * 32)  # fmt: skip
        session.add_all([experiment, camera, recording])
        session.flush()
        calibration = Calibration(kind="procam", camera_id=camera.id, path=str(calibration_path),
                                  image_width_px=calibration_size[0], image_height_px=calibration_size[1])  # fmt: skip
        session.add(calibration)
        session.commit()
        ids = {"recording": recording.id, "calibration": calibration.id}
    engine.dispose()
    return ids


def test_a_scan_job_measures_the_sphere(client, celery_worker, settings, frames) -> None:
    ids = add_scan_rows(settings, frames)
    spec = {"kind": "scan", "recording_id": ids["recording"], "procam_calibration_id": ids["calibration"]}
    job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=120)
    assert job["state"] == "succeeded", job["error"]
    assert [f["name"] for f in job["files"]] == ["scan.h5"]
    assert job["result"]["points_by_source"]["stripe edge"] > 1000
    assert any("points" in m and "decoded" in m for m in log_messages(client, job["id"]))
    [path] = [p for p in settings.data_path.rglob("scan.h5") if job["id"] in str(p)]
    stored = read_scan(path)
    edge = stored.source == 0
    radial = np.linalg.norm(stored.points_cam_mm[edge] - np.array([0.0, 0.0, 300.0]), axis=1) - 20.0
    # One sample per pixel here (supersample 1): the sphere's points within the science test's 0.05 mm.
    assert np.sqrt(np.mean(radial[np.abs(radial) < 1.0] ** 2)) < 0.05
    # The scan view's data: a sample of the points (stripe edges first), the depth map and the decoding's maps.
    view = client.get(f"/api/v1/jobs/{job['id']}/scan", params={"max_points": 2000}).json()
    assert view["points"]["n_total"] == len(stored.sigma_mm) and len(view["points"]["z_mm"]) == 2000
    assert view["points"]["source"][0] == 0 and 0 in view["points"]["source"] and 2 in view["points"]["source"]
    assert view["qa"]["valid_share"] == pytest.approx(stored.qa["valid_share"])
    assert view["code"]["width"] == 360 and len(view["code"]["values"]) == 270 // view["code"]["step_px"] + (
        270 % view["code"]["step_px"] > 0)  # fmt: skip
    other = client.get(f"/api/v1/jobs/{job['id']}/topography")
    assert other.status_code == 404 and "not a topography" in other.json()["detail"]


def test_a_scan_job_maps_the_patterns_pixels_to_the_calibrations(client, celery_worker, settings, frames) -> None:
    """A calibration whose projector pixel 0 is the patterns' pixel −3 (principal point 3 px further): the spec's
    projector_offset_x_px 3 gives the sphere back, and the file records the mapping."""
    matrix = RIG.projector_matrix.copy()
    matrix[0, 2] += 3.0
    shifted = replace(RIG, projector_matrix=matrix)
    ids = add_scan_rows(settings, frames, model=shifted)
    spec = {"kind": "scan", "recording_id": ids["recording"], "procam_calibration_id": ids["calibration"],
            "projector_offset_x_px": 3.0, "code_points": False}  # fmt: skip
    job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=120)
    assert job["state"] == "succeeded", job["error"]
    [path] = [p for p in settings.data_path.rglob("scan.h5") if job["id"] in str(p)]
    stored = read_scan(path)
    radial = np.linalg.norm(stored.points_cam_mm - np.array([0.0, 0.0, 300.0]), axis=1) - 20.0
    assert np.sqrt(np.mean(radial[np.abs(radial) < 1.0] ** 2)) < 0.05
    assert stored.provenance["projector_offset_xy_px"] == [3.0, 0.0]


def test_a_calibration_of_another_image_size_is_refused_before_queueing(client, celery_worker, settings,
                                                                        frames) -> None:  # fmt: skip
    ids = add_scan_rows(settings, frames, calibration_size=(640, 480))
    spec = {"kind": "scan", "recording_id": ids["recording"], "procam_calibration_id": ids["calibration"]}
    response = client.post("/api/v1/jobs", json=spec)
    assert response.status_code in (409, 422), response.text
    assert "procam_calibration_id" in response.text


def test_a_patterns_json_naming_missing_frames_fails_the_job_in_a_sentence(client, celery_worker, settings,
                                                                            frames) -> None:  # fmt: skip
    wrong = patterns_json_text(PatternSequence(axis="columns", projector_size_wh_px=(320, 200),
                                               gray_frames=tuple(range(2, 12)), band_px=1.0,
                                               threshold=WhiteBlack(0, 1)))  # fmt: skip
    ids = add_scan_rows(settings, frames, patterns=wrong)
    spec = {"kind": "scan", "recording_id": ids["recording"], "procam_calibration_id": ids["calibration"]}
    job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=120)
    assert job["state"] == "failed"
    assert "patterns.json: gray_frames names frames 10, 11 but the recording has 10 frames" in job["error"]
    assert job["files"] == []


def test_a_procam_calibration_job_records_a_versioned_calibration(client, celery_worker, settings) -> None:
    sidecars = {"patterns-columns.json": patterns_json_text(POSE_COLUMNS),
                "patterns-rows.json": patterns_json_text(POSE_ROWS)}  # fmt: skip
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        experiment = Experiment(name="rig")
        camera = Camera(experiment=experiment, name="left", image_width_px=360, image_height_px=270,
                        pixel_pitch_um=5.0)  # fmt: skip
        session.add_all([experiment, camera])
        recordings = []
        for i, pose_frames in enumerate(pose_recordings(seed=12)):
            relative = Path("recordings") / f"pose{i}"
            write_recording(settings.data_path / relative, pose_frames, sidecars=sidecars)
            recordings.append(Recording(camera=camera, kind="coded", state="ready", path=str(relative), frame_count=19,
                                        width_px=360, height_px=270, sha256=f"{i:02d}" * 32))  # fmt: skip
        session.add_all(recordings)
        session.commit()
        ids = [r.id for r in recordings]
        camera_id = camera.id
    engine.dispose()
    spec = {"kind": "procam_calibration", "recording_ids": ids, "board": {"cols": 9, "rows": 7, "square_mm": 8.0}}
    job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=180)
    assert job["state"] == "succeeded", job["error"]
    assert job["result"]["poses"] == 4 and job["result"]["stereo_rms_px"] < 0.2
    assert [f["name"] for f in job["files"]] == ["procam.json"]
    [calibration] = client.get("/api/v1/calibrations", params={"camera_id": camera_id}).json()
    assert calibration["kind"] == "procam" and calibration["version"] == 1
    report = client.get(f"/api/v1/calibrations/{calibration['id']}/procam-report").json()["report"]
    assert [p["pose"] for p in report["poses"]] == ["pose0", "pose1", "pose2", "pose3"]
    assert report["verdict"]["level"] == job["result"]["verdict"] and report["rms"]["stereo_px"] < 0.2
    assert len(report["poses"][0]["projector_residual_px"]) == 63
