"""What one API process shares between requests: its settings, database and Celery client."""

from __future__ import annotations

from dataclasses import dataclass, field

from celery import Celery
from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from fringelab.core.accounts import TokenCache
from fringelab.core.settings import Settings
from fringelab.formats.hdf5 import FrameCache


@dataclass
class AppState:
    settings: Settings
    engine: Engine
    sessions: sessionmaker[Session]
    celery: Celery
    tokens: TokenCache = field(default_factory=lambda: TokenCache(ttl_s=5.0))
    # Result frames recently read (grids, profiles), by the file's identity: `FrameCache`.
    frames: FrameCache = field(default_factory=lambda: FrameCache(max_bytes=0))
