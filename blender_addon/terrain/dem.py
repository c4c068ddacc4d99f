"""DEM import with GDAL: any raster GDAL opens, in metres on a projected metric CRS.

* A projected metric CRS, north-up with square cells, is used as is.
* A geographic CRS (degrees) is reprojected (bilinear) into a local azimuthal
  equidistant projection centred on the DEM, on the body named by the CRS's
  ellipsoid (Earth, Mars, Moon, Europa) or an explicit ``body=``; otherwise refused.
  Degrees are never taken as metres.
* A raster without a CRS is refused unless the caller says it is metric
  (``assume_metric=True`` and a ``body``).

The reprojection is a GDAL warped VRT: nothing is computed until a window is read, so
large DEMs are read by windows (``bounds=``) and never whole.
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from osgeo import gdal, osr

from board.atomic import file_sha256 as _file_sha256
from board.conventions import Body
from board.errors import CrsError, DemReadError, InvalidInputError

from . import crs as _crs
from .model import DemRaster
from .nodata import (
    DEFAULT_MAX_HOLE_CELLS,
    DEFAULT_MAX_MISSING_FRACTION,
    check_missing,
    fill_small_holes,
)

log = logging.getLogger(__name__)
gdal.UseExceptions()

#: Largest raster (cells) :func:`read_dem` reads whole (1.6 GB as float32); beyond it pass ``bounds=``.
DEFAULT_MAX_CELLS = 400_000_000

_FEET = {"ft", "foot", "feet", "us survey foot", "ftus", "us-ft"}


@dataclass
class MetricSource:
    """A DEM opened in its metric working CRS (north-up, square cells), not yet read.

    dataset : GDAL dataset in the working CRS (the file itself, or a warped VRT over it)
    geotransform : of ``dataset`` (metres)
    crs_wkt : WKT of the working (metric, projected) CRS
    body : the body (radius for curvature)
    is_geographic : the file's CRS is in degrees (and was reprojected)
    warped : ``dataset`` is a warped VRT (bilinear) over the file
    source_srs : CRS of the file's own coordinates (lon, lat order for a geographic one)
    """

    path: Path
    dataset: gdal.Dataset
    geotransform: tuple[float, float, float, float, float, float]
    crs_wkt: str
    body: Body
    is_geographic: bool
    warped: bool
    source_srs: osr.SpatialReference
    nodata: float | None
    scale: float
    offset: float
    src_dataset: gdal.Dataset | None = None
    dtype: str = ""

    @property
    def size(self) -> tuple[int, int]:
        """(cols, rows) of the working grid."""
        return self.dataset.RasterXSize, self.dataset.RasterYSize

    @property
    def cell_m(self) -> float:
        return abs(self.geotransform[1])

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the working grid, metres."""
        gt = self.geotransform
        cols, rows = self.size
        return gt[0], gt[3] + rows * gt[5], gt[0] + cols * gt[1], gt[3]

    def working_srs(self) -> osr.SpatialReference:
        return _crs.srs_from_wkt(self.crs_wkt)

    def to_heights(self, raw: np.ndarray) -> np.ndarray:
        """Raw band values -> float32 metres, NaN where nodata."""
        a = raw.astype(np.float32, copy=True)
        if self.nodata is not None and not math.isnan(self.nodata):
            a[raw == self.nodata] = np.nan
        if self.scale != 1.0 or self.offset != 0.0:
            a = a * np.float32(self.scale) + np.float32(self.offset)
        return a

    def read_window(self, col0: int, row0: int, cols: int, rows: int) -> np.ndarray:
        """Heights (float32 m, NaN nodata) of a window of the working grid."""
        raw = self.dataset.GetRasterBand(1).ReadAsArray(col0, row0, cols, rows)
        if raw is None:
            raise DemReadError(f"GDAL could not read window {col0},{row0} {cols}x{rows} of {self.path}")
        return self.to_heights(raw)


