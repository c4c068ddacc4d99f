"""DEM import: reprojection of degrees to metres (checked against spherical geometry), bodies, refusals,
nodata filling, windowed reads, and the real DEMs of ../shared/data/dems."""
from __future__ import annotations

import math

import numpy as np
import pytest
from osgeo import gdal, osr

from blender_addon.terrain.dem import dem_info, read_dem, resolve_dem, to_metric_xy
from board.errors import CrsError, DemReadError, InvalidInputError, NoDataError

gdal.UseExceptions()

MARS_A = 3396190.0


def geog_wkt(radius: float, name: str = "Mars 2000") -> str:
    srs = osr.SpatialReference()
    srs.SetGeogCS(name, f"D_{name}", f"{name} sphere", radius, 0.0)
    return srs.ExportToWkt()


def write_tif(path, array, gt, wkt="", nodata=None, dtype=gdal.GDT_Float32):
    rows, cols = array.shape
    ds = gdal.GetDriverByName("GTiff").Create(str(path), cols, rows, 1, dtype)
    ds.SetGeoTransform(gt)
    if wkt:
        ds.SetProjection(wkt)
    b = ds.GetRasterBand(1)
    if nodata is not None:
        b.SetNoDataValue(nodata)
    b.WriteArray(array)
    ds = None
    return path


def haversine(lon1, lat1, lon2, lat2, R):
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dl, dp = math.radians(lon2 - lon1), math.radians(lat2 - lat1)
    h = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * R * math.asin(math.sqrt(h))


def inverse_aeqd(x, y, lon0, lat0, R):
    """Inverse spherical azimuthal equidistant (Snyder 1987, eqs. 20-14, 25-15) in degrees."""
    rho = np.hypot(x, y)
    c = rho / R
    p0, l0 = math.radians(lat0), math.radians(lon0)
    with np.errstate(invalid="ignore", divide="ignore"):
        lat = np.arcsin(np.cos(c) * math.sin(p0) + np.where(rho > 0, y * np.sin(c) * math.cos(p0) / rho, 0.0))
        lon = l0 + np.arctan2(x * np.sin(c), rho * math.cos(p0) * np.cos(c) - y * math.sin(p0) * np.sin(c))
    return np.degrees(lon), np.degrees(lat)


@pytest.fixture()
def mars_geographic(tmp_path):
    """A 0.4 x 0.3 degree DEM on the Mars sphere at 30 N with two spikes at known lon/lat."""
    lon0, lat0, d = 100.0, 30.3, 0.0025  # 148 m N-S cells, 128 m E-W at 30 N
    cols, rows = 160, 120
    z = np.zeros((rows, cols), np.float32)
    spikes = [(20, 30), (95, 140)]  # (row, col)
    for r, c in spikes:
        z[r, c] = 1000.0
    path = write_tif(tmp_path / "mars_geo.tif", z, (lon0, d, 0, lat0, 0, -d), geog_wkt(MARS_A))
    lonlat = [(lon0 + (c + 0.5) * d, lat0 - (r + 0.5) * d) for r, c in spikes]
    return path, lonlat, (lon0, lat0, d, cols, rows)


def test_geographic_reprojected_with_metric_cells(mars_geographic):
    path, lonlat, (lon0, lat0, d, cols, rows) = mars_geographic
    dem = read_dem(path)
    assert dem.body.name == "mars"
    clat = lat0 - rows * d / 2
    # cell = the smaller ground size of a source cell at the centre latitude, on the sphere
    expect_cell = min(MARS_A * math.radians(d) * math.cos(math.radians(clat)), MARS_A * math.radians(d))
    assert dem.cell_m == pytest.approx(expect_cell, rel=1e-3)
    # spikes land where spherical geometry says: their separation is the great-circle distance
    a = np.nan_to_num(dem.array, nan=0.0)
    peaks = []
    for lon, lat in lonlat:
        x, y = to_metric_xy(lon, lat, dem_path=path)
        gt = dem.geotransform
        c, r = int((x - gt[0]) / gt[1]), int((y - gt[3]) / gt[5])
        win = a[r - 2 : r + 3, c - 2 : c + 3]
        rr, cc = np.unravel_index(np.argmax(win), win.shape)
        assert win.max() > 300.0  # the spike survives bilinear resampling nearby
        peaks.append((x, y))
    d_metric = math.dist(peaks[0], peaks[1])
    d_true = haversine(*lonlat[0], *lonlat[1], MARS_A)
    assert d_metric == pytest.approx(d_true, rel=2e-4)


