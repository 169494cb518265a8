"""FRINGELAB_ROOT_PATH: the API behind a reverse proxy that serves it at a sub-path and strips the prefix (as
`location /fringelab/ { proxy_pass http://api:8000/; }` does in nginx)."""

from __future__ import annotations

import httpx
import pytest
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route

from backend.app import create_app, uvicorn_options
from fringelab.core.settings import SettingsError, load_settings
from tests.api.lab.conftest import serve_app

PREFIX = "/fringelab"
HOP_BY_HOP = {"host", "content-length", "transfer-encoding", "connection"}


def test_the_root_path_is_normalised_and_checked(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("FRINGELAB_ROOT_PATH", "/lab/fringelab/")
    assert load_settings().root_path == "/lab/fringelab"
    monkeypatch.setenv("FRINGELAB_ROOT_PATH", "fringelab")
    with pytest.raises(SettingsError, match="FRINGELAB_ROOT_PATH"):
        load_settings()


def stripping_proxy(upstream: str) -> Starlette:
    """A reverse proxy serving `upstream` at PREFIX: the prefix is cut off, the Host header kept."""

    async def forward(request: Request) -> Response:
        path = request.url.path.removeprefix(PREFIX) or "/"
        headers = {k: v for k, v in request.headers.items() if k.lower() not in HOP_BY_HOP}
        headers["X-Forwarded-Host"] = request.headers["host"]
        async with httpx.AsyncClient(base_url=upstream) as client:
            answer = await client.request(
                request.method, path, params=request.query_params, headers=headers, content=await request.body()
            )
        kept = {k: v for k, v in answer.headers.items() if k.lower() not in HOP_BY_HOP | {"content-encoding"}}
        return Response(answer.content, status_code=answer.status_code, headers=kept)

    methods = ["GET", "POST", "PUT", "PATCH", "DELETE", "HEAD", "OPTIONS"]
    return Starlette(routes=[Route(PREFIX + "/{rest:path}", forward, methods=methods)])


@pytest.mark.integration
def test_the_api_works_behind_a_proxy_at_a_sub_path(settings):
    prefixed = settings.model_copy(update={"root_path": PREFIX})
    options = {k: v for k, v in uvicorn_options(prefixed).items() if k not in ("host", "port")}
    assert options["root_path"] == PREFIX
    with (
        serve_app(create_app(prefixed), **options) as upstream,
        serve_app(stripping_proxy(upstream)) as proxy,
        httpx.Client(base_url=proxy + PREFIX, timeout=30) as client,
    ):
        assert client.get("/api/v1/auth/me").json()["username"] == "local"
        document = client.get("/api/openapi.json").json()
        assert document["servers"] == [{"url": PREFIX}]  # generated clients put it before every path
        assert f"{PREFIX}/api/openapi.json" in client.get("/api/docs").text

        experiment = client.post("/api/v1/experiments", json={"name": "behind a proxy"}).json()
        camera = client.post(
            f"/api/v1/experiments/{experiment['id']}/cameras",
            json={"name": "left", "image_width_px": 64, "image_height_px": 48, "pixel_pitch_um": 20},
        ).json()
        metadata = f"filename cjEuemlw,filetype eA==,camera_id {_b64(camera['id'])},kind dGVzdA=="
        created = client.post(
            "/api/v1/uploads", headers={"Tus-Resumable": "1.0.0", "Upload-Length": "10", "Upload-Metadata": metadata}
        )
        assert created.status_code == 201, created.text
        location = created.headers["Location"]
        assert location.startswith(f"{proxy}{PREFIX}/api/v1/uploads/"), location  # a URL the client can follow
        assert client.head(location, headers={"Tus-Resumable": "1.0.0"}).headers["Upload-Offset"] == "0"


def _b64(value: object) -> str:
    import base64

    return base64.b64encode(str(value).encode()).decode()


def test_the_compose_stack_passes_the_root_path_to_the_api():
    from tests.system.test_compose import SERVICES

    assert SERVICES["api"]["environment"]["FRINGELAB_ROOT_PATH"] == "${FRINGELAB_ROOT_PATH:-}"
