"""Browser-facing protections of every answer and every state-changing request (pure ASGI, no HTTP codes but 403).

- Security headers on every response: a Content-Security-Policy that allows this origin's scripts, styles and
  images only (the dashboard is static ES modules; Plotly draws inline styles, hence 'unsafe-inline' for
  styles only), frame-ancestors 'none' and X-Frame-Options DENY (no clickjacking), nosniff, no referrer.
- An Origin check on state-changing requests (POST, PUT, PATCH, DELETE) that carry the session cookie, and on
  every one while accounts are off (then any page the browser shows could act as the local admin without a
  cookie): the browser sends `Origin` with every cross-site one; one that names another site (or `null`) is
  refused with a 403, so a cross-site form cannot start, cancel or delete anything even where SameSite does not
  hold (an old browser, a sibling sub-domain). With accounts on, requests with a bearer token and no cookie are
  scripts and are not checked.
- A Host check (`allowed_hosts`, FRINGELAB_ALLOWED_HOSTS): a request naming another host is refused with a 400.
  A DNS-rebinding page (attacker.example resolving to 127.0.0.1) reaches a loopback server with its own name as
  Host; with accounts off it would otherwise get the whole API.
"""

from __future__ import annotations

import json
from urllib.parse import urlsplit

from starlette.types import ASGIApp, Message, Receive, Scope, Send

SESSION_COOKIE = "fringelab_session"
STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; "
    "connect-src 'self'; font-src 'self' data:; object-src 'none'; base-uri 'self'; form-action 'self'; "
    "frame-ancestors 'none'"
)
# The API docs (Swagger UI, ReDoc) load their scripts from a CDN; they get a policy that allows it.
DOCS_POLICY = (
    "default-src 'self'; script-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net; "
    "style-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net https://fonts.googleapis.com; "
    "img-src 'self' data: https://fastapi.tiangolo.com https://cdn.redoc.ly; "
    "font-src 'self' https://fonts.gstatic.com; "
    "worker-src 'self' blob:; frame-ancestors 'none'"
)
HEADERS = (
    (b"x-frame-options", b"DENY"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"cross-origin-opener-policy", b"same-origin"),
)


class SecurityHeaders:
    def __init__(
        self,
        app: ASGIApp,
        *,
        allowed_origins: list[str],
        docs_prefixes: tuple[str, ...],
        allowed_hosts: frozenset[str] | None = None,
        check_every_origin: bool = False,
    ) -> None:
        """`allowed_hosts`: the Host names served (lower case, no port); None serves any. `check_every_origin`:
        check the Origin of state-changing requests without the session cookie too (accounts off)."""
        self.app = app
        self.allowed_origins = {origin.lower() for origin in allowed_origins}
        self.docs_prefixes = docs_prefixes
        self.allowed_hosts = allowed_hosts
        self.check_every_origin = check_every_origin

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope["headers"])
        if self.allowed_hosts is not None and host_name(headers.get(b"host", b"")) not in self.allowed_hosts:
            detail = ("this server does not answer to that Host name; open it by its address (the names it answers "
                      "to are in FRINGELAB_ALLOWED_HOSTS)")  # fmt: skip
            await _refuse(send, detail, status=400, code="host_not_allowed")
            return
        checked = self.check_every_origin or _has_session_cookie(headers)
        if scope["method"] in STATE_CHANGING and checked and not self._same_origin(scope, headers):
            await _refuse(send, "cross-site request refused: the Origin of a request with the session cookie must be "
                          "this server's (or one in FRINGELAB_ALLOWED_ORIGINS)")  # fmt: skip
            return
        path = scope.get("path", "")
        policy = DOCS_POLICY if path.startswith(self.docs_prefixes) else CONTENT_SECURITY_POLICY

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                present = {name.lower() for name, _value in message.get("headers", [])}
                extra = [(name, value) for name, value in HEADERS if name not in present]
                if b"content-security-policy" not in present:
                    extra.append((b"content-security-policy", policy.encode()))
                message["headers"] = [*message.get("headers", []), *extra]
            await send(message)

        await self.app(scope, receive, with_headers)

    def _same_origin(self, scope: Scope, headers: dict[bytes, bytes]) -> bool:
        claimed = headers.get(b"origin") or headers.get(b"referer")
        if claimed is None:
            return True  # browsers send Origin with every cross-site POST: none at all is a script, not a form
        parts = urlsplit(claimed.decode("latin-1"))
        origin = f"{parts.scheme}://{parts.netloc}".lower()
        host = headers.get(b"host", b"").decode("latin-1").lower()
        scheme = scope.get("scheme", "http")
        return (
            origin in self.allowed_origins
            or origin == f"{scheme}://{host}"
            or (bool(host) and parts.netloc.lower() == host and parts.scheme in ("http", "https"))
        )


def _has_session_cookie(headers: dict[bytes, bytes]) -> bool:
    return SESSION_COOKIE.encode() + b"=" in headers.get(b"cookie", b"")


def host_name(host: bytes) -> str:
    """The name in a Host header, lower case, without its port (an IPv6 address keeps its brackets)."""
    text = host.decode("latin-1").strip().lower()
    if text.startswith("["):
        return text[: text.find("]") + 1] if "]" in text else text
    return text.rsplit(":", 1)[0] if ":" in text else text


async def _refuse(send: Send, detail: str, *, status: int = 403, code: str = "cross_site_request") -> None:
    import logging

    logging.getLogger(__name__).warning("refused a request: %s", code)
    body = json.dumps({"detail": detail, "code": code}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()), *HEADERS]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})