@dataclass
class DemInfo:
    """What a DEM is, without reading its heights.

    size : (cols, rows) of the metric working grid
    cell_m : its cell size, metres
    bounds : (xmin, ymin, xmax, ymax) in the working CRS, metres
    crs_wkt : WKT of the metric working CRS (coordinates of everything downstream)
    body : the body
    sha256 : content hash of the file
    is_geographic : the file is in degrees (reprojected on read)
    nodata_fraction : estimate of the fraction of missing cells (from a decimated read)
    """

    path: str
    size: tuple[int, int]
    cell_m: float
    bounds: tuple[float, float, float, float]
    crs_wkt: str
    body: Body
    sha256: str
    is_geographic: bool
    nodata_fraction: float
    source_crs_wkt: str = ""
    dtype: str = ""
    driver: str = ""
    extra: dict = field(default_factory=dict)

    def to_json_dict(self) -> dict:
        return {
            "path": self.path,
            "size": list(self.size),
            "cell_m": self.cell_m,
            "bounds": list(self.bounds),
            "crs_wkt": self.crs_wkt,
            "body": {"name": self.body.name, "radius_m": self.body.radius_m},
            "sha256": self.sha256,
            "is_geographic": self.is_geographic,
            "nodata_fraction": self.nodata_fraction,
            "source_crs_wkt": self.source_crs_wkt,
            "dtype": self.dtype,
            "driver": self.driver,
        }


