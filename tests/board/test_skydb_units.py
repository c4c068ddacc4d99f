"""The skyline database's int16 elevation unit: 0.005 deg for new stores, 0.01 deg stores still read right.

Truth is arithmetic: rounding to a unit u leaves at most u / 2 and u / sqrt(12) RMS on uniform values.
"""
import json

import numpy as np
import pytest

from board.errors import FormatError, InvalidInputError
from board.skydb import (
    ELEVATION_SCALE_DEG,
    LEGACY_ELEVATION_SCALE_DEG,
    MISSING,
    GridSpec,
    SkyDB,
    SkyDBMeta,
    SkyDBWriter,
    dequantize_elevation,
    quantize_elevation,
)


def _meta(**kw):
    grid = GridSpec.from_center((0.0, 0.0), size_m=10.0, step_m=5.0, crs_wkt="LOCAL_CS[\"t\"]")
    return SkyDBMeta(grid=grid, camera_height_m=2.0, n_azimuth=400, tile_size=2, dem_sha256="abc", **kw)


def _write(path, meta, el):
    w = SkyDBWriter.create(path, meta)
    for t in w.tiles:
        w.write_tile(t, el[t.row0:t.row0 + t.nrows, t.col0:t.col0 + t.ncols])
    return w.finalize()


@pytest.mark.parametrize("unit", [0.01, 0.005])
def test_rounding_error_is_half_a_unit_at_most_and_uniform(unit):
    el = np.random.default_rng(3).uniform(-89.0, 89.0, 200_000)
    err = dequantize_elevation(quantize_elevation(el, unit), np.float64, unit) - el
    assert np.abs(err).max() <= unit / 2 + 1e-9
    assert np.sqrt(np.mean(err ** 2)) == pytest.approx(unit / np.sqrt(12), rel=0.02)


def test_the_finer_unit_spans_every_elevation():
    el = np.array([-90.0, -45.0, 0.0, 45.0, 90.0])
    q = quantize_elevation(el, ELEVATION_SCALE_DEG)
    assert not np.any(q == MISSING) and np.abs(q).max() < 32767  # no saturation, no sentinel
    np.testing.assert_allclose(dequantize_elevation(q, np.float64, ELEVATION_SCALE_DEG), el, atol=1e-9)


@pytest.mark.parametrize("unit", [LEGACY_ELEVATION_SCALE_DEG, ELEVATION_SCALE_DEG])
def test_store_round_trip_in_its_own_unit(tmp_path, unit):
    rng = np.random.default_rng(5)
    el = rng.uniform(-10.0, 40.0, (3, 3, 400))
    db = _write(tmp_path / "db.zarr", _meta(elevation_scale_deg=unit), el)
    again = SkyDB.open(tmp_path / "db.zarr")
    assert again.meta.elevation_scale_deg == unit and again.summary()["elevation_scale_deg"] == unit
    raw = again.read_tile_raw(again.tiles[0])
    np.testing.assert_array_equal(raw, np.round(el[:2, :2] / unit).astype(np.int16))
    err = again.read_all().astype(np.float64) - el
    assert np.abs(err).max() <= unit / 2 + 1e-5
    np.testing.assert_array_equal(again.skyline(1, 2), db.read_all()[1, 2])


def test_new_stores_are_finer_than_legacy_ones(tmp_path):
    el = np.random.default_rng(6).uniform(0.0, 5.0, (3, 3, 400))
    fine = _write(tmp_path / "fine.zarr", _meta(), el)
    coarse = _write(tmp_path / "coarse.zarr", _meta(elevation_scale_deg=0.01), el)
    rms = [float(np.sqrt(np.mean((d.read_all() - el) ** 2))) for d in (fine, coarse)]
    assert fine.meta.elevation_scale_deg == 0.005
    assert rms[0] == pytest.approx(rms[1] / 2, rel=0.1)


