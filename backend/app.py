"""The FastAPI application factory: routers, the frontend and the shared state of one API process.

`fringelab api` serves it from FRINGELAB_API_PROCESSES processes (uvicorn's workers, each calling
`app_from_env`); what must hold across them (token revocations, request rates, the job reconciliation) goes
through Redis, what may differ (caches of immutable results, shared polls of event streams) is per process."""

from __future__ import annotations

import gc
import hashlib
import logging
import re
from contextlib import asynccontextmanager

import anyio
from fastapi import FastAPI

from backend import __version__
from backend.api import (
    auth,
    camera_against_camera,
    comparisons,
    demo,
    docs,
    experiments,
    health,
    jobs,
    overview,
    recordings,
    results,
    scans,
    simulations,
    uploads,
)
from backend.errors import install_error_handlers
from backend.frontend import mount_docs, mount_frontend
from backend.health import HealthCache, health_redis_client, system_health
from backend.limits import BodySizeLimit, PlainJsonNumbers, SharedRateLimiter
from backend.openapi import install_openapi, operation_id
from backend.polls import SharedPolls
from backend.security import SecurityHeaders
from backend.shedding import QUIET_REFUSALS, LoadShedding
from backend.streams import StreamSlots
from fringelab.core.accounts import TokenCache, dummy_hash
from fringelab.core.app_state import AppState
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.queue import create_celery
from fringelab.core.reconcile import reconcile_periodically, reconcile_quietly
from fringelab.core.settings import Settings, load_settings
from fringelab.formats.hdf5 import FrameCache

# The routes that stream a request body to disk under FRINGELAB_MAX_UPLOAD_BYTES instead of the JSON cap: the
# recordings' uploads and a simulation's PUT (a model of many MB).
UPLOAD_PATHS = re.compile(r"/api/v1/(?:uploads(?:/|$)|experiments/[^/]+/simulations/[^/]+$)")


# The health answer: at most a second old, and per client address at most this rate (a monitor asks every few
# seconds; `fringelab up` and the tests poll a few times a second while a server starts).
HEALTH_MAX_AGE_S = 1.0
HEALTH_REQUESTS_PER_S = 20.0
HEALTH_REQUEST_BURST = 60


def is_upload_path(path: str) -> bool:
    return UPLOAD_PATHS.match(path) is not None


def is_unshed_path(path: str) -> bool:
    """Requests the load shedding does not count: the health check (from a cache), event streams (long-lived,
    capped per user) and uploads (streamed to disk)."""
    return path == "/api/v1/health" or path.endswith("/events") or is_upload_path(path)


