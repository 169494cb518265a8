"""Deletes and what goes with them: the plan a confirmation shows (`GET .../deletion`) lists the recordings, the
finished jobs on them, their calibrations and exports and the bytes; the delete removes exactly that (rows and
files) and is refused, naming the jobs, while a queued or running job uses any of it."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.models import Calibration, Job, JobLog, Recording
from fringelab.core.storage import job_dir, recording_dir
from tests.api.recordings.test_api_experiments import _stored_recording


@pytest.fixture
def client(settings):
    with TestClient(create_app(settings)) as made:
        yield made


def _job(session, settings, job_id: str, kind: str, state: str, spec: dict, *, size: int = 0) -> Job:
    files = []
    if size:
        folder = job_dir(settings.data_path, job_id)
        folder.mkdir(parents=True)
        (folder / "out.bin").write_bytes(b"x" * size)
        files = [{"name": "out.bin", "path": f"results/jobs/{job_id}/out.bin", "size_bytes": size, "sha256": ""}]
    job = Job(id=job_id, kind=kind, state=state, spec=spec, files=files)
    session.add(job)
    session.add(JobLog(job_id=job_id, level="info", message="made by the test"))
    return job


def test_a_recordings_plan_lists_its_jobs_calibrations_and_exports_and_the_delete_removes_them(client, settings):
    eid, cid, rid = _stored_recording(client, settings)
    state = client.app.state.fringelab
    with state.sessions() as session:
        _job(session, settings, "cal-1", "camera_calibration", "succeeded", {"recording_id": rid}, size=3000)
        session.flush()
        session.add(Calibration(kind="camera", camera_id=cid, recording_id=rid, job_id="cal-1",
                                path="results/jobs/cal-1/out.bin"))  # fmt: skip
        _job(session, settings, "topo-1", "topography", "failed", {"recording_id": rid}, size=5000)
        _job(session, settings, "export-1", "export", "succeeded", {"job_id": "topo-1"}, size=7000)
        _job(session, settings, "other", "topography", "succeeded", {"recording_id": rid + 1000})
        session.commit()
    with state.sessions() as session:
        session.get(Recording, rid).size_bytes = 2
        session.commit()
    plan = client.get(f"/api/v1/recordings/{rid}/deletion").json()
    assert (plan["recordings"], plan["jobs"], plan["calibrations"], plan["blocked_by"]) == (1, 3, 1, [])
    assert plan["bytes"] == 2 + 3000 + 5000 + 7000  # the recording's file, and each job's files once
    assert plan["summary"].startswith(f"Deletes recording {rid} (a.zip) with 1 recording, 3 jobs and 1 calibration")

    with state.sessions() as session:  # an export started from the failed topography's sibling: now running
        _job(session, settings, "export-2", "export", "running", {"job_id": "cal-1"})
        session.commit()
    refused = client.delete(f"/api/v1/recordings/{rid}")
    assert refused.status_code == 409 and refused.json()["code"] == "in_use"
    assert "export job export-2 (running)" in refused.json()["detail"]
    blocked = client.get(f"/api/v1/recordings/{rid}/deletion").json()
    assert blocked["blocked_by"] == [{"id": "export-2", "kind": "export", "state": "running"}]
    assert "Not possible now: export job export-2 (running)" in blocked["summary"]
    with state.sessions() as session:
        session.get(Job, "export-2").state = "cancelled"
        session.commit()

    assert client.delete(f"/api/v1/recordings/{rid}").status_code == 204
    with state.sessions() as session:
        left = {job.id for job in session.query(Job)}
        assert left == {"other"}, left  # export-2 went with cal-1 (its source); "other" used another recording
        assert session.query(Calibration).count() == 0
        assert session.query(JobLog).filter(JobLog.job_id != "other").count() == 0
    for job_id in ("cal-1", "topo-1", "export-1"):
        assert not job_dir(settings.data_path, job_id).exists()
    assert not recording_dir(settings.data_path, rid).exists()


def test_a_job_is_deleted_with_its_result_but_not_while_it_or_a_user_of_its_calibration_runs(client, settings):
    _eid, cid, rid = _stored_recording(client, settings)
    state = client.app.state.fringelab
    with state.sessions() as session:
        _job(session, settings, "cal-2", "camera_calibration", "running", {"recording_id": rid}, size=100)
        session.commit()
    refused = client.delete("/api/v1/jobs/cal-2")
    assert (refused.status_code, refused.json()["code"]) == (409, "in_use")
    assert "camera_calibration job cal-2 (running)" in refused.json()["detail"]
    with state.sessions() as session:
        session.get(Job, "cal-2").state = "succeeded"
        calibration = Calibration(kind="camera", camera_id=cid, recording_id=rid, job_id="cal-2", path="x.json")
        session.add(calibration)
        session.flush()
        spec = {"recording_id": rid + 5, "camera_calibration_id": calibration.id}
        _job(session, settings, "topo-2", "topography", "queued", spec)
        session.commit()
    refused = client.delete("/api/v1/jobs/cal-2")
    assert refused.status_code == 409 and "topography job topo-2 (queued)" in refused.json()["detail"]
    with state.sessions() as session:
        session.get(Job, "topo-2").state = "succeeded"
        session.commit()
    plan = client.get("/api/v1/jobs/cal-2/deletion").json()
    assert (plan["jobs"], plan["calibrations"], plan["recordings"]) == (1, 1, 0)
    assert client.delete("/api/v1/jobs/cal-2").status_code == 204
    assert client.get("/api/v1/jobs/cal-2").status_code == 404
    assert client.get("/api/v1/jobs/topo-2").status_code == 200  # it used the calibration: it keeps its result
    assert client.get(f"/api/v1/recordings/{rid}").status_code == 200
    assert not job_dir(settings.data_path, "cal-2").exists()