def test_store_without_the_key_is_read_as_legacy(tmp_path):
    """A store whose attributes lack elevation_scale_deg is read in the 0.01 deg units of skyloc before it."""
    el = np.full((3, 3, 400), 12.34)
    _write(tmp_path / "db.zarr", _meta(elevation_scale_deg=0.01), el)
    zj = tmp_path / "db.zarr" / "zarr.json"
    doc = json.loads(zj.read_text())
    del doc["attributes"]["elevation_scale_deg"]
    zj.write_text(json.dumps(doc))
    db = SkyDB.open(tmp_path / "db.zarr")
    assert db.meta.elevation_scale_deg == LEGACY_ELEVATION_SCALE_DEG
    np.testing.assert_allclose(db.read_all(), 12.34, atol=0.005)


def test_unknown_unit_is_refused_by_reader_and_writer(tmp_path):
    _write(tmp_path / "db.zarr", _meta(), np.zeros((3, 3, 400)))
    zj = tmp_path / "db.zarr" / "zarr.json"
    doc = json.loads(zj.read_text())
    doc["attributes"]["elevation_scale_deg"] = 0.003
    zj.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="0.003.*re-render"):
        SkyDB.open(tmp_path / "db.zarr")
    with pytest.raises(InvalidInputError, match="0.003 deg is not one of 0.01, 0.005"):
        SkyDBWriter.create(tmp_path / "other.zarr", _meta(elevation_scale_deg=0.003))
    assert not (tmp_path / "other.zarr").exists()


def test_resume_in_another_unit_is_refused(tmp_path):
    w = SkyDBWriter.create(tmp_path / "db.zarr", _meta(elevation_scale_deg=0.01))
    w.write_tile(w.tiles[0], np.zeros((2, 2, 400)))
    with pytest.raises(InvalidInputError, match="elevation_scale_deg"):
        SkyDBWriter.create(tmp_path / "db.zarr", _meta())


@pytest.mark.slow
def test_the_finer_unit_pins_a_far_horizon_floor_closer(tmp_path):
    """Analytic truth (board.match.synthetic hills): a crater floor whose rims stand 25-40 km away, so the
    horizon moves a fraction of a millidegree per metre.  Exact level queries at off-grid positions, seen on
    the database's azimuths (heading 0), are located against the same 5 m database stored in 0.01 and in
    0.005-degree units: with nothing else in error the rounding is the floor, and halving it brings the fixes
    in (measured: median 0.79 -> 0.23 m)."""
    from board.locate import locate
    from board.match.synthetic import MountainField, observe
    from board.skyline import Skyline

    rng = np.random.default_rng(11)
    n = 120
    d = rng.uniform(25_000.0, 40_000.0, n)
    a = rng.uniform(0.0, 2.0 * np.pi, n)
    h = d * np.tan(np.radians(rng.uniform(0.3, 1.5, n))) + d ** 2 / (2 * 1_737_400.0)
    mf = MountainField(d * np.sin(a), d * np.cos(a), h, d * rng.uniform(0.01, 0.03, n))
    grid = GridSpec.from_center((0.0, 0.0), 100.0, 5.0)
    az = np.arange(360.0)
    dbs = {}
    for unit in (0.01, 0.005):
        meta = SkyDBMeta(grid=grid, camera_height_m=2.0, n_azimuth=360, tile_size=16, renderer="analytic",
                         body="moon", body_radius_m=1_737_400.0, elevation_scale_deg=unit)
        w = SkyDBWriter.create(tmp_path / f"db{unit}.zarr", meta)
        for t in w.tiles:
            ii, jj = np.mgrid[t.row0:t.row0 + t.nrows, t.col0:t.col0 + t.ncols]
            x, y = grid.xy(ii, jj)
            w.write_tile(t, mf.horizon_chunked(x.ravel(), y.ravel(), az).reshape(t.nrows, t.ncols, 360))
        dbs[unit] = w.finalize()
    errs = {0.01: [], 0.005: []}
    for _ in range(10):
        x, y = rng.uniform(-35.0, 35.0, 2)
        sky = Skyline(observe(az, mf.horizon(x, y, az)[0], heading_deg=0.0, n=360))
        for unit, db in dbs.items():
            fix = locate(db, sky)
            errs[unit].append(float(np.hypot(fix.x - x, fix.y - y)))
            assert fix.status != "ok" or errs[unit][-1] < 25.0
    coarse, fine = np.median(errs[0.01]), np.median(errs[0.005])
    assert fine <= 0.7 * coarse, (errs)
    assert coarse > 0.2, errs  # the control: 0.01 deg is metres' worth here, the test can fail
