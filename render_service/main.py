"""The render-service application: ``create_app(settings)`` builds the FastAPI app.

Run it with ``skyloc serve`` (uvicorn) or ``uvicorn --factory render_service.main:app_from_env``.
Errors are JSON ``{"detail": reason, "code": machine_code}``: SkylocError subclasses map to
422 (invalid input, CRS, nodata, unreadable DEM, corrupt file), 404 (unknown job), 500 otherwise;
routing and parsing errors (400, 404, 405) carry a code too; a data directory that does not take
writes (full, read-only) answers 503 ``storage_unavailable``.

Middleware, outermost first: CORS (only when configured), :class:`TokenGateMiddleware` (the token,
checked before any body is received), :class:`BodyLimitMiddleware` (413 on oversized bodies).
"""
from __future__ import annotations

import logging
import sqlite3
from contextlib import asynccontextmanager

from fastapi import Depends, FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from board.errors import DemReadError, FormatError, InvalidInputError, JobNotFoundError, SkylocError
from render_service import __version__
from render_service.api.deps import require_token
from render_service.api.docs import install_local_docs
from render_service.api.routes import dems, health, jobs, ui
from render_service.engine import check_dashboard_address
from render_service.gdal_cache import set_cache_max
from render_service.security import TokenAuth, TokenGateMiddleware, check_startup, load_token
from render_service.settings import ServiceSettings
from render_service.storage import DataDirLock, StorageMonitor, check_data_dir, is_storage_error, storage_reason
from render_service.store import JobStore

log = logging.getLogger(__name__)

#: Largest JSON request body (bytes); DEM uploads are limited by ``settings.max_upload_bytes``.
MAX_JSON_BYTES = 1 << 20
_HTTP_CODES = {400: "bad_request", 401: "unauthorized", 403: "forbidden", 404: "not_found", 405: "method_not_allowed",
               409: "conflict", 410: "gone", 413: "too_large", 415: "unsupported_media_type",
               416: "range_not_satisfiable", 422: "invalid_input", 501: "not_available", 503: "storage_unavailable"}
