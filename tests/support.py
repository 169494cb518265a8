"""Real services for tests: a Redis server of our own on a free port, and waiting helpers (no sleeps)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import redis

from backend.supervisor import redis_server_binary
from fringelab.core.startup_checks import free_port


def wait_for(predicate: Callable[[], object], *, timeout_s: float, what: str, interval_s: float = 0.05) -> object:
    """Poll until `predicate()` is truthy; fail the test naming `what` after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(interval_s)


class RedisServer:
    """A redis-server child process on a free port (never the user's Redis), restartable on the same port."""

    def __init__(self, directory: Path, *, appendonly: bool = False) -> None:
        self.directory = directory
        self.port = free_port()
        self.appendonly = appendonly
        self.process: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> None:
        argv = [
            redis_server_binary(),
            "--bind", "127.0.0.1",
            "--port", str(self.port),
            "--dir", str(self.directory),
            "--save", "",
            "--appendonly", "yes" if self.appendonly else "no",
        ]  # fmt: skip
        self.process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        client = redis.Redis.from_url(self.url, socket_connect_timeout=0.2)

        def answers() -> bool:
            try:
                return bool(client.ping())
            except redis.ConnectionError:
                return False

        wait_for(answers, timeout_s=10, what=f"redis-server on port {self.port}")
        client.close()

    def stop(self) -> None:
        if self.process and self.process.poll() is None:
            self.process.terminate()
            self.process.wait(timeout=10)

    def kill(self) -> None:
        """As a crash: clients see their connections reset and the port refuses until `start`."""
        if self.process and self.process.poll() is None:
            self.process.kill()
            self.process.wait(timeout=10)


class UpProcess:
    """`fringelab up` as a user runs it, in a subprocess on a free port with its own data directory."""

    def __init__(self, data_dir: Path, *, extra_env: dict[str, str] | None = None) -> None:
        import os
        import sys

        self.port = free_port()
        self.data_dir = data_dir
        self.log_path = data_dir.parent / f"up-{self.port}.log"
        clean = {k: v for k, v in os.environ.items() if not k.startswith("FRINGELAB_")}
        self.env = {**clean, "FRINGELAB_PORT": str(self.port), "FRINGELAB_DATA_DIR": str(data_dir), **(extra_env or {})}
        self.argv = [sys.executable, "-m", "backend.cli", "up"]
        self.process: subprocess.Popen[bytes] | None = None

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def log(self) -> str:
        return self.log_path.read_text() if self.log_path.exists() else ""

    def start(self, *, timeout_s: float = 120) -> None:
        import httpx

        with self.log_path.open("wb") as log:
            self.process = subprocess.Popen(self.argv, env=self.env, stdout=log, stderr=subprocess.STDOUT)

        def healthy() -> bool:
            if self.process and self.process.poll() is not None:
                raise RuntimeError(f"`fringelab up` exited early:\n{self.log()[-3000:]}")
            try:
                response = httpx.get(f"{self.base_url}/api/v1/health", timeout=5)
            except httpx.HTTPError:
                return False
            return response.status_code == 200 and response.json()["workers"] >= 1

        wait_for(healthy, timeout_s=timeout_s, what="a healthy `fringelab up`", interval_s=0.3)
        banner = f"fringelab is running at {self.base_url}"
        wait_for(lambda: banner in self.log(), timeout_s=30, what=banner)

    def stop(self, *, timeout_s: float = 60) -> int:
        import signal

        assert self.process is not None
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        try:
            return self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            raise


def bearer(token: str) -> dict[str, str]:
    """The header that authenticates a request with an API token."""
    return {"Authorization": f"Bearer {token}"}


_ADD_PEOPLE = """
import json, sys
from fringelab.core.accounts import create_user, issue_token
from fringelab.core.db import make_engine, make_sessionmaker, upgrade_database
from fringelab.core.settings import load_settings

settings = load_settings()
upgrade_database(settings.resolved_database_url)
tokens = {}
with make_sessionmaker(make_engine(settings.resolved_database_url))() as session:
    for name, admin in json.loads(sys.argv[1]):
        user = create_user(session, name, f"{name}-password", role="admin" if admin else "member")
        tokens[name] = issue_token(session, user, kind="api")[1]
    session.commit()
print(json.dumps(tokens))
"""


def add_people(env: dict[str, str], people: Iterable[tuple[str, bool]]) -> dict[str, str]:
    """Users (password "<name>-password"; admin or member) and an API token each, {name: token}, made as
    `fringelab user add` and `fringelab token create` make them, in one process with the server's environment
    (the six commands of three people cost 12 s; tests/api/auth/test_accounts.py runs the commands themselves)."""
    done = subprocess.run([sys.executable, "-c", _ADD_PEOPLE, json.dumps(list(people))], env=env,
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    return dict(json.loads(done.stdout))
