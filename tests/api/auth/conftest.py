from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.accounts import create_user, issue_token
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.settings import Settings


@pytest.fixture
def auth_settings(settings: Settings) -> Settings:
    return settings.model_copy(update={"auth_enabled": True, "login_max_failures": 3})


@pytest.fixture
def accounts(auth_settings: Settings) -> dict[str, str]:
    """Users `admin`, `ada` and `bob` (members), each with an API token; returns username -> token."""
    engine = make_engine(auth_settings.resolved_database_url)
    tokens = {}
    with make_sessionmaker(engine)() as session:
        for name, role in (("admin", "admin"), ("ada", "member"), ("bob", "member")):
            user = create_user(session, name, f"{name}-password", role=role)
            tokens[name] = issue_token(session, user, name="tests")[1]
        session.commit()
    engine.dispose()
    return tokens


@pytest.fixture
def client(auth_settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(auth_settings)) as made:
        yield made
