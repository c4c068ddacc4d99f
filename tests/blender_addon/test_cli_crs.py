"""CRS honesty at the command line (issue 13 point 3): what was assumed, and the fix, in every message."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from skyloc.cli import main

gdal = pytest.importorskip("osgeo.gdal")
osr = pytest.importorskip("osgeo.osr")


def _tif(path, gt, epsg: int | None, n: int = 120):
    """A small hilly GeoTIFF with geotransform ``gt`` and CRS EPSG ``epsg`` (None: no CRS)."""
    ds = gdal.GetDriverByName("GTiff").Create(str(path), n, n, 1, gdal.GDT_Float32)
    ds.SetGeoTransform(gt)
    if epsg is not None:
        srs = osr.SpatialReference()
        srs.ImportFromEPSG(epsg)
        ds.SetProjection(srs.ExportToWkt())
    yy, xx = np.mgrid[0:n, 0:n] / n
    ds.GetRasterBand(1).WriteArray((300 * np.sin(6 * xx) * np.cos(5 * yy) + 400).astype(np.float32))
    ds = None
    return path


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_dem_info_prints_bounds_in_the_crs_at_expects(tmp_path):
    geo = _tif(tmp_path / "geo.tif", (10.0, 0.001, 0, 45.12, 0, -0.001), 4326)
    r = run("dem", "info", geo)
    assert r.exit_code == 0, r.output
    # the file's own lon/lat extent, from the geotransform written above
    assert "lon 10.000000..10.120000, lat 45.000000..45.120000 deg" in r.output
    assert "(what --at / --center expect)" in r.output and "working     x" in r.output
    d = json.loads(run("dem", "info", geo, "--json").output)
    np.testing.assert_allclose(d["source_bounds"], [10.0, 45.0, 10.12, 45.12])
    utm = _tif(tmp_path / "utm.tif", (500000.0, 30.0, 0, 5000000.0, 0, -30.0), 32633)
    r = run("dem", "info", utm)
    assert "x 500000.00..503600.00, y 4996400.00..5000000.00 m in WGS 84 / UTM zone 33N" in r.output


def test_projected_numbers_given_as_lonlat_say_what_was_assumed(tmp_path):
    utm = _tif(tmp_path / "utm.tif", (500000.0, 30.0, 0, 5000000.0, 0, -30.0), 32633)
    r = run("db", "horizon", "--dem", utm, "--at", "501800,4998200", "--crs", "EPSG:4326")
    assert r.exit_code == 1
    assert "taken as lon,lat in EPSG:4326" in r.output and "look like projected metres" in r.output
    assert "--crs EPSG:326" in r.output
    geo = _tif(tmp_path / "geo.tif", (10.0, 0.001, 0, 45.12, 0, -0.001), 4326)
    r = run("db", "horizon", "--dem", geo, "--at", "501800,4998200")
    assert r.exit_code == 1 and "the DEM's own CRS" in r.output and "lon,lat in degrees" in r.output
    # the same point given right: in the DEM's CRS, and in lon,lat with --crs
    r = run("db", "horizon", "--dem", utm, "--at", "501800,4998200", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["crs_name"] == "WGS 84 / UTM zone 33N"


def test_db_render_has_the_assume_metric_the_no_crs_message_offers(tmp_path):
    raw = _tif(tmp_path / "raw.tif", (0.0, 5.0, 0, 600.0, 0, -5.0), None)
    r = run("db", "horizon", "--dem", raw, "--at", "300,300")
    assert r.exit_code == 1 and "--assume-metric" in r.output
    r = run("db", "horizon", "--dem", raw, "--at", "300,300", "--assume-metric", "--body", "mars", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["x"] == pytest.approx(300.0)
    out = tmp_path / "db.zarr"
    r = run("db", "render", "--dem", raw, "--center", "300,300", "--size", 20, "--step", 10, "--out", out,
            "--assume-metric", "--body", "mars", "--no-progress")
    assert r.exit_code == 0, r.output
    assert "positions (skyloc locate's x, y) are metres in" in r.output and out.is_dir()
