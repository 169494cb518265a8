"""`GET /api/v1/health`: is every part up (database, Redis, workers), and which one is not.

Served on the event loop from the process's `HealthCache` (made at most once a second by a thread of its own),
so no number of health requests can occupy the threads that serve everything else; anonymous callers are rate
limited per address (429 with Retry-After)."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response

from backend.errors import error_responses
from backend.health import Health, HealthCache
from fringelab.core.errors import RateLimited

router = APIRouter(tags=["health"])


@router.head("/health", include_in_schema=False)
@router.get(
    "/health",
    response_model=Health,
    responses={503: {"model": Health, "description": "A part is down; `failing` names it."}, **error_responses(429)},
)
async def health(request: Request) -> Response:
    """Checks the database, Redis and the live workers (their heartbeats in Redis); 503 when any of them is
    down. The answer is at most a second old."""
    cache: HealthCache = request.app.state.health
    wait_s = cache.limiter.take(request.client.host if request.client else "unknown")
    if wait_s > 0:
        raise RateLimited("too many health requests from this address; slow down", retry_after_s=wait_s)
    body = await cache.get()
    status = 200 if body.ok else 503
    if request.method == "HEAD":
        return Response(status_code=status, media_type="application/json")
    return JSONResponse(body.model_dump(), status_code=status)
