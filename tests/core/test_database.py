"""Migrations run against SQLite (the embedded default) and PostgreSQL (the lab server)."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator

import pytest
from alembic import command
from sqlalchemy import create_engine, inspect, text

from fringelab.core.db import DatabaseError, alembic_config, make_engine, upgrade_database
from fringelab.core.models import Base

POSTGRES_ADMIN_URL = os.environ.get("FRINGELAB_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


def _tables(url: str) -> set[str]:
    engine = make_engine(url)
    try:
        return set(inspect(engine).get_table_names())
    finally:
        engine.dispose()


@pytest.fixture
def postgres_url() -> Iterator[str]:
    """A throw-away PostgreSQL database, or a skip with the reason when no server is reachable."""
    admin = create_engine(POSTGRES_ADMIN_URL, isolation_level="AUTOCOMMIT")
    name = f"fringelab_test_{uuid.uuid4().hex[:10]}"
    try:
        with admin.connect() as connection:
            connection.execute(text(f'CREATE DATABASE "{name}"'))
    except Exception as error:  # any failure to reach the server means: no PostgreSQL here
        admin.dispose()
        pytest.skip(f"PostgreSQL not reachable at {POSTGRES_ADMIN_URL}: {type(error).__name__}")
    yield POSTGRES_ADMIN_URL.rsplit("/", 1)[0] + f"/{name}"
    with admin.connect() as connection:
        connection.execute(text(f'DROP DATABASE "{name}" WITH (FORCE)'))
    admin.dispose()


@pytest.fixture(params=["sqlite", "postgresql"])
def database_url(request: pytest.FixtureRequest, tmp_path) -> str:
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'var' / 'fringelab.db'}"
    return request.getfixturevalue("postgres_url")


def test_migrations_create_every_table_and_go_back_down(database_url):
    upgrade_database(database_url)
    assert _tables(database_url) >= set(Base.metadata.tables)
    upgrade_database(database_url)  # a second upgrade is a no-op
    command.downgrade(alembic_config(database_url), "base")
    assert not (_tables(database_url) & set(Base.metadata.tables))


def test_migrations_match_the_models(database_url):
    """Autogenerate finds nothing to do: every model change has its migration."""
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    upgrade_database(database_url)
    engine = make_engine(database_url)
    with engine.connect() as connection:
        diff = compare_metadata(MigrationContext.configure(connection), Base.metadata)
    engine.dispose()
    assert diff == []


def test_sqlite_runs_in_wal_mode_with_foreign_keys(tmp_path):
    url = f"sqlite:///{tmp_path / 'fringelab.db'}"
    upgrade_database(url)
    engine = make_engine(url)
    with engine.connect() as connection:
        assert connection.execute(text("PRAGMA journal_mode")).scalar() == "wal"
        assert connection.execute(text("PRAGMA foreign_keys")).scalar() == 1
    engine.dispose()


def test_an_unreachable_database_is_named():
    with pytest.raises(DatabaseError, match=r"127\.0\.0\.1:1.*FRINGELAB_DATABASE_URL"):
        upgrade_database("postgresql+psycopg://nobody@127.0.0.1:1/none?connect_timeout=2")


def _upgrade_in_a_process(url: str) -> None:
    upgrade_database(url)


def test_processes_that_start_together_upgrade_one_at_a_time(database_url):
    """The web server and a command such as `fringelab user add` start together and both upgrade a new database:
    each succeeds (the later ones find the work done), where two interleaved upgrades fail halfway (SQLite: "table
    _alembic_tmp_users already exists")."""
    import multiprocessing

    spawn = multiprocessing.get_context("spawn")
    processes = [spawn.Process(target=_upgrade_in_a_process, args=(database_url,)) for _ in range(4)]
    for process in processes:
        process.start()
    for process in processes:
        process.join(timeout=300)
    assert [process.exitcode for process in processes] == [0] * 4
    assert {"users", "jobs", "job_chunks", "alembic_version"} <= _tables(database_url)
