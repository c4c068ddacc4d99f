"""Multi-resolution terrain around a site: nested, max-downsampled levels, written with GDAL.

Level 0 is the DEM at native resolution over the search grid (site +- grid_half_m)
plus a margin; level k has cells ``c_k = c_0 * 2**k`` and covers the grid plus
``n * c_{k+1} / radians(azimuth_step_deg)`` with ``n = cells_per_step``
(:data:`CELLS_PER_STEP`).  A renderer samples, at a point, the finest level containing
it, so level k (k >= 1) is only used at distances

    d >= n * c_k / radians(azimuth_step_deg)   from every grid position,

where one of its cells subtends at most 1/n of an azimuth step.  With n = 1 (one cell
per step, the rule up to session 7) the max-pooled cells lifted far ridges: database
horizons were 0.013-0.021 deg RMS above the full-resolution ones on the Moon DEM and
0.08 deg on the Baltoro one, which moved lost-in-space fixes by metres
(docs/terrain.md, "Why four cells per step").  With n = 4 (sessions 7-16) a lunar floor's
horizons 25-40 km away still stood 0.0032 deg RMS (0.0018 deg on average) above the native ones,
as much as the rest of the database's error; n = 8 (docs/terrain.md, "Why eight cells per step")
keeps them within 0.0005 deg.  Levels are aligned on the
native grid (each coarse cell is exactly 2**k x 2**k native cells), nest (each contains
the finer ones) and stop at the DEM's edge or ``max_radius_m``.  Coarse cells hold the
MAXIMUM of the native cells they cover (GDAL Warp ``max``), so distant peaks keep their
height (a mean would flatten them and lower the horizon).

On disk (``out_dir``): ``level_K.tif`` (Float32 GeoTIFF, NaN nodata), ``terrain.vrt``
(all levels mosaicked, finest on top, for QGIS) and ``terrain.json`` (the index).
"""
from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from osgeo import gdal

from board.atomic import atomic_dir
from board.conventions import Body
from board.errors import FormatError, InvalidInputError

from .dem import MetricSource, file_sha256, open_metric_source
from .model import MultiResTerrain, TerrainLevel
from .nodata import DEFAULT_MAX_HOLE_CELLS, FillReport, check_missing, fill_small_holes

log = logging.getLogger(__name__)
gdal.UseExceptions()

TERRAIN_FORMAT = "skyloc-multires"
TERRAIN_VERSION = 1
#: Largest fraction of the search grid allowed to stay without data (after filling small holes).
DEFAULT_MAX_GRID_MISSING = 0.01
#: Coarse level k is used only where one of its cells subtends at most 1/CELLS_PER_STEP azimuth step
#: (4 in sessions 7-16; 8 since session 17: docs/terrain.md, "Why eight cells per step").
CELLS_PER_STEP = 8
_GTIFF_OPTIONS = ["TILED=YES", "COMPRESS=DEFLATE", "PREDICTOR=3", "BLOCKXSIZE=256", "BLOCKYSIZE=256"]


@dataclass(frozen=True)
class LevelPlan:
    """Where one level lies: cell size (m), bounds (xmin, ymin, xmax, ymax, metres), inner distance (m)."""

    index: int
    cell_m: float
    bounds: tuple[float, float, float, float]
    inner_distance_m: float

    @property
    def size(self) -> tuple[int, int]:
        """(cols, rows)."""
        xmin, ymin, xmax, ymax = self.bounds
        return int(round((xmax - xmin) / self.cell_m)), int(round((ymax - ymin) / self.cell_m))


def _snap_out(b: tuple[float, float, float, float], origin: tuple[float, float], cell: float):
    ox, oy = origin
    xmin = ox + math.floor((b[0] - ox) / cell + 1e-9) * cell
    xmax = ox + math.ceil((b[2] - ox) / cell - 1e-9) * cell
    ymin = oy + math.floor((b[1] - oy) / cell + 1e-9) * cell
    ymax = oy + math.ceil((b[3] - oy) / cell - 1e-9) * cell
    return xmin, ymin, xmax, ymax


