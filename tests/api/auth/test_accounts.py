"""Logins, tokens, roles, rate limits and size limits against the real app, database and Redis."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import redis
from fastapi.testclient import TestClient

from backend.app import create_app
from tests.support import bearer, wait_for


@pytest.fixture(autouse=True)
def _fresh_rate_limits(redis_server):
    redis.Redis.from_url(redis_server.url).flushdb()


def test_auth_off_acts_as_local_admin(settings):
    with TestClient(create_app(settings)) as client:
        response = client.get("/api/v1/auth/me")
    assert response.json() == {"username": "local", "role": "admin", "auth_enabled": False}


@pytest.mark.parametrize(
    ("headers", "message"),
    [({}, "authentication required"), (bearer("flb_guessed"), "unknown token"), ({"Authorization": "Basic x"}, "")],
)
def test_missing_or_wrong_token_is_401_with_a_reason(client, accounts, headers, message):
    response = client.get("/api/v1/auth/me", headers=headers)
    assert response.status_code == 401
    assert response.json()["code"] == "unauthorized"
    assert message in response.json()["detail"]
    assert response.headers["www-authenticate"] == "Bearer"


def test_token_lifecycle_create_use_revoke(client, accounts):
    created = client.post("/api/v1/auth/tokens", json={"name": "script"}, headers=bearer(accounts["ada"]))
    assert created.status_code == 201
    secret = created.json()["token"]
    assert client.get("/api/v1/auth/me", headers=bearer(secret)).json()["username"] == "ada"
    listed = client.get("/api/v1/auth/tokens", headers=bearer(secret)).json()
    assert [t["name"] for t in listed] == ["tests", "script"]
    assert all("token" not in t for t in listed)  # secrets are never listed
    assert (
        client.delete(f"/api/v1/auth/tokens/{created.json()['id']}", headers=bearer(accounts["bob"])).status_code == 404
    )
    assert client.delete(f"/api/v1/auth/tokens/{created.json()['id']}", headers=bearer(secret)).status_code == 204
    revoked = client.get("/api/v1/auth/me", headers=bearer(secret))
    assert revoked.status_code == 401 and "revoked" in revoked.json()["detail"]


def test_expired_token_is_401(client, accounts, auth_settings):
    from datetime import timedelta

    from fringelab.core.db import make_engine, make_sessionmaker
    from fringelab.core.models import ApiToken, utcnow

    engine = make_engine(auth_settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        for row in session.query(ApiToken):
            row.expires_at = utcnow() - timedelta(seconds=1)
        session.commit()
    engine.dispose()
    response = client.get("/api/v1/auth/me", headers=bearer(accounts["ada"]))
    assert response.status_code == 401 and "expired" in response.json()["detail"]


def test_login_sets_a_session_cookie_and_logout_ends_it(client, accounts):
    response = client.post("/api/v1/auth/login", json={"username": "ada", "password": "ada-password"})
    assert response.status_code == 200
    assert "httponly" in response.headers["set-cookie"].lower()
    assert client.get("/api/v1/auth/me").json()["username"] == "ada"
    cookie = client.cookies.get("fringelab_session")
    assert client.post("/api/v1/auth/logout").status_code == 204
    client.cookies.set("fringelab_session", cookie)
    assert client.get("/api/v1/auth/me").status_code == 401


def test_login_brute_force_is_rate_limited(client, accounts):
    for _ in range(3):
        assert client.post("/api/v1/auth/login", json={"username": "ada", "password": "nope"}).status_code == 401
    blocked = client.post("/api/v1/auth/login", json={"username": "ada", "password": "ada-password"})
    assert blocked.status_code == 429
    assert int(blocked.headers["retry-after"]) > 0


def test_member_doing_admin_work_is_403_and_admin_can(client, accounts):
    new_user = {"username": "carl", "password": "carl-password"}
    forbidden = client.post("/api/v1/users", json=new_user, headers=bearer(accounts["ada"]))
    assert forbidden.status_code == 403 and forbidden.json()["code"] == "forbidden"
    created = client.post("/api/v1/users", json=new_user, headers=bearer(accounts["admin"]))
    assert created.status_code == 201
    disabled = client.patch(
        f"/api/v1/users/{created.json()['id']}", json={"disabled": True}, headers=bearer(accounts["admin"])
    )
    assert disabled.json()["disabled"] is True
    assert client.post("/api/v1/auth/login", json=new_user).status_code == 401
    trail = client.get("/api/v1/audit", headers=bearer(accounts["admin"])).json()
    assert [(e["username"], e["action"], e["object_type"]) for e in trail[:2]] == [
        ("admin", "update", "user"),
        ("admin", "create", "user"),
    ]


def test_disabled_account_tokens_stop_working(client, accounts):
    ada = next(
        u for u in client.get("/api/v1/users", headers=bearer(accounts["admin"])).json() if u["username"] == "ada"
    )
    client.patch(f"/api/v1/users/{ada['id']}", json={"disabled": True}, headers=bearer(accounts["admin"]))
    response = client.get("/api/v1/auth/me", headers=bearer(accounts["ada"]))
    assert response.status_code == 401 and "disabled" in response.json()["detail"]


def test_oversized_request_body_is_413(client, accounts):
    response = client.post(
        "/api/v1/auth/tokens", content=b"{" + b" " * 2_000_000 + b"}", headers=bearer(accounts["ada"])
    )
    assert response.status_code == 413
    assert response.json()["code"] == "payload_too_large"


def _cli(*args: str, env: dict[str, str], stdin: str = "") -> subprocess.CompletedProcess[str]:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("FRINGELAB_")}
    return subprocess.run(
        [sys.executable, "-m", "backend.cli", *args], env={**clean, **env}, input=stdin, capture_output=True, text=True
    )


def test_admin_cli_adds_lists_disables_users_and_creates_tokens(tmp_path, client, auth_settings):
    env = {"FRINGELAB_DATA_DIR": str(auth_settings.data_dir)}
    assert _cli("user", "add", "dora", "--admin", "--password-stdin", env=env, stdin="dora-password\n").returncode == 0
    assert "dora\tadmin\tactive" in _cli("user", "list", env=env).stdout
    token = _cli("token", "create", "dora", "--name", "ci", env=env).stdout.strip()
    assert token.startswith("flb_")
    assert client.get("/api/v1/auth/me", headers=bearer(token)).json()["username"] == "dora"
    short = _cli("user", "add", "eve", "--password-stdin", env=env, stdin="short\n")
    assert short.returncode == 2 and "at least 8" in short.stderr
    last = _cli("user", "disable", "dora", env=env)
    assert last.returncode == 2 and "last active admin" in last.stderr  # a server without an admin is lost
    assert _cli("user", "add", "erin", "--password-stdin", env=env, stdin="erin-password\n").returncode == 0
    assert _cli("user", "promote", "erin", env=env).returncode == 0
    assert _cli("user", "disable", "dora", env=env).returncode == 0
    # Another process changed the account: this API sees it once its token cache (FRINGELAB_TOKEN_CACHE_S) expires.
    wait_for(lambda: client.get("/api/v1/auth/me", headers=bearer(token)).status_code == 401,
             timeout_s=auth_settings.token_cache_s + 5, what="the disabled account's token to be refused")  # fmt: skip
    expired = _cli("token", "create", "erin", "--days", "-1", env=env)
    assert expired.returncode == 2 and "0 (never expires) to 3650" in expired.stderr


def test_refuses_a_network_address_with_auth_off(tmp_path):
    result = _cli("api", env={"FRINGELAB_HOST": "0.0.0.0", "FRINGELAB_DATA_DIR": str(tmp_path)})
    assert result.returncode == 2
    assert "FRINGELAB_AUTH_ENABLED" in result.stderr and "Traceback" not in result.stderr
