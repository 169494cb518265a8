"""With auth on, jobs follow their experiment: others' jobs do not exist for you; selftests are for admins."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from backend.app import create_app
from fringelab.core.accounts import create_user, issue_token
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import AuditEvent, Experiment, Job, JobChunk, User


@pytest.fixture
def auth_client(settings):
    with TestClient(create_app(settings.model_copy(update={"auth_enabled": True}))) as client:
        yield client


@pytest.fixture
def tokens(settings, add_rows):
    """Admin `root` and members `ada` (who owns the experiment of `add_rows`) and `bob`."""
    ids = add_rows(recording_state="ingesting")
    engine = make_engine(settings.resolved_database_url)
    made = {}
    with make_sessionmaker(engine)() as session:
        for name, role in (("root", "admin"), ("ada", "member"), ("bob", "member")):
            user = create_user(session, name, f"{name}-password", role=role)
            made[name] = {"Authorization": f"Bearer {issue_token(session, user)[1]}"}
            if name == "ada":
                session.get(Experiment, ids["experiment"]).owner_id = user.id  # type: ignore[union-attr]
        session.commit()
    engine.dispose()
    made["ids"] = ids  # type: ignore[assignment]
    return made


def test_jobs_follow_the_access_to_their_experiment(auth_client, tokens, settings):
    selftest = {"kind": "selftest", "frames": 3}
    assert auth_client.post("/api/v1/jobs", json=selftest).status_code == 401
    refused = auth_client.post("/api/v1/jobs", json=selftest, headers=tokens["ada"])
    assert refused.status_code == 403 and refused.json()["code"] == "forbidden"
    job = auth_client.post("/api/v1/jobs", json=selftest, headers=tokens["root"]).json()
    assert auth_client.get(f"/api/v1/jobs/{job['id']}", headers=tokens["ada"]).status_code == 404
    assert auth_client.get("/api/v1/jobs", headers=tokens["ada"]).json()["total"] == 0
    assert auth_client.get("/api/v1/jobs", headers=tokens["root"]).json()["total"] == 1

    ids = tokens["ids"]
    topography = {
        "kind": "topography",
        "recording_id": ids["test"],
        "camera_calibration_id": ids["camera_cal"],
        "projector_calibration_id": ids["projector_cal"],
    }
    # bob may not even learn that the recording exists (the same answer as for an id nobody has); ada is told
    refused = auth_client.post("/api/v1/jobs", json=topography, headers=tokens["bob"]).json()
    nobody = auth_client.post("/api/v1/jobs", json={**topography, "recording_id": 99999}, headers=tokens["bob"]).json()
    assert refused["code"] == "recording_not_found" and refused["detail"].replace(str(ids["test"]), "N") == nobody[
        "detail"
    ].replace("99999", "N")
    assert auth_client.post("/api/v1/jobs", json=topography, headers=tokens["ada"]).json()["code"] == (
        "recording_not_ready"
    )

    assert auth_client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=tokens["root"]).status_code == 200
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        actions = [(e.username, e.action) for e in session.query(AuditEvent).filter_by(object_type="job")]
    engine.dispose()
    assert actions == [("root", "start"), ("root", "cancel")]


def test_the_jobs_list_shows_each_job_as_its_own_page_does_and_only_what_the_reader_may_see(
    auth_client, tokens, settings
):
    """The list reads plain rows with its names joined in (not job objects): each item must still be what
    GET /jobs/{id} answers, with the experiment's and camera's names, chunks and retries, and a member must still
    see only the jobs of experiments they may read, with a total that counts those alone."""
    ids = tokens["ids"]
    at = datetime(2026, 11, 27, 12, 0, tzinfo=UTC)
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        bob = session.scalars(select(User).where(User.username == "bob")).one()
        foreign = Experiment(name="bob's plate", owner_id=bob.id)
        session.add(foreign)
        session.flush()
        own = ids["experiment"]
        done = {"state": "succeeded", "started_at": at, "finished_at": at + timedelta(seconds=1)}
        rows = [
            Job(id="topo", kind="topography", experiment_id=own, spec={"recording_id": ids["test"]}, **done,
                files=[{"name": "topography.h5", "path": "x", "size_bytes": 3, "sha256": "", "media_type": "m"}]),
            Job(id="export", kind="export", experiment_id=own, spec={"job_id": "topo"}, **done),
            Job(id="failed", kind="topography", experiment_id=own, state="failed", error="no light",
                spec={"recording_id": ids["test"]}),
            Job(id="again", kind="topography", experiment_id=own, state="queued", retry_of="failed", attempt=2,
                spec={"recording_id": ids["test"]}),
            Job(id="bobs", kind="topography", experiment_id=foreign.id, spec={"recording_id": ids["test"]}),
            Job(id="selftest", kind="selftest", state="queued", spec={"frames": 3}),
        ]  # fmt: skip
        for minutes, job in enumerate(rows):
            job.created_at = at + timedelta(minutes=minutes)
        session.add_all(rows)
        session.add_all([JobChunk(job_id="topo", phase=phase, index=index, first_frame=index * 10,
                                  stop_frame=index * 10 + 10, state="done", done=10, worker="w1",
                                  started_at=at, finished_at=at)
                         for phase in (1, 0) for index in (1, 0)])  # fmt: skip
        session.commit()
    engine.dispose()

    def listed(who: str, **params: object) -> dict:
        answer = auth_client.get("/api/v1/jobs", params=params, headers=tokens[who])
        assert answer.status_code == 200 and answer.headers["content-type"] == "application/json"
        return answer.json()

    mine = listed("ada")
    assert [job["id"] for job in mine["items"]] == ["again", "failed", "export", "topo"] and mine["total"] == 4
    for job in mine["items"]:
        assert job == auth_client.get(f"/api/v1/jobs/{job['id']}", headers=tokens["ada"]).json()
    by_id = {job["id"]: job for job in mine["items"]}
    assert {(j["experiment_name"], j["camera_name"]) for j in mine["items"]} == {("plate 1", "left")}
    assert by_id["failed"]["retried_by"] == "again" and by_id["again"]["retry_of"] == "failed"
    assert [(c["phase"], c["index"]) for c in by_id["topo"]["chunks"]] == [(0, 0), (0, 1), (1, 0), (1, 1)]
    assert by_id["topo"]["files"][0]["url"] == "/api/v1/jobs/topo/files/topography.h5"
    assert listed("ada", limit=2, offset=1) == {"items": mine["items"][1:3], "total": 4}
    assert listed("ada", offset=10) == {"items": [], "total": 4}  # past the end: the total still counts
    assert listed("ada", state="failed")["total"] == 1 and listed("bob", kind="export")["total"] == 0
    everything = listed("root")
    assert [job["id"] for job in everything["items"]] == ["selftest", "bobs", "again", "failed", "export", "topo"]
    assert everything["items"][1]["experiment_name"] == "bob's plate" and everything["items"][0]["camera_name"] is None
    assert listed("bob")["total"] == 1
