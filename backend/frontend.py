"""Serving the dashboard: the static ES modules of frontend/ and the plotly.js bundled in the `plotly` package, and
the API docs (Swagger UI at /api/docs, ReDoc at /api/redoc) from the assets in the `fastapi-offline` package.

plotly.js is served under a versioned path (cacheable forever) and the page learns that path from index.html
(`<meta name="plotly-js">`, rendered once at start-up); the first figure a page draws loads it (frontend/plots.js).
Nothing is fetched from a CDN and no web font is loaded (ReDoc's Google fonts are switched off): the dashboard
and the docs work on a lab network offline.
"""

from __future__ import annotations

import base64
from pathlib import Path

import fastapi_offline
import plotly
import plotly.offline
from fastapi import APIRouter, FastAPI, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import FileResponse, HTMLResponse, Response
from fastapi.staticfiles import StaticFiles

FRONTEND_DIR = Path(__file__).resolve().parent.parent / "frontend"
PLOTLY_JS = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
PLOTLY_JS_URL = f"/vendor/plotly-{plotly.offline.get_plotlyjs_version()}.min.js"
IMMUTABLE = {"Cache-Control": "public, max-age=31536000, immutable"}
DOCS_ASSETS = Path(fastapi_offline.__file__).parent / "static"
DOCS_ASSETS_URL = "/api/docs-assets"
DOCS_URL = "/api/docs"
REDOC_URL = "/api/redoc"
OAUTH2_REDIRECT_URL = "/api/docs/oauth2-redirect"
# ReDoc's sidebar shows Redocly's logo from their CDN: offline that is a failed request. Our own icon, inlined,
# takes its place in the script as served (the file in the package is left as it is).
REDOC_LOGO_URL = "https://cdn.redoc.ly/redoc/logo-mini.svg"


def _redoc_js() -> bytes:
    icon = base64.b64encode((FRONTEND_DIR / "favicon.svg").read_bytes()).decode()
    text = (DOCS_ASSETS / "redoc.standalone.js").read_text(encoding="utf-8")
    return text.replace(REDOC_LOGO_URL, f"data:image/svg+xml;base64,{icon}").encode()


def mount_docs(app: FastAPI) -> None:
    """Swagger UI and ReDoc with their scripts, styles and icon served from the installed package (create the app
    with `docs_url=None, redoc_url=None`). Under a root path (a reverse proxy's prefix) every URL carries it."""
    router = APIRouter(include_in_schema=False)
    openapi_url = app.openapi_url or "/api/openapi.json"
    redoc_js = _redoc_js()

    @router.get(f"{DOCS_ASSETS_URL}/redoc.standalone.js")
    def redoc_script() -> Response:
        return Response(redoc_js, media_type="text/javascript", headers={"Cache-Control": "no-cache"})

    @router.get(DOCS_URL)
    def swagger_ui(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "")
        return get_swagger_ui_html(
            openapi_url=f"{root}{openapi_url}",
            title=f"{app.title} API",
            oauth2_redirect_url=f"{root}{OAUTH2_REDIRECT_URL}",
            swagger_js_url=f"{root}{DOCS_ASSETS_URL}/swagger-ui-bundle.js",
            swagger_css_url=f"{root}{DOCS_ASSETS_URL}/swagger-ui.css",
            swagger_favicon_url=f"{root}/favicon.svg",
            swagger_ui_parameters={"validatorUrl": None},  # no badge fetched from validator.swagger.io
        )

    @router.get(OAUTH2_REDIRECT_URL)
    def swagger_ui_redirect() -> HTMLResponse:
        return get_swagger_ui_oauth2_redirect_html()

    @router.get(REDOC_URL)
    def redoc(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "")
        return get_redoc_html(
            openapi_url=f"{root}{openapi_url}",
            title=f"{app.title} API",
            redoc_js_url=f"{root}{DOCS_ASSETS_URL}/redoc.standalone.js",
            redoc_favicon_url=f"{root}/favicon.svg",
            with_google_fonts=False,
        )

    app.include_router(router)
    app.mount(DOCS_ASSETS_URL, StaticFiles(directory=DOCS_ASSETS), name="docs-assets")


def mount_frontend(app: FastAPI) -> None:
    index_html = (FRONTEND_DIR / "index.html").read_text().replace("{{PLOTLY_JS_URL}}", PLOTLY_JS_URL)
    router = APIRouter(include_in_schema=False)

    @router.api_route("/", methods=["GET", "HEAD"], response_class=HTMLResponse)
    def index() -> HTMLResponse:
        return HTMLResponse(index_html, headers={"Cache-Control": "no-cache"})

    @router.get(PLOTLY_JS_URL)
    def plotly_js() -> FileResponse:
        return FileResponse(PLOTLY_JS, media_type="text/javascript", headers=IMMUTABLE)

    app.include_router(router)
    app.mount("/", StaticFiles(directory=FRONTEND_DIR), name="frontend")