def _intersect(a, b):
    return max(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), min(a[3], b[3])


def plan_levels(
    dem_bounds: tuple[float, float, float, float],
    native_cell_m: float,
    origin_xy: tuple[float, float],
    site_xy: tuple[float, float],
    *,
    grid_half_m: float,
    azimuth_step_deg: float = 1.0,
    max_radius_m: float | None = None,
    cells_per_step: int = CELLS_PER_STEP,
) -> list[LevelPlan]:
    """Plan the nested levels (see module docstring); pure geometry, reads nothing.

    dem_bounds : (xmin, ymin, xmax, ymax) of the DEM (metres); origin_xy : a corner of its native grid
    site_xy : centre of the search grid; grid_half_m : half its side (m)
    max_radius_m : stop at this distance beyond the grid's edge (default: the DEM's edge)
    cells_per_step : coarse cells per azimuth step where a level starts (integer >= 1; more = finer, larger files)
    """
    if grid_half_m < 0 or azimuth_step_deg <= 0 or native_cell_m <= 0:
        raise InvalidInputError("grid_half_m must be >= 0 and azimuth_step_deg, the cell size > 0")
    _check_cells_per_step(cells_per_step)
    sx, sy = site_xy
    xmin, ymin, xmax, ymax = dem_bounds
    if not (xmin <= sx <= xmax and ymin <= sy <= ymax):
        raise InvalidInputError(
            f"site ({sx:.1f}, {sy:.1f}) is outside the DEM (x {xmin:.1f}..{xmax:.1f}, y {ymin:.1f}..{ymax:.1f} "
            "in its metric CRS): give a centre inside it (coordinates in the DEM's own CRS, or say which with --crs)"
        )
    reach = math.inf if max_radius_m is None else grid_half_m + float(max_radius_m)
    roi = _intersect(dem_bounds, (sx - reach, sy - reach, sx + reach, sy + reach))
    step = math.radians(azimuth_step_deg)
    levels: list[LevelPlan] = []
    k = 0
    while True:
        cell = native_cell_m * 2**k
        half = grid_half_m + cells_per_step * (2.0 * cell) / step  # until the next (2x coarser) level is admissible
        want = _intersect(roi, (sx - half, sy - half, sx + half, sy + half))
        b = _snap_out(want, origin_xy, cell)
        inner = 0.0 if k == 0 else cells_per_step * cell / step
        levels.append(LevelPlan(k, cell, b, inner))
        covers = want == roi
        if covers or k > 40:
            return levels
        k += 1


def _check_cells_per_step(n: object) -> None:
    """Refuse a cells_per_step that is not an integer >= 1 (a bool, a float or 0 would silently change the rule)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InvalidInputError(
            f"cells_per_step must be an integer >= 1 (got {n!r}): use {CELLS_PER_STEP} (the default), "
            "or 1 for the smaller, coarser terrain of skyloc before session 7"
        )


def _warp_level(src: MetricSource, plan: LevelPlan) -> np.ndarray:
    """Max-downsample the metric DEM onto one level's grid with gdal.Warp (to memory); float32 m, NaN nodata."""
    cols, rows = plan.size
    opts = gdal.WarpOptions(
        format="MEM",
        outputBounds=plan.bounds,
        width=cols,
        height=rows,
        resampleAlg="max",
        srcNodata=src.nodata,
        dstNodata=float("nan"),
        outputType=gdal.GDT_Float32,
        workingType=gdal.GDT_Float32,
        overviewLevel="NONE",
        warpMemoryLimit=256 * 1024 * 1024,
        multithread=False,
    )
    ds = gdal.Warp("", src.dataset, options=opts)
    raw = ds.GetRasterBand(1).ReadAsArray()
    a = raw.astype(np.float32)
    if src.scale != 1.0 or src.offset != 0.0:
        a = a * np.float32(src.scale) + np.float32(src.offset)
    return a


