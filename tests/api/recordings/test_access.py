"""With accounts on, recordings and uploads follow their experiment: the owner may, others get a 404 (their
bytes never written), strangers a 401; uploads and deletes go to the audit trail."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest
from sqlalchemy import Engine, select

from fringelab.core.accounts import create_user, issue_token
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import AuditEvent, Job
from fringelab.core.storage import tus_dir
from tests.api.recordings.conftest import TUS, serve, tus_create, tus_patch
from tests.formats.recording_files import stripe_frames, write_zip


@pytest.fixture
def server(settings) -> Iterator[tuple[str, dict[str, str], Engine]]:  # type: ignore[no-untyped-def]
    """The API with accounts on, and API tokens of `ada` and `bob` (members)."""
    secured = settings.model_copy(update={"auth_enabled": True})
    engine = make_engine(secured.resolved_database_url)
    tokens = {}
    with make_sessionmaker(engine)() as session:
        for name in ("ada", "bob"):
            tokens[name] = issue_token(session, create_user(session, name, f"{name}-password"), name="tests")[1]
        session.commit()
    with serve(secured) as base_url:
        yield base_url, tokens, engine
    engine.dispose()


def client_of(base_url: str, token: str | None) -> httpx.Client:
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    return httpx.Client(base_url=base_url, headers=headers, timeout=60)


def test_recordings_and_uploads_belong_to_the_experiment_owner(server, settings, tmp_path):
    base_url, tokens, engine = server
    ada, bob, nobody = client_of(base_url, tokens["ada"]), client_of(base_url, tokens["bob"]), client_of(base_url, None)
    experiment = ada.post("/api/v1/experiments", json={"name": "ada's plate"}).json()
    body = {"name": "left", "image_width_px": 64, "image_height_px": 48, "pixel_pitch_um": 20}
    camera = ada.post(f"/api/v1/experiments/{experiment['id']}/cameras", json=body).json()
    data = write_zip(tmp_path / "r.zip", stripe_frames(3)).read_bytes()
    put = f"/api/v1/uploads/cameras/{camera['id']}/r.zip"

    for response in (
        nobody.get("/api/v1/experiments"),
        nobody.put(put, params={"kind": "test"}, content=data),
        tus_create(nobody, len(data), filename="r.zip", filetype="x", camera_id=camera["id"], kind="test"),
    ):
        assert response.status_code == 401, response.text
        assert response.json()["code"] == "unauthorized"

    assert bob.get("/api/v1/experiments").json() == []
    for response in (
        bob.get(f"/api/v1/experiments/{experiment['id']}"),
        bob.get(f"/api/v1/cameras/{camera['id']}"),
        bob.post(f"/api/v1/experiments/{experiment['id']}/cameras",
                 json={"name": "right", "image_width_px": 1, "image_height_px": 1, "pixel_pitch_um": 1}),
        bob.put(put, params={"kind": "test"}, content=data),
        tus_create(bob, len(data), filename="r.zip", filetype="x", camera_id=camera["id"], kind="test"),
    ):  # fmt: skip
        assert response.status_code == 404, response.text

    # A half-done tus upload of ada's: bob can neither see it nor write into it.
    created = tus_create(ada, len(data), filename="r.zip", filetype="x", camera_id=camera["id"], kind="test")
    location = created.headers["Location"]
    assert tus_patch(ada, location, 0, data[:100]).status_code == 204
    assert bob.head(location, headers=TUS).status_code == 404
    sneaky = tus_patch(bob, location, 100, b"\0" * 50)
    assert (sneaky.status_code, sneaky.json()["code"]) == (404, "upload_not_found")
    assert (tus_dir(settings.data_path) / location.rsplit("/", 1)[1]).read_bytes() == data[:100]  # untouched
    last = tus_patch(ada, location, 100, data[100:])
    assert last.status_code == 204, last.text
    recording_id = int(last.headers["Fringelab-Recording-Id"])
    stored = ada.get(f"/api/v1/recordings/{recording_id}").json()
    assert stored["size_bytes"] == len(data)

    for path in (f"/api/v1/recordings/{recording_id}", f"/api/v1/recordings/{recording_id}/frames/0",
                 f"/api/v1/recordings/{recording_id}/qa", f"/api/v1/recordings/{recording_id}/file"):  # fmt: skip
        assert bob.get(path).status_code == 404, path
    assert bob.delete(f"/api/v1/recordings/{recording_id}").status_code == 404
    assert bob.get("/api/v1/recordings").json() == []
    assert [r["id"] for r in ada.get("/api/v1/recordings").json()] == [recording_id]
    refused = ada.delete(f"/api/v1/recordings/{recording_id}")  # its ingest is queued (no worker here)
    assert (refused.status_code, refused.json()["code"]) == (409, "in_use")
    with make_sessionmaker(engine)() as session:
        session.get(Job, stored["ingest_job_id"]).state = "cancelled"
        session.commit()
    assert ada.delete(f"/api/v1/recordings/{recording_id}").status_code == 204
    with make_sessionmaker(engine)() as session:
        events = [(e.username, e.action, e.object_type, e.object_id) for e in session.scalars(select(AuditEvent))]
    assert ("ada", "upload", "recording", str(recording_id)) in events
    assert ("ada", "delete", "recording", str(recording_id)) in events
