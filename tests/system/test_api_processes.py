"""A web server of several processes (FRINGELAB_API_PROCESSES) behaves as one: a token revoked or an account
disabled in one process is refused by all of them at once, a user's request rate counts over all of them, and an
open jobs-list stream ends when its reader's access does.

Real processes: `fringelab api` with 2 processes on a free loopback port, the tests' own Redis on a free port.
Each check keeps connections open on both processes (a keep-alive connection stays with the process that
accepted it, which psutil shows), so a per-process cache or counter would be seen to disagree.
"""

from __future__ import annotations

import http.client
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import httpx
import psutil
import pytest

from backend.limits import lease_for
from backend.supervisor import STATUS_FILE, Supervisor, running_redis_url
from fringelab.core.settings import Settings
from fringelab.core.startup_checks import free_port
from tests.support import RedisServer, add_people, bearer, wait_for

pytestmark = [pytest.mark.integration, pytest.mark.slow]

PROCESSES = 2
RATE_PER_S = 5.0
BURST = 320  # over 64: each process leases tokens from Redis (backend.limits.lease_for: 10 per call)
TOKEN_CACHE_S = 300  # far longer than any test: a process that kept trusting a revoked token would show it
PEOPLE = ("admin", "ada", "bob", "cy", "dan", "eve")


@dataclass
class ApiServer:
    process: subprocess.Popen[bytes]
    url: str
    port: int
    env: dict[str, str]
    tokens: dict[str, str] = field(default_factory=dict)

    def cli(self, *args: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "backend.cli", *args], env=self.env, input=stdin,
                              capture_output=True, text=True, timeout=120)  # fmt: skip

    def serving_processes(self) -> list[psutil.Process]:
        return psutil.Process(self.process.pid).children(recursive=True)

    def process_of(self, client: Pinned) -> int | None:
        """The PID of the web server process holding `client`'s kept-alive connection."""
        pid_of: dict[int, int] = {}  # the client's port -> the server process holding that connection
        for child in self.serving_processes():
            for connection in child.net_connections(kind="tcp"):
                if connection.status == psutil.CONN_ESTABLISHED and connection.laddr.port == self.port:
                    pid_of[connection.raddr.port] = child.pid
        port = client.local_port
        return pid_of.get(port) if port is not None else None


@dataclass(frozen=True)
class Answer:
    status_code: int
    headers: dict[str, str]  # names in lower case
    text: str

    def json(self) -> Any:
        return json.loads(self.text)


class Pinned:
    """One kept-alive HTTP/1.1 connection (the standard library's: its socket, hence its port, is known) sending
    the requests of one user: it stays with the server process that accepted it."""

    def __init__(self, server: ApiServer, token: str) -> None:
        self.connection = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
        self.headers = bearer(token)

    @property
    def local_port(self) -> int | None:
        return int(self.connection.sock.getsockname()[1]) if self.connection.sock else None

    def get(self, path: str) -> Answer:
        self.connection.request("GET", path, headers=self.headers)
        answer = self.connection.getresponse()
        text = answer.read().decode()
        assert not answer.will_close, "the server closed a kept-alive connection"
        return Answer(answer.status, {k.lower(): v for k, v in answer.getheaders()}, text)

    def close(self) -> None:
        self.connection.close()


