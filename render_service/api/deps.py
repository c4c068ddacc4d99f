"""FastAPI dependencies: the settings, store and runner of the app, and the token check.

All are `async` (they do no I/O) so FastAPI calls them in the event loop, not the thread pool.
"""
from __future__ import annotations

from fastapi import Request

from render_service.settings import ServiceSettings
from render_service.store import JobStore


async def get_settings(request: Request) -> ServiceSettings:
    return request.app.state.settings


async def get_store(request: Request) -> JobStore:
    return request.app.state.store


async def get_runner(request: Request):
    """The JobRunner, or None when the app runs without a cluster (unit tests)."""
    return request.app.state.runner


async def require_token(request: Request) -> None:
    """401 unless the request carries the server's token (see render_service.security)."""
    request.app.state.auth(request)
