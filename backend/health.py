"""Health of the system's parts (database, Redis, live workers), shared by `/api/v1/health` and `fringelab health`."""

from __future__ import annotations

import json
from pathlib import Path

import redis
from celery import Celery
from pydantic import BaseModel, Field
from sqlalchemy import Engine

from backend import __version__
from fringelab.core.db import DatabaseError, check_database
from fringelab.core.services import redacted_url


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


def _redis_health(url: str) -> PartHealth:
    try:
        client = redis.Redis.from_url(url, socket_timeout=2, socket_connect_timeout=2)
        client.ping()
        client.close()
    except redis.RedisError as error:
        return PartHealth(ok=False, detail=f"Redis at {redacted_url(url)} unreachable: {error}")
    return PartHealth(ok=True)


def system_health(
    *, engine: Engine, redis_url: str, celery: Celery, worker_timeout_s: float, data_path: Path | None = None
) -> Health:
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
    processes = supervised_children(data_path)
    failing += [f"{child.name} (restarting)" for child in processes if not child.running]
    return Health(ok=not failing, version=__version__, database=database, redis=redis_part, workers=workers,
                  failing=failing, processes=processes)  # fmt: skip
