"""Per-process resources of a worker: the database sessions and the Redis client, made once per process (after the
prefork fork), and where a job keeps its files."""

from __future__ import annotations

import os
from pathlib import Path

import redis
from celery import Celery
from sqlalchemy.orm import Session, sessionmaker

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.settings import Settings
from fringelab.core.storage import job_dir as storage_job_dir

_sessions: dict[tuple[int, str], sessionmaker[Session]] = {}
_redis: dict[tuple[int, str], redis.Redis] = {}


def settings_of(app: Celery) -> Settings:
    return app.fringelab_settings


def sessions_of(app: Celery) -> sessionmaker[Session]:
    """The session factory of this process; a forked child makes its own engine instead of sharing sockets."""
    url = settings_of(app).resolved_database_url
    key = (os.getpid(), url)
    if key not in _sessions:
        _sessions[key] = make_sessionmaker(make_engine(url))
    return _sessions[key]


def redis_of(app: Celery) -> redis.Redis:
    """This process's client of the queue's Redis (for what the job system signals besides tasks)."""
    url = settings_of(app).redis_url
    key = (os.getpid(), url)
    if key not in _redis:
        _redis[key] = redis.Redis.from_url(url, socket_timeout=10, socket_connect_timeout=5)
    return _redis[key]


def job_dir(settings: Settings, job_id: str) -> Path:
    """`DATA_DIR/results/jobs/<job id>` (the rule is `fringelab.core.storage.job_dir`, which deletes use too)."""
    return storage_job_dir(settings.data_path, job_id)
