"""Settings of every fringelab process: one `Settings` object, built once at start-up and passed down.

Values come from `FRINGELAB_*` environment variables (and a `.env` file in the working directory, if any).
Nothing here runs at import time; `load_settings()` is called by the CLI entry points and by tests.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationError, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

ENV_PREFIX = "FRINGELAB_"
# Database connections of a web server process kept beyond its requests: event streams' shared polls, the
# reconciliation, the flush of token uses. A process asks for BACKGROUND_CONNECTIONS; where its share of a database
# server's connections is small, it keeps a third of its pool (at least MIN_BACKGROUND_CONNECTIONS) instead, so that
# 8 processes on PostgreSQL (11 connections each) still run 8 requests at once each, not 1.
BACKGROUND_CONNECTIONS = 10
MIN_BACKGROUND_CONNECTIONS = 3


class SettingsError(Exception):
    """Settings with an invalid value; the message names the environment variable."""


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, env_file=".env", extra="ignore", frozen=True)

    data_dir: Path = Field(Path("var"), description="Database (SQLite), uploads and results live here.")
    database_url: str = Field("", description="SQLAlchemy URL; empty means SQLite at DATA_DIR/fringelab.db (WAL mode).")
    redis_url: str = Field(
        "", description="Broker and result backend; empty means `fringelab up` starts its own redis-server."
    )
    host: str = Field("127.0.0.1", description="Address the web server binds.")
    port: int = Field(8000, ge=1, le=65535, description="Port of the web server.")
    root_path: str = Field(
        "",
        description="Path prefix under which a reverse proxy serves the API (e.g. `/fringelab`); empty: at the root.",
    )
    worker_concurrency: int = Field(0, ge=0, description="Worker processes; 0 means one per CPU core.")
    worker_nice: int = Field(
        10,
        ge=0,
        le=19,
        description="Scheduling niceness of the worker processes (0-19): the higher, the more the web server's "
        "requests go first while a job computes on the same cores.",
    )
    api_processes: int = Field(
        0,
        ge=0,
        le=64,
        description="Web server processes sharing the port; 0 means one per CPU core, at most 8. Token "
        "revocations and the per-user request rate are shared between them through Redis.",
    )
    job_time_limit_s: int = Field(6 * 3600, ge=10, description="Hard time limit of one task.")
    visibility_timeout_s: int = Field(
        12 * 3600, ge=60, description="Redis redelivers an unacknowledged task after this; longer than any job."
    )
    health_worker_timeout_s: float = Field(1.0, gt=0, le=30, description="How long /health waits for workers.")
    chunk_frames: int = Field(
        100,
        ge=1,
        description="Most frames per parallel chunk of a topography (or selftest) job (chunks shrink "
        "towards the job's end).",
    )
    cancel_grace_s: float = Field(
        10.0, ge=0, description="After a cancel, seconds a running task has to stop before its process is terminated."
    )
    worker_redis_wait_s: float = Field(
        10.0,
        ge=0,
        description="How long a starting worker waits for its Redis (restarted beside it by `fringelab up`, or "
        "started later by compose) before it exits with the error.",
    )
    worker_lost_after_s: float = Field(
        60.0, ge=2, description="A running task that has not reported for this long is lost with its worker."
    )
    reconcile_interval_s: float = Field(
        30.0, ge=0, description="How often the API re-queues jobs the queue lost; 0 means only at start-up."
    )
    list_events_s: float = Field(
        300.0,
        gt=0,
        description="Lifetime of a jobs-list event stream (/jobs/events); the browser then reconnects by itself.",
    )
    auth_enabled: bool = Field(
        False, description="Require a login or API token; must be on to bind an address other than loopback."
    )
    session_ttl_h: float = Field(12.0, gt=0, description="Lifetime of a browser login session, in hours.")
    login_max_failures: int = Field(
        10, ge=1, description="Login attempts per account and per client address in a window before a 429."
    )
    login_concurrency: int = Field(
        0, ge=0, le=64, description="Password checks at once per web server process (64 MiB each); 0: from memory."
    )
    login_window_s: int = Field(300, ge=1, description="Window in which failed logins are counted.")
    max_json_bytes: int = Field(1_048_576, ge=1024, description="Largest accepted non-upload request body.")
    trusted_proxies: str = Field(
        "",
        description="Comma-separated addresses of reverse proxies whose X-Forwarded-For/-Proto headers are believed "
        "(e.g. 127.0.0.1 when nginx runs on this machine); empty: forwarded headers are ignored.",
    )
    secure_cookies: Literal["auto", "always", "never"] = Field(
        "auto", description="Mark the session cookie Secure: auto does so when the request came over HTTPS."
    )
    allowed_origins: str = Field(
        "",
        description="Comma-separated extra origins (https://host:port) allowed to send state-changing requests "
        "with the session cookie; the server's own origin always is.",
    )
    allowed_hosts: str = Field(
        "",
        description="Comma-separated Host names this server answers to ('*': any); empty: with accounts off the "
        "loopback names (localhost, 127.0.0.1, [::1]) and FRINGELAB_HOST, with accounts on any.",
    )
    api_threads: int = Field(
        8,
        ge=4,
        le=1000,
        description="Threads of each web server process that run its blocking routes (database, files), and so "
        "the requests it runs at once. More only compete for the process's GIL, with its event loop among them.",
    )
    api_queue: int = Field(
        57,
        ge=0,
        le=1000,
        description="Requests a web server process holds, waiting for their turn, beyond the threads it runs; more "
        "get 503 with Retry-After.",
    )
    frame_cache_bytes: int = Field(
        64 * 2**20,
        ge=0,
        le=2**40,
        description="Bytes of result frames a web server process keeps in memory for grid and profile reads (0: none).",
    )
    db_pool_size: int = Field(
        0,
        ge=0,
        description="Database connections of one web server process; 0 means one per API thread (+ 10), within "
        "FRINGELAB_DB_MAX_CONNECTIONS shared by the API processes.",
    )
    db_max_connections: int = Field(
        90,
        ge=4,
        description="Database connections all web server processes together may open (PostgreSQL allows 100 by "
        "default; keep this below its max_connections minus the workers' own); each process gets its share.",
    )
    token_cache_s: float = Field(
        5.0, ge=0, le=300, description="How long a checked token is trusted without asking the database again."
    )
    user_requests_per_s: float = Field(
        100.0,
        gt=0,
        description="Requests per second one user may send on average, all web server processes together "
        "(counted in Redis); a 429 beyond.",
    )
    user_request_burst: int = Field(300, ge=1, description="Requests one user may send at once above that rate.")
    log_level: Literal["debug", "info", "warning", "error"] = Field("info", description="Log level.")
    max_upload_bytes: int = Field(64 * 2**30, ge=1, description="Largest recording one upload may be, in bytes.")
    min_free_disk_bytes: int = Field(
        2**30,
        ge=0,
        description="Uploads are refused when they would leave less free space than this on the data volume.",
    )
    simulation_check_bytes: int = Field(
        2 * 2**30,
        ge=256 * 2**20,
        description="Memory (address space) of the process in a worker that checks an uploaded simulation.",
    )
    simulation_check_s: float = Field(
        300.0, gt=0, le=86400, description="Time the process in a worker that checks an uploaded simulation may take."
    )
    simulation_max_bytes: int = Field(
        2**30,
        ge=2**20,
        description="Memory the arrays a simulation declares may take (its nodes, elements and the states a reader "
        "holds at once, from the file's header or size); a model declaring more is refused before they are "
        "allocated, at its check and in comparisons.",
    )
    event_streams_per_user: int = Field(
        32, ge=1, le=10_000, description="Event streams one user may hold open in one web server process."
    )
    user_quota_bytes: int = Field(
        0,
        ge=0,
        description="Bytes of recordings, simulations and results one user's experiments may hold, plus their "
        "unfinished uploads; 0: no quota.",
    )
    upload_reservation_h: float = Field(
        6.0,
        gt=0,
        le=24 * 30,
        description="An unfinished resumable upload keeps room for the bytes it announced for this long after its "
        "last byte, counted against its owner only.",
    )
    upload_expiry_days: int = Field(
        5, ge=1, description="An unfinished resumable upload is deleted after this many days."
    )
    max_frames_bytes: int = Field(
        256 * 2**30,
        ge=1,
        description="A recording whose frames decode to more bytes than this (frames × frame size, from its "
        "headers) is refused before its ingest writes anything.",
    )
    max_frame_bytes: int = Field(
        256 * 2**20,
        ge=1024,
        description="A frame that decodes to more bytes than this (width × height × channels × bytes per sample, "
        "from its header) is refused before it is decoded.",
    )
    zip_max_uncompressed_bytes: int = Field(
        256 * 2**30, ge=1, description="A ZIP whose entries expand to more than this in total is refused."
    )
    zip_max_ratio: float = Field(
        200.0,
        gt=1,
        description="A ZIP entry over 1 MiB that expands more than this many times is refused as a ZIP bomb.",
    )
    preview_size_px: int = Field(
        800, ge=64, le=8192, description="Longer side of the frame previews an upload's ingest stores, in pixels."
    )

    @field_validator("log_level", mode="before")
    @classmethod
    def _lower(cls, value: object) -> object:
        return value.lower() if isinstance(value, str) else value

    @field_validator("root_path")
    @classmethod
    def _root_path(cls, value: str) -> str:
        value = value.rstrip("/")
        if value and (not value.startswith("/") or "//" in value or any(c in value for c in "?#% ")):
            raise ValueError("expected a path such as /fringelab (a leading /, no query, no spaces)")
        return value

    @property
    def binds_loopback_only(self) -> bool:
        return self.host in ("127.0.0.1", "::1", "localhost") or self.host.startswith("127.")

    @property
    def data_path(self) -> Path:
        return self.data_dir.resolve()

    @property
    def resolved_database_url(self) -> str:
        return self.database_url or f"sqlite:///{self.data_path / 'fringelab.db'}"

    @property
    def trusted_proxy_list(self) -> list[str]:
        return [address.strip() for address in self.trusted_proxies.split(",") if address.strip()]

    @property
    def allowed_origin_list(self) -> list[str]:
        return [origin.strip().rstrip("/") for origin in self.allowed_origins.split(",") if origin.strip()]

    @property
    def allowed_host_names(self) -> frozenset[str] | None:
        """The Host names served, lower case without a port; None: any."""
        names = [name.strip().lower() for name in self.allowed_hosts.split(",") if name.strip()]
        if "*" in names or (not names and self.auth_enabled):
            return None
        if not names:
            names = ["localhost", "127.0.0.1", "[::1]"]
            if self.host not in ("", "0.0.0.0", "::"):
                names.append(f"[{self.host}]" if ":" in self.host else self.host.lower())
        return frozenset(f"[{name}]" if ":" in name and not name.startswith("[") else name for name in names)

    @property
    def resolved_api_processes(self) -> int:
        return self.api_processes or max(1, min(8, os.cpu_count() or 1))

    @property
    def resolved_db_pool_size(self) -> int:
        """Database connections of one web server process: one for each request it runs at once (its threads;
        those waiting for their turn hold none, `backend.shedding`) and BACKGROUND_CONNECTIONS for event streams and
        background work, but no more than its share of FRINGELAB_DB_MAX_CONNECTIONS of a database server, so that N
        processes never open more than it allows (several processes × a pool sized for one once exceeded
        PostgreSQL's 100)."""
        if self.db_pool_size:
            return self.db_pool_size
        wanted = self.api_threads + BACKGROUND_CONNECTIONS
        if self.resolved_database_url.startswith("sqlite"):
            return wanted  # a file, no server: no limit of connections to share
        return max(2, min(wanted, self.db_max_connections // self.resolved_api_processes))

    @property
    def resolved_api_threads(self) -> int:
        """Threads of one web server process: no more than it has database connections, as a thread beyond
        would only wait for one (the pool's 30 s timeout, then a 500)."""
        return max(2, min(self.api_threads, self.resolved_db_pool_size))

    @property
    def resolved_api_running(self) -> int:
        """Requests one web server process runs at once (`backend.shedding`): its threads, but no more than its
        database connections less those kept for background work. A running request keeps its connection until its
        answer is serialised, which takes a thread again: with more requests in the application than connections,
        threads waiting for a connection held by requests waiting for a thread stalled a process until the pool's
        timeout (measured: answers after 10 s at 4 threads, 16 queued, 14 connections). Requests waiting for their turn
        (FRINGELAB_API_QUEUE) wait before the application and hold no connection."""
        connections = max(1, self.resolved_db_pool_size - self.resolved_background_connections)
        return max(1, min(self.resolved_api_threads, connections))

    @property
    def resolved_background_connections(self) -> int:
        """Connections of one web server process kept for its background work (BACKGROUND_CONNECTIONS, or a third
        of a small pool but at least MIN_BACKGROUND_CONNECTIONS): background work waits for a connection, never
        a request for background work, so a smaller reserve slows streams' polls at worst."""
        pool = self.resolved_db_pool_size
        return min(BACKGROUND_CONNECTIONS, max(MIN_BACKGROUND_CONNECTIONS, pool // 3))

    @property
    def resolved_api_in_flight(self) -> int:
        """Requests one web server process takes at once before it answers 503: those it runs and
        FRINGELAB_API_QUEUE waiting for their turn."""
        return self.resolved_api_running + self.api_queue

    @property
    def resolved_worker_concurrency(self) -> int:
        return self.worker_concurrency or os.cpu_count() or 1


def load_settings(**overrides: object) -> Settings:
    """Build the settings from the environment; an invalid value raises SettingsError naming its variable."""
    try:
        return Settings(**overrides)  # type: ignore[arg-type]
    except ValidationError as error:
        problems = []
        for item in error.errors():
            field = str(item["loc"][0]) if item["loc"] else "?"
            problems.append(f"{ENV_PREFIX}{field.upper()}: {item['msg']} (got {item.get('input')!r})")
        raise SettingsError("invalid setting " + "; ".join(problems)) from None


def settings_table() -> list[tuple[str, str, str]]:
    """(variable, default, description) of every setting, for the README and `.env.example`."""
    rows = []
    for name, field in Settings.model_fields.items():
        default = field.default
        rows.append((f"{ENV_PREFIX}{name.upper()}", "" if default is None else str(default), field.description or ""))
    return rows
