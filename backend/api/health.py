"""`GET /api/v1/health`: is every part up (database, Redis, workers), and which one is not."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from backend.api.deps import StateDep
from backend.health import Health, system_health

router = APIRouter(tags=["health"])


@router.get(
    "/health",
    response_model=Health,
    responses={503: {"model": Health, "description": "A part is down; `failing` names it."}},
)
def health(state: StateDep) -> JSONResponse:
    """Checks the database, Redis and the live workers (a bounded ping); 503 when any of them is down."""
    body = system_health(
        engine=state.engine,
        redis_url=state.settings.redis_url,
        celery=state.celery,
        worker_timeout_s=state.settings.health_worker_timeout_s,
        data_path=state.settings.data_path,
    )
    return JSONResponse(body.model_dump(), status_code=200 if body.ok else 503)