_SHA_CACHE: dict[tuple[str, int, int], str] = {}


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (hex), streamed; cached per (path, size, mtime)."""
    p = Path(path)
    st = p.stat()
    key = (str(p.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _SHA_CACHE:
        _SHA_CACHE[key] = _file_sha256(p)
    return _SHA_CACHE[key]


def _open(path: str | os.PathLike) -> gdal.Dataset:
    p = Path(path)
    if not p.exists() and not str(path).startswith("/vsi"):
        raise DemReadError(f"DEM file {str(path)!r} does not exist: check the path")
    try:
        ds = gdal.Open(str(path), gdal.GA_ReadOnly)
    except RuntimeError as exc:
        raise DemReadError(f"GDAL cannot open {str(path)!r} as a raster ({exc}): give a GeoTIFF or another GDAL raster") from None
    if ds is None or ds.RasterCount < 1:
        raise DemReadError(f"{str(path)!r} has no raster band: give a single-band DEM")
    return ds


def _nice_cell(c: float) -> float:
    """Round a cell size to 4 significant digits (stable, readable grids)."""
    return float(f"{c:.4g}")


def open_metric_source(
    path: str | os.PathLike, *, body: str | float | Body | None = None, assume_metric: bool = False
) -> MetricSource:
    """Open a DEM in its metric working CRS (see module docstring); reads no heights.

    Raises DemReadError (unreadable), CrsError (no CRS, degrees without a body, non-metric units).
    """
    ds = _open(path)
    band = ds.GetRasterBand(1)
    gt = ds.GetGeoTransform(can_return_null=True)
    wkt = ds.GetProjectionRef() or ""
    nodata = band.GetNoDataValue()
    scale = band.GetScale() or 1.0
    offset = band.GetOffset() or 0.0
    unit = (band.GetUnitType() or "").strip().lower()
    if unit in _FEET:
        scale, offset = scale * 0.3048, offset * 0.3048
    dtype = gdal.GetDataTypeName(band.DataType)
    if gt is None:
        raise CrsError(f"{path}: the raster has no georeferencing (geotransform): georeference it (gdal_translate -a_ullr / -a_srs)")
    if not wkt:
        if not assume_metric:
            raise CrsError(
                f"{path}: the raster has no CRS, so its units are unknown (degrees are never taken as metres): "
                "assign one (gdal_translate -a_srs ...) or, if its coordinates are metres, say so "
                "(assume_metric=True / --assume-metric) and give the body (--body NAME|RADIUS)"
            )
        if body is None:
            raise CrsError(f"{path}: a raster without CRS declared metric needs its body: {_crs.BODY_HINT}")
        the_body, _ = _crs.resolve_body(None, body)
        srs = _crs.body_equirectangular_srs(the_body)
        return _finish_projected(path, ds, gt, srs, the_body, nodata, scale, offset, dtype, srs)

    srs = _crs.srs_from_wkt(wkt)
    if _crs.is_geographic(srs):
        the_body, override = _crs.resolve_body(srs, body)
        return _warp_geographic(path, ds, gt, srs, the_body, override, nodata, scale, offset, dtype)
    if not srs.IsProjected():
        raise CrsError(f"{path}: CRS {srs.GetName()!r} is neither geographic nor projected: reproject it (gdalwarp -t_srs)")
    unit_m = _crs.linear_unit_m(srs)
    if not math.isclose(unit_m, 1.0, rel_tol=1e-9):
        raise CrsError(
            f"{path}: the CRS's unit is {srs.GetLinearUnitsName()} ({unit_m} m), not metres: "
            "reproject it to a metre-based CRS (gdalwarp -t_srs ...)"
        )
    the_body, _ = _crs.resolve_body(srs, body)
    return _finish_projected(path, ds, gt, srs, the_body, nodata, scale, offset, dtype, srs)


def _finish_projected(path, ds, gt, srs, body, nodata, scale, offset, dtype, source_srs) -> MetricSource:
    north_up = gt[2] == 0 and gt[4] == 0 and gt[5] < 0 < gt[1]
    square = math.isclose(abs(gt[1]), abs(gt[5]), rel_tol=1e-6)
    if north_up and square:
        return MetricSource(
            Path(path), ds, tuple(gt), srs.ExportToWkt(), body, False, False, source_srs,
            nodata, scale, offset, src_dataset=ds, dtype=dtype,
        )
    # rotated, south-up or rectangular cells: warp onto a north-up square grid in the same CRS
    cell = min(math.hypot(gt[1], gt[4]), math.hypot(gt[2], gt[5]))
    log.info("%s: not north-up with square cells; warping to a %.3f m north-up grid", path, cell)
    vrt = _warp_vrt(ds, srs, srs, cell, nodata)
    return MetricSource(
        Path(path), vrt, tuple(vrt.GetGeoTransform()), srs.ExportToWkt(), body, False, True, source_srs,
        None, scale, offset, src_dataset=ds, dtype=dtype,
    )


def _warp_vrt(ds, src_srs, dst_srs, cell, nodata) -> gdal.Dataset:
    opts = gdal.WarpOptions(
        format="VRT",
        srcSRS=src_srs.ExportToWkt(),
        dstSRS=dst_srs.ExportToWkt(),
        xRes=cell,
        yRes=cell,
        targetAlignedPixels=True,
        resampleAlg="bilinear",
        srcNodata=nodata,
        dstNodata=float("nan"),
        outputType=gdal.GDT_Float32,
        workingType=gdal.GDT_Float64,
        errorThreshold=0.0,
    )
    return gdal.Warp("", ds, options=opts)


def _warp_geographic(path, ds, gt, srs, body, override, nodata, scale, offset, dtype) -> MetricSource:
    cols, rows = ds.RasterXSize, ds.RasterYSize
    lon0, lon1 = gt[0], gt[0] + cols * gt[1] + rows * gt[2]
    lat0, lat1 = gt[3], gt[3] + cols * gt[4] + rows * gt[5]
    clon, clat = (lon0 + lon1) / 2.0, (lat0 + lat1) / 2.0
    if not (-90.0 <= min(lat0, lat1) and max(lat0, lat1) <= 90.0):
        raise CrsError(f"{path}: latitudes {lat0}..{lat1} are outside -90..90: the CRS or georeferencing is wrong")
    src_srs = _crs.sphere_geographic_srs(body) if override else srs
    dst_srs = _crs.local_aeqd_srs(clon, clat, base=None if override else srs, body=body)
    dx, dy = _crs.geographic_cell_m(src_srs, clat, math.hypot(gt[1], gt[4]), math.hypot(gt[2], gt[5]))
    cell = _nice_cell(min(dx, dy))
    vrt = _warp_vrt(ds, src_srs, dst_srs, cell, nodata)
    log.info("%s: geographic (%s) reprojected to %s at %.4g m (%.4g x %.4g m cells in the source)",
             path, body.name, dst_srs.GetName(), cell, dx, dy)
    return MetricSource(
        Path(path), vrt, tuple(vrt.GetGeoTransform()), dst_srs.ExportToWkt(), body, True, True, src_srs,
        None, scale, offset, src_dataset=ds, dtype=dtype,
    )


def snap_window(src: MetricSource, bounds: tuple[float, float, float, float]) -> tuple[int, int, int, int]:
    """Grid window (col0, row0, cols, rows) covering ``bounds`` (xmin, ymin, xmax, ymax, metres), clipped to the DEM.

    Raises InvalidInputError when the bounds do not overlap the DEM.
    """
    xmin, ymin, xmax, ymax = bounds
    if not (xmax > xmin and ymax > ymin):
        raise InvalidInputError(f"bounds {bounds} are empty: give (xmin, ymin, xmax, ymax) with xmin < xmax, ymin < ymax")
    gt = src.geotransform
    cols, rows = src.size
    c0 = max(int(math.floor((xmin - gt[0]) / gt[1] + 1e-9)), 0)
    c1 = min(int(math.ceil((xmax - gt[0]) / gt[1] - 1e-9)), cols)
    r0 = max(int(math.floor((ymax - gt[3]) / gt[5] + 1e-9)), 0)
    r1 = min(int(math.ceil((ymin - gt[3]) / gt[5] - 1e-9)), rows)
    if c1 <= c0 or r1 <= r0:
        b = src.bounds()
        raise InvalidInputError(
            f"bounds x {xmin:.1f}..{xmax:.1f}, y {ymin:.1f}..{ymax:.1f} do not overlap the DEM "
            f"(x {b[0]:.1f}..{b[2]:.1f}, y {b[1]:.1f}..{b[3]:.1f} m in its metric CRS): pick an area inside it"
        )
    return c0, r0, c1 - c0, r1 - r0


def available_memory_bytes() -> int | None:
    """Memory available to this process (Linux MemAvailable), or None when unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def read_dem(
    path: str | os.PathLike,
    *,
    body: str | float | Body | None = None,
    bounds: tuple[float, float, float, float] | None = None,
    assume_metric: bool = False,
    max_cells: int = DEFAULT_MAX_CELLS,
    max_hole_cells: int = DEFAULT_MAX_HOLE_CELLS,
    max_missing_fraction: float = DEFAULT_MAX_MISSING_FRACTION,
) -> DemRaster:
    """Read a DEM (or a window of it) as float32 metres on its metric working CRS.

    Parameters
    ----------
    path : any raster GDAL opens
    body : body name or radius (metres); default: from the CRS's ellipsoid
    bounds : (xmin, ymin, xmax, ymax) in the metric working CRS (metres); only that window is read
    assume_metric : a raster without CRS has metric coordinates (needs ``body``)
    max_cells : refuse to read more cells than this at once (pass ``bounds``)
    max_hole_cells : interior nodata holes up to this many cells are filled
    max_missing_fraction : refuse (NoDataError) when more of the window is still missing

    Returns a DemRaster: array (rows, cols) float32 m, NaN = nodata outside the footprint.
    """
    src = open_metric_source(path, body=body, assume_metric=assume_metric)
    cols, rows = src.size
    if bounds is None:
        c0, r0, nc, nr = 0, 0, cols, rows
    else:
        c0, r0, nc, nr = snap_window(src, bounds)
    avail = available_memory_bytes()
    if avail is not None and nc * nr * 4 * 2 > avail:
        raise DemReadError(
            f"{path}: reading {nc} x {nr} cells ({nc * nr * 4 / 1e9:.1f} GB as float32) would not fit in the "
            f"{avail / 1e9:.1f} GB of memory available: read a window with bounds=(xmin, ymin, xmax, ymax), or build "
            "a multi-resolution terrain (skyloc dem prepare), which reads by windows"
        )
    if nc * nr > max_cells:
        raise DemReadError(
            f"{path}: reading {nc} x {nr} cells ({nc * nr * 4 / 1e9:.1f} GB as float32) exceeds max_cells={max_cells}: "
            "read a window with bounds=(xmin, ymin, xmax, ymax), or build a multi-resolution terrain "
            "(skyloc dem prepare), which reads by windows"
        )
    array = src.read_window(c0, r0, nc, nr)
    gt = src.geotransform
    wgt = (gt[0] + c0 * gt[1], gt[1], 0.0, gt[3] + r0 * gt[5], 0.0, gt[5])
    report = fill_small_holes(array, max_hole_cells=max_hole_cells)
    if report.n_filled:
        log.info("%s: filled %d nodata cells in %d small hole(s)", path, report.n_filled, report.n_holes_filled)
    check_missing(report, max_fraction=max_missing_fraction, geotransform=wgt, what=f"{Path(path).name} (window read)")
    return DemRaster(
        array=array, geotransform=wgt, crs_wkt=src.crs_wkt, body=src.body,
        sha256=file_sha256(path), source=str(path),
    )


