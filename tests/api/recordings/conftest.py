"""Fixtures of the recording tests: the API on a real uvicorn server (loopback), an experiment with a camera,
and a small tus client speaking the protocol with raw HTTP requests."""

from __future__ import annotations

import base64
import contextlib
import threading
from collections.abc import Iterator
from dataclasses import dataclass

import httpx
import pytest
import uvicorn

from backend.app import create_app
from fringelab.core.settings import Settings
from fringelab.core.startup_checks import free_port
from tests.support import wait_for

TUS = {"Tus-Resumable": "1.0.0"}


@dataclass
class Api:
    base_url: str
    client: httpx.Client
    settings: Settings

    def camera(self, *, width: int = 64, height: int = 48, name: str = "left") -> int:
        experiment = self.client.post("/api/v1/experiments", json={"name": "plate 3"}).json()
        body = {"name": name, "image_width_px": width, "image_height_px": height, "pixel_pitch_um": 20.0}
        created = self.client.post(f"/api/v1/experiments/{experiment['id']}/cameras", json=body)
        assert created.status_code == 201, created.text
        return int(created.json()["id"])

    def wait_settled(self, recording_id: int, *, timeout_s: float = 60) -> dict:
        """The recording once its ingest has ended (ready or invalid)."""

        def settled() -> dict | None:
            body = self.client.get(f"/api/v1/recordings/{recording_id}").json()
            return body if body["state"] in ("ready", "invalid") else None

        return wait_for(settled, timeout_s=timeout_s, what=f"recording {recording_id} to settle")  # type: ignore[return-value]


@contextlib.contextmanager
def serve(settings: Settings) -> Iterator[str]:
    """The fringelab API on a uvicorn server in a thread of this process, on a free loopback port."""
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    wait_for(lambda: server.started, timeout_s=20, what="the API server to start")
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(timeout=20)


@pytest.fixture
def api(settings: Settings) -> Iterator[Api]:
    with serve(settings) as base_url, httpx.Client(base_url=base_url, timeout=60) as client:
        yield Api(base_url, client, settings)


def tus_metadata(**items: object) -> str:
    return ",".join(f"{key} {base64.b64encode(str(value).encode()).decode()}" for key, value in items.items())


def tus_create(client: httpx.Client, length: int, **metadata: object) -> httpx.Response:
    return client.post("/api/v1/uploads", headers={**TUS, "Upload-Length": str(length),
                                                    "Upload-Metadata": tus_metadata(**metadata)})  # fmt: skip


def tus_patch(client: httpx.Client, location: str, offset: int, data: bytes) -> httpx.Response:
    headers = {**TUS, "Upload-Offset": str(offset), "Content-Type": "application/offset+octet-stream"}
    return client.patch(location, headers=headers, content=data)


def tus_offset(client: httpx.Client, location: str) -> int:
    response = client.head(location, headers=TUS)
    assert response.status_code == 200, response.status_code
    return int(response.headers["Upload-Offset"])


def tus_upload(
    client: httpx.Client, data: bytes, *, camera_id: int, kind: str = "test", filename: str = "r.zip",
    chunk: int = 1 << 20,
) -> httpx.Response:  # fmt: skip
    """Create an upload and PATCH it in chunks; the last PATCH's response."""
    created = tus_create(client, len(data), filename=filename, filetype="application/octet-stream",
                         camera_id=camera_id, kind=kind)  # fmt: skip
    assert created.status_code == 201, created.text
    location = created.headers["Location"]
    offset = 0
    response = created
    while offset < len(data):
        response = tus_patch(client, location, offset, data[offset : offset + chunk])
        if response.status_code != 204:
            return response
        offset = int(response.headers["Upload-Offset"])
    return response