@pytest.fixture(scope="module")
def api_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ApiServer]:
    root = tmp_path_factory.mktemp("processes")
    redis_server = RedisServer(root)
    redis_server.start()
    port = free_port()
    clean = {k: v for k, v in os.environ.items() if not k.startswith("FRINGELAB_")}
    env = {**clean, "FRINGELAB_DATA_DIR": str(root / "var"), "FRINGELAB_PORT": str(port),
           "FRINGELAB_REDIS_URL": redis_server.url, "FRINGELAB_AUTH_ENABLED": "true",
           "FRINGELAB_API_PROCESSES": str(PROCESSES), "FRINGELAB_TOKEN_CACHE_S": str(TOKEN_CACHE_S),
           "FRINGELAB_USER_REQUESTS_PER_S": str(RATE_PER_S), "FRINGELAB_USER_REQUEST_BURST": str(BURST),
           "FRINGELAB_LIST_EVENTS_S": "30", "FRINGELAB_LOG_LEVEL": "warning"}  # fmt: skip
    log = (root / "api.log").open("wb")
    process = subprocess.Popen([sys.executable, "-m", "backend.cli", "api"], env=env, stdout=log,
                               stderr=subprocess.STDOUT, start_new_session=True)  # fmt: skip
    server = ApiServer(process, f"http://127.0.0.1:{port}", port, env)
    try:
        server.tokens.update(add_people(env, [(name, name == "admin") for name in PEOPLE]))

        def up() -> bool:
            if process.poll() is not None:
                raise RuntimeError(f"`fringelab api` exited:\n{(root / 'api.log').read_text()[-3000:]}")
            try:
                return httpx.get(f"{server.url}/api/v1/auth/me", timeout=2).status_code == 401
            except httpx.HTTPError:
                return False

        wait_for(up, timeout_s=120, what="`fringelab api` answering", interval_s=0.2)
        wait_for(lambda: len(server.serving_processes()) >= PROCESSES, timeout_s=60, what="its processes")
        yield server
    finally:
        os.killpg(process.pid, 15)
        process.wait(timeout=60)
        log.close()
        redis_server.stop()


def pinned_clients(server: ApiServer, who: str, *, per_process: int = 2, most: int = 200) -> list[Pinned]:
    """Connections of `who`, each kept alive, `per_process` on every process, each of which has then checked
    `who`'s token. Connections are opened 20 ms apart and those a process already has enough of are closed
    unused: made back to back, nearly all are accepted by the same process."""
    kept: dict[int, list[Pinned]] = {}
    for _attempt in range(most):
        opened = Pinned(server, server.tokens[who])
        opened.connection.connect()
        time.sleep(0.02)  # accepted by then, and the other process gets its turn
        pid = wait_for(partial(server.process_of, opened), timeout_s=5, what="the connection accepted")
        held = kept.setdefault(int(pid), [])  # type: ignore[call-overload]
        if len(held) < per_process:
            held.append(opened)
        else:
            opened.close()
        if len(kept) >= PROCESSES and all(len(held) >= per_process for held in kept.values()):
            clients = [client for held in kept.values() for client in held]
            for client in clients:
                assert client.get("/api/v1/auth/me").status_code == 200  # this process has now checked the token
            return clients
    spread = {pid: len(held) for pid, held in kept.items()}
    raise AssertionError(f"{most} connections did not reach {PROCESSES} processes: {spread}")


def test_the_server_runs_several_processes(api_server: ApiServer) -> None:
    clients = pinned_clients(api_server, "ada", per_process=1)
    assert len({api_server.process_of(c) for c in clients}) == PROCESSES
    for client in clients:
        client.close()


def test_a_revoked_token_is_refused_by_every_process_at_once(api_server: ApiServer) -> None:
    clients = pinned_clients(api_server, "bob")
    with httpx.Client(base_url=api_server.url, headers=bearer(api_server.tokens["bob"]), timeout=30) as bob:
        token_id = bob.get("/api/v1/auth/tokens").json()[0]["id"]
    with httpx.Client(base_url=api_server.url, headers=bearer(api_server.tokens["admin"]), timeout=30) as admin:
        assert admin.delete(f"/api/v1/auth/tokens/{token_id}").status_code == 204
    # Every process had bob's token checked and trusted for TOKEN_CACHE_S; none may answer it any more.
    answers = [client.get("/api/v1/auth/me") for client in clients]
    assert [a.status_code for a in answers] == [401] * len(clients), [a.text for a in answers]
    assert "revoked" in answers[0].json()["detail"]
    for client in clients:
        client.close()


