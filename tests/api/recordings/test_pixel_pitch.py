"""A camera's pixel pitch along u and along v: given apart for non-square pixels (D_u = 1000 / pitch_u px/mm,
D_v = 1000 / pitch_v), the same for square ones when v is left out; the schema says what a data sheet gives."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.models import Camera


@pytest.fixture
def client(settings):
    with TestClient(create_app(settings)) as made:
        yield made


def test_pitch_along_u_and_v(client):
    eid = client.post("/api/v1/experiments", json={"name": "x"}).json()["id"]
    body = {
        "name": "left",
        "image_width_px": 1280,
        "image_height_px": 800,
        "pixel_pitch_um": 11.5,
        "pixel_pitch_v_um": 12.0,
    }
    camera = client.post(f"/api/v1/experiments/{eid}/cameras", json=body).json()
    assert (camera["pixel_pitch_um"], camera["pixel_pitch_v_um"]) == (11.5, 12.0)
    square = {**body, "name": "right"}
    del square["pixel_pitch_v_um"]
    right = client.post(f"/api/v1/experiments/{eid}/cameras", json=square).json()
    assert right["pixel_pitch_v_um"] == 11.5  # square pixels
    with client.app.state.fringelab.sessions() as session:
        assert session.get(Camera, camera["id"]).pixel_pitch_uv_um == (11.5, 12.0)
        assert session.get(Camera, right["id"]).pixel_pitch_uv_um == (11.5, 11.5)
    changed = client.patch(f"/api/v1/cameras/{right['id']}", json={"pixel_pitch_v_um": 11.0}).json()
    assert (changed["pixel_pitch_um"], changed["pixel_pitch_v_um"]) == (11.5, 11.0)
    assert (
        client.post(f"/api/v1/experiments/{eid}/cameras", json={**body, "name": "z", "pixel_pitch_v_um": 0}).status_code
        == 422
    )
    schema = client.get("/api/openapi.json").json()["components"]["schemas"]["CameraCreate"]["properties"]
    assert "horizontal × vertical, which is u × v" in schema["pixel_pitch_um"]["description"]
