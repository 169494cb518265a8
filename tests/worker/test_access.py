"""With auth on, jobs follow their experiment: others' jobs do not exist for you; selftests are for admins."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.accounts import create_user, issue_token
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import AuditEvent, Experiment


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
