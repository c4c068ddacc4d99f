"""Skyline database: round trip, resume without rewriting, refusal of bad stores."""
import json

import numpy as np
import pytest

from board.errors import FormatError, InvalidInputError
from board.skydb import GridSpec, SkyDB, SkyDBMeta, SkyDBWriter, dequantize_elevation, quantize_elevation


def _meta(tile=4, **kw):
    grid = GridSpec.from_center((1000.0, 2000.0), size_m=45.0, step_m=5.0, crs_wkt="LOCAL_CS[\"test\"]")
    return SkyDBMeta(grid=grid, camera_height_m=2.0, n_azimuth=36, tile_size=tile, dem_sha256="abc", **kw)


def test_grid_matches_gdal_pixel_centres():
    g = GridSpec.from_center((1000.0, 2000.0), size_m=1000.0, step_m=5.0)
    assert (g.nx, g.ny) == (201, 201) and g.n_positions == 40401
    x, y = g.xy(0, 0)
    assert (x, y) == (500.0, 2500.0)  # row 0 is the northern edge, column 0 the western
    x, y = g.xy(100, 100)
    assert (x, y) == (1000.0, 2000.0)
    assert g.ij(1000.0, 2000.0) == (100.0, 100.0)


def test_quantize_round_trip_and_missing():
    el = np.array([-12.345, 0.0, 3.14159, np.nan, 89.99])
    back = dequantize_elevation(quantize_elevation(el))
    assert np.isnan(back[3])
    np.testing.assert_allclose(back[[0, 1, 2, 4]], el[[0, 1, 2, 4]], atol=0.005 + 1e-6)


def test_round_trip_and_resume_never_rewrites(tmp_path):
    path = tmp_path / "db.zarr"
    meta = _meta(has_distance=True)
    w = SkyDBWriter.create(path, meta)
    rng = np.random.default_rng(0)
    truth = rng.uniform(-5, 30, size=(10, 10, 36)).astype(np.float32)
    truth[2, 3, 5] = np.nan
    tiles = w.tiles
    assert len(tiles) == 9  # 10 x 10 positions in tiles of 4: 3 x 3
    for t in tiles[:4]:
        sl = np.s_[t.row0:t.row0 + t.nrows, t.col0:t.col0 + t.ncols]
        w.write_tile(t, truth[sl], distance_m=np.full(truth[sl].shape, 1234.0))
    # "interrupted": a new writer resumes with the 5 remaining tiles
    w2 = SkyDBWriter.create(path, meta)
    pending = w2.pending_tiles()
    assert [t.key for t in pending] == [t.key for t in tiles[4:]]
    with pytest.raises(InvalidInputError, match="already written"):
        w2.write_tile(tiles[0], np.zeros((4, 4, 36)))
    with pytest.raises(InvalidInputError):
        w2.finalize()
    for t in pending:
        sl = np.s_[t.row0:t.row0 + t.nrows, t.col0:t.col0 + t.ncols]
        w2.write_tile(t, truth[sl], distance_m=np.full(truth[sl].shape, 1234.0))
    db = w2.finalize()
    assert db.complete and db.n_tiles_done() == 9
    got = db.read_all()
    assert np.isnan(got[2, 3, 5])
    np.testing.assert_allclose(got, truth, atol=0.0051)
    np.testing.assert_allclose(db.skyline(7, 8), truth[7, 8], atol=0.0051)
    d = db.read_distance(db.tiles[0])
    assert np.all(d == 1230.0)
    s = db.summary()
    assert s["positions"] == 100 and s["tiles_done"] == 9 and s["dem_sha256"] == "abc"


def test_resume_refuses_a_different_database(tmp_path):
    path = tmp_path / "db.zarr"
    SkyDBWriter.create(path, _meta())
    other = _meta()
    other.camera_height_m = 1.5
    with pytest.raises(InvalidInputError, match="camera_height_m"):
        SkyDBWriter.create(path, other)


def test_resume_across_renderer_versions(tmp_path, caplog):
    """A partial store of another renderer version is not resumed (tiles would mix); a complete one is kept."""
    path = tmp_path / "db.zarr"
    old = _meta()
    old.renderer_version = "2"
    w = SkyDBWriter.create(path, old)
    t = w.tiles[0]
    w.write_tile(t, np.full((t.nrows, t.ncols, old.n_azimuth), 1.0))
    new = _meta()
    new.renderer_version = "3"
    with pytest.raises(InvalidInputError, match="version 2; this is version 3"):
        SkyDBWriter.create(path, new)
    w = SkyDBWriter.create(path, old)  # the version that started it finishes it
    for t in w.pending_tiles():
        w.write_tile(t, np.full((t.nrows, t.ncols, old.n_azimuth), 1.0))
    w.finalize()
    with caplog.at_level("WARNING"):
        again = SkyDBWriter.create(path, new)
    assert again.pending_tiles() == [] and "rendered by" in caplog.text


def test_reader_refuses_unknown_version_and_corrupt(tmp_path):
    path = tmp_path / "db.zarr"
    SkyDBWriter.create(path, _meta())
    zj = path / "zarr.json"
    doc = json.loads(zj.read_text())
    doc["attributes"]["version"] = 99
    zj.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="version 99"):
        SkyDB.open(path)
    zj.write_text("{ not json")
    with pytest.raises(FormatError, match="corrupt"):
        SkyDB.open(path)
    with pytest.raises(FormatError, match="no skyline database"):
        SkyDB.open(tmp_path / "nothing.zarr")


