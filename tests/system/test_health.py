"""`GET /api/v1/health` against a real Redis and a real Celery worker."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from backend.app import create_app
from backend.frontend import PLOTLY_JS_URL
from fringelab.core.settings import Settings
from fringelab.core.startup_checks import free_port


@pytest.mark.integration
def test_healthy_with_a_live_worker(settings, celery_worker):
    with TestClient(create_app(settings)) as client:
        response = client.get("/api/v1/health")
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["ok"] is True
    assert body["workers"] >= 1
    assert body["failing"] == []


@pytest.mark.integration
def test_no_worker_is_a_503_naming_workers(settings):
    import redis

    redis.Redis.from_url(settings.redis_url).flushdb()  # no heartbeat left by an earlier test's worker
    with TestClient(create_app(settings)) as client:
        response = client.get("/api/v1/health")
    assert response.status_code == 503
    assert response.json()["failing"] == ["workers"]


def test_redis_down_is_a_503_naming_redis(tmp_path):
    settings = Settings(_env_file=None, data_dir=tmp_path, redis_url=f"redis://127.0.0.1:{free_port()}/0")  # type: ignore[call-arg]
    with TestClient(create_app(settings)) as client:
        response = client.get("/api/v1/health")
    assert response.status_code == 503
    body = response.json()
    assert "redis" in body["failing"]
    assert "unreachable" in body["redis"]["detail"]


@pytest.mark.integration
def test_a_task_runs_end_to_end(celery_worker):
    result = celery_worker.send_task("fringelab.ping", args=["hello"])
    assert result.get(timeout=30)["payload"] == "hello"


def test_frontend_and_api_docs_are_served(settings):
    with TestClient(create_app(settings)) as client:
        page = client.get("/")
        docs = client.get("/api/docs")
        schema = client.get("/api/openapi.json")
        plotly_js = client.get(PLOTLY_JS_URL)
    assert page.status_code == 200 and "fringelab" in page.text
    assert PLOTLY_JS_URL in page.text and "{{" not in page.text
    assert plotly_js.status_code == 200 and "immutable" in plotly_js.headers["cache-control"]
    assert len(plotly_js.content) > 1_000_000  # the real bundle, not a placeholder
    assert docs.status_code == 200
    assert "/api/v1/health" in schema.json()["paths"]
