"""Shared fixtures: clean settings, a Redis server of the tests' own, a real Celery worker."""

from __future__ import annotations

import os
import shutil
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
DATABASE_NAME = "fringelab.db"  # Settings.resolved_database_url's file in the data directory


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


@pytest.fixture(scope="session")
def migrated_data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A data directory holding an SQLite database migrated to head, made once per session: each test's `settings`
    copies it. Migrating takes ~0.2 s of CPU and ~1 s of disk syncs on a shared machine, and `settings` is in
    hundreds of tests; the migrations themselves are tested in tests/core/test_database.py."""
    data_dir = tmp_path_factory.mktemp("migrated") / "var"
    upgrade_database(f"sqlite:///{data_dir / DATABASE_NAME}")
    return data_dir


@pytest.fixture
def settings(tmp_path: Path, redis_server: RedisServer, migrated_data_dir: Path) -> Settings:
    """Settings on a fresh data directory with a migrated SQLite database (a copy of `migrated_data_dir`'s) and
    the tests' Redis."""
    made = Settings(_env_file=None, data_dir=tmp_path / "var", redis_url=redis_server.url)  # type: ignore[call-arg]
    # The copy must be where the settings look for the database, or every test would find an empty one.
    assert made.resolved_database_url == f"sqlite:///{made.data_path / DATABASE_NAME}", made.resolved_database_url
    shutil.copytree(migrated_data_dir, made.data_path)
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
