"""Experiments shared with a group: readers see everything and change nothing (403 read_only), writers may edit
and add but not re-share (403 not_owner), everyone else gets a 404 whatever they send."""

from __future__ import annotations

from sqlalchemy import select

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import AuditEvent
from tests.support import bearer


def tus_creation(camera_id: int, *, size: int) -> dict[str, str]:
    from tests.api.recordings.conftest import tus_metadata

    metadata = tus_metadata(filename="r.zip", filetype="application/zip", camera_id=camera_id, kind="test")
    return {"Tus-Resumable": "1.0.0", "Upload-Length": str(size), "Upload-Metadata": metadata}


CAMERA = {"name": "left", "image_width_px": 512, "image_height_px": 480, "pixel_pitch_um": 9.0}


def _shared_setup(client, tokens) -> tuple[dict, dict, dict]:
    """ada's experiment with a camera, and a group `impact-lab` with bob in it (not cy)."""
    ada, admin = bearer(tokens["ada"]), bearer(tokens["admin"])
    group = client.post("/api/v1/groups", json={"name": "impact-lab", "members": ["bob"]}, headers=admin)
    assert group.status_code == 201, group.text
    experiment = client.post("/api/v1/experiments", json={"name": "plate 3"}, headers=ada).json()
    camera = client.post(f"/api/v1/experiments/{experiment['id']}/cameras", json=CAMERA, headers=ada)
    assert camera.status_code == 201, camera.text
    return group.json(), experiment, camera.json()


def test_a_read_share_lets_group_members_read_but_not_write(lab_client, tokens):
    group, experiment, camera = _shared_setup(lab_client, tokens)
    ada, bob = bearer(tokens["ada"]), bearer(tokens["bob"])
    eid = experiment["id"]
    assert experiment["owner"] == "ada" and experiment["access"] == "owner" and experiment["group_id"] is None
    assert lab_client.get(f"/api/v1/experiments/{eid}", headers=bob).status_code == 404

    shared = lab_client.patch(f"/api/v1/experiments/{eid}", json={"group_id": group["id"]}, headers=ada)
    assert shared.status_code == 200, shared.text
    assert (shared.json()["group"], shared.json()["group_access"]) == ("impact-lab", "read")

    seen = lab_client.get(f"/api/v1/experiments/{eid}", headers=bob)
    assert seen.status_code == 200 and seen.json()["access"] == "read" and seen.json()["owner"] == "ada"
    assert [e["id"] for e in lab_client.get("/api/v1/experiments", headers=bob).json()] == [eid]
    assert lab_client.get(f"/api/v1/cameras/{camera['id']}", headers=bob).status_code == 200
    assert lab_client.get(f"/api/v1/experiments/{eid}/cameras", headers=bob).status_code == 200

    for response in (
        lab_client.patch(f"/api/v1/experiments/{eid}", json={"notes": "mine now"}, headers=bob),
        lab_client.patch(f"/api/v1/experiments/{eid}", json={"group_access": "write"}, headers=bob),
        lab_client.delete(f"/api/v1/experiments/{eid}", headers=bob),
        lab_client.post(f"/api/v1/experiments/{eid}/cameras", json={**CAMERA, "name": "right"}, headers=bob),
        lab_client.patch(f"/api/v1/cameras/{camera['id']}", json={"pixel_pitch_um": 1}, headers=bob),
        lab_client.delete(f"/api/v1/cameras/{camera['id']}", headers=bob),
        lab_client.put(f"/api/v1/uploads/cameras/{camera['id']}/r.zip", params={"kind": "test"}, content=b"PK",
                       headers=bob),
        lab_client.post("/api/v1/uploads", headers={**bob, **tus_creation(camera["id"], size=100)}),
    ):  # fmt: skip
        assert response.status_code == 403, response.text
        assert response.json()["code"] == "read_only"
        assert "read-only access" in response.json()["detail"]
    assert lab_client.get(f"/api/v1/experiments/{eid}", headers=ada).json()["notes"] == ""


