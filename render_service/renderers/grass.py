"""Horizons from GRASS GIS ``r.horizon`` (raster mode): an independent implementation for cross-checks.

Used by the tests and the benchmark only.  GRASS runs in a throw-away location created from a
GeoTIFF of the DEM in its metric working CRS; ``r.horizon`` computes, for every cell of a small
region around the requested points (reading the DEM ``bufferzone`` metres around it), the horizon
angle in each direction.  Its conventions differ from skyloc's:

* directions are degrees counter-clockwise from east; they are converted here to azimuths
  clockwise from grid north with :func:`board.conventions.az_from_en_deg`;
* the observer is at the cell's own height (no camera height) at the cell centre;
* the march uses one-cell steps (``distance=1``).
"""
from __future__ import annotations

import logging
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from blender_addon.terrain.model import DemRaster
from board.conventions import az_from_en_deg
from board.errors import InvalidInputError, SkylocError

log = logging.getLogger(__name__)


@dataclass
class GrassHorizons:
    """r.horizon results at points.

    azimuth_deg : (n_dir,) clockwise from grid north, sorted ascending
    elevation_deg : (n_points, n_dir) horizon angle, degrees
    label_ccw_east_deg : (n_dir,) the direction labels r.horizon gave (CCW from east), same order
    n_cells : cells of the region r.horizon computed
    seconds : wall time of the r.horizon call alone
    """

    azimuth_deg: np.ndarray
    elevation_deg: np.ndarray
    label_ccw_east_deg: np.ndarray
    n_cells: int
    seconds: float


def grass_available() -> bool:
    """True when the ``grass`` launcher is on PATH."""
    return shutil.which("grass") is not None


def write_geotiff(dem: DemRaster, path: Path) -> Path:
    """Write a DemRaster as a Float32 GeoTIFF in its metric CRS (NaN nodata)."""
    from osgeo import gdal  # noqa: PLC0415

    rows, cols = dem.array.shape
    ds = gdal.GetDriverByName("GTiff").Create(str(path), cols, rows, 1, gdal.GDT_Float32)
    ds.SetGeoTransform(dem.geotransform)
    ds.SetProjection(dem.crs_wkt)
    band = ds.GetRasterBand(1)
    band.SetNoDataValue(float("nan"))
    band.WriteArray(np.asarray(dem.array, dtype=np.float32))
    ds = None
    return path


def r_horizon(dem: DemRaster, points_xy, *, step_deg: float = 1.0, workdir=None,
              timeout_s: float = 1800.0) -> GrassHorizons:
    """Run ``r.horizon`` over the cells around ``points_xy`` (metres, DEM CRS) and sample it there.

    The region is the bounding box of the points, snapped to the DEM's cells; the buffer covers
    the whole DEM, so every horizon sees the same terrain as skyloc's renderers.
    """
    if not grass_available():
        raise SkylocError("GRASS GIS is not installed (apt install grass-core)")
    pts = np.atleast_2d(np.asarray(points_xy, dtype=float))
    xmin, ymin, xmax, ymax = dem.bounds()
    c = dem.cell_m
    if np.any((pts[:, 0] <= xmin) | (pts[:, 0] >= xmax) | (pts[:, 1] <= ymin) | (pts[:, 1] >= ymax)):
        raise InvalidInputError("every point must lie inside the DEM")
    tmp = Path(tempfile.mkdtemp(prefix="skyloc-grass-", dir=workdir))
    try:
        tif = write_geotiff(dem, tmp / "dem.tif")
        n, s = pts[:, 1].max() + c / 2, pts[:, 1].min() - c / 2
        e, w = pts[:, 0].max() + c / 2, pts[:, 0].min() - c / 2
        buffer_m = max(xmax - xmin, ymax - ymin)
        coords = ",".join(f"{x!r},{y!r}" for x, y in pts)
        script = tmp / "run.sh"
        script.write_text(
            "set -e\n"
            f"r.in.gdal -o input={tif} output=dem --quiet\n"
            "g.region raster=dem\n"
            f"g.region n={n!r} s={s!r} e={e!r} w={w!r} align=dem\n"
            "g.region -g | grep '^cells='\n"
            "t0=$(date +%s%N)\n"
            f"r.horizon -d elevation=dem step={step_deg!r} bufferzone={buffer_m!r} distance=1.0 output=hor --quiet\n"
            "t1=$(date +%s%N)\n"
            "echo \"milliseconds=$(( (t1 - t0) / 1000000 ))\"\n"
            "echo \"maps=$(g.list raster pattern='hor_*' sep=comma)\"\n"
            f"r.what map=$(g.list raster pattern='hor_*' sep=comma) coordinates={coords} separator=comma\n"
        )
        proc = subprocess.run(["grass", "--tmp-location", str(tif), "--exec", "bash", str(script)],
                              capture_output=True, text=True, timeout=timeout_s)
        if proc.returncode != 0:
            raise SkylocError(f"r.horizon failed ({proc.returncode}): {proc.stderr[-2000:]}")
        out = proc.stdout
        n_cells = int(re.search(r"^cells=(\d+)", out, re.M).group(1))
        seconds = int(re.search(r"^milliseconds=(\d+)", out, re.M).group(1)) / 1000.0
        maps = re.search(r"^maps=(.*)$", out, re.M).group(1).split(",")
        labels = np.array([float(m[len("hor_"):].replace("_", ".")) for m in maps])
        rows = [ln for ln in out.splitlines() if ln.count(",") >= len(maps) + 2]
        vals = np.array([[float(v) if v not in ("", "*") else np.nan for v in ln.split(",")[3:3 + len(maps)]]
                         for ln in rows])
        if vals.shape != (len(pts), len(maps)):
            raise SkylocError(f"unexpected r.what output: {vals.shape} for {len(pts)} points, {len(maps)} maps")
        az = az_from_en_deg(np.cos(np.radians(labels)), np.sin(np.radians(labels)))
        order = np.argsort(az)
        return GrassHorizons(np.asarray(az)[order], vals[:, order], labels[order], n_cells, seconds)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
