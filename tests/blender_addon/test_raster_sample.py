"""Block-by-block grid sampling of a raster band (blender_addon.terrain.raster_sample) against brute force.

The truth is the whole array read at once and indexed at the same grid; the layouts are the ones DEMs
come in: tiled GeoTIFFs (tiles not dividing the size), striped ones (one row and many rows per strip),
and a single-strip file.
"""
from __future__ import annotations

import numpy as np
import pytest

gdal = pytest.importorskip("osgeo.gdal")

from blender_addon.terrain.raster_sample import grid_indices, sample_grid  # noqa: E402


def _write(path, a, options):
    gdal.UseExceptions()
    ds = gdal.GetDriverByName("GTiff").Create(str(path), a.shape[1], a.shape[0], 1, gdal.GDT_Float32,
                                              options=options)
    ds.GetRasterBand(1).WriteArray(a)
    ds.GetRasterBand(1).SetNoDataValue(-9999)
    ds.FlushCache()
    ds = None
    return gdal.Open(str(path))


@pytest.mark.parametrize("options", [
    ["TILED=YES", "BLOCKXSIZE=256", "BLOCKYSIZE=128", "COMPRESS=DEFLATE"],
    ["TILED=YES", "BLOCKXSIZE=16", "BLOCKYSIZE=16"],
    ["ROWSPERSTRIP=1"],
    ["ROWSPERSTRIP=37", "COMPRESS=LZW"],
    ["ROWSPERSTRIP=100000"],  # one strip: the whole raster is one block
])
@pytest.mark.parametrize("max_cells", [50, 2_000, 10**9])
def test_sample_grid_equals_the_whole_array_at_the_grid(tmp_path, options, max_cells):
    rng = np.random.default_rng(7)
    a = rng.normal(size=(301, 517)).astype(np.float32)
    ds = _write(tmp_path / "a.tif", a, options)
    got = sample_grid(ds.GetRasterBand(1), max_cells=max_cells)
    full = ds.GetRasterBand(1).ReadAsArray()
    k = max(1.0, np.sqrt(a.size / max_cells))
    ri, ci = grid_indices(301, int(301 / k)), grid_indices(517, int(517 / k))
    np.testing.assert_array_equal(got, full[np.ix_(ri, ci)])
    assert got.size <= max_cells or max_cells >= a.size
    if max_cells >= a.size:
        np.testing.assert_array_equal(got, a)  # no decimation: every pixel


def test_grid_indices_are_strip_centres():
    np.testing.assert_array_equal(grid_indices(10, 5), [1, 3, 5, 7, 9])
    np.testing.assert_array_equal(grid_indices(7, 7), np.arange(7))
    assert grid_indices(3, 10).tolist() == [0, 1, 2]  # never more samples than pixels
    assert grid_indices(1000, 1).tolist() == [500]


def test_dem_info_nodata_fraction_matches_the_exact_share(tmp_path):
    """A DEM whose left 30 % and a diagonal band are nodata: the sampled share is the exact one to 1 %."""
    from osgeo import osr

    from blender_addon.terrain.dem import dem_info

    rows, cols = 900, 1400
    y, x = np.mgrid[0:rows, 0:cols]
    a = (100 + 0.1 * x + 0.05 * y).astype(np.float32)
    miss = (x < 0.3 * cols) | (np.abs(x - y) < 40)
    a[miss] = -9999
    gdal.UseExceptions()
    ds = gdal.GetDriverByName("GTiff").Create(str(tmp_path / "d.tif"), cols, rows, 1, gdal.GDT_Float32,
                                              options=["TILED=YES", "BLOCKXSIZE=128", "BLOCKYSIZE=128"])
    ds.SetGeoTransform((500000, 10, 0, 4000000, 0, -10))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32633)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(a)
    ds.GetRasterBand(1).SetNoDataValue(-9999)
    ds = None
    info = dem_info(tmp_path / "d.tif", sample_cells=20_000)
    assert info.nodata_fraction == pytest.approx(miss.mean(), abs=0.01)
