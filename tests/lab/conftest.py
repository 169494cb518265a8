"""Fixtures of the lab-server tests: the app with accounts on, and people with API tokens."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import redis
from fastapi.testclient import TestClient

from backend.app import create_app
from backend.auth import create_user, issue_token
from backend.db import make_engine, make_sessionmaker
from backend.settings import Settings

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


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}
