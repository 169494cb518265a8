"""Experiments, cameras and recordings through the API: create, list, read, update, delete, errors."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.models import Camera, Job, Recording
from fringelab.core.storage import recording_dir


@pytest.fixture
def client(settings):
    with TestClient(create_app(settings)) as made:
        yield made


def test_experiment_and_camera_lifecycle(client):
    created = client.post(
        "/api/v1/experiments", json={"name": " plate 3 ", "plate": "AA7075", "test_date": "2026-11-20"}
    )
    assert created.status_code == 201, created.text
    experiment = created.json()
    assert experiment["name"] == "plate 3" and experiment["plate"] == "AA7075"
    eid = experiment["id"]
    assert [e["id"] for e in client.get("/api/v1/experiments").json()] == [eid]
    updated = client.patch(f"/api/v1/experiments/{eid}", json={"notes": "punch 20 mm"})
    assert updated.json()["notes"] == "punch 20 mm" and updated.json()["plate"] == "AA7075"

    body = {"name": "left", "image_width_px": 1280, "image_height_px": 800, "pixel_pitch_um": 20}
    camera = client.post(f"/api/v1/experiments/{eid}/cameras", json=body)
    assert camera.status_code == 201, camera.text
    cid = camera.json()["id"]
    assert client.get(f"/api/v1/experiments/{eid}/cameras").json()[0]["name"] == "left"
    assert client.patch(f"/api/v1/cameras/{cid}", json={"pixel_pitch_um": 28}).json()["pixel_pitch_um"] == 28
    twin = client.post(f"/api/v1/experiments/{eid}/cameras", json=body)
    assert twin.status_code == 409 and twin.json()["code"] == "camera_exists"
    assert client.get(f"/api/v1/cameras/{cid}/recordings").json() == []

    assert client.delete(f"/api/v1/cameras/{cid}").status_code == 204
    assert client.get(f"/api/v1/cameras/{cid}").status_code == 404
    assert client.delete(f"/api/v1/experiments/{eid}").status_code == 204
    missing = client.get(f"/api/v1/experiments/{eid}")
    assert missing.status_code == 404
    assert missing.json() == {"detail": f"experiment {eid} not found", "code": "not_found"}


@pytest.mark.parametrize(
    "body",
    [
        {"name": ""},
        {"name": "x", "test_date": "20 Nov"},
        {"name": "x", "colour": "red"},
    ],
)
def test_bad_experiment_fields_are_422_with_a_code(client, body):
    response = client.post("/api/v1/experiments", json=body)
    assert response.status_code == 422
    assert response.json()["code"] == "invalid_input"


def test_bad_camera_fields_are_422(client):
    eid = client.post("/api/v1/experiments", json={"name": "x"}).json()["id"]
    for body in (
        {"name": "left", "image_width_px": 0, "image_height_px": 800, "pixel_pitch_um": 20},
        {"name": "left", "image_width_px": 1280, "image_height_px": 800, "pixel_pitch_um": -1},
        {"name": "left", "image_width_px": 1280, "image_height_px": 800},
    ):
        assert client.post(f"/api/v1/experiments/{eid}/cameras", json=body).status_code == 422
    # access (here: existence) is checked before the body: an unknown experiment is a 404 whatever is sent
    assert client.post("/api/v1/experiments/999/cameras", json={}).json()["code"] == "not_found"
    good = {"name": "left", "image_width_px": 1, "image_height_px": 1, "pixel_pitch_um": 1}
    assert client.post("/api/v1/experiments/999/cameras", json=good).json()["code"] == "not_found"


def _stored_recording(client, settings) -> tuple[int, int, int]:
    """An experiment, camera and recording with a file on disk, made directly in the database."""
    eid = client.post("/api/v1/experiments", json={"name": "x"}).json()["id"]
    body = {"name": "left", "image_width_px": 64, "image_height_px": 48, "pixel_pitch_um": 20}
    cid = client.post(f"/api/v1/experiments/{eid}/cameras", json=body).json()["id"]
    state = client.app.state.fringelab
    with state.sessions() as session:
        recording = Recording(camera_id=cid, kind="test", state="ready", filename="a.zip", path="")
        session.add(recording)
        session.commit()
        folder = recording_dir(settings.data_path, recording.id)
        folder.mkdir(parents=True)
        (folder / "recording.zip").write_bytes(b"PK")
        recording.path = str((folder / "recording.zip").relative_to(settings.data_path))
        session.commit()
        return eid, cid, recording.id


def test_jobs_name_their_experiment_and_camera(client, settings):
    """The jobs list names each job's experiment and camera: through its recording, or the job it reads."""
    eid, _, rid = _stored_recording(client, settings)
    state = client.app.state.fringelab
    with state.sessions() as session:
        spec = {"recording_id": rid}
        session.add(Job(id="job-1", kind="topography", state="succeeded", experiment_id=eid, spec=spec))
        session.add(Job(id="job-2", kind="export", state="succeeded", experiment_id=eid, spec={"job_id": "job-1"}))
        session.add(Job(id="job-3", kind="selftest", state="succeeded", spec={}))
        session.commit()
    jobs = {job["id"]: job for job in client.get("/api/v1/jobs").json()["items"]}
    names = {job_id: (job["experiment_name"], job["camera_name"]) for job_id, job in jobs.items()}
    assert names == {"job-1": ("x", "left"), "job-2": ("x", "left"), "job-3": (None, None)}


