"""``/docs`` (Swagger UI) and ``/redoc`` from local assets, so the API documentation works offline.

The JavaScript and CSS come from the installed ``fastapi-offline`` package (its ``static`` folder,
served under ``/docs-assets``), not from a CDN and not from files copied into this repository.
"""
from __future__ import annotations

import importlib.util
import logging
from pathlib import Path

from fastapi import FastAPI
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

from board.errors import SkylocError

log = logging.getLogger(__name__)

ASSETS_URL = "/docs-assets"


def assets_dir() -> Path:
    """The folder of Swagger UI / ReDoc assets shipped by ``fastapi-offline`` (SkylocError when missing)."""
    spec = importlib.util.find_spec("fastapi_offline")
    if spec is None or spec.origin is None:
        raise SkylocError("the API documentation needs the fastapi-offline package: pip install fastapi-offline "
                          "(it is in skyloc's 'ground' extra)")
    folder = Path(spec.origin).parent / "static"
    names = ("swagger-ui-bundle.js", "swagger-ui.css", "redoc.standalone.js")
    missing = [n for n in names if not (folder / n).is_file()]
    if missing:
        raise SkylocError(f"fastapi-offline has no {', '.join(missing)}: reinstall it")
    return folder


def install_local_docs(app: FastAPI) -> None:
    """Add ``/docs``, ``/docs/oauth2-redirect`` and ``/redoc`` served from :func:`assets_dir`."""
    app.mount(ASSETS_URL, StaticFiles(directory=str(assets_dir())), name="docs-assets")
    title = app.title

    @app.get("/docs", include_in_schema=False)
    async def swagger_ui() -> HTMLResponse:
        return get_swagger_ui_html(openapi_url=app.openapi_url, title=f"{title} - Swagger UI",
                                   oauth2_redirect_url="/docs/oauth2-redirect",
                                   swagger_js_url=f"{ASSETS_URL}/swagger-ui-bundle.js",
                                   swagger_css_url=f"{ASSETS_URL}/swagger-ui.css",
                                   swagger_favicon_url=f"{ASSETS_URL}/favicon.png")

    @app.get("/docs/oauth2-redirect", include_in_schema=False)
    async def swagger_redirect() -> HTMLResponse:
        return get_swagger_ui_oauth2_redirect_html()

    @app.get("/redoc", include_in_schema=False)
    async def redoc() -> HTMLResponse:
        return get_redoc_html(openapi_url=app.openapi_url, title=f"{title} - ReDoc",
                              redoc_js_url=f"{ASSETS_URL}/redoc.standalone.js",
                              redoc_favicon_url=f"{ASSETS_URL}/favicon.png", with_google_fonts=False)
