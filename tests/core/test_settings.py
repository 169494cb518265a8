from pathlib import Path

import pytest

from fringelab.core.settings import (
    BACKGROUND_CONNECTIONS,
    MIN_BACKGROUND_CONNECTIONS,
    Settings,
    SettingsError,
    load_settings,
    settings_table,
)

ROOT = Path(__file__).resolve().parents[2]


def test_defaults_are_the_embedded_laptop_setup(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    settings = load_settings()
    assert (settings.host, settings.port) == ("127.0.0.1", 8000)
    assert settings.redis_url == ""
    assert settings.resolved_database_url == f"sqlite:///{tmp_path / 'var' / 'fringelab.db'}"
    assert settings.resolved_worker_concurrency >= 1


def test_environment_variables_use_the_prefix(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("FRINGELAB_PORT", "8123")
    monkeypatch.setenv("FRINGELAB_LOG_LEVEL", "DEBUG")
    settings = load_settings()
    assert settings.port == 8123
    assert settings.log_level == "debug"


@pytest.mark.parametrize(
    ("variable", "value"),
    [("FRINGELAB_PORT", "eighty"), ("FRINGELAB_PORT", "70000"), ("FRINGELAB_LOG_LEVEL", "loud")],
)
def test_an_invalid_value_names_its_variable(monkeypatch, tmp_path, variable, value):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(variable, value)
    with pytest.raises(SettingsError, match=variable):
        load_settings()


def test_every_setting_is_documented_in_readme_and_env_example():
    readme = (ROOT / "README.md").read_text()
    example = (ROOT / ".env.example").read_text()
    for variable, _default, description in settings_table():
        assert f"`{variable}`" in readme, f"{variable} missing from the README settings table"
        assert f"{variable}=" in example, f"{variable} missing from .env.example"
        assert description, f"{variable} has no description"


def test_settings_are_read_when_built_not_at_import(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("FRINGELAB_PORT", "9001")
    assert Settings(_env_file=None).port == 9001  # type: ignore[call-arg]
    monkeypatch.setenv("FRINGELAB_PORT", "9002")
    assert Settings(_env_file=None).port == 9002  # type: ignore[call-arg]


POSTGRES = "postgresql://fringelab@db/fringelab"


@pytest.mark.parametrize(
    ("processes", "connections", "threads"),
    [(1, 50, 40), (2, 45, 40), (4, 22, 22), (8, 11, 11)],  # 40 threads (asked) + 10, within 90 / processes
)
def test_the_web_servers_database_connections_stay_within_the_total(processes, connections, threads):
    """N API processes × a pool sized for one once exceeded PostgreSQL's 100 connections: each process gets its
    share of FRINGELAB_DB_MAX_CONNECTIONS (90), and no more threads than connections (a thread without one waits)."""
    settings = Settings(_env_file=None, api_processes=processes, api_threads=40, database_url=POSTGRES)  # type: ignore[call-arg]
    assert (settings.resolved_db_pool_size, settings.resolved_api_threads) == (connections, threads)
    assert processes * settings.resolved_db_pool_size <= settings.db_max_connections
    assert Settings(_env_file=None, api_processes=8, db_pool_size=30).resolved_db_pool_size == 30  # type: ignore[call-arg]
    # SQLite (the default) is a file: each process gets a connection for each request it runs (8 threads by
    # default), and 10; it takes 57 more waiting for their turn (FRINGELAB_API_QUEUE), so that a burst of 60
    # connections that the kernel gives to one process is still all served (tests/system/test_hostile.py)
    sqlite = Settings(_env_file=None, api_processes=processes)  # type: ignore[call-arg]
    assert (sqlite.resolved_db_pool_size, sqlite.resolved_api_in_flight) == (18, 65)
    # never more requests running than connections for them (beside streams and background work); those waiting
    # for their turn hold none (backend.shedding), so a process takes as many in all whatever its database
    background = settings.resolved_background_connections
    assert MIN_BACKGROUND_CONNECTIONS <= background <= BACKGROUND_CONNECTIONS
    assert settings.resolved_api_running <= max(1, settings.resolved_db_pool_size - background)
    # a small share of the server's connections still runs as many requests at once as the process has threads
    # (8 processes on PostgreSQL ran 1 request each at once when 10 of their 11 connections were kept)
    shared = Settings(_env_file=None, api_processes=processes, database_url=POSTGRES)  # type: ignore[call-arg]
    assert shared.resolved_api_running == shared.resolved_api_threads == 8
    assert settings.resolved_api_in_flight == settings.resolved_api_running + settings.api_queue


def test_the_default_web_server_processes_follow_the_cores():
    import os

    assert Settings(_env_file=None).resolved_api_processes == max(1, min(8, os.cpu_count() or 1))  # type: ignore[call-arg]