def test_an_account_disabled_from_the_command_line_is_refused_by_every_process(api_server: ApiServer) -> None:
    clients = pinned_clients(api_server, "dan")
    disabled = api_server.cli("user", "disable", "dan")
    assert disabled.returncode == 0, disabled.stderr
    assert [client.get("/api/v1/auth/me").status_code for client in clients] == [401] * len(clients)
    for client in clients:
        client.close()


def test_a_users_request_rate_counts_over_all_processes(api_server: ApiServer) -> None:
    started = time.monotonic()  # cy's bucket is full (burst) and refills from here on
    clients = pinned_clients(api_server, "cy", per_process=3)  # each took one request of the bucket
    statuses: list[int] = []
    retry_after: list[str] = []
    while len(statuses) < PROCESSES * BURST + 10:  # what per-process buckets would let through, and more
        for client in clients:
            answer = client.get("/api/v1/auth/me")
            statuses.append(answer.status_code)
            if answer.status_code == 429:
                retry_after.append(answer.headers.get("retry-after", ""))
    elapsed_s = time.monotonic() - started
    sent = len(clients) + len(statuses)
    allowed = BURST + RATE_PER_S * elapsed_s + 1  # what one bucket refills in the time taken, +1 for rounding
    # What leases may add or hold back: lease - 1 tokens per process (`SharedRateLimiter`'s stated tolerance).
    slack = PROCESSES * (lease_for(BURST) - 1)
    ok = len(clients) + statuses.count(200)
    assert set(statuses) <= {200, 429}
    assert ok <= allowed + slack, f"{ok} of {sent} allowed in {elapsed_s:.1f} s; one bucket allows {allowed:.0f}"
    assert ok >= BURST - slack, f"{ok} of {sent} allowed; the burst is {BURST}"
    if sent > allowed + 1:  # sent faster than the rate (always, unless the machine is very slow)
        assert retry_after and all(value.isdigit() for value in retry_after)
    for client in clients:
        client.close()


def test_a_jobs_list_stream_ends_when_its_token_is_revoked(api_server: ApiServer) -> None:
    with httpx.Client(base_url=api_server.url, headers=bearer(api_server.tokens["eve"]), timeout=30) as eve:
        token_id = eve.get("/api/v1/auth/tokens").json()[0]["id"]
        with eve.stream("GET", "/api/v1/jobs/events", timeout=httpx.Timeout(30, read=20)) as stream:
            assert stream.status_code == 200
            lines = stream.iter_lines()
            assert next(line for line in lines if line.startswith("event:")) == "event: jobs"
            with httpx.Client(base_url=api_server.url, headers=bearer(api_server.tokens["admin"])) as admin:
                assert admin.delete(f"/api/v1/auth/tokens/{token_id}").status_code == 204
            revoked_at = time.monotonic()
            rest = list(lines)  # the server ends the stream; a read timeout (20 s) would fail the test
    assert time.monotonic() - revoked_at < 10  # the stream re-checks its reader every 2 s
    assert "event: end" in rest
    assert any("access ended" in line and "revoked" in line for line in rest)


def test_the_cli_finds_the_redis_that_up_started(tmp_path: Path) -> None:
    settings = Settings(_env_file=None, data_dir=tmp_path / "var")  # type: ignore[call-arg]
    settings.data_path.mkdir(parents=True)
    assert running_redis_url(settings) == ""  # nothing running
    supervisor = Supervisor(settings, tmp_path, embedded_redis_url="redis://127.0.0.1:6390/0")
    supervisor.write_status()
    assert (settings.data_path / STATUS_FILE).exists()
    assert running_redis_url(settings) == "redis://127.0.0.1:6390/0"
    configured = settings.model_copy(update={"redis_url": "redis://lab:6379/0"})
    assert running_redis_url(configured) == "redis://lab:6379/0"
