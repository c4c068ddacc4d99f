"""Render a skyline database from a DEM, tile by tile, resumably.

The pieces are separate so that the render service can farm tiles to Dask workers:

* :func:`prepare_job` validates the request and describes the render (grid, spec, metadata);
* :func:`load_terrain` builds (or loads) the multi-resolution terrain around the site, once per
  process or worker;
* :func:`open_writer` creates the Zarr store, or reopens it to resume;
* :func:`render_and_write_tile` renders one tile and writes it, unless it is already done
  (so a tile is never written twice; distinct tiles are distinct Zarr chunks, safe in parallel).

:func:`render_database` chains them with a tqdm progress bar; it is what ``skyloc db render``
and the demo call.  All coordinates are metres in the DEM's metric working CRS (the CRS that
:func:`blender_addon.terrain.dem.read_dem` gives; the database records its WKT).
"""
from __future__ import annotations

import logging
import math
import shutil
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from blender_addon.terrain.model import MultiResTerrain
from board.conventions import Body, body_from_name
from board.errors import InvalidInputError, NoDataError
from board.skydb import ELEVATION_SCALE_DEG, GridSpec, SkyDB, SkyDBMeta, SkyDBWriter, Tile, checked_elevation_scale
from render_service.renderers.base import RenderSpec, get_renderer, render_tile_sampled
from render_service.renderers.raymarch import check_positions_inside

log = logging.getLogger(__name__)


@dataclass
class RenderJob:
    """A validated skyline-database render.

    dem_path : the DEM file (GDAL raster)
    grid : positions, metres in the DEM's metric CRS (``grid.crs_wkt``)
    spec : what to render at every position (body radius from the DEM's body)
    meta : the database metadata (renderer, version, DEM hash...)
    body : the body the DEM lives on
    assume_metric : the DEM has no CRS and its coordinates are metres (``--assume-metric``)
    """

    dem_path: Path
    grid: GridSpec
    spec: RenderSpec
    meta: SkyDBMeta
    body: Body
    renderer: str = "raymarch"
    extra: dict = field(default_factory=dict)
    assume_metric: bool = False


def _dem_module():
    """blender_addon.terrain.dem (GDAL), imported on first use."""
    from blender_addon.terrain import dem  # noqa: PLC0415

    return dem


def _multires_module():
    """blender_addon.terrain.multires, imported on first use."""
    from blender_addon.terrain import multires  # noqa: PLC0415

    return multires


def renderer_version(renderer: str) -> str:
    """Version string of a renderer (its module's ``__version__``)."""
    fn = _resolve_renderer(renderer)
    return str(getattr(sys.modules[fn.__module__], "__version__", "0"))


def _resolve_renderer(renderer: str):
    try:
        return get_renderer(renderer)
    except (ImportError, AttributeError) as exc:
        raise InvalidInputError(f"renderer {renderer!r} is not available here ({exc}); "
                                "use --renderer raymarch or install its component") from exc


