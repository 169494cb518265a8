"""Database engine, sessions and migrations (SQLAlchemy 2 + Alembic).

SQLite (WAL mode, foreign keys on) is the embedded default; PostgreSQL is used through its URL on a lab server.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from alembic import command
from alembic.config import Config
from sqlalchemy import Engine, create_engine, event, text
from sqlalchemy.orm import Session, sessionmaker

MIGRATIONS_DIR = Path(__file__).parent / "migrations"


class DatabaseError(Exception):
    """The database cannot be reached or migrated; the message says how to fix it."""


def make_engine(url: str, *, max_connections: int = 10) -> Engine:
    """An engine that opens at most `max_connections` connections (half kept, the rest on demand): the web
    server passes one per thread that may run a route, so that no request waits for a connection another
    holds, within its share of the database's connections (`Settings.resolved_db_pool_size`)."""
    kept = max(1, (max_connections + 1) // 2)
    pool: dict[str, int] = {"pool_size": kept, "max_overflow": max(0, max_connections - kept), "pool_timeout": 30}
    if url.startswith("sqlite"):
        path = url.split("///", 1)[-1]
        if path and path != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        if not path or path == ":memory:":
            pool = {}  # one in-memory database per connection: SQLAlchemy's own single-thread pool
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30}, **pool)

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(dbapi_connection, _record) -> None:
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA foreign_keys=ON")
            cursor.execute("PRAGMA busy_timeout=30000")
            cursor.close()

        return engine
    return create_engine(url, pool_pre_ping=True, **pool)


def make_sessionmaker(engine: Engine) -> sessionmaker[Session]:
    return sessionmaker(engine, expire_on_commit=False)


@contextmanager
def session_scope(factory: sessionmaker[Session]) -> Iterator[Session]:
    """A session that commits on success and rolls back on any error."""
    session = factory()
    try:
        yield session
        session.commit()
    except BaseException:
        session.rollback()
        raise
    finally:
        session.close()


def check_database(engine: Engine) -> None:
    try:
        with engine.connect() as connection:
            connection.execute(text("SELECT 1"))
    except Exception as error:
        url = engine.url.render_as_string(hide_password=True)
        reason = str(getattr(error, "orig", None) or error).strip().splitlines()[0]
        raise DatabaseError(f"database {url} unreachable ({reason}); check FRINGELAB_DATABASE_URL") from None


def alembic_config(url: str) -> Config:
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    config.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return config


def upgrade_database(url: str, revision: str = "head") -> None:
    """Apply the migrations up to `revision`; raise DatabaseError with a usable message on failure."""
    engine = make_engine(url)
    try:
        check_database(engine)
    finally:
        engine.dispose()
    command.upgrade(alembic_config(url), revision)
