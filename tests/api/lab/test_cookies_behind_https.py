"""The session cookie is `Secure` behind HTTPS (issue 16, finding 13): directly over HTTPS, or behind a trusted
reverse proxy that says so with X-Forwarded-Proto; a forwarded header from anyone else is ignored."""

from __future__ import annotations

import httpx
import pytest

from backend.app import create_app, uvicorn_options
from tests.api.lab.conftest import serve_app

pytestmark = pytest.mark.integration


def _login_cookie(url: str, **headers: str) -> str:
    answer = httpx.post(f"{url}/api/v1/auth/login", json={"username": "ada", "password": "ada-password"},
                        headers=headers, timeout=30)  # fmt: skip
    assert answer.status_code == 200, answer.text
    return answer.headers["set-cookie"]


@pytest.mark.parametrize(("trusted", "secure"), [("127.0.0.1", True), ("", False)])
def test_secure_cookie_only_when_a_trusted_proxy_says_https(lab_settings, tokens, trusted, secure):
    settings = lab_settings.model_copy(update={"trusted_proxies": trusted})
    options = {k: v for k, v in uvicorn_options(settings).items() if k in ("proxy_headers", "forwarded_allow_ips")}
    with serve_app(create_app(settings), **options) as url:
        assert ("; secure" in _login_cookie(url, **{"X-Forwarded-Proto": "https"}).lower()) is secure
        assert "; secure" not in _login_cookie(url).lower()  # plain HTTP on loopback: a Secure cookie would be lost


def test_secure_cookies_always(lab_settings, tokens):
    settings = lab_settings.model_copy(update={"secure_cookies": "always"})
    with serve_app(create_app(settings)) as url:
        assert "; secure" in _login_cookie(url).lower()
