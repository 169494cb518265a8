"""Start-up checks of the outside parts (Redis, ports), with errors a person can act on."""

from __future__ import annotations

import errno
import socket
import time
from urllib.parse import urlsplit, urlunsplit

import redis


def redacted_url(url: str) -> str:
    """A service URL safe to print, log or return: any password (and user name) replaced by ***.

    Every message that names a Redis or database URL goes through this; a URL is never shown raw."""
    parts = urlsplit(url)
    if parts.password is None and parts.username is None:
        return url
    host = parts.hostname or ""
    if ":" in host:
        host = f"[{host}]"
    netloc = f"***@{host}" + (f":{parts.port}" if parts.port else "")
    return urlunsplit((parts.scheme, netloc, parts.path, parts.query, parts.fragment))


class ServiceError(Exception):
    """A part the process needs is missing or busy; the message names it and says how to fix it."""


def check_redis(url: str, *, timeout_s: float = 3.0, wait_s: float = 0.0) -> None:
    """Raise ServiceError unless Redis at `url` answers, trying again for up to `wait_s` (a worker started while
    its Redis restarts beside it, under `fringelab up` or compose, waits for it rather than exiting)."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            client = redis.Redis.from_url(url, socket_timeout=timeout_s, socket_connect_timeout=timeout_s)
            client.ping()
            client.close()
            return
        except redis.RedisError as error:
            if time.monotonic() < deadline:
                time.sleep(0.25)
                continue
            waited = f" for {wait_s:g} s" if wait_s else ""
            raise ServiceError(
                f"Redis at {redacted_url(url)} is unreachable{waited} ({error}); start it, fix FRINGELAB_REDIS_URL, "
                "or leave FRINGELAB_REDIS_URL empty so that `fringelab up` starts its own"
            ) from None


def check_port_free(host: str, port: int) -> None:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as error:
            if error.errno == errno.EADDRINUSE:
                raise ServiceError(
                    f"port {port} on {host} is already in use; stop the program using it or set FRINGELAB_PORT"
                ) from None
            raise ServiceError(f"cannot bind {host}:{port} ({error.strerror}); check FRINGELAB_HOST") from None


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free right now (the OS picks it)."""
    with socket.socket() as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])