#: Answers every route can give (documented in the OpenAPI schema of each operation).
_ERROR_JSON = {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorOut"}}}  # JSON on every route
_COMMON_RESPONSES = {
    400: {"content": _ERROR_JSON, "description": "Malformed request (unparsable multipart body)"},
    404: {"content": _ERROR_JSON, "description": "No such route or resource"},
    405: {"content": _ERROR_JSON, "description": "Method not allowed on this route"},
    413: {"content": _ERROR_JSON, "description": "Request body too large"},
    503: {"content": _ERROR_JSON, "description": "The server's data directory does not take writes (full, read-only)"},
}


def status_for(exc: SkylocError) -> int:
    """HTTP status of a SkylocError: what the client must fix is 4xx, the rest 500."""
    if isinstance(exc, JobNotFoundError):
        return 404
    if isinstance(exc, (InvalidInputError, DemReadError, FormatError)):
        return 422
    return 500


class BodyLimitMiddleware:
    """Pure ASGI middleware: 413 when a request body exceeds its limit (declared or streamed)."""

    def __init__(self, app, *, upload_limit: int, json_limit: int = MAX_JSON_BYTES) -> None:
        self.app = app
        self.upload_limit = upload_limit
        self.json_limit = json_limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        upload = scope["path"].rstrip("/") == "/v1/dems"
        limit = self.upload_limit + 64 * 1024 if upload else self.json_limit
        declared = dict(scope.get("headers") or []).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            return await _too_large(send, limit, upload=upload)
        seen = 0
        exceeded = False
        replaced = False

        async def limited_receive():
            nonlocal seen, exceeded
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    exceeded = True
                    raise _BodyTooLarge
            return message

        async def guarded_send(message):
            nonlocal replaced
            if exceeded:  # whatever the app answers after the overflow, the client gets 413
                if not replaced:
                    replaced = True
                    await _too_large(send, limit, upload=upload)
                return
            await send(message)

        try:
            await self.app(scope, limited_receive, guarded_send)
        except _BodyTooLarge:
            if not replaced:
                await _too_large(send, limit, upload=upload)


class _BodyTooLarge(Exception):
    """Raised inside receive() when a streamed body exceeds the limit."""


async def _too_large(send, limit: int, *, upload: bool) -> None:
    if upload:
        text = f"request body larger than {limit} bytes: upload a smaller file (see the server's max_upload_bytes)"
    else:
        text = (f"request body larger than {limit} bytes: JSON requests are limited to {limit // 1024} KiB; "
                "send a smaller request")
    body = JSONResponse({"detail": text, "code": "too_large"}, status_code=413)
    await send({"type": "http.response.start", "status": 413, "headers": body.raw_headers})
    await send({"type": "http.response.body", "body": body.body})


def error_text(exc: BaseException) -> str:
    """The message of an exception (a KeyError's own text, not its repr in quotes)."""
    if isinstance(exc, KeyError) and exc.args:
        return str(exc.args[0])
    return str(exc)


def _install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(SkylocError)
    async def skyloc_error(request: Request, exc: SkylocError) -> JSONResponse:
        status = status_for(exc)
        if status >= 500:
            log.error("%s %s failed: %s", request.method, request.url.path, exc)
        return JSONResponse({"detail": error_text(exc), "code": exc.code}, status_code=status)

    @app.exception_handler(StarletteHTTPException)  # FastAPI's HTTPException and routing's 404 / 405 / 400
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        return JSONResponse({"detail": exc.detail, "code": _HTTP_CODES.get(exc.status_code, f"http_{exc.status_code}")},
                            status_code=exc.status_code, headers=getattr(exc, "headers", None))

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [{k: v for k, v in e.items() if k in ("loc", "msg", "type")} for e in exc.errors()]
        return JSONResponse({"detail": jsonable_encoder(errors), "code": "validation_error"}, status_code=422)

    async def storage_error(request: Request, exc: Exception) -> JSONResponse:
        if not is_storage_error(exc):
            return await internal_error(request, exc)
        log.error("%s %s: the data directory does not take writes: %s", request.method, request.url.path, exc)
        app.state.monitor.problem(force=True)
        return JSONResponse({"detail": storage_reason(exc).replace("submit the job again", "try again"),
                             "code": "storage_unavailable"}, status_code=503, headers={"Retry-After": "30"})

    app.add_exception_handler(OSError, storage_error)
    app.add_exception_handler(sqlite3.Error, storage_error)

    @app.exception_handler(Exception)
    async def internal_error(request: Request, exc: Exception) -> JSONResponse:
        log.exception("%s %s failed", request.method, request.url.path)
        return JSONResponse({"detail": "internal error: see the server log", "code": "internal_error"},
                            status_code=500)


def _limit_gdal_cache(nbytes: int) -> None:
    """Bound GDAL's block cache in this (API) process (see :mod:`render_service.gdal_cache`)."""
    set_cache_max(nbytes)


def create_app(settings: ServiceSettings | None = None) -> FastAPI:
    """Build the app for ``settings``: checks the token rule and the data directory, takes its lock,
    opens the store, starts the job runner (and Dask) on startup.

    Raises InvalidInputError when a non-loopback host has no token, the token file is unusable, the
    data directory cannot be written, or another server holds it.
    """
    settings = settings or ServiceSettings()
    token = load_token(settings)
    check_startup(settings, token)
    check_dashboard_address(settings.dashboard)  # refused at start, not later in the runner thread
    if settings.dashboard and token is None:
        raise InvalidInputError("--dashboard needs a token (the dashboard is served behind it): set SKYLOC_TOKEN "
                                "or pass --token-file FILE, or start without --dashboard")
    check_data_dir(settings.data_dir)
    lock = DataDirLock(settings.data_dir)
    try:
        store = JobStore(settings.store_path)
    except BaseException:
        lock.release()
        raise
    monitor = StorageMonitor(settings.data_dir, min_free_bytes=settings.min_free_bytes)
    _limit_gdal_cache(settings.gdal_cache_bytes)
    runner = None
    if settings.start_cluster:
        from render_service.runner import JobRunner  # noqa: PLC0415

        runner = JobRunner(store=store, settings=settings, monitor=monitor)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if runner is not None:
            runner.start()
        try:
            yield
        finally:
            if runner is not None:
                runner.stop()
            store.close()
            lock.release()

    app = FastAPI(title="skyloc render service", version=__version__, lifespan=lifespan,
                  docs_url=None, redoc_url=None, responses=_COMMON_RESPONSES,
                  description="REST queue for skyline databases and simulator test sets, rendered on Dask. "
                              "Authenticate with `Authorization: Bearer <token>`.")
    app.state.settings = settings
    app.state.store = store
    app.state.runner = runner
    app.state.monitor = monitor
    app.state.lock = lock
    app.state.auth = TokenAuth(token)
    auth = [Depends(require_token)]
    install_local_docs(app)
    app.include_router(health.router)
    app.include_router(dems.router, dependencies=auth)
    app.include_router(jobs.router, dependencies=auth)
    app.include_router(ui.router, dependencies=auth)
    _install_error_handlers(app)
    app.add_middleware(BodyLimitMiddleware, upload_limit=settings.max_upload_bytes)
    app.add_middleware(TokenGateMiddleware, auth=app.state.auth)  # outside the body limit: no body read at all
    if settings.cors_origins:  # outermost: preflight requests carry no token
        from fastapi.middleware.cors import CORSMiddleware  # noqa: PLC0415

        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["*"],
                           allow_headers=["Authorization", "Content-Type", "Idempotency-Key"])
    log.info("render service: data in %s, %s", settings.data_dir,
             "token required" if app.state.auth.enabled else "no token (loopback only)")
    return app


def app_from_env() -> FastAPI:
    """Factory for ``uvicorn --factory``: settings from the ``SKYLOC_*`` environment."""
    return create_app(ServiceSettings())