# A job uses what its kind's inputs name (fringelab.core.job_kinds; `named_by` is tested in tests/core): the
# key-suffix scan of any spec (`recording_ids`, nested `..._recording_id`) that this test also covered is retired.
@pytest.mark.parametrize("spec_key", ["recording_id"])
def test_delete_is_refused_while_a_job_uses_the_recording_and_then_removes_its_files(client, settings, spec_key):
    eid, cid, rid = _stored_recording(client, settings)
    spec = {spec_key: rid}
    state = client.app.state.fringelab
    with state.sessions() as session:
        session.add(Job(id="job-1", kind="topography", state="running", spec=spec))
        session.commit()
    for path in (f"/api/v1/recordings/{rid}", f"/api/v1/cameras/{cid}", f"/api/v1/experiments/{eid}"):
        refused = client.delete(path)
        assert refused.status_code == 409, path
        assert refused.json()["code"] == "in_use" and "topography job job-1 (running)" in refused.json()["detail"]
    assert recording_dir(settings.data_path, rid).exists()
    with state.sessions() as session:
        session.get(Job, "job-1").state = "succeeded"
        session.commit()
    assert client.delete(f"/api/v1/experiments/{eid}").status_code == 204
    assert not recording_dir(settings.data_path, rid).exists()
    with state.sessions() as session:
        assert session.get(Camera, cid) is None and session.get(Recording, rid) is None


def test_recording_reads_lists_and_not_ready_previews(client, settings):
    _eid, cid, rid = _stored_recording(client, settings)
    body = client.get(f"/api/v1/recordings/{rid}").json()
    assert body["camera_id"] == cid and body["warnings"] == [] and body["state"] == "ready"
    assert body["created_at"].endswith("Z")  # UTC, though SQLite stores it without a zone
    assert [r["id"] for r in client.get(f"/api/v1/recordings?camera_id={cid}").json()] == [rid]
    assert client.get("/api/v1/recordings?state=invalid").json() == []
    renamed = client.patch(f"/api/v1/recordings/{rid}", json={"filename": "plate3-test.zip"})
    assert renamed.json()["filename"] == "plate3-test.zip"
    no_previews = client.get(f"/api/v1/recordings/{rid}/frames/0")
    assert no_previews.status_code == 409 and no_previews.json()["code"] == "not_ready"
    assert client.get("/api/v1/recordings/999/frames/0").status_code == 404
    assert client.get(f"/api/v1/recordings/{rid}/file").content == b"PK"


def test_the_openapi_schema_documents_every_route(client):
    paths = client.get("/api/openapi.json").json()["paths"]
    for path in (
        "/api/v1/experiments",
        "/api/v1/experiments/{experiment_id}/cameras",
        "/api/v1/recordings/{recording_id}",
        "/api/v1/recordings/{recording_id}/frames/{index}",
        "/api/v1/recordings/{recording_id}/qa",
        "/api/v1/uploads",
        "/api/v1/uploads/{uuid}",
        "/api/v1/uploads/cameras/{camera_id}/{filename}",
    ):
        assert path in paths, path


def test_the_job_spec_schemas_are_the_openapi_documents_own(client):
    """GET /jobs/specs (what the dashboard's forms are built from) holds each startable kind's spec model as the
    OpenAPI document does, its references pointing within itself, at a tenth of the size."""
    from fringelab.core.job_kinds import JOB_KINDS

    answer = client.get("/api/v1/jobs/specs")
    assert answer.status_code == 200
    schemas = answer.json()["schemas"]
    document = client.get("/api/openapi.json").json()["components"]["schemas"]
    for entry in JOB_KINDS.values():
        name = entry.spec.__name__
        assert (name in schemas) == entry.startable, name
        if entry.startable:
            assert schemas[name]["properties"].keys() == document[name]["properties"].keys(), name
            assert schemas[name]["properties"]["kind"]["const"] == entry.kind
    refs = {value.split("/")[-1] for value in _values_of(schemas, "$ref")}
    assert refs and refs <= schemas.keys()
    assert len(answer.content) * 5 < len(client.get("/api/openapi.json").content)


def _values_of(tree, key):
    if isinstance(tree, dict):
        for k, v in tree.items():
            if k == key:
                yield v
            else:
                yield from _values_of(v, key)
    elif isinstance(tree, list):
        for v in tree:
            yield from _values_of(v, key)
