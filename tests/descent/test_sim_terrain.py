"""Lander-scale Europa terrain: the memorandum's relief, determinism, albedo maps, DEM files."""
import numpy as np
import pytest

from blender_addon.descent.constants import EUROPA_ALBEDO
from blender_addon.descent.terrain import load_terrain, procedural_europa
from board.errors import InvalidInputError


def test_procedural_terrain_has_the_memorandum_relief_and_is_reproducible():
    a = procedural_europa(4, size_m=100.0, res_m=0.5)
    assert a.shape == (201, 201) and a.bounds == (-50.0, -50.0, 50.0, 50.0)
    assert a.height.min() == 0.0 and a.height.max() == pytest.approx(31.7, abs=1e-4)
    assert a.sha256 == procedural_europa(4, size_m=100.0, res_m=0.5).sha256
    assert a.sha256 != procedural_europa(5, size_m=100.0, res_m=0.5).sha256
    # albedo centred on Europa's with splotches and darker striae
    assert np.median(a.albedo) == pytest.approx(EUROPA_ALBEDO, rel=0.05)
    assert a.albedo.min() < 0.8 * EUROPA_ALBEDO and a.albedo.std() > 0.02
    n = a.normals()
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-6)
    assert (n[..., 2] > 0).all()


def test_normals_of_a_plane():
    from blender_addon.descent.terrain import DescentTerrain

    ix, iy = np.meshgrid(np.arange(20), np.arange(15))
    plane = DescentTerrain(0.1 * ix * 0.5 - 0.2 * iy * 0.5, np.full((15, 20), 0.6), 0.0, 0.0, 0.5, "plane")
    want = np.array([-0.1, 0.2, 1.0]) / np.linalg.norm([-0.1, 0.2, 1.0])      # z = 0.1 x - 0.2 y
    np.testing.assert_allclose(plane.normals(), np.broadcast_to(want, (15, 20, 3)), atol=1e-6)


def test_height_at_is_bilinear_between_nodes():
    t = procedural_europa(1, size_m=40.0, res_m=1.0)
    x, y = t.x0 + 3.25, t.y0 + 7.5
    h = t.height
    expect = 0.75 * (0.5 * h[7, 3] + 0.5 * h[8, 3]) + 0.25 * (0.5 * h[7, 4] + 0.5 * h[8, 4])
    assert t.height_at(x, y) == pytest.approx(expect, rel=1e-6)
    assert np.isnan(t.height_at(t.x0 - 1.0, y))


def test_a_dem_file_keeps_its_coordinates_and_heights(tmp_path):
    pytest.importorskip("osgeo")
    from osgeo import gdal

    from blender_addon.terrain.procedural import synthesize

    path = synthesize("europa", size_m=160.0, res_m=2.0, seed=3, out_path=tmp_path / "e.tif")
    t = load_terrain(str(path))
    ds = gdal.Open(str(path))
    gt = ds.GetGeoTransform()
    z = ds.GetRasterBand(1).ReadAsArray()
    # GDAL pixel (row 5, col 9) centre = node (ix 9, iy rows - 1 - 5)
    x = gt[0] + 9.5 * gt[1]
    y = gt[3] + 5.5 * gt[5]
    assert t.height_at(x, y) == pytest.approx(float(z[5, 9]), abs=1e-4)
    assert t.res_m == 2.0 and t.spec == str(path)


@pytest.mark.parametrize("spec, match", [("procedural:mars:1", "procedural:europa:SEED"),
                                         ("procedural:europa:x", "SEED must be an integer")])
def test_bad_terrain_specs_are_refused(spec, match):
    with pytest.raises(InvalidInputError, match=match):
        load_terrain(spec)
