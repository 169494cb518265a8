"""The FastAPI application factory: routers, the frontend and the shared state of one API process."""

from __future__ import annotations

from contextlib import asynccontextmanager

from fastapi import FastAPI

from backend import __version__
from backend.api import auth, experiments, health, recordings, uploads
from backend.db import make_engine, make_sessionmaker
from backend.errors import install_error_handlers
from backend.frontend import mount_frontend
from backend.limits import BodySizeLimit
from backend.settings import Settings
from backend.state import AppState
from worker.celery_app import create_celery

UPLOAD_PREFIXES = ("/api/v1/uploads",)


def create_app(settings: Settings) -> FastAPI:
    engine = make_engine(settings.resolved_database_url)
    state = AppState(
        settings=settings, engine=engine, sessions=make_sessionmaker(engine), celery=create_celery(settings)
    )

    @asynccontextmanager
    async def lifespan(_app: FastAPI):  # type: ignore[no-untyped-def]
        yield
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
    mount_frontend(app)  # last: it serves every path the API does not
    return app
