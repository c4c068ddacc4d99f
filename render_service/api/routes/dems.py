"""``POST /v1/dems`` (upload and validate a DEM), ``GET /v1/dems``, ``GET /v1/dems/{id}``."""
from __future__ import annotations

import hashlib
import logging
import os
import uuid
from pathlib import Path

from fastapi import APIRouter, Depends, File, Form, HTTPException, UploadFile
from fastapi import Path as PathParam
from fastapi.concurrency import run_in_threadpool

from board.errors import InvalidInputError, SkylocError
from render_service.api.deps import get_settings, get_store
from render_service.gdal_cache import validation_cache
from render_service.schemas import DemOut, ErrorOut
from render_service.settings import ServiceSettings
from render_service.store import DemRecord, JobStore
from render_service.uploads import ALLOWED_DRIVERS, _short, check_body, safe_filename, validate_dem

log = logging.getLogger(__name__)
router = APIRouter(prefix="/v1/dems", tags=["dems"])
_ERRORS = {401: {"model": ErrorOut}, 413: {"model": ErrorOut}, 422: {"model": ErrorOut}, 503: {"model": ErrorOut}}


def dem_out(rec: DemRecord, *, created: bool = False) -> DemOut:
    i = rec.info
    b = [float(v) for v in i["bounds"]]
    return DemOut(id=rec.id, sha256=rec.sha256, filename=rec.filename, size=tuple(i["size"]), cell_m=i["cell_m"],
                  bounds=tuple(b), center=((b[0] + b[2]) / 2, (b[1] + b[3]) / 2), body=i["body"]["name"],
                  body_radius_m=i["body"]["radius_m"], is_geographic=i["is_geographic"],
                  nodata_fraction=i["nodata_fraction"], crs_wkt=i["crs_wkt"], created=created)


def _ingest(tmp: Path, sha: str, filename: str, body: str | None, settings: ServiceSettings,
            store: JobStore) -> tuple[DemRecord, bool]:
    final = settings.dems_dir / f"{sha}{Path(filename).suffix.lower()}"
    try:
        with validation_cache(tmp, base_bytes=settings.gdal_cache_bytes, allowed_drivers=ALLOWED_DRIVERS):
            info = validate_dem(tmp, body=body, settings=settings)
    except SkylocError as exc:
        raise type(exc)(_short(exc)) from None  # no server paths in the answer
    os.replace(tmp, final)
    return store.add_dem(sha256=sha, filename=filename, path=str(final), body=body, info=info)


@router.post("", status_code=201, response_model=DemOut, responses=_ERRORS,
             summary="Upload a DEM (multipart field 'file'), validated with GDAL, stored by content hash")
async def upload_dem(file: UploadFile = File(..., description="GeoTIFF (or USGS DEM, AAIGrid, HFA) DEM"),
                     body: str | None = Form(None, max_length=32,
                                             description="Body for a DEM in degrees: earth, mars, moon, europa "
                                                         "or a radius in metres"),
                     settings: ServiceSettings = Depends(get_settings),
                     store: JobStore = Depends(get_store)) -> DemOut:
    filename = safe_filename(file.filename)
    body = check_body(body)
    settings.dems_dir.mkdir(parents=True, exist_ok=True)
    tmp = settings.dems_dir / f".upload-{uuid.uuid4().hex}{Path(filename).suffix.lower()}"
    h = hashlib.sha256()
    try:
        with open(tmp, "wb") as fh:
            while chunk := await file.read(1 << 20):
                h.update(chunk)
                fh.write(chunk)
        rec, created = await run_in_threadpool(_ingest, tmp, h.hexdigest(), filename, body, settings, store)
    finally:
        tmp.unlink(missing_ok=True)
    log.info("DEM %s %s (%s)", rec.id, "stored" if created else "already known", filename)
    return dem_out(rec, created=created)


@router.get("", response_model=list[DemOut], responses=_ERRORS, summary="List uploaded DEMs")
def list_dems(store: JobStore = Depends(get_store)) -> list[DemOut]:
    return [dem_out(r) for r in store.list_dems()]


@router.get("/{dem_id}", response_model=DemOut, responses={**_ERRORS, 404: {"model": ErrorOut}},
            summary="One uploaded DEM")
def get_dem(dem_id: str = PathParam(pattern=r"^[0-9a-f]{8,64}$"), store: JobStore = Depends(get_store)) -> DemOut:
    try:
        return dem_out(store.get_dem(dem_id=dem_id))
    except InvalidInputError as exc:
        raise HTTPException(404, str(exc)) from None