def prepare_job(dem_path, *, center_xy: tuple[float, float], size_m: float, step_m: float,
                spec: RenderSpec, renderer: str = "raymarch", tile_size: int = 64,
                body: str | float | None = None, what: str = "the grid", assume_metric: bool = False,
                elevation_unit_deg: float | None = None) -> RenderJob:
    """Validate a render request and describe it; nothing is written.

    ``center_xy`` is in metres in the DEM's metric working CRS; ``spec.body_radius_m`` is replaced
    by the DEM's body radius (or ``body``'s) so the curvature matches the terrain.  ``elevation_unit_deg``
    is the database's int16 elevation unit (degrees; None: board.skydb.ELEVATION_SCALE_DEG).
    Raises InvalidInputError (bad step, size, tile, renderer, elevation unit), DemReadError, CrsError.
    """
    unit = checked_elevation_scale(ELEVATION_SCALE_DEG if elevation_unit_deg is None else elevation_unit_deg)
    if not (isinstance(tile_size, (int, np.integer)) and tile_size > 0):
        raise InvalidInputError(f"tile size must be a positive number of positions, got {tile_size}")
    grid = GridSpec.from_center(center_xy, size_m, step_m)          # validates step > 0, size >= 0
    render_fn = _resolve_renderer(renderer)
    info = _dem_module().dem_info(str(dem_path), body=body, assume_metric=assume_metric)
    the_body = body_from_name(body) if body is not None else info.body
    spec = replace(spec, body_radius_m=float(the_body.radius_m))
    grid = replace(grid, crs_wkt=info.crs_wkt)
    xmin, ymin, xmax, ymax = info.bounds
    gx0, gy0, gx1, gy1 = grid.bounds()
    if not (xmin <= gx0 and gx1 <= xmax and ymin <= gy0 and gy1 <= ymax):
        raise InvalidInputError(
            f"{what} ({gx0:.1f}..{gx1:.1f}, {gy0:.1f}..{gy1:.1f} m) is not inside the DEM "
            f"({xmin:.1f}..{xmax:.1f}, {ymin:.1f}..{ymax:.1f} m, metric CRS): choose a centre and size inside "
            "the DEM (coordinates are in the DEM's own CRS unless --crs is given)")
    meta = SkyDBMeta(
        grid=grid, camera_height_m=float(spec.camera_height_m), n_azimuth=int(spec.n_azimuth),
        azimuth_start_deg=float(spec.azimuth_start_deg), body=the_body.name,
        body_radius_m=float(the_body.radius_m), refraction_k=float(spec.refraction_k), renderer=renderer,
        renderer_version=str(getattr(sys.modules[render_fn.__module__], "__version__", "0")),
        dem_sha256=info.sha256, tile_size=int(tile_size), has_distance=True, has_ground=True, elevation_scale_deg=unit,
        azimuth_subsamples=int(spec.azimuth_subsamples),
        extra={"dem_path": str(Path(dem_path).resolve()), "center_xy_m": [float(center_xy[0]), float(center_xy[1])],
               "size_m": float(size_m), "step_m": float(step_m),
               "max_distance_m": spec.max_distance_m},
    )
    return RenderJob(Path(dem_path), grid, spec, meta, the_body, renderer, assume_metric=assume_metric)


#: Coarsest azimuth resolution the terrain levels are planned for (degrees).  The levels' cells
#: subtend at most this angle where they start; a database with fewer azimuths still wants the
#: elevation accuracy of 1 degree cells (the far-field error scales with the cell's angle).
MAX_TERRAIN_AZIMUTH_STEP_DEG = 1.0


def terrain_azimuth_step_deg(n_azimuth: int) -> float:
    """Azimuth step (degrees) to plan the multi-resolution levels for ``n_azimuth`` samples."""
    return min(MAX_TERRAIN_AZIMUTH_STEP_DEG, 360.0 / n_azimuth)


def load_terrain(job: RenderJob, *, terrain_dir=None) -> MultiResTerrain:
    """The multi-resolution terrain for a job: loaded from ``terrain_dir`` if it holds one, else built.

    Raises InvalidInputError if the terrain's finest level does not cover every grid position.
    """
    mr = _multires_module()
    tdir = Path(terrain_dir) if terrain_dir is not None else None
    if tdir is not None and (tdir / "terrain.json").is_file():
        log.info("loading the prepared terrain from %s", tdir)
        terrain = mr.load_multires(tdir)
        n = terrain.meta.get("cells_per_step", 1)
        if n < mr.CELLS_PER_STEP:
            log.warning(
                "the prepared terrain in %s starts its coarse levels at %d cell(s) per azimuth step (this skyloc: %d); "
                "its far horizons may be lifted by up to a coarse cell: rebuild it with `skyloc dem prepare` "
                "for the most accurate database", tdir, n, mr.CELLS_PER_STEP)
    else:
        half = max(job.grid.nx, job.grid.ny) * abs(job.grid.geotransform[1]) / 2.0
        cx, cy = job.meta.extra["center_xy_m"]
        terrain = mr.build_multires(str(job.dem_path), (cx, cy), grid_half_m=half,
                                    azimuth_step_deg=terrain_azimuth_step_deg(job.spec.n_azimuth), out_dir=tdir,
                                    body=job.body, max_radius_m=job.spec.max_distance_m,
                                    assume_metric=job.assume_metric)
    gx0, gy0, gx1, gy1 = job.grid.bounds()
    check_positions_inside(terrain, [gx0, gx1, gx0, gx1], [gy0, gy0, gy1, gy1])
    return terrain


