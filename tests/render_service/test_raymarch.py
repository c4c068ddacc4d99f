"""Ray-march renderer against analytic geometry and the brute-force reference.

Terrains here are analytic functions sampled at the cell centres of nested levels (the
renderer's MultiResTerrain input), so the truth comes from the geometry, not from a DEM.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from skyloc_service_test_helpers import analytic_terrain

from blender_addon.terrain.model import DemRaster, MultiResTerrain, TerrainLevel
from board.conventions import BODIES, Body, horizon_dip_deg
from board.errors import InvalidInputError
from board.skydb import GridSpec, plan_tiles
from render_service.renderers import raymarch
from render_service.renderers.base import RenderSpec, get_renderer
from render_service.renderers.reference import accurate_horizon_with_distance, brute_force_horizon_with_distance


def ray_truth(fn, x, y, z_eye, az_deg, c_per_m, d_max, n=200_000):
    """Exact horizon tangent max along each azimuth of the analytic surface (dense 1-D search)."""
    d = np.linspace(d_max / n, d_max, n)
    out = []
    for a in np.radians(np.atleast_1d(az_deg)):
        z = fn(x + d * math.sin(a), y + d * math.cos(a))
        out.append(np.degrees(np.arctan(np.max((z - z_eye - c_per_m * d * d) / d))))
    return np.array(out)


@pytest.mark.parametrize("radius_m,height_m", [(100e3, 20.0), (BODIES["mars"].radius_m, 60.0)])
def test_flat_plane_on_sphere_dips_by_acos(radius_m, height_m):
    terrain = analytic_terrain(lambda X, Y: np.zeros_like(X), [(400, 1.0), (4000, 10.0), (40000, 100.0)],
                               radius_m=radius_m)
    spec = RenderSpec(camera_height_m=height_m, n_azimuth=72, body_radius_m=radius_m)
    az, el, dist = raymarch.horizon_at(terrain, 3.0, -7.0, spec)
    dip = horizon_dip_deg(height_m, radius_m)            # acos(R / (R + h))
    np.testing.assert_allclose(el, -dip, atol=2e-3 * dip + 1e-4)
    # the tangent point lies at sqrt(2 R h) (to within the sampling of a flat maximum)
    np.testing.assert_allclose(dist, math.sqrt(2 * radius_m * height_m), rtol=0.1)


def test_refraction_flattens_the_sphere():
    r, h, k = 100e3, 20.0, 0.13
    terrain = analytic_terrain(lambda X, Y: np.zeros_like(X), [(400, 1.0), (4000, 10.0), (40000, 100.0)])
    spec = RenderSpec(camera_height_m=h, n_azimuth=8, body_radius_m=r, refraction_k=k)
    _, el, _ = raymarch.horizon_at(terrain, 0.0, 0.0, spec)
    np.testing.assert_allclose(el, -horizon_dip_deg(h, r / (1 - k)), rtol=3e-3)


def test_plateau_wall_seen_off_centre_at_every_azimuth():
    """Flat floor inside a circle of radius D, a plateau of height H outside it; observer off-centre."""
    D, H, h, R = 300.0, 60.0, 2.0, 1e5
    c = 1.0 / (2 * R)
    cell = 1.0

    def fn(X, Y):
        return np.where(np.hypot(X, Y) >= D, H, 0.0)

    terrain = analytic_terrain(fn, [(420, cell), (3000, 10.0)], radius_m=R)
    ox, oy = 120.0, -45.0
    spec = RenderSpec(camera_height_m=h, n_azimuth=360, body_radius_m=R)
    az, el, dist = raymarch.horizon_at(terrain, ox, oy, spec)
    u = np.stack([np.sin(np.radians(az)), np.cos(np.radians(az))], axis=1)   # clockwise from north
    ou = u @ np.array([ox, oy])
    t = -ou + np.sqrt(ou**2 - (ox**2 + oy**2) + D**2)                       # distance to the circle
    # the sampled edge is a bilinear ramp up to 1.5 cells either side of the circle, and the march
    # samples it every cell at most (the step at these distances): the first full-height sample
    # lies within 2.5 cells beyond the circle
    hi = np.degrees(np.arctan((H - h - c * (t - 1.5 * cell) ** 2) / (t - 1.5 * cell)))
    lo = np.degrees(np.arctan((H - h - c * (t + 2.5 * cell) ** 2) / (t + 2.5 * cell)))
    assert np.all(el <= hi + 1e-4) and np.all(el >= lo - 1e-4)
    np.testing.assert_allclose(dist, t, atol=2.5 * cell)
    # the wall is nearest (highest) towards the offset, azimuth atan2(east, north) = 110.6 deg
    assert el[111] > el[291] + 5.0


def test_crater_seen_from_its_centre():
    """Parabolic bowl with a rim at Rr (height Hr) and an outer flank falling off: the rim is the horizon."""
    Rr, Hr, W, h = 400.0, 80.0, 300.0, 2.0
    R = BODIES["moon"].radius_m
    c = 1.0 / (2 * R)

    def fn(X, Y):
        r = np.hypot(X, Y)
        return np.where(r <= Rr, Hr * (r / Rr) ** 2, Hr * np.clip(1 - (r - Rr) / W, 0, 1))

    terrain = analytic_terrain(fn, [(600, 1.0), (3000, 8.0), (20000, 50.0)], radius_m=R)
    spec = RenderSpec(camera_height_m=h, n_azimuth=90, body_radius_m=R)
    _, el, dist = raymarch.horizon_at(terrain, 0.0, 0.0, spec)
    expected = math.degrees(math.atan2(Hr - h - c * Rr**2, Rr))
    # a bilinear surface cuts the rim's kink by at most slope x cell: 0.4 m at 400 m = 0.06 degree
    np.testing.assert_allclose(el, expected, atol=0.06)
    np.testing.assert_allclose(dist, Rr, atol=2.0)


def test_observer_on_a_summit_sees_a_negative_horizon():
    """Smooth summit z = -s sqrt(r^2 + a^2): every azimuth looks down; truth from a dense 1-D search."""
    s, a, h, R = 0.08, 50.0, 3.0, 2e5
    c = 1.0 / (2 * R)

    def fn(X, Y):
        return -s * np.sqrt(X**2 + Y**2 + a**2)

    terrain = analytic_terrain(fn, [(500, 1.0), (5000, 10.0), (30000, 100.0)], radius_m=R)
    spec = RenderSpec(camera_height_m=h, n_azimuth=24, body_radius_m=R)
    az, el, _ = raymarch.horizon_at(terrain, 0.0, 0.0, spec)
    truth = ray_truth(fn, 0.0, 0.0, fn(0.0, 0.0) + h, az, c, 29000.0)
    assert np.all(el < 0)
    # coarse levels are point samples of the same surface: agreement to a few thousandths of a degree
    np.testing.assert_allclose(el, truth, atol=0.01)


def _fractal(n, seed, amp, cell):
    rng = np.random.default_rng(seed)
    f = np.fft.fftfreq(n)
    k = np.hypot(*np.meshgrid(f, f))
    k[0, 0] = 1.0
    spec = rng.normal(size=(n, n)) + 1j * rng.normal(size=(n, n))
    z = np.real(np.fft.ifft2(spec / k**1.8))
    return (amp * (z - z.mean()) / z.std()).astype(np.float32)


def _one_level(n: int, cell: float, *, seed: int, amp: float):
    """A centred single-level fractal terrain on a 1000 km body, as a MultiResTerrain and as a DemRaster."""
    z = _fractal(n, seed=seed, amp=amp, cell=cell)
    x0, y0 = -n * cell / 2, n * cell / 2
    body = Body("custom", 1e6)
    return (MultiResTerrain([TerrainLevel(z, x0, y0, cell)], "", body, (0.0, 0.0)),
            DemRaster(z, (x0, cell, 0.0, y0, 0.0, -cell), "", body))


def test_single_level_matches_brute_force_reference():
    """On one level (no multi-resolution), skipping and step growth must not change the horizon."""
    terrain, dem = _one_level(400, 10.0, seed=3, amp=120.0)
    spec = RenderSpec(camera_height_m=2.0, n_azimuth=180, body_radius_m=1e6)
    rng = np.random.default_rng(1)
    diffs, exact = [], []
    for x, y in rng.uniform(-1200, 1200, size=(6, 2)):
        _, el, _ = raymarch.horizon_at(terrain, x, y, spec)
        _, ref, _ = accurate_horizon_with_distance(dem, x, y, spec)
        diffs.append(el - ref)
        # with a constant quarter-cell step and no exact near field the march samples where the
        # quarter-cell reference does
        _, el_fixed, _ = raymarch.horizon_at(terrain, x, y, spec,
                                             options=raymarch.MarchOptions(step_per_m=0.0, near_field_cells=0.0))
        _, ref_q, _ = brute_force_horizon_with_distance(dem, x, y, spec, step_cells=0.25)
        exact.append(el_fixed - ref_q)
    diffs, exact = np.abs(np.concatenate(diffs)), np.abs(np.concatenate(exact))
    assert np.median(diffs) <= 0.02 and np.percentile(diffs, 99) <= 0.2
    assert np.percentile(exact, 99) <= 0.02


@pytest.mark.parametrize("side", [1.0, -1.0])
@pytest.mark.parametrize("crest_cells", [0.4, 1.3, 2.0])
def test_near_field_ridge_matches_closed_form(crest_cells, side):
    """A straight ridge (crest on a cell-centre column) 0.4-2 cells from the eye, on a tilted plane.

    The eye is on a cell-centre row (and with crest_cells=2 on a cell centre): rays start on
    lattice lines, going forwards and backwards.

    z = H - s |x - x_r| (down to a floor) + q y is piecewise linear with its kinks on lattice
    columns, so the bilinear surface is exactly this function.  Looking across the ridge at
    azimuth az (towards it), the ground rises along the ray at slope g = s |sin az| + q cos az up
    to the crest at distance D = |x_r - x_e| / |sin az|, then falls: the horizon tangent is
    g - h / D - c D, formed at D.  A quarter-cell sampling misses this by up to degrees.
    """
    cell, s, q, h, R = 30.0, 0.6, 0.1, 2.0, 6.371e6
    c = 1.0 / (2 * R)
    x_r = side * (-585.0 + 30.0 * 20)                     # a level-0 cell-centre column (n = 40)
    depth = 4 * cell * s                                   # the ridge flanks reach the floor 4 cells out

    def fn(X, Y):
        return np.maximum(100.0 - s * np.abs(X - x_r), 100.0 - depth) + q * Y

    terrain = analytic_terrain(fn, [(600, cell), (6000, 300.0)], radius_m=R)
    xe, ye = x_r - side * crest_cells * cell, 15.0          # 15 m: a cell-centre row
    spec = RenderSpec(camera_height_m=h, n_azimuth=360, body_radius_m=R)
    az, el, dist = raymarch.horizon_at(terrain, xe, ye, spec)
    a = np.radians(az)
    sel = side * np.sin(a) > math.sin(math.radians(40))   # towards the ridge, not grazing it
    D = crest_cells * cell / np.abs(np.sin(a[sel]))
    g = s * np.abs(np.sin(a[sel])) + q * np.cos(a[sel])
    truth = np.degrees(np.arctan(g - h / D - c * D))
    np.testing.assert_allclose(el[sel], truth, atol=0.01)
    np.testing.assert_allclose(dist[sel], D, rtol=1e-3)
    # the old fixed quarter-cell march (no near field) misses the nearest ridge by far more
    if crest_cells < 1:
        _, el_old, _ = raymarch.horizon_at(terrain, xe, ye, spec,
                                           options=raymarch.MarchOptions(near_field_cells=0.0))
        assert np.max(np.abs(el_old[sel] - truth)) > 1.0


def nested_bilinear(terrain, px, py):
    """Heights (m) of the nested bilinear surface the march samples, each point on the finest level
    holding it (NaN outside every level): a plain numpy second implementation of the kernels' lookup."""
    px, py = np.asarray(px, dtype=np.float64), np.asarray(py, dtype=np.float64)
    z = np.full(px.shape, np.nan)
    for lev in reversed(terrain.levels):                      # coarse first, finer levels overwrite
        u = (px - lev.x0) / lev.cell_m - 0.5
        v = (lev.y0 - py) / lev.cell_m - 0.5
        rows, cols = lev.array.shape
        inside = (u >= 0) & (v >= 0) & (u <= cols - 1) & (v <= rows - 1)
        ci = np.minimum(u[inside].astype(int), cols - 2)
        ri = np.minimum(v[inside].astype(int), rows - 2)
        fu, fv = u[inside] - ci, v[inside] - ri
        a = lev.array.astype(np.float64)
        top = a[ri, ci] + fu * (a[ri, ci + 1] - a[ri, ci])
        bot = a[ri + 1, ci] + fu * (a[ri + 1, ci + 1] - a[ri + 1, ci])
        z[inside] = top + fv * (bot - top)
    return z