def test_a_write_share_lets_members_edit_but_only_the_owner_reshares(lab_client, tokens):
    group, experiment, camera = _shared_setup(lab_client, tokens)
    ada, bob, admin = bearer(tokens["ada"]), bearer(tokens["bob"]), bearer(tokens["admin"])
    eid = experiment["id"]
    body = {"group_id": group["id"], "group_access": "write"}
    assert lab_client.patch(f"/api/v1/experiments/{eid}", json=body, headers=ada).status_code == 200

    edited = lab_client.patch(f"/api/v1/experiments/{eid}", json={"notes": "punch 20 mm"}, headers=bob)
    assert edited.status_code == 200 and edited.json()["access"] == "write"
    added = lab_client.post(f"/api/v1/experiments/{eid}/cameras", json={**CAMERA, "name": "right"}, headers=bob)
    assert added.status_code == 201, added.text
    # resending the sharing as it is (a form sends every field) is not re-sharing
    same = lab_client.patch(f"/api/v1/experiments/{eid}", json={**body, "notes": "v2"}, headers=bob)
    assert same.status_code == 200, same.text
    for change in ({"group_id": None}, {"group_access": "read"}):
        refused = lab_client.patch(f"/api/v1/experiments/{eid}", json=change, headers=bob)
        assert (refused.status_code, refused.json()["code"]) == (403, "not_owner"), refused.text

    # an admin may re-share; an unknown group is named
    unknown = lab_client.patch(f"/api/v1/experiments/{eid}", json={"group_id": 999}, headers=admin)
    assert (unknown.status_code, unknown.json()["code"]) == (422, "unknown_group")
    unshared = lab_client.patch(f"/api/v1/experiments/{eid}", json={"group_id": None}, headers=admin)
    assert unshared.status_code == 200 and unshared.json()["group_id"] is None
    assert lab_client.get(f"/api/v1/experiments/{eid}", headers=bob).status_code == 404
    assert lab_client.get("/api/v1/experiments", headers=bob).json() == []


def test_an_experiment_can_be_shared_when_it_is_created(lab_client, tokens, lab_settings):
    group, _, _ = _shared_setup(lab_client, tokens)
    ada, bob = bearer(tokens["ada"]), bearer(tokens["bob"])
    body = {"name": "plate 4", "group_id": group["id"], "group_access": "write"}
    created = lab_client.post("/api/v1/experiments", json=body, headers=ada)
    assert created.status_code == 201, created.text
    assert lab_client.get(f"/api/v1/experiments/{created.json()['id']}", headers=bob).json()["access"] == "write"
    missing = lab_client.post("/api/v1/experiments", json={"name": "x", "group_id": 999}, headers=ada)
    assert missing.json()["code"] == "unknown_group"

    lab_client.patch(f"/api/v1/experiments/{created.json()['id']}", json={"group_access": "read"}, headers=ada)
    engine = make_engine(lab_settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        shares = [
            (e.username, e.detail) for e in session.scalars(select(AuditEvent).where(AuditEvent.action == "share"))
        ]
    engine.dispose()
    assert shares == [("ada", {"group_id": group["id"], "group_access": "read"})]


def test_strangers_get_404_before_their_body_is_validated(lab_client, tokens):
    _, experiment, camera = _shared_setup(lab_client, tokens)
    cy = bearer(tokens["cy"])
    eid, cid = experiment["id"], camera["id"]
    for method, path, body in (
        ("PATCH", f"/api/v1/experiments/{eid}", {"name": "", "colour": "red"}),
        ("POST", f"/api/v1/experiments/{eid}/cameras", {"image_width_px": -1}),
        ("PATCH", f"/api/v1/cameras/{cid}", {"pixel_pitch_um": "wide"}),
    ):
        stranger = lab_client.request(method, path, json=body, headers=cy)
        assert (stranger.status_code, stranger.json()["code"]) == (404, "not_found"), (path, stranger.text)
        anonymous = lab_client.request(method, path, json=body)
        assert anonymous.status_code == 401, (path, anonymous.text)
        owner = lab_client.request(method, path, json=body, headers=bearer(tokens["ada"]))
        assert owner.status_code == 422, (path, owner.text)  # the owner is told what is wrong with the body
    upload = lab_client.put(f"/api/v1/uploads/cameras/{cid}/r.zip", params={"kind": "sideways"}, headers=cy)
    assert upload.status_code == 404, upload.text


def test_group_members_are_listed_to_admins_only(lab_client, tokens):
    """Issue 26: `/groups` listed every member's username to any member."""
    _shared_setup(lab_client, tokens)
    as_admin = lab_client.get("/api/v1/groups", headers=bearer(tokens["admin"])).json()
    as_member = lab_client.get("/api/v1/groups", headers=bearer(tokens["bob"])).json()
    assert [g["members"] for g in as_admin] == [["bob"]]
    assert [(g["name"], g["members"]) for g in as_member] == [("impact-lab", [])]