def create_app(settings: Settings, *, openapi_at_start: bool = False) -> FastAPI:
    """The application of one web server process. `openapi_at_start`: build the OpenAPI document in the
    lifespan, before the process takes its first request (what a served process does, `app_from_env`); built on
    first use instead, it took 0.4 s of CPU on an idle machine and 0.7-9.6 s of wall time under load, paid by the
    request that asked for it (issue 26). Then freeze (`gc.freeze`) every object made so far, out of the garbage
    collector's way. Tests that start an app per test leave both undone."""
    engine = make_engine(settings.resolved_database_url, max_connections=settings.resolved_db_pool_size)
    state = AppState(
        settings=settings,
        engine=engine,
        sessions=make_sessionmaker(engine),
        celery=create_celery(settings, for_requests=True),
        tokens=TokenCache(ttl_s=settings.token_cache_s, redis_url=settings.redis_url),
        frames=FrameCache(max_bytes=settings.frame_cache_bytes),
    )

    @asynccontextmanager
    async def lifespan(served: FastAPI):
        # Blocking routes run in this many threads; the database pool holds a connection for each.
        anyio.to_thread.current_default_thread_limiter().total_tokens = settings.resolved_api_threads
        if openapi_at_start:
            served.openapi()
            # What the start made (modules, routes, models, this document: ~200,000 objects) lives as long as the
            # process; frozen, the collector never walks it again. A full collection walking it took ~100 ms of
            # CPU, holding the GIL: under load 400-940 ms in which the event loop answered nothing (issue 26).
            gc.freeze()
        reconcile_quietly(state.sessions, state.celery, settings)  # jobs the queue lost while the API was down
        if state.tokens.watch is not None:  # listening before the first request, which then need not wait
            state.tokens.watch.start()
        async with anyio.create_task_group() as background:
            if settings.reconcile_interval_s > 0:
                background.start_soon(reconcile_periodically, state.sessions, state.celery, settings)
            background.start_soon(_flush_token_uses_periodically, state)
            if settings.auth_enabled:
                background.start_soon(anyio.to_thread.run_sync, dummy_hash)
            yield
            background.cancel_scope.cancel()
        if state.tokens.watch is not None:
            state.tokens.watch.stop()
        state.tokens.flush_last_used(state.sessions)
        engine.dispose()

    app = FastAPI(
        title="fringelab",
        version=__version__,
        summary="Out-of-plane deformation of plates from structured light and photogrammetry.",
        docs_url=None,  # served by mount_docs from the installed assets, not from a CDN
        redoc_url=None,
        openapi_url="/api/openapi.json",
        lifespan=lifespan,
        generate_unique_id_function=operation_id,
    )
    app.state.fringelab = state
    app.state.polls = SharedPolls(max_age_s=jobs.EVENTS_POLL_S)
    app.state.stream_slots = StreamSlots(per_user=settings.event_streams_per_user)
    app.state.user_limiter = SharedRateLimiter(
        redis_url=settings.redis_url,
        rate_per_s=settings.user_requests_per_s,
        burst=settings.user_request_burst,
        namespace=hashlib.sha256(settings.resolved_database_url.encode()).hexdigest()[:12],
    )
    health_redis = health_redis_client(settings.redis_url, timeout_s=settings.health_worker_timeout_s)
    app.state.health = HealthCache(
        lambda: system_health(
            engine=engine, redis_client=health_redis, redis_url=settings.redis_url, data_path=settings.data_path
        ),
        max_age_s=HEALTH_MAX_AGE_S,
        rate_per_s=HEALTH_REQUESTS_PER_S,
        burst=HEALTH_REQUEST_BURST,
    )
    install_error_handlers(app)
    app.add_middleware(PlainJsonNumbers, exempt=is_upload_path)  # runs after the size cap below
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_json_bytes, exempt=is_upload_path)
    app.add_middleware(
        SecurityHeaders,
        allowed_origins=settings.allowed_origin_list,
        docs_prefixes=("/api/docs", "/api/redoc"),
        allowed_hosts=settings.allowed_host_names,
        check_every_origin=not settings.auth_enabled,
    )
    # Outermost: a request beyond the bound is refused before anything else is done for it.
    app.add_middleware(LoadShedding, max_in_flight=settings.resolved_api_in_flight,
                       max_running=settings.resolved_api_running,
                       exempt=is_unshed_path)  # fmt: skip
    logging.getLogger("uvicorn.access").addFilter(QUIET_REFUSALS)  # once per process: the filter is one object
    app.include_router(health.router, prefix="/api/v1")
    app.include_router(auth.router, prefix="/api/v1")
    app.include_router(experiments.router, prefix="/api/v1")
    app.include_router(recordings.router, prefix="/api/v1")
    app.include_router(uploads.create_router(state), prefix="/api/v1")
    app.include_router(simulations.router, prefix="/api/v1")
    app.include_router(comparisons.router, prefix="/api/v1")
    app.include_router(jobs.router, prefix="/api/v1")
    app.include_router(results.router, prefix="/api/v1")
    app.include_router(scans.router, prefix="/api/v1")
    app.include_router(camera_against_camera.router, prefix="/api/v1")
    app.include_router(demo.router, prefix="/api/v1")
    app.include_router(docs.router, prefix="/api/v1")
    app.include_router(overview.router, prefix="/api/v1")

    install_openapi(app)
    mount_docs(app)
    mount_frontend(app)  # last: it serves every path the API does not
    return app


def app_from_env() -> FastAPI:
    """The app of one web server process, from the environment: what uvicorn calls in each of its workers
    (`backend.app:app_from_env`, factory); `fringelab api` has checked these settings before."""
    return create_app(load_settings(), openapi_at_start=True)


TOKEN_USE_FLUSH_S = 10.0


async def _flush_token_uses_periodically(state: AppState) -> None:
    """Write the tokens' `last_used_at` in one transaction every TOKEN_USE_FLUSH_S, never per request."""
    while True:
        await anyio.sleep(TOKEN_USE_FLUSH_S)
        try:
            await anyio.to_thread.run_sync(state.tokens.flush_last_used, state.sessions)
        except Exception:  # a busy or unreachable database: the uses are dropped, the next flush writes newer ones
            logging.getLogger(__name__).warning("could not record the tokens' last use", exc_info=True)


def uvicorn_options(settings: Settings) -> dict[str, object]:
    """How `fringelab api` serves the app (in FRINGELAB_API_PROCESSES processes, see `backend.cli.cmd_api`).
    Behind a reverse proxy at a sub-path (FRINGELAB_ROOT_PATH, the proxy
    strips the prefix), the server's root path makes the docs, the OpenAPI `servers` and every URL the API
    builds (tus `Location`) carry the prefix. X-Forwarded-For and -Proto are believed only from the proxies named
    in FRINGELAB_TRUSTED_PROXIES (uvicorn's default trusts them from any loopback client, which let anyone on
    this machine pick the client address the login rate limit counts)."""
    proxies = settings.trusted_proxy_list
    return {
        "host": settings.host,
        "port": settings.port,
        "log_level": settings.log_level,
        "root_path": settings.root_path,
        "proxy_headers": bool(proxies),
        # Longer than clients keep idle connections (httpx 5 s, browsers ~60 s): a server that closes first races
        # a request sent on the closing connection, which the client sees as a dropped connection.
        "timeout_keep_alive": 75,
        "forwarded_allow_ips": ",".join(proxies) if proxies else "",
    }
