"""GDAL's block cache in the API process, sized so that DEM validation runs in bounded memory.

GDAL keeps every block it reads in one process-wide cache, by default 5 % of RAM: validating a huge
sparse GeoTIFF (the nodata scan of :func:`blender_addon.terrain.dem.dem_info` touches every block) grew
the API process by 1.1 GB.  The cache is capped at ``gdal_cache_bytes``.  The scan walks the file block
by block (:mod:`blender_addon.terrain.raster_sample`), so it needs one block in the cache to read each
block once; while one upload is validated the cap is raised by a few of the file's blocks so that even a
file with blocks larger than the cap is not decoded again for every sampled row.  Validations run one at
a time (a lock), so the process never holds more than one such cache.
"""
from __future__ import annotations

import logging
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

log = logging.getLogger(__name__)

_LOCK = threading.Lock()


def set_cache_max(nbytes: int) -> None:
    """Cap GDAL's block cache of this process at ``nbytes`` (no-op without GDAL)."""
    try:
        from osgeo import gdal  # noqa: PLC0415
    except ImportError:  # GDAL is checked when a DEM is uploaded
        return
    gdal.SetCacheMax(int(nbytes))


#: blocks of the file added to the cache while it is validated
VALIDATION_BLOCKS = 4


def block_bytes(path: Path, allowed_drivers: tuple[str, ...]) -> int:
    """Bytes of one block of band 1 of the raster at ``path`` (0 when GDAL cannot open it)."""
    from osgeo import gdal  # noqa: PLC0415

    gdal.UseExceptions()
    try:
        ds = gdal.OpenEx(str(path), gdal.OF_RASTER | gdal.OF_READONLY, allowed_drivers=list(allowed_drivers))
    except RuntimeError:
        return 0  # the validation reports it
    if ds is None or ds.RasterCount < 1:
        return 0
    band = ds.GetRasterBand(1)
    bx, by = band.GetBlockSize()
    itemsize = max(1, gdal.GetDataTypeSize(band.DataType) // 8)
    return max(1, bx) * max(1, by) * itemsize


@contextmanager
def validation_cache(path: Path, *, base_bytes: int, allowed_drivers: tuple[str, ...]) -> Iterator[int]:
    """Hold the validation lock with the cache at ``base_bytes`` + a few blocks of ``path``; yields that size."""
    with _LOCK:
        size = int(base_bytes) + VALIDATION_BLOCKS * block_bytes(path, allowed_drivers)
        set_cache_max(size)
        try:
            yield size
        finally:
            set_cache_max(base_bytes)