def nested_bilinear_horizon(terrain, x, y, cam_h, az_deg, c_per_m, d_max, step_m=0.01):
    """Horizon elevation (degrees) at (x, y) by a dense 1-D search of :func:`nested_bilinear`."""
    z_eye = float(nested_bilinear(terrain, [x], [y])[0]) + cam_h
    d = np.arange(step_m, d_max, step_m)
    out = []
    for a in np.radians(np.atleast_1d(az_deg)):
        z = nested_bilinear(terrain, x + d * math.sin(a), y + d * math.cos(a))
        ok = np.isfinite(z)
        out.append(np.degrees(np.arctan(np.max((z[ok] - z_eye - c_per_m * d[ok] ** 2) / d[ok]))))
    return np.array(out)


def test_wall_just_beyond_the_finest_level_is_not_skipped():
    """Flat floor and a ring wall of height H between radii D and D + W, on two levels: the 1 m
    level 0 (130 cells: its last 64-cell skip block reaches 62 m past its edge) holds only floor, the
    wall is on level 1.  Skipping a level-0 block must stop at the level's edge, since the block's
    maximum knows nothing of the coarser terrain beyond: the seed pass's samples on the floor past
    the wall beat the block's bound, and the skip used to jump over the wall to the block's far side."""
    D, W, H, h, R = 95.0, 6.0, 20.0, 1.5, 1e5           # D > 65 sqrt(2): level 0 is all floor

    def fn(X, Y):
        r = np.hypot(X, Y)
        return np.where((r >= D) & (r <= D + W), H, 0.0)

    terrain = analytic_terrain(fn, [(65, 1.0), (200, 2.0)], radius_m=R)
    spec = RenderSpec(camera_height_m=h, n_azimuth=72, body_radius_m=R)
    for x, y in ((3.0, -7.0), (-20.0, 15.0)):
        az, el, _ = raymarch.horizon_at(terrain, x, y, spec)
        want = nested_bilinear_horizon(terrain, x, y, h, az, 1.0 / (2 * R), 190.0)
        assert want.min() > 8.0                       # the wall's top is the horizon everywhere
        # the march samples the 2 m ramp up the wall every 0.01 d at most: it may reach the top up to
        # one step late (a slightly lower tangent), never early.  The missed wall was 0.5 deg and more.
        d_min = D - math.hypot(x, y)
        tol = math.degrees(math.atan((H - h) / d_min) - math.atan((H - h) / (1.01 * d_min)))   # ~0.12 deg
        assert np.all(el <= want + 1e-3) and np.all(el >= want - tol), ((el - want).min(), tol)