def dem_info(
    path: str | os.PathLike, *, body: str | float | Body | None = None, assume_metric: bool = False,
    sample_cells: int = 1_000_000,
) -> DemInfo:
    """Describe a DEM without reading it whole (validation of uploads); raises the same refusals as read_dem.

    ``nodata_fraction`` is estimated on a regular grid of at most ``sample_cells`` cells, read block by
    block (:func:`blender_addon.terrain.raster_sample.sample_grid`): memory stays about one block of the
    file plus the grid, whatever the raster's size.
    """
    from blender_addon.terrain.raster_sample import sample_grid  # noqa: PLC0415

    src = open_metric_source(path, body=body, assume_metric=assume_metric)
    fds = src.src_dataset or src.dataset
    raw = sample_grid(fds.GetRasterBand(1), max_cells=sample_cells)
    nod = fds.GetRasterBand(1).GetNoDataValue()
    a = raw.astype(np.float64)
    miss = np.isnan(a) if nod is None else (np.isnan(a) | (raw == nod))
    cols, rows = src.size
    return DemInfo(
        path=str(path), size=(cols, rows), cell_m=src.cell_m, bounds=src.bounds(), crs_wkt=src.crs_wkt,
        body=src.body, sha256=file_sha256(path), is_geographic=src.is_geographic,
        nodata_fraction=float(miss.mean()), source_crs_wkt=fds.GetProjectionRef() or "",
        dtype=src.dtype, driver=fds.GetDriver().ShortName,
    )


