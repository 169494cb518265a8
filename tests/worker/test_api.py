"""The jobs API against a real Redis and a real Celery worker (threads pool): start, watch, cancel, retry, and the
clear refusals of bad requests."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from fringelab.core.settings import Settings
from fringelab.core.startup_checks import free_port
from tests.worker.conftest import log_messages, wait_job
from worker.jobs.selftest import selftest_frame

SELFTEST = {"kind": "selftest", "frames": 12, "frame_size_px": 32, "chunk_frames": 5}


@pytest.mark.integration
def test_a_selftest_runs_in_chunks_and_its_file_holds_every_frame_once(client, celery_worker, tmp_path):
    created = client.post("/api/v1/jobs", json=SELFTEST)
    assert created.status_code == 201, created.text
    assert created.json()["state"] == "queued"
    job = wait_job(client, created.json()["id"])
    assert job["state"] == "succeeded", job["error"]
    # two fan-outs (compute, then verify every frame again), each over the same three chunks
    ranges = [(0, 5), (5, 10), (10, 12)]
    assert [(c["phase"], c["first_frame"], c["stop_frame"], c["state"]) for c in job["chunks"]] == [
        (phase, first, stop, "done") for phase in (0, 1) for first, stop in ranges
    ]
    assert job["progress"] | {"eta_s": None} == {
        "stage": "writing",
        "done": 1,
        "total": 1,
        "fraction": 1.0,
        "eta_s": None,
    }
    workers = job["result"]["workers"]
    assert job["result"]["frames"] == 12
    assert sum(workers["computing"].values()) == sum(workers["verifying"].values()) == 12
    assert job["provenance"]["spec"] == SELFTEST | {"kind": "selftest"}
    assert job["provenance"]["code_version"]
    assert job["duration_s"] > 0
    [file] = job["files"]
    download = client.get(file["url"])
    assert download.status_code == 200
    path = tmp_path / "selftest.h5"
    path.write_bytes(download.content)
    with h5py.File(path) as result:
        assert result["frame"][:].tolist() == list(range(12))
        expected = [selftest_frame(f, size_px=32)[1].encode() for f in range(12)]
        assert result["digest"][:].tolist() == expected
        assert result["chain"][-1].decode() == job["result"]["digest"]
        np.testing.assert_allclose(result["value"][:], [selftest_frame(f, size_px=32)[0] for f in range(12)])
    messages = log_messages(client, job["id"])
    assert messages[0].startswith("queued (selftest, attempt 1)")
    assert any(m.startswith("started on ") for m in messages)
    assert "computing frames: 3 chunk(s) of up to 5 frames" in messages
    assert "verifying frames: 3 chunk(s) of up to 5 frames" in messages
    assert messages[-1] == "succeeded: selftest.h5"


@pytest.mark.integration
def test_the_event_stream_shows_the_job_in_order_and_ends(client, celery_worker):
    job_id = client.post("/api/v1/jobs", json=SELFTEST | {"frames": 40, "frame_size_px": 128}).json()["id"]
    events = []
    with client.stream("GET", f"/api/v1/jobs/{job_id}/events") as stream:
        assert stream.headers["content-type"].startswith("text/event-stream")
        event: dict[str, str] = {}
        for line in stream.iter_lines():
            if line.startswith(("event:", "data:", "id:")):
                key, _, value = line.partition(":")
                event[key] = value.strip()
            elif not line and event:
                events.append((event["event"], json.loads(event["data"])))
                event = {}
    kinds = [kind for kind, _ in events]
    assert kinds[-1] == "end" and events[-1][1]["state"] == "succeeded"
    views = [data for kind, data in events if kind == "job"]
    states = [v["state"] for v in views]
    assert states == sorted(states, key=["queued", "running", "succeeded"].index)
    assert states[-1] == "succeeded"
    stages = [v["progress"]["stage"] for v in views if v["state"] == "running"]
    order = ["", "computing frames", "chaining", "verifying frames", "writing"]
    assert stages == sorted(stages, key=order.index), "stages out of order"
    for stage in order:
        done = [v["progress"]["done"] for v in views if v["progress"]["stage"] == stage and v["state"] == "running"]
        assert done == sorted(done), f"progress went backwards in {stage}"
    logged = [data["message"] for kind, data in events if kind == "log"]
    assert logged == log_messages(client, job_id)


def test_an_invalid_spec_is_a_422_naming_the_field(client):
    for spec, field in (
        ({"kind": "selftest", "frames": 0}, "frames"),
        ({"kind": "selftest", "frame": 10}, "frame"),
        ({"kind": "topography", "recording_id": 1}, "camera_calibration_id"),
        (
            {
                "kind": "topography",
                "recording_id": 1,
                "camera_calibration_id": 1,
                "projector_calibration_id": 1,
                "frames": {"first": 9, "last": 3},
            },
            "frames",
        ),
    ):
        response = client.post("/api/v1/jobs", json=spec)
        assert response.status_code == 422, spec
        body = response.json()
        assert body["code"] == "invalid_input"
        assert field in body["detail"], body
        assert any(field in [str(part) for part in error["loc"]] for error in body["errors"]), body
    unknown = client.post("/api/v1/jobs", json={"kind": "nonsense"})
    assert unknown.status_code == 422
    assert "'kind'" in unknown.json()["detail"] and "topography" in unknown.json()["detail"]


def test_inputs_are_checked_against_the_database_before_anything_is_queued(client, add_rows):
    ids = add_rows(frame_count=20)
    base = {
        "kind": "topography",
        "recording_id": ids["test"],
        "camera_calibration_id": ids["camera_cal"],
        "projector_calibration_id": ids["projector_cal"],
    }
    for changes, status, code, field in (
        ({"recording_id": 999}, 422, "recording_not_found", "recording_id"),
        ({"camera_calibration_id": ids["projector_cal"]}, 422, "calibration_not_found", "camera_calibration_id"),
        ({"camera_calibration_id": ids["other_camera_cal"]}, 422, "calibration_mismatch", "camera_calibration_id"),
        ({"frames": {"first": 0, "last": 20}}, 422, "frame_out_of_range", "frames.last"),
    ):
        response = client.post("/api/v1/jobs", json=base | changes)
        assert response.status_code == status, response.text
        assert response.json()["code"] == code
        assert response.json()["field"] == field
    mismatch = client.post("/api/v1/jobs", json=base | {"camera_calibration_id": ids["other_camera_cal"]})
    assert "(right)" in mismatch.json()["detail"] and "use a calibration of that camera" in mismatch.json()["detail"]
    assert client.get("/api/v1/jobs").json()["total"] == 0


def test_a_recording_not_ready_or_a_calibration_of_another_size_is_refused(client, add_rows):
    ingesting = add_rows(recording_state="ingesting")
    spec = {
        "kind": "topography",
        "recording_id": ingesting["test"],
        "camera_calibration_id": ingesting["camera_cal"],
        "projector_calibration_id": ingesting["projector_cal"],
    }
    response = client.post("/api/v1/jobs", json=spec)
    assert response.status_code == 409
    assert response.json()["code"] == "recording_not_ready"
    assert "wait for its ingest job" in response.json()["detail"]

    resized = add_rows(calibration_size=(1280, 1024))
    response = client.post(
        "/api/v1/jobs",
        json=spec
        | {
            "recording_id": resized["test"],
            "camera_calibration_id": resized["camera_cal"],
            "projector_calibration_id": resized["projector_cal"],
        },
    )
    assert response.status_code == 422
    assert response.json()["code"] == "calibration_mismatch"
    assert "1280x1024 px" in response.json()["detail"] and "640x480 px" in response.json()["detail"]


def test_cancel_a_queued_job_twice_and_retry_it(client):
    """No worker runs: the job stays queued, so cancel finds it queued."""
    job_id = client.post("/api/v1/jobs", json=SELFTEST).json()["id"]
    duplicate = client.post("/api/v1/jobs", json=SELFTEST)
    assert duplicate.status_code == 409 and duplicate.json()["code"] == "duplicate_job"
    assert duplicate.json()["job_id"] == job_id  # the queued job's id, for a script to watch it
    assert job_id in duplicate.json()["detail"]

    retry_running = client.post(f"/api/v1/jobs/{job_id}/retry")
    assert retry_running.status_code == 409 and retry_running.json()["code"] == "job_active"

    cancelled = client.post(f"/api/v1/jobs/{job_id}/cancel")
    assert cancelled.status_code == 200
    assert cancelled.json()["state"] == "cancelled" and not cancelled.json()["stopping"]
    again = client.post(f"/api/v1/jobs/{job_id}/cancel")
    assert again.status_code == 409
    assert again.json() == {
        "detail": f"job {job_id} was already cancelled; retry it to run it again",
        "code": "already_cancelled",
        "field": None,
    }

    retried = client.post(f"/api/v1/jobs/{job_id}/retry")
    assert retried.status_code == 201
    assert retried.json()["attempt"] == 2 and retried.json()["retry_of"] == job_id
    assert client.get(f"/api/v1/jobs/{job_id}").json()["retried_by"] == retried.json()["id"]
    twice = client.post(f"/api/v1/jobs/{job_id}/retry")
    assert twice.status_code == 409 and twice.json()["code"] == "already_retried"

    listed = client.get("/api/v1/jobs", params={"state": "cancelled"}).json()
    assert [j["id"] for j in listed["items"]] == [job_id]
    assert client.get("/api/v1/jobs", params={"kind": "selftest"}).json()["total"] == 2


@pytest.mark.integration
def test_cancel_a_running_job_stops_it_between_frames(client, celery_worker):
    job_id = client.post("/api/v1/jobs", json={"kind": "selftest", "frames": 5000, "frame_size_px": 64}).json()["id"]
    wait_job(client, job_id, until=("running",))
    response = client.post(f"/api/v1/jobs/{job_id}/cancel")
    assert response.status_code == 200 and response.json()["state"] == "cancelled"
    job = wait_job(client, job_id)
    assert job["state"] == "cancelled" and job["finished_at"] is not None
    assert job["progress"]["done"] < 5000
    messages = log_messages(client, job_id)
    assert "cancel requested: the worker stops after its current frame" in messages
    assert "stopped after the cancel" in messages
    assert client.post(f"/api/v1/jobs/{job_id}/cancel").json()["code"] == "already_cancelled"


def test_unknown_jobs_are_404_with_a_code(client):
    for method, path in (("get", ""), ("get", "/log"), ("get", "/events"), ("post", "/cancel"), ("post", "/retry")):
        response = getattr(client, method)(f"/api/v1/jobs/nope{path}")
        assert response.status_code == 404, path
        assert response.json()["code"] == "job_not_found"


def test_redis_down_at_submit_is_a_503_and_the_job_says_why(tmp_path):
    from fastapi.testclient import TestClient

    from backend.app import create_app
    from fringelab.core.db import upgrade_database

    settings = Settings(_env_file=None, data_dir=tmp_path / "var", redis_url=f"redis://127.0.0.1:{free_port()}/0")  # type: ignore[call-arg]
    upgrade_database(settings.resolved_database_url)
    with TestClient(create_app(settings)) as client:
        response = client.post("/api/v1/jobs", json=SELFTEST)
        assert response.status_code == 503
        assert response.json()["code"] == "queue_unavailable"
        [job] = client.get("/api/v1/jobs").json()["items"]
    assert job["state"] == "failed"
    assert "the job queue (Redis) is unreachable" in job["error"] and "try again" in job["error"]


def test_a_calibration_of_another_experiment_gets_the_answer_of_a_missing_one(client, add_rows):
    """Issue 26: a foreign calibration id got a different message from a missing one (an existence oracle)."""
    ids, foreign = add_rows(), add_rows()
    base = {"kind": "topography", "recording_id": ids["test"], "projector_calibration_id": ids["projector_cal"]}
    answers = [
        client.post("/api/v1/jobs", json=base | {"camera_calibration_id": calibration_id}).json()
        for calibration_id in (foreign["camera_cal"], 99_999)
    ]
    assert answers[0]["code"] == "calibration_not_found"
    assert answers[0]["detail"].replace(str(foreign["camera_cal"]), "N") == answers[1]["detail"].replace("99999", "N")