def test_eyes_on_the_lattice_match_the_accurate_reference():
    """Eyes exactly on cell centres and lattice lines (grid positions usually are): rays start on a
    cell boundary, and those going backwards enter their first cell at distance 0."""
    terrain, dem = _one_level(200, 10.0, seed=7, amp=40.0)
    spec = RenderSpec(camera_height_m=1.0, n_azimuth=360, body_radius_m=1e6)
    d = []
    for x, y in [(5.0, 5.0), (-95.0, 305.0), (5.0, 7.3), (-41.7, 45.0)]:   # centres, a column, a row
        _, el, dist = raymarch.horizon_at(terrain, x, y, spec)
        _, ref, _ = accurate_horizon_with_distance(dem, x, y, spec)
        assert np.all(dist > 0)
        d.append(np.abs(el - ref))
    d = np.concatenate(d)
    assert np.percentile(d, 99) <= 0.1 and d.max() <= 0.3


@pytest.mark.realdem
@pytest.mark.parametrize("name", ["earth_sthelens_1980_usgs30m.dem", "earth_oetztal_alps_srtm3.tif"])
def test_real_dem_matches_the_accurate_reference(real_dem, name):
    """Random positions on a real DEM (multi-resolution terrain, 2 m camera) against the brute force
    with the fine graded step (which sees near-field crests): median <= 0.05, p99 <= 0.3 degree."""
    from blender_addon.terrain.dem import read_dem
    from blender_addon.terrain.multires import build_multires

    path = real_dem(name)
    dem = read_dem(path)
    xmin, ymin, xmax, ymax = dem.bounds()
    cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
    half = min(xmax - xmin, ymax - ymin) / 4
    terrain = build_multires(path, (cx, cy), grid_half_m=half)
    spec = RenderSpec(camera_height_m=2.0, n_azimuth=360, body_radius_m=dem.body.radius_m)
    rng = np.random.default_rng(11)
    xs, ys = cx + rng.uniform(-half, half, 16), cy + rng.uniform(-half, half, 16)
    el, _ = raymarch.render_positions(terrain, xs, ys, spec)
    ref = np.stack([accurate_horizon_with_distance(dem, x, y, spec)[1] for x, y in zip(xs, ys)])
    d = np.abs(el - ref)
    assert np.median(d) <= 0.05 and np.percentile(d, 99) <= 0.3


