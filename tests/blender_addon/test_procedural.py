"""Procedural terrain: determinism (bytes), CRS and body, crater morphometry against published ratios,
power-law size-frequency, and the icy and block landforms measured on flat ground."""
from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest
from osgeo import gdal, osr

from blender_addon.terrain.dem import dem_info, read_dem
from blender_addon.terrain.procedural import PRESETS, generate, synthesize
from blender_addon.terrain.procedural import craters as cr
from blender_addon.terrain.procedural import features as ft
from board.errors import InvalidInputError


def sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_same_seed_same_bytes_different_seed_different(tmp_path, preset):
    a = synthesize(preset, size_m=1500, res_m=5, seed=42, out_path=tmp_path / "a.tif")
    b = synthesize(preset, size_m=1500, res_m=5, seed=42, out_path=tmp_path / "b.tif")
    c = synthesize(preset, size_m=1500, res_m=5, seed=43, out_path=tmp_path / "c.tif")
    assert sha(a) == sha(b)
    assert sha(a) != sha(c)
    za, zc = gdal.Open(str(a)).ReadAsArray(), gdal.Open(str(c)).ReadAsArray()
    # a different terrain, not a tiny perturbation of the same one
    assert np.sqrt(np.mean((za - zc) ** 2)) > 0.5 * za.std()


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_written_with_projected_crs_on_the_body(tmp_path, preset):
    p = synthesize(preset, size_m=2000, res_m=10, seed=1, out_path=tmp_path / "t.tif")
    info = dem_info(p)
    assert info.body.name == PRESETS[preset].body and not info.is_geographic
    assert info.size == (200, 200) and info.cell_m == 10.0
    assert info.bounds == (-1000.0, -1000.0, 1000.0, 1000.0)
    srs = osr.SpatialReference(wkt=info.crs_wkt)
    assert srs.IsProjected() and srs.GetLinearUnits() == 1.0
    dem = read_dem(p)
    assert np.isfinite(dem.array).all() and np.ptp(dem.array) > 20.0
    assert not list(tmp_path.glob(".*"))  # no temporary file left


def test_bad_arguments_refused():
    with pytest.raises(InvalidInputError, match="preset"):
        generate("venus", size_m=1000, res_m=5, seed=0)
    with pytest.raises(InvalidInputError, match="cells per side"):
        generate("mars", size_m=1e6, res_m=1, seed=0)
    with pytest.raises(InvalidInputError, match="positive"):
        generate("mars", size_m=1000, res_m=0, seed=0)


def radial_profile(z, cell, cx, cy, edges):
    r, c = np.mgrid[0 : z.shape[0], 0 : z.shape[1]]
    d = np.hypot((c + 0.5) * cell - cx, (r + 0.5) * cell - cy)
    idx = np.digitize(d.ravel(), edges)
    return np.array([z.ravel()[idx == i].mean() for i in range(1, len(edges))])


def test_simple_crater_morphometry():
    """Fresh simple craters: depth/diameter ~0.2 (Pike 1977: 0.14-0.25), rim height/D ~0.04, ejecta thinning outwards."""
    D, cell = 200.0, 1.0
    z = np.zeros((800, 800), np.float32)
    cr.stamp_craters(z, [cr.Crater(400.0, 400.0, D, 1.0)], cell_m=cell, transition_m=6000.0)
    R = D / 2
    floor = z.min()
    rim = z.max()
    d_over_D = (rim - floor) / D
    assert 0.14 <= d_over_D <= 0.25
    assert 0.02 <= rim / D <= 0.06
    prof = radial_profile(z, cell, 400.0, 400.0, np.array([1.1, 1.3, 1.6, 2.0, 2.5, 3.2, 3.8]) * R)
    assert (prof[:5] > 0).all() and (np.diff(prof[:5]) < 0).all()  # ejecta thins outwards
    assert abs(prof[-1]) < 1e-6  # nothing beyond ~3 R
    # the lowest point is at the centre
    assert z[399:401, 399:401].min() == pytest.approx(floor, abs=0.05 * D * 0.2)


def test_complex_crater_has_central_peak_and_is_shallower():
    D, cell, trans = 20000.0, 50.0, 6000.0
    n = int(3.5 * D / cell)
    z = np.zeros((n, n), np.float32)
    c = n * cell / 2
    cr.stamp_craters(z, [cr.Crater(c, c, D, 1.0)], cell_m=cell, transition_m=trans)
    R = D / 2
    prof = radial_profile(z, cell, c, c, np.array([0.0, 0.05, 0.25, 0.35, 0.9, 1.1]) * R)
    centre, floor = prof[0], prof[2]
    assert centre > floor + 0.1 * (z.max() - z.min())  # a central peak stands above the floor
    d_over_D = (z.max() - floor) / D
    assert 0.03 <= d_over_D < 0.14  # complex craters are shallower than simple ones (Pike: ~0.05-0.1)
    ring = radial_profile(z, cell, c, c, np.array([0.2, 0.3, 0.38]) * R)
    assert abs(ring[0] - ring[1]) < 0.05 * (z.max() - floor)  # flat floor


