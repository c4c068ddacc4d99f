"""``GET /healthz``: liveness without authentication (no job or DEM information)."""
from __future__ import annotations

from fastapi import APIRouter, Depends

from render_service import __version__
from render_service.api.deps import get_runner
from render_service.schemas import HealthOut

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=HealthOut, summary="Liveness and worker count")
async def healthz(runner=Depends(get_runner)) -> HealthOut:
    workers = runner.n_workers() if runner is not None else None
    scheduler = None
    if runner is not None and runner.client is not None:
        scheduler = "local" if runner.cluster is not None else "remote"
    error = runner.error if runner is not None else None
    return HealthOut(status="degraded" if error else "ok", version=__version__, workers=workers,
                     scheduler=scheduler, detail=error)