def test_geographic_heights_match_source_function(tmp_path):
    """A smooth height field f(lon, lat) in degrees; after reprojection every cell holds f at the
    lon/lat that the inverse azimuthal-equidistant formulas give for its centre."""
    lon0, lat0, d = -40.0, -10.0, 0.002
    cols, rows = 150, 100
    lon = lon0 + (np.arange(cols) + 0.5) * d
    lat = lat0 - (np.arange(rows) + 0.5) * d
    f = lambda lo, la: 500.0 * np.sin(np.radians(lo) * 300.0) + 300.0 * np.cos(np.radians(la) * 200.0)  # noqa: E731
    z = f(lon[None, :], lat[:, None]).astype(np.float32)
    path = write_tif(tmp_path / "f.tif", z, (lon0, d, 0, lat0, 0, -d), geog_wkt(MARS_A))
    dem = read_dem(path)
    srs = osr.SpatialReference(wkt=dem.crs_wkt)
    clon = srs.GetProjParm(osr.SRS_PP_LONGITUDE_OF_CENTER)
    clat = srs.GetProjParm(osr.SRS_PP_LATITUDE_OF_CENTER)
    assert clon == pytest.approx(lon0 + cols * d / 2, abs=1e-5)
    gt = dem.geotransform
    r, c = np.mgrid[0 : dem.shape[0], 0 : dem.shape[1]]
    x = gt[0] + (c + 0.5) * gt[1]
    y = gt[3] + (r + 0.5) * gt[5]
    lo, la = inverse_aeqd(x, y, clon, clat, MARS_A)
    ok = ~np.isnan(dem.array)
    inside = (lo > lon0 + d) & (lo < lon0 + (cols - 1) * d) & (la < lat0 - d) & (la > lat0 - (rows - 1) * d)
    assert (ok & inside).sum() > 0.8 * inside.sum()
    err = np.abs(dem.array - f(lo, la))[ok & inside]
    # bilinear interpolation error of this field at these cells is below ~1 m; a 1-cell misplacement would be ~10 m
    assert np.percentile(err, 99) < 1.5


def test_unknown_body_refused_then_explicit_radius(tmp_path):
    titan = 2_575_000.0
    z = np.zeros((50, 60), np.float32)
    path = write_tif(tmp_path / "titan.tif", z, (10.0, 0.01, 0, 5.0, 0, -0.01), geog_wkt(titan, "Titan"))
    with pytest.raises(CrsError, match="--body"):
        read_dem(path)
    with pytest.raises(CrsError, match="--body"):
        dem_info(path)
    dem = read_dem(path, body=titan)
    assert dem.body.radius_m == titan
    expect = titan * math.radians(0.01) * math.cos(math.radians(4.75))
    assert dem.cell_m == pytest.approx(expect, rel=1e-3)


def test_explicit_body_overrides_mislabelled_crs(tmp_path):
    """A Mars DEM labelled EPSG:4326: body="mars" makes the degrees Mars degrees (not Earth's)."""
    z = np.zeros((40, 40), np.float32)
    path = write_tif(tmp_path / "mislabelled.tif", z, (0.0, 0.01, 0, 0.2, 0, -0.01), osr.SRS_WKT_WGS84_LAT_LONG)
    earth = read_dem(path)
    mars = read_dem(path, body="mars")
    assert earth.body.name == "earth" and mars.body.name == "mars"
    # WGS84 near the equator: the N-S cell is the smaller one, meridian radius a (1 - e^2)
    a, e2 = 6378137.0, 0.00669437999014
    assert earth.cell_m == pytest.approx(a * (1 - e2) * math.radians(0.01), rel=1e-3)
    assert mars.cell_m == pytest.approx(3389500.0 * math.radians(0.01), rel=1e-3)


