"""Health of the system's parts (database, Redis, live workers), shared by `/api/v1/health` and `fringelab health`."""

from __future__ import annotations

import redis
from celery import Celery
from pydantic import BaseModel
from sqlalchemy import Engine

from backend import __version__
from fringelab.core.db import DatabaseError, check_database


class PartHealth(BaseModel):
    ok: bool
    detail: str = ""


class Health(BaseModel):
    ok: bool
    version: str
    database: PartHealth
    redis: PartHealth
    workers: int
    failing: list[str]


def _redis_health(url: str) -> PartHealth:
    try:
        client = redis.Redis.from_url(url, socket_timeout=2, socket_connect_timeout=2)
        client.ping()
        client.close()
    except redis.RedisError as error:
        return PartHealth(ok=False, detail=f"Redis at {url} unreachable: {error}")
    return PartHealth(ok=True)


def system_health(*, engine: Engine, redis_url: str, celery: Celery, worker_timeout_s: float) -> Health:
    """Check each part; a bounded broadcast ping counts the live workers."""
    try:
        check_database(engine)
        database = PartHealth(ok=True)
    except DatabaseError as error:
        database = PartHealth(ok=False, detail=str(error))
    redis_part = _redis_health(redis_url) if redis_url else PartHealth(ok=False, detail="FRINGELAB_REDIS_URL is empty")
    workers = len(celery.control.ping(timeout=worker_timeout_s) or []) if redis_part.ok else 0
    failing = [name for name, part in (("database", database), ("redis", redis_part)) if not part.ok]
    if workers == 0:
        failing.append("workers")
    return Health(
        ok=not failing, version=__version__, database=database, redis=redis_part, workers=workers, failing=failing
    )
