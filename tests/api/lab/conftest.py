"""Fixtures of the lab-server tests: the app with accounts on, and people with API tokens."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from typing import Any

import pytest
import redis
import uvicorn
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.accounts import create_user, issue_token
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.settings import Settings
from fringelab.core.startup_checks import free_port
from tests.support import wait_for

PEOPLE = (("admin", "admin"), ("ada", "member"), ("bob", "member"), ("cy", "member"))


@pytest.fixture
def lab_settings(settings: Settings, redis_server) -> Settings:  # type: ignore[no-untyped-def]
    redis.Redis.from_url(redis_server.url).flushdb()  # no login failures or queued tasks of earlier tests
    return settings.model_copy(update={"auth_enabled": True})


@pytest.fixture
def tokens(lab_settings: Settings) -> dict[str, str]:
    """Users admin (admin), ada, bob and cy (members), each with an API token: username -> token."""
    engine = make_engine(lab_settings.resolved_database_url)
    made = {}
    with make_sessionmaker(engine)() as session:
        for name, role in PEOPLE:
            made[name] = issue_token(session, create_user(session, name, f"{name}-password", role=role))[1]
        session.commit()
    engine.dispose()
    return made


@pytest.fixture
def lab_client(lab_settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(lab_settings)) as client:
        yield client


@contextlib.contextmanager
def serve_app(app: Any, **options: Any) -> Iterator[str]:
    """An ASGI app on a uvicorn server in a thread of this process, on a free loopback port; yields its URL."""
    port = free_port()
    config = uvicorn.Config(app, **{"log_level": "warning", **options, "host": "127.0.0.1", "port": port})
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    wait_for(lambda: server.started, timeout_s=20, what="the server to start")
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(timeout=20)