def test_reader_refuses_a_damaged_array(tmp_path):
    path = tmp_path / "db.zarr"
    SkyDBWriter.create(path, _meta())
    (path / "elevation" / "zarr.json").write_text("{ truncated")
    with pytest.raises(FormatError, match="corrupt"):
        SkyDB.open(path)


def _filled_db(tmp_path, tile=4, **kw):
    """A complete 10 x 10 x 36 store (tiles of ``tile``, edge tiles partial) and its float32 truth."""
    w = SkyDBWriter.create(tmp_path / "db.zarr", _meta(tile=tile, **kw))
    rng = np.random.default_rng(1)
    truth = rng.uniform(-5, 30, size=(10, 10, 36)).astype(np.float32)
    for t in w.tiles:
        sl = np.s_[t.row0:t.row0 + t.nrows, t.col0:t.col0 + t.ncols]
        w.write_tile(t, truth[sl], distance_m=np.full(truth[sl].shape, 1234.0) if w.meta.has_distance else None)
    return w.finalize(), truth


@pytest.mark.parametrize("cache_mb", [0.0, 64.0])
def test_direct_chunk_reads_equal_zarr(tmp_path, cache_mb):
    """Windows across chunk and array edges read from the chunk files (and the cache) equal zarr's reads."""
    import zarr

    from board.skydb import Tile

    db, _ = _filled_db(tmp_path)
    db = SkyDB.open(db.path, cache_mb=cache_mb)
    ref = np.asarray(zarr.open_group(str(db.path), mode="r")["elevation"][...])
    rng = np.random.default_rng(2)
    for _ in range(2):  # the second pass reads from the cache when there is one
        for _ in range(40):
            r0, c0 = rng.integers(0, 10, 2)
            nr, nc = rng.integers(1, 11 - r0), rng.integers(1, 11 - c0)
            got = db.read_tile_raw(Tile(-1, -1, int(r0), int(c0), int(nr), int(nc)))
            np.testing.assert_array_equal(got, ref[r0:r0 + nr, c0:c0 + nc])
        for t in db.tiles:
            np.testing.assert_array_equal(db.read_tile_raw(t), ref[t.row0:t.row0 + t.nrows, t.col0:t.col0 + t.ncols])
    np.testing.assert_array_equal(db.skyline(9, 9), dequantize_elevation(ref[9, 9]))
    # the cache holds exactly the array (edge chunks trimmed), never more
    assert db.cached_mb == pytest.approx(ref.nbytes / 1e6 if cache_mb else 0.0)


@pytest.mark.parametrize("has_distance", [False, True])
def test_cache_is_bounded_and_only_for_complete_stores(tmp_path, has_distance):
    db, _ = _filled_db(tmp_path, has_distance=has_distance)
    array_mb = 10 * 10 * 36 * 2 / 1e6 * (2 if has_distance else 1)  # elevations (and distances)
    small = SkyDB.open(db.path, cache_mb=array_mb * 0.99)  # the arrays do not fit: streamed, nothing kept
    small.read_all()
    assert small.cached_mb == 0.0
    fits = SkyDB.open(db.path, cache_mb=array_mb)
    fits.read_all()
    for t in fits.tiles:
        d = fits.read_distance(t)
        assert d is None or np.all(d == 1230.0)
    assert fits.cached_mb == pytest.approx(array_mb)
    w = SkyDBWriter.create(tmp_path / "partial.zarr", _meta())
    w.write_tile(w.tiles[0], np.zeros((4, 4, 36)))
    partial = SkyDB.open(tmp_path / "partial.zarr")  # still being rendered: chunks may change, never cached
    got = partial.read_all()
    assert partial.cached_mb == 0.0
    assert np.all(got[:4, :4] == 0.0) and np.isnan(got[4:]).all()  # unwritten chunks read as missing


@pytest.mark.parametrize("damage", ["garbage", "truncated", "empty"])
def test_damaged_chunk_is_a_format_error(tmp_path, damage):
    db, _ = _filled_db(tmp_path)
    chunk = db.path / "elevation" / "c" / "1" / "1" / "0"
    data = chunk.read_bytes()
    chunk.write_bytes({"garbage": b"\x00garbage", "truncated": data[:len(data) // 2], "empty": b""}[damage])
    db = SkyDB.open(db.path)
    np.testing.assert_array_equal(np.isfinite(db.read_tile(db.tiles[0])), True)  # other chunks still read
    with pytest.raises(FormatError, match="truncated or corrupt"):
        db.read_tile(db.tiles[4])
    with pytest.raises(FormatError, match="truncated or corrupt"):
        db.read_all()


def test_unusual_layout_falls_back_to_zarr(tmp_path):
    """A store whose arrays use a layout the direct reader does not handle (here: no compression and
    dot-separated chunk keys, written by zarr itself) is still read, through zarr."""
    import zarr

    db, truth = _filled_db(tmp_path)
    src = zarr.open_group(str(db.path), mode="r")
    other = tmp_path / "other.zarr"
    g = zarr.open_group(str(other), mode="w")
    g.attrs.update(dict(src.attrs))
    for name in ("elevation", "tile_done"):
        a = src[name]
        b = g.create_array(name, shape=a.shape, chunks=a.chunks, dtype=a.dtype, fill_value=a.fill_value,
                           compressors=None, chunk_key_encoding={"name": "v2", "separator": "."})
        b[...] = a[...]
    reread = SkyDB.open(other)
    assert reread._readers["elevation"] is None
    np.testing.assert_array_equal(reread.read_all(), db.read_all())
    np.testing.assert_allclose(reread.read_all(), truth, atol=0.0051)
