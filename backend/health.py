"""Health of the system's parts (database, Redis, live workers), shared by `/api/v1/health` and `fringelab health`."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

import anyio
import redis
from pydantic import BaseModel, Field
from sqlalchemy import Engine

from backend import __version__
from backend.limits import UserRateLimiter
from fringelab.core.db import DatabaseError, check_database
from fringelab.core.liveness import live_workers
from fringelab.core.startup_checks import redacted_url


class PartHealth(BaseModel):
    ok: bool
    detail: str = ""


class ChildHealth(BaseModel):
    name: str
    running: bool
    restarts: int
    last_exit: str = ""


class Health(BaseModel):
    ok: bool
    version: str
    database: PartHealth
    redis: PartHealth
    workers: int
    failing: list[str]
    processes: list[ChildHealth] = Field(
        default_factory=list,
        description="Under `fringelab up`: its child processes, whether each runs and how often it was restarted.",
    )


def supervised_children(data_path: Path | None) -> list[ChildHealth]:
    """What `fringelab up` last wrote of its children (nothing when the API runs without it)."""
    if data_path is None:
        return []
    try:
        document = json.loads((data_path / "supervisor.json").read_text())
        return [ChildHealth.model_validate(child) for child in document["children"]]
    except (OSError, ValueError, KeyError, TypeError):
        return []


def system_health(
    *, engine: Engine, redis_client: redis.Redis | None, redis_url: str, data_path: Path | None = None
) -> Health:
    """Check each part: the database, Redis (one bounded round trip, the client's timeouts) and the live workers
    from their own heartbeats in Redis (`fringelab.core.liveness`), never a broadcast to the workers."""
    try:
        check_database(engine)
        database = PartHealth(ok=True)
    except DatabaseError as error:
        database = PartHealth(ok=False, detail=str(error))
    workers = 0
    if redis_client is None:
        redis_part = PartHealth(ok=False, detail="FRINGELAB_REDIS_URL is empty")
    else:
        try:
            workers = len(live_workers(redis_client))
            redis_part = PartHealth(ok=True)
        except redis.RedisError as error:
            redis_part = PartHealth(ok=False, detail=f"Redis at {redacted_url(redis_url)} unreachable: {error}")
    failing = [name for name, part in (("database", database), ("redis", redis_part)) if not part.ok]
    if workers == 0:
        failing.append("workers")
    processes = supervised_children(data_path)
    failing += [f"{child.name} (restarting)" for child in processes if not child.running]
    return Health(ok=not failing, version=__version__, database=database, redis=redis_part, workers=workers,
                  failing=failing, processes=processes)  # fmt: skip


def health_redis_client(redis_url: str, *, timeout_s: float) -> redis.Redis | None:
    """The client a health check asks Redis with: every call bounded by `timeout_s` (FRINGELAB_HEALTH_TIMEOUT_S)."""
    if not redis_url:
        return None
    return redis.Redis.from_url(redis_url, socket_timeout=timeout_s, socket_connect_timeout=timeout_s)


class HealthCache:
    """The health answer of one web server process, made at most once per `max_age_s` by one thread of its own
    (never one of the request threads), and handed to every request meanwhile. While it is being made, a request
    gets the previous answer at once; only the very first request of the process waits for it. Anonymous callers
    are limited per client address (`limiter`), loopback counted like any other."""

    def __init__(self, compute: Callable[[], Health], *, max_age_s: float, rate_per_s: float, burst: int) -> None:
        self._compute = compute
        self.max_age_s = max_age_s
        self.limiter = UserRateLimiter(rate_per_s=rate_per_s, burst=burst)
        self._body: Health | None = None
        self._at = 0.0
        self._lock: anyio.Lock | None = None
        self._thread = anyio.CapacityLimiter(1)

    async def get(self) -> Health:
        if self._body is not None and time.monotonic() - self._at < self.max_age_s:
            return self._body
        if self._lock is None:
            self._lock = anyio.Lock()
        if self._lock.locked() and self._body is not None:
            return self._body
        async with self._lock:
            if self._body is not None and time.monotonic() - self._at < self.max_age_s:
                return self._body
            body = await anyio.to_thread.run_sync(self._compute, limiter=self._thread)
            self._body, self._at = body, time.monotonic()
            return body
