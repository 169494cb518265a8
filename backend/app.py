"""The FastAPI application factory: routers, the frontend and the shared state of one API process."""

from __future__ import annotations

from contextlib import asynccontextmanager

import anyio
from fastapi import FastAPI

from backend import __version__
from backend.api import auth, demo, experiments, health, jobs, recordings, results, uploads
from backend.errors import install_error_handlers
from backend.frontend import mount_frontend
from backend.limits import BodySizeLimit
from backend.openapi import install_openapi
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.jobs import reconcile_periodically, reconcile_quietly
from fringelab.core.queue import create_celery
from fringelab.core.settings import Settings
from fringelab.core.state import AppState

UPLOAD_PREFIXES = ("/api/v1/uploads",)


def create_app(settings: Settings) -> FastAPI:
    engine = make_engine(settings.resolved_database_url)
    state = AppState(
        settings=settings, engine=engine, sessions=make_sessionmaker(engine), celery=create_celery(settings)
    )

    @asynccontextmanager
    async def lifespan(_app: FastAPI):  # type: ignore[no-untyped-def]
        reconcile_quietly(state.sessions, state.celery, settings)  # jobs the queue lost while the API was down
        async with anyio.create_task_group() as background:
            if settings.reconcile_interval_s > 0:
                background.start_soon(reconcile_periodically, state.sessions, state.celery, settings)
            yield
            background.cancel_scope.cancel()
        engine.dispose()

    app = FastAPI(
        title="fringelab",
        version=__version__,
        summary="Out-of-plane deformation of plates from structured light and photogrammetry.",
        docs_url="/api/docs",
        redoc_url="/api/redoc",
        openapi_url="/api/openapi.json",
        lifespan=lifespan,
    )
    app.state.fringelab = state
    install_error_handlers(app)
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_json_bytes, exempt_prefixes=UPLOAD_PREFIXES)
    app.include_router(health.router, prefix="/api/v1")
    app.include_router(auth.router, prefix="/api/v1")
    app.include_router(experiments.router, prefix="/api/v1")
    app.include_router(recordings.router, prefix="/api/v1")
    app.include_router(uploads.create_router(state), prefix="/api/v1")
    app.include_router(jobs.router, prefix="/api/v1")
    app.include_router(results.router, prefix="/api/v1")
    app.include_router(demo.router, prefix="/api/v1")

    install_openapi(app)
    mount_frontend(app)  # last: it serves every path the API does not
    return app


def uvicorn_options(settings: Settings) -> dict[str, object]:
    """How `fringelab api` serves the app. Behind a reverse proxy at a sub-path (FRINGELAB_ROOT_PATH, the proxy
    strips the prefix), the server's root path makes the docs, the OpenAPI `servers` and every URL the API
    builds (tus `Location`) carry the prefix."""
    return {
        "host": settings.host,
        "port": settings.port,
        "log_level": settings.log_level,
        "root_path": settings.root_path,
    }