def test_accurate_reference_step_agrees_with_a_uniform_fine_step():
    """The graded reference step (fine near the eye, coarser far) against a uniform 0.01-cell step."""
    cell, n = 10.0, 200
    z = _fractal(n, seed=5, amp=40.0, cell=cell)          # slopes up to ~1.7
    x0, y0 = -n * cell / 2, n * cell / 2
    dem = DemRaster(z, (x0, cell, 0.0, y0, 0.0, -cell), "", Body("custom", 1e6))
    spec = RenderSpec(camera_height_m=2.0, n_azimuth=180, body_radius_m=1e6)
    d = []
    for x, y in np.random.default_rng(2).uniform(-600, 600, size=(4, 2)):
        _, acc, _ = accurate_horizon_with_distance(dem, x, y, spec)
        _, fine, _ = brute_force_horizon_with_distance(dem, x, y, spec, step_cells=0.01)
        d.append(np.abs(acc - fine))
    d = np.concatenate(d)
    assert np.median(d) <= 0.005 and d.max() <= 0.1


def test_render_tile_shapes_positions_and_contract():
    def fn(X, Y):
        return 30.0 * np.sin(X / 150.0) * np.cos(Y / 210.0)

    terrain = analytic_terrain(fn, [(300, 2.0), (3000, 20.0)])
    grid = GridSpec.from_center((10.0, -20.0), size_m=60.0, step_m=10.0)
    tiles = plan_tiles(grid, 4)
    spec = RenderSpec(camera_height_m=1.5, n_azimuth=16, body_radius_m=1e5)
    render = get_renderer("raymarch")
    tile = tiles[-1]                                       # an edge tile (smaller than 4 x 4)
    res = render(terrain, grid, tile, spec)
    assert res.elevation_deg.shape == (tile.nrows, tile.ncols, 16) == res.distance_m.shape
    # every position of the tile equals a single-position render there
    i, j = tile.row0 + tile.nrows - 1, tile.col0
    x, y = grid.xy(i, j)
    _, el, _ = raymarch.horizon_at(terrain, float(x), float(y), spec)
    np.testing.assert_array_equal(res.elevation_deg[-1, 0], el.astype(np.float32))
    assert np.all(np.isfinite(res.elevation_deg))


def test_positions_outside_the_terrain_are_refused():
    terrain = analytic_terrain(lambda X, Y: np.zeros_like(X), [(100, 1.0), (1000, 10.0)])
    spec = RenderSpec(n_azimuth=8)
    with pytest.raises(InvalidInputError, match="outside the terrain"):
        raymarch.horizon_at(terrain, 150.0, 0.0, spec)
    grid = GridSpec.from_center((90.0, 0.0), size_m=40.0, step_m=10.0)
    with pytest.raises(InvalidInputError, match="outside"):
        raymarch.render_tile(terrain, grid, plan_tiles(grid, 8)[0], spec)