def _read_level0(src: MetricSource, plan: LevelPlan) -> np.ndarray:
    """Native cells of level 0 (no resampling); cells outside the DEM are NaN."""
    gt = src.geotransform
    cols, rows = plan.size
    c_off = int(round((plan.bounds[0] - gt[0]) / gt[1]))
    r_off = int(round((plan.bounds[3] - gt[3]) / gt[5]))
    out = np.full((rows, cols), np.nan, dtype=np.float32)
    scols, srows = src.size
    c0, r0 = max(c_off, 0), max(r_off, 0)
    c1, r1 = min(c_off + cols, scols), min(r_off + rows, srows)
    if c1 > c0 and r1 > r0:
        out[r0 - r_off : r1 - r_off, c0 - c_off : c1 - c_off] = src.read_window(c0, r0, c1 - c0, r1 - r0)
    return out


def build_multires(
    dem_path: str | os.PathLike,
    site_xy: tuple[float, float],
    *,
    grid_half_m: float,
    azimuth_step_deg: float = 1.0,
    out_dir: str | os.PathLike | None = None,
    body: str | float | Body | None = None,
    max_radius_m: float | None = None,
    assume_metric: bool = False,
    max_hole_cells: int = DEFAULT_MAX_HOLE_CELLS,
    max_grid_missing: float = DEFAULT_MAX_GRID_MISSING,
    progress: bool = False,
    cells_per_step: int = CELLS_PER_STEP,
) -> MultiResTerrain:
    """Build the nested max-downsampled levels of a DEM around a site (finest first).

    dem_path : any DEM :func:`dem.read_dem` accepts; site_xy : grid centre in the DEM's metric working CRS (m)
    grid_half_m : half the search grid's side (m); azimuth_step_deg : skyline azimuth resolution (deg)
    out_dir : when given, writes level_K.tif, terrain.vrt and terrain.json there (atomically)
    max_radius_m : how far beyond the grid's edge to keep terrain (default: to the DEM's edge)
    max_grid_missing : refuse (NoDataError) when more of the search grid has no data
    cells_per_step : a coarse level starts where one of its cells subtends 1/cells_per_step azimuth step

    Returns a MultiResTerrain whose levels are float32 metres with NaN for nodata.
    """
    _check_cells_per_step(cells_per_step)
    src = open_metric_source(dem_path, body=body, assume_metric=assume_metric)
    gt = src.geotransform
    plans = plan_levels(
        src.bounds(), src.cell_m, (gt[0], gt[3]), (float(site_xy[0]), float(site_xy[1])),
        grid_half_m=grid_half_m, azimuth_step_deg=azimuth_step_deg, max_radius_m=max_radius_m,
        cells_per_step=int(cells_per_step),
    )
    sha = file_sha256(dem_path)
    levels: list[TerrainLevel] = []
    reports: list[FillReport] = []
    it = plans
    if progress:
        from tqdm import tqdm

        it = tqdm(plans, desc="terrain levels", unit="level")
    for plan in it:
        arr = _read_level0(src, plan) if plan.index == 0 else _warp_level(src, plan)
        rep = fill_small_holes(arr, max_hole_cells=max_hole_cells)
        reports.append(rep)
        lvl = TerrainLevel(array=arr, x0=plan.bounds[0], y0=plan.bounds[3], cell_m=plan.cell_m)
        if plan.index == 0:
            _check_grid(lvl, site_xy, grid_half_m, max_grid_missing, max_hole_cells, dem_path)
        levels.append(lvl)
        log.info("level %d: %.4g m cells, %d x %d, from %.0f m, %.2f%% nodata", plan.index, plan.cell_m,
                 arr.shape[1], arr.shape[0], plan.inner_distance_m, 100 * rep.missing_fraction)
    meta = {
        "grid_half_m": float(grid_half_m),
        "azimuth_step_deg": float(azimuth_step_deg),
        "max_radius_m": None if max_radius_m is None else float(max_radius_m),
        "cells_per_step": int(cells_per_step),
        "inner_distance_m": [p.inner_distance_m for p in plans],
        "source": str(dem_path),
        "source_is_geographic": src.is_geographic,
    }
    terrain = MultiResTerrain(levels=levels, crs_wkt=src.crs_wkt, body=src.body,
                              site_xy=(float(site_xy[0]), float(site_xy[1])), dem_sha256=sha, meta=meta)
    if out_dir is not None:
        write_multires(terrain, out_dir, reports=reports)
    return terrain