def to_metric_xy(
    x, y, *, dem_path: str | os.PathLike, crs: str | None = None,
    body: str | float | Body | None = None, assume_metric: bool = False,
):
    """Convert point(s) to the DEM's metric working CRS (metres).

    ``(x, y)`` are in ``crs`` (e.g. "EPSG:4326", a WKT or PROJ string; lon, lat order for
    geographic CRSs) or, when ``crs`` is None, in the DEM's own CRS (lon, lat for a DEM in degrees).
    Scalars give a tuple of floats; arrays give a tuple of float64 arrays of the same shape.
    """
    src = open_metric_source(dem_path, body=body, assume_metric=assume_metric)
    dst = src.working_srs()
    from_srs = src.source_srs if crs is None else _crs.srs_from_wkt(crs)
    scalar = np.ndim(x) == 0 and np.ndim(y) == 0
    xa, ya = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    if from_srs.IsSame(dst):
        xm, ym = xa.copy(), ya.copy()
    else:
        try:
            ct = osr.CoordinateTransformation(from_srs, dst)
            pts = np.asarray(ct.TransformPoints(np.stack([xa.ravel(), ya.ravel()], axis=1).tolist()), dtype=np.float64)
        except RuntimeError as exc:
            raise CrsError(f"cannot convert ({x}, {y}) from {from_srs.GetName()!r} to the DEM's CRS: {exc}") from None
        xm, ym = pts[:, 0].reshape(xa.shape), pts[:, 1].reshape(xa.shape)
    if not (np.isfinite(xm).all() and np.isfinite(ym).all()):
        raise CrsError(f"({x}, {y}) in {from_srs.GetName()!r} has no position in the DEM's CRS: check the coordinates and --crs")
    if scalar:
        return float(xm), float(ym)
    return xm, ym


# ---------------------------------------------------------------- DEM specs (files or procedural)

PROCEDURAL_PREFIX = "procedural:"
DEFAULT_PROCEDURAL_SIZE_M = 20000.0
DEFAULT_PROCEDURAL_RES_M = 5.0


def default_cache_dir() -> Path:
    """Where procedural DEMs are cached: $SKYLOC_CACHE_DIR, else $XDG_CACHE_HOME/skyloc, else ~/.cache/skyloc."""
    env = os.environ.get("SKYLOC_CACHE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "skyloc"


def resolve_dem(spec: str | os.PathLike, *, cache_dir: str | os.PathLike | None = None) -> Path:
    """Path of a DEM given as a file path or ``procedural:PRESET:SEED[:SIZE_M[:RES_M]]``.

    A procedural DEM is synthesised once into ``cache_dir`` (default :func:`default_cache_dir`)
    and reused (same spec, same file).  Default size 20000 m at 5 m.
    """
    s = str(spec)
    if not s.startswith(PROCEDURAL_PREFIX):
        p = Path(s).expanduser()
        if not p.is_file():
            raise DemReadError(f"DEM {s!r} does not exist: give a raster file or procedural:PRESET:SEED[:SIZE_M[:RES_M]]")
        return p
    parts = s[len(PROCEDURAL_PREFIX):].split(":")
    if not 2 <= len(parts) <= 4:
        raise InvalidInputError(f"bad procedural DEM spec {s!r}: use procedural:PRESET:SEED[:SIZE_M[:RES_M]], e.g. procedural:mars:7")
    preset = parts[0].strip().lower()
    try:
        seed = int(parts[1])
        size_m = float(parts[2]) if len(parts) > 2 else DEFAULT_PROCEDURAL_SIZE_M
        res_m = float(parts[3]) if len(parts) > 3 else DEFAULT_PROCEDURAL_RES_M
    except ValueError:
        raise InvalidInputError(f"bad procedural DEM spec {s!r}: SEED must be an integer, SIZE_M and RES_M numbers") from None
    from .procedural import synthesize  # local import: procedural is heavier

    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    cache.mkdir(parents=True, exist_ok=True)
    out = cache / f"procedural_{preset}_s{seed}_{size_m:g}m_{res_m:g}m.tif"
    if not out.is_file():
        synthesize(preset, size_m=size_m, res_m=res_m, seed=seed, out_path=out)
    return out
