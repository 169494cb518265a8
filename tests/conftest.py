"""Shared fixtures: clean settings, a Redis server of the tests' own, a real Celery worker."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
from celery import Celery
from celery.contrib.testing.worker import start_worker

from fringelab.core.db import upgrade_database
from fringelab.core.settings import Settings
from tests.support import RedisServer
from worker.app import create_worker_app

SHARED_DIR = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(autouse=True)
def _no_user_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tests never see the developer's FRINGELAB_* variables."""
    for name in list(os.environ):
        if name.startswith("FRINGELAB_"):
            monkeypatch.delenv(name)
    # Starlette's TestClient sends `Host: testserver`; the servers the tests start are reached at 127.0.0.1.
    monkeypatch.setenv("FRINGELAB_ALLOWED_HOSTS", "localhost,127.0.0.1,[::1],testserver")


@pytest.fixture(scope="session")
def redis_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RedisServer]:
    server = RedisServer(tmp_path_factory.mktemp("redis"))
    server.start()
    yield server
    server.stop()


@pytest.fixture
def settings(tmp_path: Path, redis_server: RedisServer) -> Settings:
    """Settings on a fresh data directory with a migrated SQLite database and the tests' Redis."""
    made = Settings(_env_file=None, data_dir=tmp_path / "var", redis_url=redis_server.url)  # type: ignore[call-arg]
    upgrade_database(made.resolved_database_url)
    return made


@pytest.fixture
def celery_worker(settings: Settings, redis_server: RedisServer) -> Iterator[Celery]:
    """A real worker (threads in this process) consuming from the tests' Redis; for quick flow tests."""
    import redis

    redis.Redis.from_url(redis_server.url).flushdb()
    app = create_worker_app(settings)
    app.loader.import_default_modules()
    with start_worker(app, pool="threads", concurrency=2, perform_ping_check=False, shutdown_timeout=30):
        yield app
