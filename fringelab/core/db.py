"""Database engine, sessions and migrations (SQLAlchemy 2 + Alembic).

SQLite (WAL mode, foreign keys on) is the embedded default; PostgreSQL is used through its URL on a lab server.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import Engine, create_engine, event, text
from sqlalchemy.orm import Session, sessionmaker

if TYPE_CHECKING:
    from alembic.config import Config

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
    from alembic.config import Config  # half a second to import: only where a database is upgraded

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    config.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return config


def upgrade_database(url: str, revision: str = "head") -> None:
    """Apply the migrations up to `revision`; raise DatabaseError with a usable message on failure. Processes
    that start together (the web server's, a command such as `fringelab user add`) upgrade one at a time
    (`_one_upgrade_at_a_time`): the second finds the first one's work done instead of repeating it halfway."""
    from alembic import command

    engine = make_engine(url)
    try:
        check_database(engine)
        with _one_upgrade_at_a_time(engine):
            command.upgrade(alembic_config(url), revision)
    finally:
        engine.dispose()


# The PostgreSQL advisory lock that upgrades take (any fixed number; "fringelab" in ASCII, cut to 63 bits).
UPGRADE_LOCK_KEY = 0x6672696E67656C61


@contextmanager
def _one_upgrade_at_a_time(engine: Engine) -> Iterator[None]:
    """Hold the database's upgrade lock: a lock file beside an SQLite database, an advisory lock on PostgreSQL
    (held by a connection of its own until the upgrade ends)."""
    if engine.dialect.name == "sqlite":
        path = engine.url.database
        if not path or path == ":memory:":
            yield
            return
        try:
            import fcntl
        except ImportError:  # not POSIX: no lock (start one process first there)
            yield
            return
        with Path(f"{path}.upgrade-lock").open("a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
            yield
    elif engine.dialect.name == "postgresql":
        with engine.connect() as connection:
            connection.execute(text("SELECT pg_advisory_lock(:key)"), {"key": UPGRADE_LOCK_KEY})
            try:
                yield
            finally:
                connection.execute(text("SELECT pg_advisory_unlock(:key)"), {"key": UPGRADE_LOCK_KEY})
    else:
        yield
