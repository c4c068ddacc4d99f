"""`skyloc dem synth|info|prepare` through the real root group."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from blender_addon.terrain.dem import to_metric_xy
from blender_addon.terrain.multires import load_multires
from skyloc.cli import main


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_synth_then_prepare(tmp_path):
    tif = tmp_path / "t.tif"
    png = tmp_path / "t.png"
    r = run("dem", "synth", "--preset", "mars", "--size", 3000, "--res", 10, "--seed", 7, "--out", tif, "--preview", png)
    assert r.exit_code == 0, r.output
    assert "300 x 300" in r.output and "mars" in r.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = run("dem", "info", tif, "--json")
    info = json.loads(r.output)
    assert info["body"]["name"] == "mars" and info["bounds"] == [-1500.0, -1500.0, 1500.0, 1500.0]
    out = tmp_path / "terrain"
    r = run("dem", "prepare", "--dem", tif, "--center", "100,-200", "--out", out, "--grid-size", 400,
            "--azimuth-step", 2)
    assert r.exit_code == 0, r.output
    t = load_multires(out)
    assert t.site_xy == (100.0, -200.0) and t.meta["grid_half_m"] == 200.0 and t.meta["azimuth_step_deg"] == 2.0
    assert f"| {len(t.levels) - 1} |" in r.output  # one table row per level
    assert (out / "levels.png").read_bytes()[:4] == b"\x89PNG"


def test_prepare_geographic_dem_with_lonlat_center(real_dem, tmp_path):
    path = real_dem("earth_baltoro_karakoram_srtm3.tif")
    out = tmp_path / "b"
    r = run("dem", "prepare", "--dem", path, "--center", "76.4,35.75", "--out", out, "--grid-size", 2000)
    assert r.exit_code == 0, r.output
    t = load_multires(out)
    assert t.body.name == "earth"
    assert np.allclose(t.site_xy, to_metric_xy(76.4, 35.75, dem_path=path))
    # the same site given in another CRS (UTM 43N) lands on the same metric point
    from osgeo import osr

    wgs, utm = osr.SpatialReference(), osr.SpatialReference()
    wgs.ImportFromEPSG(4326)
    utm.ImportFromEPSG(32643)
    wgs.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
    utm.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
    e, n, _ = osr.CoordinateTransformation(wgs, utm).TransformPoint(76.4, 35.75)
    out2 = tmp_path / "b2"
    r = run("dem", "prepare", "--dem", path, "--center", f"{e},{n}", "--crs", "EPSG:32643", "--out", out2,
            "--grid-size", 2000)
    assert r.exit_code == 0, r.output
    assert np.allclose(load_multires(out2).site_xy, t.site_xy, atol=0.01)


@pytest.mark.parametrize(
    "args, message",
    [
        (("--center", "50000,0"), "outside the DEM"),
        (("--center", "12"), "X,Y"),
        (("--center", "0,0", "--body", "pluto"), "unknown body"),
    ],
)
def test_prepare_refusals_exit_nonzero_and_leave_nothing(tmp_path, args, message):
    tif = tmp_path / "t.tif"
    assert run("dem", "synth", "--preset", "moon", "--size", 1000, "--res", 10, "--seed", 1, "--out", tif).exit_code == 0
    out = tmp_path / "never"
    r = CliRunner().invoke(main, ["dem", "prepare", "--dem", str(tif), "--out", str(out), *args])
    assert r.exit_code != 0
    assert message in r.output
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.tif"]


def test_prepare_degrees_without_body_is_refused(tmp_path):
    from osgeo import gdal, osr

    srs = osr.SpatialReference()
    srs.SetGeogCS("Titan", "D_Titan", "Titan", 2575000.0, 0.0)
    p = tmp_path / "titan.tif"
    ds = gdal.GetDriverByName("GTiff").Create(str(p), 50, 50, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((10.0, 0.01, 0, 5.0, 0, -0.01))
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(np.zeros((50, 50), np.float32))
    ds = None
    r = CliRunner().invoke(main, ["dem", "prepare", "--dem", str(p), "--center", "10.25,4.75", "--out",
                                  str(tmp_path / "o"), "--grid-size", "100"])
    assert r.exit_code != 0 and "--body" in r.output
    r = run("dem", "prepare", "--dem", p, "--center", "10.25,4.75", "--out", tmp_path / "o", "--grid-size", 100,
            "--body", 2575000)
    assert r.exit_code == 0, r.output
    assert load_multires(tmp_path / "o").body.radius_m == 2575000.0