def _check_grid(lvl: TerrainLevel, site_xy, grid_half_m, max_missing, max_hole_cells, dem_path) -> None:
    """Refuse when the search grid (inside level 0) has too much missing data."""
    sx, sy = site_xy
    c = lvl.cell_m
    c0 = max(int(math.floor((sx - grid_half_m - lvl.x0) / c)), 0)
    c1 = min(int(math.ceil((sx + grid_half_m - lvl.x0) / c)), lvl.array.shape[1])
    r0 = max(int(math.floor((lvl.y0 - (sy + grid_half_m)) / c)), 0)
    r1 = min(int(math.ceil((lvl.y0 - (sy - grid_half_m)) / c)), lvl.array.shape[0])
    sub = lvl.array[r0:max(r1, r0 + 1), c0:max(c1, c0 + 1)]
    miss = np.isnan(sub)
    rep = FillReport(n_missing=int(miss.sum()), missing_fraction=float(miss.mean()))
    if rep.n_missing:
        rows = np.flatnonzero(miss.any(axis=1))
        cols = np.flatnonzero(miss.any(axis=0))
        rep.missing_bbox_rc = (int(rows[0]), int(cols[0]), int(rows[-1]), int(cols[-1]))
    gt = (lvl.x0 + c0 * c, c, 0.0, lvl.y0 - r0 * c, 0.0, -c)
    check_missing(
        rep, max_fraction=max_missing, geotransform=gt,
        what=f"the search grid ({2 * grid_half_m:g} m square around ({sx:.1f}, {sy:.1f})) on {Path(dem_path).name}",
        fix=f"move the grid inside the DEM's data, shrink it (--grid-size), fill the gap (holes up to "
            f"{max_hole_cells} cells are filled automatically) or use a complete DEM",
    )


def _write_level(path: Path, lvl: TerrainLevel, crs_wkt: str) -> None:
    rows, cols = lvl.array.shape
    ds = gdal.GetDriverByName("GTiff").Create(str(path), cols, rows, 1, gdal.GDT_Float32, options=_GTIFF_OPTIONS)
    ds.SetGeoTransform(lvl.geotransform)
    ds.SetProjection(crs_wkt)
    band = ds.GetRasterBand(1)
    band.SetNoDataValue(float("nan"))
    band.SetUnitType("m")
    band.WriteArray(lvl.array)
    ds.FlushCache()
    ds = None


