"""GDAL's block cache in the API process, sized so that DEM validation runs in bounded memory.

GDAL keeps every block it reads in one process-wide cache, by default 5 % of RAM: validating a huge
sparse GeoTIFF (the decimated nodata scan of :func:`blender_addon.terrain.dem.dem_info` touches every
block) grew the API process by 1.1 GB.  The cache is capped at ``gdal_cache_bytes``; while one upload is
validated it is raised by one row of the file's blocks, so that the scan, which walks the raster row by
row, reads each block once instead of re-reading evicted ones (a cache smaller than a block row made
the 30000 x 30000 scan about 4 times slower).  Validations
run one at a time (a lock), so the process never holds more than one such cache.
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


def block_row_bytes(path: Path, allowed_drivers: tuple[str, ...]) -> int:
    """Bytes of one row of band 1's blocks of the raster at ``path`` (0 when GDAL cannot open it)."""
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
    return -(-ds.RasterXSize // max(1, bx)) * bx * by * itemsize


@contextmanager
def validation_cache(path: Path, *, base_bytes: int, allowed_drivers: tuple[str, ...]) -> Iterator[int]:
    """Hold the validation lock with the cache at ``base_bytes`` + one block row of ``path``; yields that size."""
    with _LOCK:
        size = int(base_bytes) + block_row_bytes(path, allowed_drivers)
        set_cache_max(size)
        try:
            yield size
        finally:
            set_cache_max(base_bytes)