def test_diameters_follow_the_power_law():
    rng = np.random.default_rng(0)
    slope, dmin, dmax, area, n1 = 2.0, 20.0, 5000.0, 400e6, 0.01
    d = cr.draw_diameters(rng, area_m2=area, density_per_km2_above_1km=n1, slope=slope, d_min_m=dmin, d_max_m=dmax)
    expected = n1 * area / 1e6 * ((dmin / 1000) ** -slope - (dmax / 1000) ** -slope)
    assert abs(len(d) - expected) < 5 * math.sqrt(expected)
    assert d.min() >= dmin and d.max() <= dmax
    # maximum-likelihood Pareto exponent (dmax is far enough to ignore the truncation)
    slope_hat = len(d) / np.log(d / dmin).sum()
    assert slope_hat == pytest.approx(slope, rel=0.05)


def test_blocks_heights_in_range():
    rng = np.random.default_rng(1)
    z = np.zeros((300, 300), np.float32)
    ft.add_blocks(z, rng, cell_m=1.0, count=500, h_min_m=0.5, h_max_m=3.0)
    up = z[z > 0]
    assert up.min() >= 0.5 - 1e-6 and up.max() <= 3.0 + 1e-6
    assert 500 <= up.size <= 500 * 9
    # power law: more small blocks than large ones
    assert (up < 1.0).sum() > (up > 2.0).sum()


def test_crevasses_are_narrow_deep_cuts():
    rng = np.random.default_rng(2)
    z = np.zeros((600, 600), np.float32)
    ft.add_crevasses(z, rng, cell_m=5.0, count=5, length_m=(1000.0, 2000.0), depth_m=(10.0, 30.0))
    cut = z < -1.0
    assert z.min() < -9.0 and z.max() == 0.0
    assert 0 < cut.mean() < 0.03
    # narrow: eroding the cut mask by a 5x5 square removes (almost) all of it
    from scipy import ndimage

    assert ndimage.binary_erosion(cut, np.ones((5, 5))).sum() < 0.02 * cut.sum()


def test_penitentes_have_blade_spacing():
    rng = np.random.default_rng(3)
    z = np.zeros((512, 256), np.float32)
    cover = np.full(z.shape, 5.0, np.float32)
    ft.add_penitentes(z, rng, cell_m=1.0, coverage_field=cover, height_m=(3.0, 6.0), spacing_m=4.0)
    assert z.max() <= 6.0 + 1e-4 and z.max() > 2.0
    spec = np.abs(np.fft.rfft(z - z.mean(axis=0), axis=0)).mean(axis=1)
    freqs = np.fft.rfftfreq(z.shape[0], d=1.0)
    band = freqs > 1 / 20.0  # above the slow height modulation
    peak = freqs[band][np.argmax(spec[band])]
    assert peak == pytest.approx(1 / 4.0, rel=0.1)  # blades 4 m apart north-south


def test_broken_plates_lower_matrix_between_plates():
    rng = np.random.default_rng(4)
    z = np.zeros((400, 400), np.float32)
    ft.add_broken_plates(z, rng, cell_m=10.0, centre_xy_m=(2000.0, 2000.0), radius_m=1500.0,
                         plate_size_m=(200.0, 500.0), matrix_drop_m=60.0)
    disc = z[100:300, 100:300]
    low = (disc < -40.0).mean()
    assert 0.03 < low < 0.7  # matrix between plates
    assert z[:20, :20].max() == 0.0  # untouched outside the chaos region


def test_europa_differs_from_mars_in_kind():
    """Europa has few craters and sharp small-scale features (crevasses, penitentes): its height
    distribution is narrower overall but its cell-to-cell roughness is not negligible."""
    e = generate("europa", size_m=3000, res_m=5, seed=9)
    m = generate("mars", size_m=3000, res_m=5, seed=9)
    assert e.std() < m.std()
    assert np.abs(np.diff(e, axis=0)).mean() > 0.2


@pytest.mark.parametrize("wl_min", [10.0, 200.0])  # direct synthesis, and coarse synthesis + upsampling
def test_spectral_field_spectrum(wl_min):
    """Radially averaged power falls as |k|^-beta inside the band and vanishes below the shortest wavelength."""
    from blender_addon.terrain.procedural.fields import spectral_field

    n, cell, beta = 512, 5.0, 3.0
    f = spectral_field((n, n), np.random.default_rng(0), cell_m=cell, wavelength_min_m=wl_min,
                       wavelength_max_m=2000.0, beta=beta)
    assert f.std() == pytest.approx(1.0, rel=1e-3) and abs(f.mean()) < 1e-3
    p = np.abs(np.fft.fft2(f)) ** 2
    k = np.hypot(*np.meshgrid(np.fft.fftfreq(n, cell), np.fft.fftfreq(n, cell), indexing="ij"))
    band = (k > 1 / 1000.0) & (k < 0.5 / wl_min)
    slope = np.polyfit(np.log(k[band]), np.log(p[band]), 1)[0]
    assert slope == pytest.approx(-beta, abs=0.35)
    high = k > 2.0 / wl_min
    assert p[high].sum() < 1e-3 * p.sum()