def write_multires(terrain: MultiResTerrain, out_dir: str | os.PathLike, *, reports: list[FillReport] | None = None) -> Path:
    """Write a MultiResTerrain as level_K.tif + terrain.vrt + terrain.json into ``out_dir`` (atomically).

    An existing ``out_dir`` is replaced only if it is empty or holds a previous terrain (terrain.json).
    """
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()) and not (out / "terrain.json").is_file():
        raise InvalidInputError(f"{out} exists and is not a skyloc terrain folder: choose an empty or new --out")
    with atomic_dir(out) as tmp:
        entries = []
        for k, lvl in enumerate(terrain.levels):
            name = f"level_{k}.tif"
            _write_level(tmp / name, lvl, terrain.crs_wkt)
            rows, cols = lvl.array.shape
            inner = terrain.meta.get("inner_distance_m", [None] * len(terrain.levels))[k]
            entries.append({
                "index": k, "file": name, "cell_m": lvl.cell_m, "x0": lvl.x0, "y0": lvl.y0,
                "cols": cols, "rows": rows, "bounds": list(lvl.bounds()), "inner_distance_m": inner,
                "nodata_fraction": (reports[k].missing_fraction if reports else float(np.isnan(lvl.array).mean())),
            })
        # mosaic for viewing: coarsest first so finer levels are drawn on top
        names = [str(tmp / e["file"]) for e in reversed(entries)]
        vrt = gdal.BuildVRT(str(tmp / "terrain.vrt"), names, options=gdal.BuildVRTOptions(resolution="highest"))
        vrt.FlushCache()
        vrt = None
        _relativise_vrt(tmp / "terrain.vrt", tmp)
        doc = {
            "format": TERRAIN_FORMAT,
            "version": TERRAIN_VERSION,
            "site_xy": list(terrain.site_xy),
            "crs_wkt": terrain.crs_wkt,
            "body": {"name": terrain.body.name, "radius_m": terrain.body.radius_m},
            "dem_sha256": terrain.dem_sha256,
            "rule": "level k >= 1 (cell c_k) is used only beyond inner_distance_m = "
                    "cells_per_step * c_k / radians(azimuth_step_deg) from every grid position; "
                    "cells hold the maximum of the native cells they cover",
            "vrt": "terrain.vrt",
            "levels": entries,
            "meta": terrain.meta,
        }
        (tmp / "terrain.json").write_text(json.dumps(doc, indent=2))
    for e, lvl in zip(entries, terrain.levels):
        lvl.path = str(out / e["file"])
    return out


def _relativise_vrt(vrt_path: Path, folder: Path) -> None:
    """Make the VRT's source paths relative so the folder can be moved (and survives the final rename)."""
    text = vrt_path.read_text()
    prefix = str(folder) + os.sep
    text = text.replace(f'relativeToVRT="0">{prefix}', 'relativeToVRT="1">')
    vrt_path.write_text(text)


def load_multires(out_dir: str | os.PathLike) -> MultiResTerrain:
    """Read a terrain folder written by :func:`build_multires` (levels finest first, float32 m, NaN nodata)."""
    folder = Path(out_dir)
    index = folder / "terrain.json"
    if not index.is_file():
        raise FormatError(f"{folder} has no terrain.json: build it with `skyloc dem prepare` (or build_multires(out_dir=...))")
    try:
        doc = json.loads(index.read_text())
    except json.JSONDecodeError as exc:
        raise FormatError(f"{index} is not valid JSON ({exc}): rebuild the terrain with `skyloc dem prepare`") from None
    if doc.get("format") != TERRAIN_FORMAT or doc.get("version") != TERRAIN_VERSION:
        raise FormatError(
            f"{index}: format {doc.get('format')!r} version {doc.get('version')!r} is not {TERRAIN_FORMAT} v{TERRAIN_VERSION}: "
            "rebuild it with this skyloc (`skyloc dem prepare`)"
        )
    levels = []
    for e in doc["levels"]:
        p = folder / e["file"]
        try:
            ds = gdal.Open(str(p))
        except RuntimeError as exc:
            raise FormatError(f"terrain level {p} cannot be read ({exc}): rebuild the terrain") from None
        arr = ds.GetRasterBand(1).ReadAsArray().astype(np.float32, copy=False)
        gt = ds.GetGeoTransform()
        if arr.shape != (e["rows"], e["cols"]) or not math.isclose(gt[1], e["cell_m"], rel_tol=1e-9):
            raise FormatError(f"terrain level {p} does not match terrain.json (size or cell): rebuild the terrain")
        levels.append(TerrainLevel(array=arr, x0=gt[0], y0=gt[3], cell_m=gt[1], path=str(p)))
    b = doc["body"]
    return MultiResTerrain(
        levels=levels, crs_wkt=doc["crs_wkt"], body=Body(b["name"], float(b["radius_m"])),
        site_xy=tuple(doc["site_xy"]), dem_sha256=doc.get("dem_sha256", ""), meta=doc.get("meta", {}),
    )