def test_no_crs_refused_unless_declared_metric(tmp_path):
    z = np.arange(20 * 30, dtype=np.float32).reshape(20, 30)
    path = write_tif(tmp_path / "nocrs.tif", z, (1000.0, 2.0, 0, 5000.0, 0, -2.0))
    with pytest.raises(CrsError, match="no CRS"):
        read_dem(path)
    with pytest.raises(CrsError, match="body"):
        read_dem(path, assume_metric=True)
    dem = read_dem(path, assume_metric=True, body="moon")
    assert dem.cell_m == 2.0 and dem.geotransform[0] == 1000.0
    np.testing.assert_array_equal(dem.array, z)


def test_projected_non_metre_units_refused(tmp_path):
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(2227)  # NAD83 / California zone 3 (US feet)
    z = np.zeros((10, 10), np.float32)
    path = write_tif(tmp_path / "feet.tif", z, (6e6, 10, 0, 2e6, 0, -10), srs.ExportToWkt())
    with pytest.raises(CrsError, match="metre"):
        read_dem(path)


def _utm_wkt():
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32633)
    return srs.ExportToWkt()


@pytest.mark.parametrize("dtype, gdt", [(np.int16, gdal.GDT_Int16), (np.int32, gdal.GDT_Int32),
                                         (np.float64, gdal.GDT_Float64), (np.float32, gdal.GDT_Float32)])
def test_projected_values_and_nodata(tmp_path, dtype, gdt):
    rng = np.random.default_rng(3)
    z = rng.integers(100, 3000, (40, 50)).astype(dtype)
    z[0, :5] = -9999  # edge nodata (footprint edge): stays NaN
    path = write_tif(tmp_path / "int.tif", z, (500000.0, 30.0, 0, 4e6, 0, -30.0), _utm_wkt(), nodata=-9999,
                     dtype=gdt)
    dem = read_dem(path)
    assert dem.array.dtype == np.float32 and dem.body.name == "earth"
    assert np.isnan(dem.array[0, :5]).all()
    np.testing.assert_array_equal(dem.array[1:], z[1:].astype(np.float32))


def test_unsigned_and_scaled_band(tmp_path):
    """UInt16 counts with a band scale/offset (e.g. 0.5 m steps from -1000 m) become metres."""
    z = np.arange(12 * 10, dtype=np.uint16).reshape(12, 10) + 1000
    path = write_tif(tmp_path / "u16.tif", z, (0.0, 10.0, 0, 120.0, 0, -10.0), _utm_wkt(), dtype=gdal.GDT_UInt16)
    ds = gdal.Open(str(path), gdal.GA_Update)
    ds.GetRasterBand(1).SetScale(0.5)
    ds.GetRasterBand(1).SetOffset(-1000.0)
    ds = None
    dem = read_dem(path)
    np.testing.assert_allclose(dem.array, z * 0.5 - 1000.0)


def test_small_hole_filled_large_gap_refused(tmp_path):
    # a tilted plane: an inverse-distance fill of a small hole stays within the surrounding heights
    r, c = np.mgrid[0:100, 0:120]
    z = (2.0 * c + 1.0 * r).astype(np.float32)
    z_hole = z.copy()
    z_hole[50:53, 60:63] = np.nan
    path = write_tif(tmp_path / "hole.tif", z_hole, (0.0, 5.0, 0, 1000.0, 0, -5.0), _utm_wkt(), nodata=float("nan"))
    dem = read_dem(path)
    filled = dem.array[50:53, 60:63]
    assert np.isfinite(filled).all()
    assert np.abs(filled - z[50:53, 60:63]).max() < 4.0  # plane rises 2-3 m per cell

    z_gap = z.copy()
    z_gap[10:70, 20:100] = np.nan  # 40 % of the raster
    path2 = write_tif(tmp_path / "gap.tif", z_gap, (0.0, 5.0, 0, 1000.0, 0, -5.0), _utm_wkt(), nodata=float("nan"))
    with pytest.raises(NoDataError) as exc:
        read_dem(path2)
    msg = str(exc.value)
    assert "40.0%" in msg
    # bounding box of the gap in metres: x 100..500, y 650..950
    assert "x 100.0..500.0" in msg and "y 650.0..950.0" in msg
    # the same gap is accepted when the caller allows that much missing data; it stays NaN
    dem2 = read_dem(path2, max_missing_fraction=0.5)
    assert np.isnan(dem2.array[10:70, 20:100]).all()


