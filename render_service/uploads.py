"""DEM upload validation: safe file names, allowed GDAL drivers, size limits, then the terrain rules.

No HTTP here.  A DEM is accepted only if GDAL opens it with one of :data:`ALLOWED_DRIVERS`
(self-contained raster formats: no VRT or label formats that could point at other server files),
its declared size is within the limit, and :func:`blender_addon.terrain.dem.dem_info` accepts it
(metric CRS, or degrees on a known body; nodata within bounds).
"""
from __future__ import annotations

import logging
import re
from pathlib import Path

from board.conventions import body_from_name
from board.errors import DemReadError, InvalidInputError, NoDataError
from render_service.settings import ServiceSettings

log = logging.getLogger(__name__)

#: GDAL drivers accepted for uploads (single-file formats that cannot reference other files).
ALLOWED_DRIVERS = ("GTiff", "COG", "USGSDEM", "AAIGrid", "HFA")
ALLOWED_SUFFIXES = (".tif", ".tiff", ".dem", ".asc", ".img")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
MAX_NODATA_FRACTION = 0.5


def safe_filename(name: str | None) -> str:
    """The upload's file name if it is a plain name with an allowed suffix (InvalidInputError otherwise)."""
    if not name:
        raise InvalidInputError("the upload has no file name: send the DEM as multipart field 'file' with a name")
    if "/" in name or "\\" in name or ".." in name or not _NAME.match(name):
        raise InvalidInputError(f"file name {name!r} is not allowed: use a plain name of letters, digits, '.', '_' "
                                "or '-' (no folders, no '..')")
    if Path(name).suffix.lower() not in ALLOWED_SUFFIXES:
        raise InvalidInputError(f"file name {name!r} has an unsupported suffix: upload one of "
                                f"{', '.join(ALLOWED_SUFFIXES)}")
    return name


def check_body(body: str | None) -> str | None:
    """Validate an optional body name or radius (InvalidInputError with the choices)."""
    if body is None or body == "":
        return None
    body_from_name(body)
    return body


def precheck_raster(path: Path, settings: ServiceSettings) -> None:
    """Open with the allowed drivers only and check the declared size before anything reads pixels."""
    from osgeo import gdal  # noqa: PLC0415

    gdal.UseExceptions()
    previous = gdal.GetThreadLocalConfigOption("GDAL_DISABLE_READDIR_ON_OPEN", None)
    gdal.SetThreadLocalConfigOption("GDAL_DISABLE_READDIR_ON_OPEN", "EMPTY_DIR")
    try:
        ds = gdal.OpenEx(str(path), gdal.OF_RASTER | gdal.OF_READONLY, allowed_drivers=list(ALLOWED_DRIVERS))
    except RuntimeError as exc:
        raise DemReadError(f"the upload is not a readable DEM ({_short(exc)}): upload a GeoTIFF, USGS DEM, "
                           "Arc/Info ASCII grid or Erdas Imagine raster") from None
    finally:
        gdal.SetThreadLocalConfigOption("GDAL_DISABLE_READDIR_ON_OPEN", previous)
    if ds is None:
        raise DemReadError("the upload is not a readable DEM: upload a GeoTIFF, USGS DEM, Arc/Info ASCII grid "
                           "or Erdas Imagine raster")
    cols, rows, bands = ds.RasterXSize, ds.RasterYSize, ds.RasterCount
    driver = ds.GetDriver().ShortName
    ds = None
    if bands < 1:
        raise DemReadError("the upload has no raster band: upload a single-band DEM")
    if cols * rows > settings.max_dem_pixels:
        raise InvalidInputError(f"the DEM declares {cols} x {rows} = {cols * rows} cells, more than this server's "
                                f"limit of {settings.max_dem_pixels}: crop or resample it before uploading")
    log.debug("upload opened by GDAL driver %s, %d x %d", driver, cols, rows)


def validate_dem(path: Path, *, body: str | None, settings: ServiceSettings) -> dict:
    """Validate a stored upload and return its JSON-able summary (DemInfo.to_json_dict)."""
    from blender_addon.terrain.dem import dem_info  # noqa: PLC0415

    precheck_raster(path, settings)
    try:
        info = dem_info(path, body=body)
    except RuntimeError as exc:  # a GDAL error the importer did not translate
        raise DemReadError(f"GDAL cannot read the DEM ({_short(exc)}): check the file") from None
    if info.nodata_fraction > MAX_NODATA_FRACTION:
        raise NoDataError(f"{100 * info.nodata_fraction:.0f}% of the DEM is nodata (limit "
                          f"{100 * MAX_NODATA_FRACTION:.0f}%): upload a DEM with heights over the search area")
    d = info.to_json_dict()
    d.pop("path", None)
    return d


def _short(exc: Exception) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    # GDAL messages name the server-side path: keep only the reason
    return re.sub(r"(?<![\w.])(/[\w.+-]+){2,}", "<file>", text)[:300]