def open_writer(path, meta: SkyDBMeta | None = None) -> SkyDBWriter:
    """Create the store at ``path`` for ``meta``, or reopen it to resume (``meta=None``: it must exist).

    Raises InvalidInputError when ``path`` holds a different database.
    """
    path = Path(path)
    if meta is None:
        meta = SkyDB.open(path).meta
    return SkyDBWriter.create(path, meta)


def render_and_write_tile(writer_path, terrain: MultiResTerrain, tile: Tile, spec: RenderSpec,
                          renderer: str = "raymarch", *, writer: SkyDBWriter | None = None) -> bool:
    """Render one tile and write it to the store at ``writer_path``; False if it was already done.

    Safe to call from several processes at once for different tiles (one Zarr chunk per tile).
    """
    w = writer if writer is not None else open_writer(writer_path)
    if w.done_mask()[tile.ti, tile.tj]:
        log.debug("tile %s already written: skipped", tile.key)
        return False
    if spec.azimuth_subsamples != w.meta.azimuth_subsamples:
        raise InvalidInputError(f"{writer_path} holds samples of {w.meta.azimuth_subsamples} ray(s) each; this render "
                                f"asks for {spec.azimuth_subsamples}: render it with --azimuth-subsamples "
                                f"{w.meta.azimuth_subsamples} or into another --out")
    res = render_tile_sampled(_resolve_renderer(renderer), terrain, w.meta.grid, tile, spec)
    w.write_tile(tile, res.elevation_deg, res.distance_m if w.meta.has_distance else None,
                 tile_ground_m(terrain, w.meta.grid, tile) if w.meta.has_ground else None)
    return True


def tile_ground_m(terrain: MultiResTerrain, grid: GridSpec, tile: Tile) -> np.ndarray:
    """(nrows, ncols) ground heights (metres) under a tile's positions, NaN where the terrain has none: the
    eye's ground of the renderers (:func:`blender_addon.core.terrain_mesh.sample_height`, bilinear on the finest
    level; ``camera_height_m`` above it)."""
    from blender_addon.core.terrain_mesh import sample_height  # noqa: PLC0415

    def ground(i: int, j: int) -> float:
        x, y = grid.xy(i, j)
        try:
            return sample_height(terrain, float(x), float(y))
        except NoDataError:
            return math.nan

    return np.array([[ground(i, j) for j in range(tile.col0, tile.col0 + tile.ncols)]
                     for i in range(tile.row0, tile.row0 + tile.nrows)], dtype=np.float32)