def test_windowed_read_matches_whole_and_big_reads_refused(tmp_path):
    rng = np.random.default_rng(5)
    z = rng.normal(0, 100, (200, 300)).astype(np.float32)
    path = write_tif(tmp_path / "big.tif", z, (0.0, 10.0, 0, 2000.0, 0, -10.0), _utm_wkt())
    with pytest.raises(DemReadError, match="bounds="):
        read_dem(path, max_cells=10_000)
    dem = read_dem(path, bounds=(555.0, 1000.0, 1205.0, 1501.0), max_cells=10_000)
    # window snapped outward to whole cells: cols 55..121, rows 49..100
    assert dem.geotransform[0] == 550.0 and dem.geotransform[3] == 1510.0
    np.testing.assert_array_equal(dem.array, z[49:100, 55:121])
    with pytest.raises(InvalidInputError, match="overlap"):
        read_dem(path, bounds=(5000.0, 5000.0, 6000.0, 6000.0))


def test_windowed_read_of_geographic_dem(mars_geographic):
    path, _, _ = mars_geographic
    whole = read_dem(path)
    xmin, ymin, xmax, ymax = whole.bounds()
    b = (xmin + 0.3 * (xmax - xmin), ymin + 0.3 * (ymax - ymin), xmin + 0.6 * (xmax - xmin), ymin + 0.7 * (ymax - ymin))
    part = read_dem(path, bounds=b, max_cells=whole.array.size // 4)
    c0 = int(round((part.geotransform[0] - whole.geotransform[0]) / whole.cell_m))
    r0 = int(round((part.geotransform[3] - whole.geotransform[3]) / -whole.cell_m))
    rows, cols = part.shape
    np.testing.assert_allclose(part.array, whole.array[r0 : r0 + rows, c0 : c0 + cols], atol=1e-4)


def test_missing_file_and_not_a_raster(tmp_path):
    with pytest.raises(DemReadError, match="does not exist"):
        read_dem(tmp_path / "nope.tif")
    bad = tmp_path / "bad.tif"
    bad.write_text("not a raster")
    with pytest.raises(DemReadError):
        read_dem(bad)
    with pytest.raises(InvalidInputError, match="procedural"):
        resolve_dem("procedural:mars")


def test_resolve_procedural_is_cached(tmp_path):
    p1 = resolve_dem("procedural:moon:3:1000:10", cache_dir=tmp_path)
    mtime = p1.stat().st_mtime_ns
    p2 = resolve_dem("procedural:moon:3:1000:10", cache_dir=tmp_path)
    assert p1 == p2 and p2.stat().st_mtime_ns == mtime
    info = dem_info(p1)
    assert info.body.name == "moon" and info.size == (100, 100) and info.cell_m == 10.0


# ------------------------------------------------------------------ real DEMs (../shared/data/dems)

@pytest.mark.realdem
@pytest.mark.parametrize(
    "name, body, geographic, cell_m",
    [
        # SOURCES.md: 1/256 deg = 76 m E-W x 118.5 m N-S; 3 arc-s = 75 x 92.6 m; 63 x 92.6 m; 30 m; 1 m
        ("moon_gld100_aristoteles_256ppd.tif", "moon", True, 76.0),
        ("earth_baltoro_karakoram_srtm3.tif", "earth", True, 75.0),
        ("earth_oetztal_alps_srtm3.tif", "earth", True, 63.0),
        ("earth_sthelens_1980_usgs30m.dem", "earth", False, 30.0),
        ("mars_gale_hirise_1m_mmgis_missionDEM.tif", "mars", False, 1.0),
    ],
)
def test_real_dems(real_dem, name, body, geographic, cell_m):
    path = real_dem(name)
    info = dem_info(path)
    assert info.body.name == body and info.is_geographic == geographic
    assert info.cell_m == pytest.approx(cell_m, rel=0.02)
    dem = read_dem(path)
    assert dem.cell_m == info.cell_m and dem.shape == (info.size[1], info.size[0])
    srs = osr.SpatialReference(wkt=dem.crs_wkt)
    assert srs.IsProjected() and srs.GetLinearUnits() == 1.0
    assert np.isfinite(dem.array).mean() > 0.9


@pytest.mark.realdem
def test_real_geographic_extent_matches_great_circle(real_dem):
    """Baltoro (EPSG:4326): the metric positions of two corners are as far apart as on the ellipsoid-ish sphere."""
    path = real_dem("earth_baltoro_karakoram_srtm3.tif")
    ds = gdal.Open(str(path))
    gt = ds.GetGeoTransform()
    lon_a, lat_a = gt[0] + 100.5 * gt[1], gt[3] + 50.5 * gt[5]
    lon_b, lat_b = gt[0] + 700.5 * gt[1], gt[3] + 380.5 * gt[5]
    pa = to_metric_xy(lon_a, lat_a, dem_path=path)
    pb = to_metric_xy(lon_b, lat_b, dem_path=path)
    d_true = haversine(lon_a, lat_a, lon_b, lat_b, 6371008.8)
    # WGS84 ellipsoid vs mean sphere: distances differ by < 0.5 %
    assert math.dist(pa, pb) == pytest.approx(d_true, rel=5e-3)
    # heights at the source pixel centres agree with the reprojected DEM (bilinear on 75 m cells of steep relief)
    dem = read_dem(path)
    src = ds.GetRasterBand(1).ReadAsArray().astype(float)
    rng = np.random.default_rng(0)
    r = rng.integers(5, 425, 300)
    c = rng.integers(5, 855, 300)
    x, y = to_metric_xy(gt[0] + (c + 0.5) * gt[1], gt[3] + (r + 0.5) * gt[5], dem_path=path)
    # vectorised conversion agrees with the scalar one
    assert to_metric_xy(gt[0] + (c[0] + 0.5) * gt[1], gt[3] + (r[0] + 0.5) * gt[5], dem_path=path) == pytest.approx((x[0], y[0]))
    fc = (x - dem.geotransform[0]) / dem.cell_m - 0.5
    fr = (dem.geotransform[3] - y) / dem.cell_m - 0.5
    i, j = fr.astype(int), fc.astype(int)
    ty, tx = fr - i, fc - j
    a = dem.array
    val = (a[i, j] * (1 - tx) + a[i, j + 1] * tx) * (1 - ty) + (a[i + 1, j] * (1 - tx) + a[i + 1, j + 1] * tx) * ty
    errs = np.abs(val - src[r, c])
    assert np.nanmedian(errs) < 15.0  # misplacing by one cell gives ~50 m on these slopes


@pytest.mark.realdem
def test_real_sthelens_edge_nodata_kept_not_filled(real_dem):
    path = real_dem("earth_sthelens_1980_usgs30m.dem")
    dem = read_dem(path)
    nan = np.isnan(dem.array)
    assert 0.0 < nan.mean() < 0.1
    # the missing cells touch the border (the quadrangle's footprint), none is an interior hole left open
    from scipy import ndimage

    labels, n = ndimage.label(nan, structure=np.ones((3, 3)))
    border = set(np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))) - {0}
    assert set(range(1, n + 1)) == border
    assert np.nanmin(dem.array) == 682.0 and np.nanmax(dem.array) == 2543.0
