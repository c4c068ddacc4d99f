"""The Blender skyline renderer: column boundaries (bpy-free), then render_tile against the
brute-force reference and the ray-marcher on a real DEM, and `--renderer blender` selection."""
from __future__ import annotations

import numpy as np
import pytest

from blender_addon.skyline_renderer import bracket_band, column_boundaries, sample_columns


def _band_image(boundary_rows: np.ndarray, h: int) -> np.ndarray:
    """Coverage image: row r of column c is terrain where r + 1 > boundary (fractional pixel at the edge)."""
    r = np.arange(h)[:, None]
    return np.clip(r + 1 - boundary_rows[None, :], 0.0, 1.0)


def test_column_boundaries_sub_pixel_from_coverage():
    rng = np.random.default_rng(0)
    b = rng.uniform(3.0, 40.0, 50)                              # boundary, rows from the top edge
    el, clipped, empty = column_boundaries(_band_image(b, 60), 10.0, 0.1)
    np.testing.assert_allclose(el, 10.0 - 0.1 * b, atol=1e-9)
    assert not clipped.any() and not empty.any()


def test_column_boundaries_binary_is_within_half_a_pixel():
    rng = np.random.default_rng(1)
    b = rng.uniform(3.0, 40.0, 200)
    centres = np.arange(60)[:, None] + 0.5
    img = (centres > b[None, :]).astype(float)                  # centre-sampled binary image
    el, _, _ = column_boundaries(img, 0.0, 0.1)
    assert np.max(np.abs(el - (-0.1 * b))) <= 0.05 + 1e-12


def test_column_boundaries_flags_clipped_and_empty_columns():
    img = np.zeros((10, 3))
    img[:, 0] = 1.0                                             # all terrain: boundary above the band
    img[5:, 1] = 1.0
    el, clipped, empty = column_boundaries(img, 5.0, 1.0)
    assert clipped.tolist() == [True, False, False] and empty.tolist() == [False, False, True]
    assert el[1] == 0.0 and el[2] == -5.0


def test_bracket_band_contains_every_boundary():
    rng = np.random.default_rng(2)
    true_el = rng.uniform(-20, 35, 100)
    rows = np.arange(180)[:, None]
    img = ((90.0 - (rows + 0.5)) < true_el[None, :]).astype(float)   # 1 deg rows, centre-sampled
    lo, hi = bracket_band(img, 1.0, pad_deg=0.0)
    assert lo <= true_el.min() and hi >= true_el.max() and hi - lo <= np.ptp(true_el) + 2.0


def test_sample_columns_is_periodic_linear_interpolation():
    az = np.arange(0, 360, 10.0)
    el = np.sin(np.radians(az))
    out = sample_columns(az, el, np.array([5.0, 355.0, 0.0]))
    np.testing.assert_allclose(out, [(el[0] + el[1]) / 2, (el[-1] + el[0]) / 2, el[0]])


def test_blender_renderer_is_selectable():
    from blender_addon import skyline_renderer
    from render_service.renderers import blender
    from render_service.renderers.base import get_renderer

    assert get_renderer("blender") is blender.render_tile
    # the database records the add-on renderer's version through the service's adapter
    assert blender.__version__ == skyline_renderer.__version__


@pytest.mark.blender
@pytest.mark.realdem
@pytest.mark.slow
def test_render_tile_matches_brute_force_and_ray_marcher_on_a_real_dem(real_dem):
    """St Helens (30 m cells, one level): Blender at 0.1 deg/px vs the brute-force reference (bilinear,
    0.3 m steps: fine enough for horizons a few metres away) and the ray-marcher.

    The ray-marcher (renderer v2) searches its near field exactly, so it is held to the same
    tolerance as the reference.
    """
    pytest.importorskip("bpy")
    from blender_addon.skyline_renderer import render_tile
    from blender_addon.terrain.dem import read_dem
    from blender_addon.terrain.model import MultiResTerrain, TerrainLevel
    from board.skydb import GridSpec, plan_tiles
    from render_service.renderers import raymarch, reference
    from render_service.renderers.base import RenderSpec

    dem = read_dem(real_dem("earth_sthelens_1980_usgs30m.dem"))
    gt = dem.geotransform
    xmin, ymin, xmax, ymax = dem.bounds()
    site = (xmin + 0.45 * (xmax - xmin), ymin + 0.55 * (ymax - ymin))
    terrain = MultiResTerrain([TerrainLevel(dem.array, gt[0], gt[3], gt[1])], dem.crs_wkt, dem.body, site,
                              meta={"grid_half_m": 300.0})
    grid = GridSpec.from_center(site, 600.0, 600.0)             # 2 x 2 positions
    tile = plan_tiles(grid, 2)[0]
    spec = RenderSpec(camera_height_m=2.0, body_radius_m=dem.body.radius_m)
    bl = render_tile(terrain, grid, tile, spec).elevation_deg
    rm = raymarch.render_tile(terrain, grid, tile, spec).elevation_deg
    xs, ys = grid.xy(*np.meshgrid(np.arange(2), np.arange(2), indexing="ij"))
    bf = np.stack([reference.brute_force_horizon(dem, x, y, spec, step_cells=0.01)[1]
                   for x, y in zip(xs.ravel(), ys.ravel())]).reshape(bl.shape)
    d_ref = np.abs(bl - bf).ravel()
    assert np.median(d_ref) <= 0.05 and np.percentile(d_ref, 99) <= 0.25
    d_rm = np.abs(bl - rm).ravel()
    assert np.median(d_rm) <= 0.05 and np.percentile(d_rm, 99) <= 0.25


@pytest.mark.blender
def test_band_reuse_gives_the_same_skyline_as_a_fresh_coarse_pass():
    """The previous position's band is only a guess: results do not depend on the rendering order."""
    pytest.importorskip("bpy")
    from blender_addon import skyline_renderer as sr
    from blender_addon.terrain.model import MultiResTerrain, TerrainLevel
    from board.conventions import BODIES

    n, cell = 200, 1.0
    c = -100 + (np.arange(n) + 0.5) * cell
    X, Y = np.meshgrid(c, -c)
    z = 12 * np.exp(-(((np.hypot(X, Y) - 60) / 8) ** 2)) + 25 * (X > 80)   # rim + a cliff to the east
    terrain = MultiResTerrain([TerrainLevel(z.astype(np.float32), -100, 100, cell)], "", BODIES["mars"], (0, 0))
    az = np.arange(0, 360, 2.0)
    kw = dict(camera_height_m=2.0, radius_m=BODIES["mars"].radius_m, refine_half_m=30.0)
    sr._SESSION.last_band = None
    fresh = sr.render_position(terrain, 20.0, 5.0, az, **kw)[0]
    sr._SESSION.last_band = (-30.0, -29.0)                        # a wrong guess: must fall back
    wrong = sr.render_position(terrain, 20.0, 5.0, az, **kw)[0]
    sr.render_position(terrain, -20.0, -10.0, az, **kw)           # a neighbour's band
    reused = sr.render_position(terrain, 20.0, 5.0, az, **kw)[0]
    np.testing.assert_array_equal(fresh, wrong)
    np.testing.assert_array_equal(fresh, reused)
    assert np.ptp(fresh) > 5.0
