"""Wire models of the render-service API, one per direction (requests ``*In``, responses ``*Out``).

Coordinates are metres in the DEM's metric working CRS (the ``crs_wkt`` and ``bounds`` the DEM
upload returns); azimuths are degrees clockwise from grid north.
"""
from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, Strict

from board.skydb import AZIMUTH_SUBSAMPLES, MAX_AZIMUTH_SUBSAMPLES

_ID = r"^[0-9a-f]{8,64}$"
#: JSON numbers only: a string ("100") or a boolean (true) is refused, not converted.
Num = Annotated[float, Strict()]
Int = Annotated[int, Strict()]


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=False)


class SkylineDbJobIn(_In):
    """A skyline-database render: a square grid of positions centred on ``center``."""

    kind: Literal["skyline_db"] = Field(description="Job kind")
    dem_id: str = Field(pattern=_ID, description="Id returned by POST /v1/dems")
    center: tuple[Num, Num] = Field(description="Grid centre [x, y], metres, in the DEM's metric working CRS")
    size_m: Num = Field(gt=0, le=1e6, description="Side of the square grid, metres")
    step_m: Num = Field(gt=0, le=1e5, description="Grid spacing, metres")
    camera_height_m: Num = Field(2.0, ge=0, le=1e4, description="Eye height above the ground, metres")
    azimuths: Int = Field(360, ge=1, le=36000, description="Azimuth samples per skyline (360: one degree)")
    azimuth_start_deg: Num = Field(0.0, ge=0, lt=360, description="Azimuth of sample 0, degrees from grid north")
    refraction_k: Num = Field(0.0, ge=0, lt=1, description="Refraction coefficient (0 on airless bodies)")
    azimuth_subsamples: Int = Field(AZIMUTH_SUBSAMPLES, ge=1, le=MAX_AZIMUTH_SUBSAMPLES,
                                    description="Rays averaged per sample across its azimuth step (1: point samples)")
    renderer: Literal["raymarch", "blender"] = Field("raymarch", description="Renderer of every tile")
    tile_size: Int = Field(64, ge=2, le=512, description="Tile side in positions (the unit of work and resumption)")


class DatasetJobIn(_In):
    """A synthetic test set rendered by the simulator from a named scene of the scenes folder."""

    kind: Literal["dataset"] = Field(description="Job kind")
    scene: str = Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$",
                       description="Scene name: scenes/<name>.toml on the server (no paths)")
    seed: Int | None = Field(None, ge=0, le=2**31 - 1, description="Override the scene's seed")


JobIn = Annotated[Union[SkylineDbJobIn, DatasetJobIn], Field(discriminator="kind")]


class ErrorOut(BaseModel):
    """Every error response: a human reason and a stable machine code."""

    detail: str | list
    code: str


class DemOut(BaseModel):
    """An uploaded, validated DEM (sizes in cells, lengths in metres, bounds in the metric CRS)."""

    id: str
    sha256: str
    filename: str
    size: tuple[int, int] = Field(description="[columns, rows]")
    cell_m: float
    bounds: tuple[float, float, float, float] = Field(description="[xmin, ymin, xmax, ymax], metric CRS")
    center: tuple[float, float] = Field(description="Centre of the bounds: a valid job centre")
    body: str
    body_radius_m: float
    is_geographic: bool
    nodata_fraction: float
    crs_wkt: str
    created: bool = Field(False, description="False when the same content was already uploaded")


class JobOut(BaseModel):
    """A job and its progress."""

    id: str
    kind: str
    state: Literal["queued", "running", "done", "failed", "cancel-requested", "cancelled"]
    tiles_done: int
    tiles_total: int
    positions_total: int
    positions_per_s: float | None = Field(description="Rendering rate of the current run")
    eta_s: float | None = Field(description="Estimated seconds to completion")
    error: str | None = Field(description="Why the job failed")
    spec: dict
    created_utc: str
    started_utc: str | None
    finished_utc: str | None
    result_url: str | None
    result_sha256: str | None
    result_bytes: int | None


class JobListOut(BaseModel):
    jobs: list[JobOut]


class HealthOut(BaseModel):
    """Liveness: ``degraded`` (with ``detail``) when the Dask cluster could not be started or reached, the job
    runner stopped, or the data directory is not writable or short of space (jobs then wait)."""

    status: Literal["ok", "degraded"]
    version: str
    workers: int | None
    scheduler: str | None
    detail: str | None = None
