"""Job planning (API process, before a job is accepted): typed specs, job ids, limits and the tile plan.

A skyline-database job is a square grid of positions (metres, in the DEM's metric working CRS) split
into tiles of ``tile_size x tile_size`` positions (:func:`board.skydb.plan_tiles`).  Jobs are stored as
the canonical JSON of their validated wire model; :func:`parse_spec` turns a stored spec back into the
model, so nothing downstream reads ``spec["size_m"]`` from a dict.
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass

from board.errors import InvalidInputError
from board.skydb import GridSpec, Tile, plan_tiles
from render_service.schemas import DatasetJobIn, SkylineDbJobIn
from render_service.settings import ServiceSettings
from render_service.store import DemRecord

JobSpec = SkylineDbJobIn | DatasetJobIn


def canonical_json(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


def spec_dict(job: JobSpec) -> dict:
    """The stored (JSON) form of a validated job."""
    return job.model_dump(mode="json")


def parse_spec(kind: str, spec: dict) -> JobSpec:
    """The typed job of a stored spec (InvalidInputError for an unknown kind)."""
    if kind == "skyline_db":
        return SkylineDbJobIn.model_validate(spec)
    if kind == "dataset":
        return DatasetJobIn.model_validate(spec)
    raise InvalidInputError(f"unknown job kind {kind!r}")


def job_id_for(job: JobSpec | dict) -> str:
    """Deterministic job id of a validated spec: the same spec always gives the same job."""
    spec = job if isinstance(job, dict) else spec_dict(job)
    return hashlib.sha256(canonical_json(spec).encode()).hexdigest()[:20]


@dataclass(frozen=True)
class DbPlan:
    """A planned database job: the grid (metres, DEM metric CRS) and its tiles."""

    grid: GridSpec
    tiles: list[Tile]


def plan_db_job(job: SkylineDbJobIn, dem: DemRecord, settings: ServiceSettings) -> DbPlan:
    """Check a database job against the limits and the DEM, and plan its tiles.

    Raises InvalidInputError naming the limit and the fix.
    """
    size_m, step_m = job.size_m, job.step_m
    area_km2 = (size_m / 1000.0) ** 2
    if area_km2 > settings.max_area_km2:
        raise InvalidInputError(f"search area {size_m:g} x {size_m:g} m = {area_km2:.3g} km^2 exceeds this server's "
                                f"limit of {settings.max_area_km2:g} km^2: split it into smaller jobs")
    n_side_f = size_m / step_m + 1.0  # float first: a tiny step must not build a 600-digit integer
    if not math.isfinite(n_side_f) or n_side_f * n_side_f > settings.max_positions:
        raise InvalidInputError(f"a step of {step_m:.3g} m over {size_m:g} m gives about {n_side_f:.3g} x "
                                f"{n_side_f:.3g} positions, more than this server's limit of "
                                f"{settings.max_positions}: use a larger step_m or a smaller size_m")
    if job.azimuths > settings.max_azimuths:
        raise InvalidInputError(f"{job.azimuths} azimuths exceed this server's limit of {settings.max_azimuths}")
    info = dem.info
    grid = GridSpec.from_center(tuple(job.center), size_m, step_m, info["crs_wkt"])
    xmin, ymin, xmax, ymax = grid.bounds()
    bx0, by0, bx1, by1 = info["bounds"]
    if xmin < bx0 or ymin < by0 or xmax > bx1 or ymax > by1:
        raise InvalidInputError(
            f"the grid [{xmin:.1f}, {ymin:.1f}, {xmax:.1f}, {ymax:.1f}] is not inside the DEM's bounds "
            f"[{bx0:.1f}, {by0:.1f}, {bx1:.1f}, {by1:.1f}] (metres, its metric CRS): move the centre or shrink size_m")
    return DbPlan(grid, plan_tiles(grid, job.tile_size))


def prepare_db_job(job: SkylineDbJobIn, dem: DemRecord):
    """The render description of a database job (:func:`render_service.dbrender.prepare_job`).

    The metadata is the CLI's (``skyloc db render``) so both produce the same database; the server
    path of the DEM is replaced by its id.
    """
    from render_service.dbrender import prepare_job  # noqa: PLC0415
    from render_service.renderers.base import RenderSpec  # noqa: PLC0415

    rspec = RenderSpec(camera_height_m=job.camera_height_m, n_azimuth=job.azimuths,
                       azimuth_start_deg=job.azimuth_start_deg, refraction_k=job.refraction_k,
                       azimuth_subsamples=job.azimuth_subsamples)
    rjob = prepare_job(dem.path, center_xy=tuple(job.center), size_m=job.size_m, step_m=job.step_m, spec=rspec,
                       renderer=job.renderer, tile_size=job.tile_size, body=dem.body)
    rjob.meta.extra.pop("dem_path", None)
    rjob.meta.extra["dem_id"] = dem.id
    return rjob
