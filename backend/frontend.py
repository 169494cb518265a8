"""Serving the dashboard: the static ES modules of frontend/ and the plotly.js bundled in the `plotly` package.

plotly.js is served under a versioned path (cacheable forever) and the page learns that path from index.html,
which is rendered once at start-up. Nothing is fetched from a CDN: the dashboard works on a lab network offline.
"""

from __future__ import annotations

from pathlib import Path

import plotly
import plotly.offline
from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

FRONTEND_DIR = Path(__file__).resolve().parent.parent / "frontend"
PLOTLY_JS = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
PLOTLY_JS_URL = f"/vendor/plotly-{plotly.offline.get_plotlyjs_version()}.min.js"
IMMUTABLE = {"Cache-Control": "public, max-age=31536000, immutable"}


def mount_frontend(app: FastAPI) -> None:
    index_html = (FRONTEND_DIR / "index.html").read_text().replace("{{PLOTLY_JS_URL}}", PLOTLY_JS_URL)
    router = APIRouter(include_in_schema=False)

    @router.get("/", response_class=HTMLResponse)
    def index() -> HTMLResponse:
        return HTMLResponse(index_html, headers={"Cache-Control": "no-cache"})

    @router.get(PLOTLY_JS_URL)
    def plotly_js() -> FileResponse:
        return FileResponse(PLOTLY_JS, media_type="text/javascript", headers=IMMUTABLE)

    app.include_router(router)
    app.mount("/", StaticFiles(directory=FRONTEND_DIR), name="frontend")
