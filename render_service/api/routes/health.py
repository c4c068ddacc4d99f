"""``GET /healthz``: liveness without authentication (no job or DEM information)."""
from __future__ import annotations

from fastapi import APIRouter, Depends, Request

from render_service import __version__
from render_service.api.deps import get_runner
from render_service.schemas import HealthOut

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=HealthOut, summary="Liveness, worker count and the data directory's state")
async def healthz(request: Request, runner=Depends(get_runner)) -> HealthOut:
    """``ok``, or ``degraded`` with the reason (Dask down, runner stopped, data directory full or read-only)."""
    workers = runner.n_workers() if runner is not None else None
    scheduler = None
    if runner is not None and runner.client is not None:
        scheduler = "local" if runner.local else "remote"
    problem = runner.problem() if runner is not None else request.app.state.monitor.problem()
    return HealthOut(status="degraded" if problem else "ok", version=__version__, workers=workers,
                     scheduler=scheduler, detail=problem)
