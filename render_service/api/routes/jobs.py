"""Jobs: submit (``POST /v1/jobs``), list, status, cancel (``DELETE``) and result download."""
from __future__ import annotations

import dataclasses
import datetime as dt
import importlib.util
import logging
import time
from pathlib import Path

from fastapi import APIRouter, Body, Depends, Header, HTTPException, Request, Response
from fastapi import Path as PathParam
from fastapi.responses import FileResponse

from board.errors import InvalidInputError
from render_service.api.deps import get_runner, get_settings, get_store
from render_service.planning import job_id_for, plan_db_job, spec_dict
from render_service.renderers.base import RENDERERS
from render_service.schemas import DatasetJobIn, ErrorOut, JobIn, JobListOut, JobOut, SkylineDbJobIn
from render_service.settings import ServiceSettings
from render_service.storage import scrub_paths
from render_service.store import JobRecord, JobStore

log = logging.getLogger(__name__)
router = APIRouter(prefix="/v1/jobs", tags=["jobs"])
_JOB_ID = PathParam(pattern=r"^[A-Za-z0-9_-]{1,64}$", description="Job id returned by POST /v1/jobs")
_ERR = {401: {"model": ErrorOut}, 404: {"model": ErrorOut}, 409: {"model": ErrorOut}, 422: {"model": ErrorOut}}


def _utc(t: float | None) -> str | None:
    if t is None:
        return None
    return dt.datetime.fromtimestamp(t, dt.timezone.utc).isoformat(timespec="seconds")


def job_out(job: JobRecord, *, now: float | None = None, runner=None) -> JobOut:
    """Wire form of a job with its rate (positions/s of the current run) and ETA.

    A failure the runner could not write yet (the disk was full) is shown as it will be stored; a
    stored error never shows a server path.
    """
    now = time.time() if now is None else now
    pending = getattr(runner, "pending_failures", None) or {}
    if job.id in pending and job.state not in ("done", "failed", "cancelled"):
        job = dataclasses.replace(job, state="failed", error=pending[job.id])
    rate = eta = None
    if job.state in ("running", "cancel-requested") and job.run_started and job.positions_done_this_run > 0:
        rate = job.positions_done_this_run / max(now - job.run_started, 1e-6)
        eta = (job.positions_total - job.positions_done) / rate
    elif job.state == "done":
        eta = 0.0
    return JobOut(id=job.id, kind=job.kind, state=job.state, tiles_done=job.tiles_done, tiles_total=job.tiles_total,
                  positions_total=job.positions_total, positions_per_s=rate, eta_s=eta,
                  error=scrub_paths(job.error, _data_dir(runner)) if job.error else None,
                  spec=job.spec, created_utc=_utc(job.created), started_utc=_utc(job.started),
                  finished_utc=_utc(job.finished),
                  result_url=f"/v1/jobs/{job.id}/result" if job.state == "done" else None,
                  result_sha256=job.result_sha256, result_bytes=job.result_bytes)


def _data_dir(runner):
    settings = getattr(runner, "settings", None)
    return settings.data_dir if settings is not None else None


def _not_available(what: str) -> HTTPException:
    return HTTPException(501, f"{what} is not available on this server (its module is not installed): "
                              "use the raymarch renderer or install the Blender extras")


def _renderer_available(name: str) -> bool:
    module = RENDERERS[name].split(":")[0]
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


@router.post("", status_code=202, response_model=JobOut, responses={**_ERR, 501: {"model": ErrorOut}},
             summary="Submit a skyline-database or dataset job (idempotent)")
def submit_job(request: Request, response: Response,
               job: JobIn = Body(..., discriminator="kind"),
               idempotency_key: str | None = Header(None, pattern=r"^[A-Za-z0-9_.:-]{1,128}$",
                                                    description="Same key, same job"),
               settings: ServiceSettings = Depends(get_settings), store: JobStore = Depends(get_store),
               runner=Depends(get_runner)) -> JobOut:
    spec = spec_dict(job)
    if isinstance(job, SkylineDbJobIn):
        if not _renderer_available(job.renderer):
            raise _not_available(f"the {job.renderer!r} renderer")
        dem = store.get_dem(dem_id=job.dem_id)
        plan = plan_db_job(job, dem, settings)
        tiles = {t.key: t.nrows * t.ncols for t in plan.tiles}
    else:
        assert isinstance(job, DatasetJobIn)
        if importlib.util.find_spec("blender_addon.sim") is None:
            raise _not_available("dataset generation (blender_addon.sim)")
        scene = Path(settings.scenes_dir) / f"{job.scene}.toml"
        if not scene.is_file():
            names = sorted(p.stem for p in Path(settings.scenes_dir).glob("*.toml"))
            raise InvalidInputError(f"unknown scene {job.scene!r}: choose one of {', '.join(names) or '(none)'}")
        tiles = {"dataset": 0}
    rec, created = store.create_job(job_id=job_id_for(spec), kind=job.kind, spec=spec,
                                    idem_key=idempotency_key, tile_keys=tiles)
    if runner is not None:
        runner.wake()
    log.info("job %s %s", rec.id, "queued" if created else "already known")
    response.headers["Location"] = f"/v1/jobs/{rec.id}"
    return job_out(rec, runner=runner)


# The two status reads are `async`: one indexed SQLite read (WAL: never blocked by writers) costs less
# than a hop through the thread pool, which matters under hundreds of concurrent pollers.
@router.get("", response_model=JobListOut, responses=_ERR, summary="List jobs, newest first")
async def list_jobs(store: JobStore = Depends(get_store), runner=Depends(get_runner)) -> JobListOut:
    now = time.time()
    return JobListOut(jobs=[job_out(j, now=now, runner=runner) for j in store.list_jobs(limit=200)])


@router.get("/{job_id}", response_model=JobOut, responses=_ERR, summary="Job state and progress")
async def get_job(job_id: str = _JOB_ID, store: JobStore = Depends(get_store), runner=Depends(get_runner)) -> JobOut:
    return job_out(store.get_job(job_id=job_id), runner=runner)


@router.delete("/{job_id}", status_code=202, response_model=JobOut, responses=_ERR,
               summary="Cancel a job: queued tiles dropped, running tiles finish, nothing published")
def cancel_job(job_id: str = _JOB_ID, store: JobStore = Depends(get_store), runner=Depends(get_runner)) -> JobOut:
    job = store.request_cancel(job_id=job_id)
    if job.state in ("done", "failed"):
        raise HTTPException(409, f"job {job_id} is already {job.state}: nothing to cancel")
    if runner is not None:
        runner.wake()
    return job_out(job, runner=runner)


@router.get("/{job_id}/result", response_class=FileResponse, responses={**_ERR, 206: {"description": "Range"}},
            summary="Download the result: zip of the Zarr store (or dataset) with MANIFEST.sha256; ranges supported")
def get_result(job_id: str = _JOB_ID, store: JobStore = Depends(get_store)) -> FileResponse:
    job = store.get_job(job_id=job_id)
    if job.state != "done" or not job.result_path:
        raise HTTPException(409, f"job {job_id} is {job.state}: the result exists once it is done")
    path = Path(job.result_path)
    if not path.is_file():
        raise HTTPException(410, f"the result of job {job_id} is gone from the server: submit the job again")
    return FileResponse(path, media_type="application/zip", filename=f"skyloc-{job.kind}-{job_id}.zip",
                        headers={"X-Checksum-SHA256": job.result_sha256 or "", "ETag": f'"{job.result_sha256}"'})
