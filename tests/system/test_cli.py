"""The `fringelab` command: versions, and one-line errors for the start-up faults a user meets."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from backend import __version__
from backend.cli import build_parser
from fringelab.core.queue import create_celery
from fringelab.core.settings import Settings
from fringelab.core.startup_checks import free_port
from tests.support import RedisServer, wait_for


def run_cli(*args: str, env: dict[str, str] | None = None, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("FRINGELAB_")}
    return subprocess.run(
        [sys.executable, "-m", "backend.cli", *args],
        env={**clean, **(env or {})},
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def assert_one_line_error(result: subprocess.CompletedProcess[str], *needles: str) -> None:
    assert result.returncode != 0
    assert "Traceback" not in result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("fringelab: error:")]
    assert len(lines) == 1, result.stderr
    for needle in needles:
        assert needle in lines[0]


def test_version():
    result = run_cli("version")
    assert result.returncode == 0
    assert result.stdout.strip() == f"fringelab {__version__}"


def test_every_process_command_exists():
    parser = build_parser()
    for argv in (["up"], ["api"], ["worker"], ["db", "upgrade"], ["version"], ["health"]):
        assert callable(parser.parse_args(argv).handler)


def test_unreachable_redis_is_named(tmp_path):
    port = free_port()
    env = {"FRINGELAB_REDIS_URL": f"redis://127.0.0.1:{port}/0", "FRINGELAB_DATA_DIR": str(tmp_path),
           "FRINGELAB_WORKER_REDIS_WAIT_S": "1"}  # fmt: skip
    for command in ("worker", "api"):
        assert_one_line_error(run_cli(command, env=env), f"127.0.0.1:{port}", "FRINGELAB_REDIS_URL")


def test_a_worker_started_before_its_redis_waits_for_it(tmp_path):
    """`fringelab up` restarts Redis beside a worker that is starting (compose may start Redis later): the worker
    waits for it (FRINGELAB_WORKER_REDIS_WAIT_S) instead of exiting, and then serves."""
    redis_server = RedisServer(tmp_path)
    clean = {k: v for k, v in os.environ.items() if not k.startswith("FRINGELAB_")}
    env = {**clean, "FRINGELAB_REDIS_URL": redis_server.url, "FRINGELAB_DATA_DIR": str(tmp_path / "var"),
           "FRINGELAB_WORKER_CONCURRENCY": "1"}  # fmt: skip
    worker = subprocess.Popen([sys.executable, "-m", "backend.cli", "worker"], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True, start_new_session=True)  # fmt: skip
    try:
        time.sleep(2)  # the worker is up to its check of Redis by now, and Redis is not there
        assert worker.poll() is None, worker.stderr.read() if worker.stderr else ""
        redis_server.start()
        celery = create_celery(Settings(_env_file=None, redis_url=redis_server.url))  # type: ignore[call-arg]
        wait_for(lambda: celery.control.ping(timeout=0.5), timeout_s=60, what="the worker to answer")
    finally:
        os.killpg(worker.pid, signal.SIGTERM)
        worker.wait(timeout=60)
        redis_server.stop()


def test_invalid_setting_is_named(tmp_path):
    result = run_cli("api", env={"FRINGELAB_PORT": "not-a-port", "FRINGELAB_DATA_DIR": str(tmp_path)})
    assert_one_line_error(result, "FRINGELAB_PORT")


def test_unreachable_database_is_named(tmp_path):
    result = run_cli("db", "upgrade", env={"FRINGELAB_DATABASE_URL": "postgresql+psycopg://x@127.0.0.1:1/db"})
    assert_one_line_error(result, "127.0.0.1:1", "FRINGELAB_DATABASE_URL")


def test_port_in_use_is_named(tmp_path, redis_server):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        env = {
            "FRINGELAB_REDIS_URL": redis_server.url,
            "FRINGELAB_PORT": str(port),
            "FRINGELAB_DATA_DIR": str(tmp_path),
        }
        for command in ("api", "up"):
            assert_one_line_error(run_cli(command, env=env), f"port {port}", "FRINGELAB_PORT")


@pytest.mark.integration
def test_health_command_reports_missing_workers(settings):
    import redis

    redis.Redis.from_url(settings.redis_url).flushdb()  # no heartbeat left by an earlier test's worker
    env = {"FRINGELAB_REDIS_URL": settings.redis_url, "FRINGELAB_DATA_DIR": str(settings.data_dir)}
    result = run_cli("health", env=env)
    assert result.returncode == 1
    assert '"failing":["workers"]' in result.stdout
