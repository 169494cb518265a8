"""Camera calibration jobs through the API on a synthetic Z-stack: versioned records, the report, the refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Camera, Experiment, Recording
from fringelab.formats.recordings import write_recording
from fringelab.formats.sidecars import z_csv_text
from fringelab.science.synthetic import reference_camera, render_zstack_frames, zstack_board
from tests.worker.conftest import log_messages, wait_job

pytestmark = pytest.mark.integration
Z_MM = np.linspace(-20.0, 60.0, 5)  # the fewest frames a zstack calibration takes, over a plausible range


@pytest.fixture(scope="module")
def zstack_frames():
    camera = reference_camera("512x480")
    board = zstack_board(camera)
    return camera, board, render_zstack_frames(camera, board, Z_MM, rng=np.random.default_rng(5))


def add_recording(
    settings, zstack_frames, *, name: str = "zstack", pitch_v_ratio: float | None = None
) -> dict[str, int]:
    """A ready camera-calibration recording (folder of PNGs with z.csv and board.json) of a camera `left` in an
    experiment of its own."""
    camera, board, frames = zstack_frames
    relative = Path("recordings") / name
    board_json = f'{{"cols": {board.cols}, "rows": {board.rows}, "square_mm": {board.square_mm}}}'
    write_recording(
        settings.data_path / relative, frames, sidecars={"z.csv": z_csv_text(Z_MM), "board.json": board_json}
    )
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        experiment = Experiment(name=f"plate {name}")
        pitch_um = 1000.0 / camera.du_px_per_mm
        row = Camera(experiment=experiment, name="left", image_width_px=512, image_height_px=480,
                     pixel_pitch_um=pitch_um,
                     pixel_pitch_v_um=None if pitch_v_ratio is None else pitch_um * pitch_v_ratio)  # fmt: skip
        recording = Recording(camera=row, kind="camera_calibration", state="ready", path=str(relative),
                              frame_count=len(frames), width_px=512, height_px=480, sha256="cd" * 32)  # fmt: skip
        session.add_all([experiment, row, recording])
        session.commit()
        ids = {"recording": recording.id, "camera": row.id, "experiment": experiment.id}
    engine.dispose()
    return ids


@pytest.fixture
def recording(settings, zstack_frames) -> dict[str, int]:
    return add_recording(settings, zstack_frames)


def test_a_camera_calibration_job_makes_a_versioned_calibration_with_a_report(client, celery_worker, recording):
    # the synthetic 512x480 camera carries its scale factor on v, as in the paper
    spec = {"kind": "camera_calibration", "recording_id": recording["recording"], "scale_on": "v"}
    job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=120)
    assert job["state"] == "succeeded", job["error"]
    assert job["result"]["version"] == 1 and job["result"]["verdict"] in ("good", "check")
    assert job["provenance"]["inputs"] == [{"recording_id": recording["recording"], "sha256": "cd" * 32, "frames": 5}]
    assert job["provenance"]["science"]["input_sha256"]
    assert [f["name"] for f in job["files"]] == ["camera.json"]
    assert any(m.startswith("camera calibration version 1: RMS") for m in log_messages(client, job["id"]))

    [calibration] = client.get("/api/v1/calibrations", params={"camera_id": recording["camera"]}).json()
    assert calibration["id"] == job["result"]["calibration_id"] and calibration["job_id"] == job["id"]
    assert (calibration["image_width_px"], calibration["image_height_px"]) == (512, 480)
    assert calibration["sha256"] == job["files"][0]["sha256"]
    report = client.get(calibration["report_url"]).json()["report"]
    # the synthetic truth: f = 22.8519 mm; 0.5 % is far outside what 5 noisy frames leave (tens of µm)
    assert report["parameters"]["f_mm"]["value"] == pytest.approx(22.8519, rel=5e-3)
    assert report["parameters"]["f_mm"]["standard_error"] > 0
    assert [f["status"] for f in report["frames"]] == ["used"] * 5
    assert all(f["rms_px"] < 0.5 for f in report["frames"])
    assert len(report["residuals"]["du_px"]) == report["n_points"]
    assert report["verdict"]["level"] == job["result"]["verdict"]
    assert client.get(calibration["file_url"]).json()["schema"] == "fringelab.camera-calibration"


def test_two_calibrations_of_one_camera_at_once_get_two_versions(client, celery_worker, recording):
    base = {"kind": "camera_calibration", "recording_id": recording["recording"]}
    ids = [client.post("/api/v1/jobs", json=base | {"reject_outliers": flag}).json()["id"] for flag in (False, True)]
    jobs = [wait_job(client, job_id, timeout_s=180) for job_id in ids]
    assert [job["state"] for job in jobs] == ["succeeded", "succeeded"]
    assert sorted(job["result"]["version"] for job in jobs) == [1, 2]
    listed = client.get("/api/v1/calibrations", params={"camera_id": recording["camera"], "kind": "camera"}).json()
    assert [c["version"] for c in listed] == [2, 1]


def test_a_calibration_that_cannot_be_done_fails_with_what_to_do(client, celery_worker, recording, settings):
    (settings.data_path / "recordings" / "zstack" / "board.json").unlink()
    spec = {"kind": "camera_calibration", "recording_id": recording["recording"]}
    job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=60)
    assert job["state"] == "failed"
    assert "no board given and no board.json in the recording" in job["error"]
    assert client.get("/api/v1/calibrations").json() == []

    wrong_board = spec | {"board": {"cols": 3, "rows": 3, "square_mm": 10}}
    job = wait_job(client, client.post("/api/v1/jobs", json=wrong_board).json()["id"], timeout_s=60)
    assert job["state"] == "failed"
    assert "chessboard" in job["error"]


def test_jobs_of_several_experiments_at_once_each_end_with_their_own_results(
    client, celery_worker, settings, zstack_frames
):
    experiments = [add_recording(settings, zstack_frames, name=f"stack-{i}") for i in range(3)]
    specs = [{"kind": "camera_calibration", "recording_id": e["recording"], "scale_on": "v"} for e in experiments]
    ids = [client.post("/api/v1/jobs", json=spec).json()["id"] for spec in specs]
    selftest = client.post("/api/v1/jobs", json={"kind": "selftest", "frames": 30, "chunk_frames": 10}).json()["id"]
    jobs = [wait_job(client, job_id, timeout_s=240) for job_id in ids]
    assert wait_job(client, selftest, timeout_s=60)["state"] == "succeeded"
    for experiment, job in zip(experiments, jobs, strict=True):
        assert job["state"] == "succeeded", job["error"]
        assert job["experiment_id"] == experiment["experiment"]
        [calibration] = client.get("/api/v1/calibrations", params={"camera_id": experiment["camera"]}).json()
        assert (calibration["job_id"], calibration["version"]) == (job["id"], 1)
    listed = client.get("/api/v1/jobs", params={"experiment_id": experiments[1]["experiment"]}).json()
    assert [j["id"] for j in listed["items"]] == [ids[1]]


def test_the_pixel_pitch_along_v_sets_d_v(client, celery_worker, settings, zstack_frames):
    """A camera entered with pixels 5 % taller than wide: the calibration takes D_v = 1000 / pitch_v px/mm, and
    the scale factor on v takes up the difference (the image itself is the same), so s_v grows by 5 %."""
    camera = zstack_frames[0]
    ids = add_recording(settings, zstack_frames, name="tall-pixels", pitch_v_ratio=1.05)
    spec = {"kind": "camera_calibration", "recording_id": ids["recording"], "scale_on": "v"}
    job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=120)
    assert job["state"] == "succeeded", job["error"]
    report = client.get(f"/api/v1/calibrations/{job['result']['calibration_id']}/report").json()["report"]
    pitch_u_um = 1000.0 / camera.du_px_per_mm
    assert report["sensor"]["pixel_pitch_um"] == pytest.approx([pitch_u_um, 1.05 * pitch_u_um], rel=1e-12)
    assert report["sensor"]["dv_px_per_mm"] == pytest.approx(camera.dv_px_per_mm / 1.05, rel=1e-12)
    assert report["sensor"]["du_px_per_mm"] == pytest.approx(camera.du_px_per_mm, rel=1e-12)
    # D_v·s_v is what the image fixes: s_v = 1.05 × the truth's, to 0.1 % (its standard error is about 1e-4).
    assert report["parameters"]["su"]["value"] == pytest.approx(1.05 * camera.su, rel=1e-3)