def render_database(dem_path, *, center_xy: tuple[float, float], size_m: float, step_m: float,
                    spec: RenderSpec, out, renderer: str = "raymarch", tile_size: int = 64,
                    terrain_dir=None, progress: bool = True, body: str | float | None = None,
                    on_tile: Callable[[int, int], None] | None = None, assume_metric: bool = False,
                    elevation_unit_deg: float | None = None) -> SkyDB:
    """Render (or resume) the skyline database of a square grid centred on ``center_xy``.

    Parameters
    ----------
    dem_path : DEM file; ``center_xy`` in metres in its metric working CRS
    size_m, step_m : grid side and spacing, metres (1000 and 5 give 201 x 201 positions)
    spec : camera height, azimuth sampling, refraction (body radius taken from the DEM's body)
    out : the Zarr store; an existing store of the same render is resumed, finished tiles kept
    terrain_dir : where the multi-resolution terrain is (or will be) prepared
    progress : show a tqdm progress bar (positions, with ETA)
    elevation_unit_deg : the int16 elevation unit, degrees (None: board.skydb.ELEVATION_SCALE_DEG)
    on_tile : called as ``on_tile(tiles_done, tiles_total)`` once the store is open and after every
        tile written (progress reporting; an exception raised there stops the render like Ctrl-C)

    A brand-new store that fails before its first tile is written is removed; an interrupted
    render (Ctrl-C) keeps every finished tile and resumes when run again.
    """
    out = Path(out)
    job = prepare_job(dem_path, center_xy=center_xy, size_m=size_m, step_m=step_m, spec=spec,
                      renderer=renderer, tile_size=tile_size, body=body, assume_metric=assume_metric,
                      elevation_unit_deg=elevation_unit_deg)
    if out.exists():
        # refuse a different database (or a non-database) before spending time on the terrain
        if not (out / "zarr.json").is_file():
            raise InvalidInputError(f"{out} exists and is not a skyline database: choose another --out or delete it")
        SkyDBWriter.check_resumable(out, job.meta)
    from tqdm import tqdm  # noqa: PLC0415

    total = job.grid.n_positions
    # the bar opens before the terrain is prepared (several seconds on a large DEM) and says so
    bar = tqdm(total=total, unit="pos", desc="skyline DB", disable=not progress, dynamic_ncols=True, file=sys.stderr)
    bar.set_postfix_str("preparing the multi-resolution terrain")
    try:
        terrain = load_terrain(job, terrain_dir=terrain_dir)
    except BaseException:
        bar.close()
        raise
    job.meta.extra["terrain_levels"] = [
        {"cell_m": float(lv.cell_m), "bounds": [float(b) for b in lv.bounds()]} for lv in terrain.levels]
    new_store = not out.exists()
    writer = SkyDBWriter.create(out, job.meta)
    written = 0
    try:
        pending = writer.pending_tiles()
        done_pos = total - sum(t.nrows * t.ncols for t in pending)
        log.info("%s: %d of %d tiles to render (%d positions, %d azimuths)", out, len(pending),
                 len(writer.tiles), total - done_pos, spec.n_azimuth)
        bar.update(done_pos)
        bar.set_postfix_str(f"rendering {len(pending)} tiles of {max(t.nrows * t.ncols for t in writer.tiles)} "
                            "positions")
        with bar:
            n_done = len(writer.tiles) - len(pending)
            if on_tile is not None:
                on_tile(n_done, len(writer.tiles))
            for tile in pending:
                render_and_write_tile(out, terrain, tile, job.spec, renderer, writer=writer)
                written += 1
                n_done += 1
                bar.update(tile.nrows * tile.ncols)
                if on_tile is not None:
                    on_tile(n_done, len(writer.tiles))
        return writer.finalize()
    except BaseException:
        bar.close()
        if new_store and written == 0:
            shutil.rmtree(out, ignore_errors=True)
            log.info("removed the unfinished new store %s", out)
        elif written or not new_store:
            log.warning("render of %s stopped: %d of %d tiles written; run the same command again to resume",
                        out, int(writer.done_mask().sum()), len(writer.tiles))
        raise


def horizon_from_dem(dem_path, *, x: float, y: float, spec: RenderSpec, body: str | float | None = None,
                     terrain_dir=None, assume_metric: bool = False
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, str, RenderSpec]:
    """Horizon at one point (metres, DEM metric CRS) straight from a DEM.

    Returns (azimuth_deg, elevation_deg, distance_m, crs_wkt, spec_used).
    """
    from render_service.renderers.raymarch import horizon_at  # noqa: PLC0415

    job = prepare_job(dem_path, center_xy=(x, y), size_m=0.0, step_m=1.0, spec=spec, body=body,
                      what="the position", assume_metric=assume_metric)
    terrain = load_terrain(job, terrain_dir=terrain_dir)
    az, el, dist = horizon_at(terrain, x, y, job.spec)
    return az, el, dist, job.grid.crs_wkt, job.spec
