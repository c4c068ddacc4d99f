"""`skyloc db render|info|horizon` end to end on a small procedural DEM, resume included."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from blender_addon.terrain.dem import read_dem
from blender_addon.terrain.procedural import synthesize
from board.skydb import SkyDB
from render_service import dbrender
from render_service.renderers import raymarch
from render_service.renderers.base import RenderSpec
from render_service.renderers.reference import brute_force_horizon
from skyloc.cli import main


@pytest.fixture(scope="module")
def dem_path(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dem") / "mars.tif"
    return synthesize("mars", size_m=3000.0, res_m=10.0, seed=11, out_path=out)


def _render_args(dem, out, *extra):
    return ["db", "render", "--dem", str(dem), "--center", "100,-50", "--size", "80", "--step", "10",
            "--azimuths", "72", "--tile", "3", "--out", str(out), "--no-progress", *extra]


def _chunk_snapshot(store: Path) -> dict[str, tuple[int, bytes]]:
    return {str(p.relative_to(store)): (p.stat().st_mtime_ns, p.read_bytes())
            for p in (store / "elevation").rglob("*") if p.is_file() and p.name != "zarr.json"}


def test_render_info_and_horizon(dem_path, tmp_path):
    out = tmp_path / "db.zarr"
    runner = CliRunner()
    res = runner.invoke(main, _render_args(dem_path, out, "--azimuth-subsamples", "1"))   # point samples
    assert res.exit_code == 0, res.output
    db = SkyDB.open(out)
    s = db.summary()
    assert db.complete and s["positions"] == 81 and s["n_azimuth"] == 72
    assert s["dem_sha256"] == hashlib.sha256(dem_path.read_bytes()).hexdigest()
    assert s["renderer"] == "raymarch" and s["renderer_version"] == raymarch.__version__
    dem = read_dem(dem_path)
    assert s["crs_wkt"] == dem.crs_wkt and s["body_radius_m"] == dem.body.radius_m
    # the stored skyline at a grid position agrees with the brute-force reference there
    i, j = 2, 6
    x, y = db.grid.xy(i, j)
    assert (float(x), float(y)) == (100.0 - 40 + 60, -50.0 + 40 - 20)
    spec = RenderSpec(camera_height_m=2.0, n_azimuth=72, body_radius_m=dem.body.radius_m)
    _, ref = brute_force_horizon(dem, float(x), float(y), spec)
    diff = np.abs(db.skyline(i, j) - ref)
    assert np.median(diff) <= 0.05 and diff.max() <= 0.5
    # db info
    res = runner.invoke(main, ["db", "info", str(out), "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert info["tiles_done"] == info["tiles_total"] == 9 and info["crs_name"]
    res = runner.invoke(main, ["db", "info", str(out)])
    assert res.exit_code == 0 and "complete" in res.output and "81" not in res.output.split("grid")[0]
    assert info["elevation_scale_deg"] == 0.005 and "units of 0.005 deg" in res.output
    assert info["azimuth_subsamples"] == 1 and "point samples" in res.output
    # the ground under each node, stored for the matcher's eye steps: the DEM's bilinear surface there
    assert info["has_ground"] and "ground heights (the eye's steps" in res.output
    gt = dem.geotransform
    u, v = (float(x) - gt[0]) / gt[1] - 0.5, (float(y) - gt[3]) / gt[5] - 0.5
    c0, r0 = int(np.floor(u)), int(np.floor(v))
    a, tu, tv = dem.array.astype(float), u - c0, v - r0
    want = ((1 - tv) * ((1 - tu) * a[r0, c0] + tu * a[r0, c0 + 1])
            + tv * ((1 - tu) * a[r0 + 1, c0] + tu * a[r0 + 1, c0 + 1]))
    from board.skydb import Tile
    assert float(db.read_ground(Tile(-1, -1, i, j, 1, 1))[0, 0]) == pytest.approx(want, abs=1e-3)
    # db horizon at the same position: same renderer, so the same skyline to the 0.005 deg quantum
    res = runner.invoke(main, ["db", "horizon", "--dem", str(dem_path), "--at", f"{float(x)},{float(y)}",
                               "--height", "2.0", "--azimuths", "72", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert doc["azimuth_deg"][:3] == [0.0, 5.0, 10.0] and len(doc["elevation_deg"]) == 72
    assert doc["crs"] == dem.crs_wkt and (doc["x"], doc["y"]) == (float(x), float(y))
    np.testing.assert_allclose(doc["elevation_deg"], db.skyline(i, j), atol=0.1)


def test_default_samples_are_the_horizon_averaged_over_their_step(dem_path, tmp_path):
    """A new database's sample is the mean of AZIMUTH_SUBSAMPLES rays across its 5-degree step (72 azimuths),
    against the brute-force reference traced at the same offsets; `db info` says so."""
    from board.skydb import AZIMUTH_SUBSAMPLES

    out = tmp_path / "box.zarr"
    runner = CliRunner()
    res = runner.invoke(main, _render_args(dem_path, out))
    assert res.exit_code == 0, res.output
    db = SkyDB.open(out)
    assert db.meta.azimuth_subsamples == AZIMUTH_SUBSAMPLES == 4
    dem = read_dem(dem_path)
    i, j = 4, 3
    x, y = (float(v) for v in db.grid.xy(i, j))
    k = AZIMUTH_SUBSAMPLES
    refs = [brute_force_horizon(dem, x, y, RenderSpec(camera_height_m=2.0, n_azimuth=72,
                                                      body_radius_m=dem.body.radius_m,
                                                      azimuth_start_deg=((m + 0.5) / k - 0.5) * 5.0))[1]
            for m in range(k)]
    box, point = np.mean(refs, axis=0), brute_force_horizon(dem, x, y, RenderSpec(
        camera_height_m=2.0, n_azimuth=72, body_radius_m=dem.body.radius_m))[1]
    diff = np.abs(db.skyline(i, j) - box)
    assert np.median(diff) <= 0.05 and diff.max() <= 0.5
    assert np.median(diff) < 0.5 * np.median(np.abs(db.skyline(i, j) - point))   # a box, not the point
    res = runner.invoke(main, ["db", "info", str(out)])
    assert res.exit_code == 0 and f"each the mean of {k} rays across its step" in res.output
    res = runner.invoke(main, _render_args(dem_path, tmp_path / "bad.zarr", "--azimuth-subsamples", "0"))
    assert res.exit_code == 1 and "--azimuth-subsamples" in res.output and not (tmp_path / "bad.zarr").exists()


def test_legacy_unit_on_request_stores_the_same_skylines_coarser(dem_path, tmp_path):
    """--elevation-unit 0.01 (the unit before session 17) stores the same render rounded to 0.01 deg."""
    runner = CliRunner()
    fine, coarse = tmp_path / "fine.zarr", tmp_path / "coarse.zarr"
    assert runner.invoke(main, _render_args(dem_path, fine)).exit_code == 0
    res = runner.invoke(main, _render_args(dem_path, coarse, "--elevation-unit", "0.01"))
    assert res.exit_code == 0, res.output
    a, b = SkyDB.open(fine), SkyDB.open(coarse)
    assert (a.meta.elevation_scale_deg, b.meta.elevation_scale_deg) == (0.005, 0.01)
    ea, eb = a.read_all().astype(np.float64), b.read_all().astype(np.float64)
    assert np.nanmax(np.abs(ea - eb)) <= 0.0075 + 1e-6       # both within half their unit of one render
    assert np.nanmean(np.abs(ea - eb) > 0.0026) > 0.05        # and they do differ: 0.01 is coarser


def test_interrupted_render_resumes_without_rewriting(dem_path, tmp_path):
    out = tmp_path / "db.zarr"
    from board.skydb import AZIMUTH_SUBSAMPLES

    spec = RenderSpec(camera_height_m=2.0, n_azimuth=72, azimuth_subsamples=AZIMUTH_SUBSAMPLES)   # the CLI's default

    def stop_after_four(done, total):
        if done == 4:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        dbrender.render_database(dem_path, center_xy=(100.0, -50.0), size_m=80.0, step_m=10.0, spec=spec,
                                 out=out, tile_size=3, progress=False, on_tile=stop_after_four)
    db = SkyDB.open(out)                      # the interrupted store is kept and readable
    assert not db.complete and db.n_tiles_done() == 4
    before = _chunk_snapshot(out)
    assert len(before) == 4                   # one chunk file per finished tile
    # resume through the CLI: the same command continues
    res = CliRunner().invoke(main, _render_args(dem_path, out))
    assert res.exit_code == 0, res.output
    db = SkyDB.open(out)
    assert db.complete and db.n_tiles_done() == 9
    after = _chunk_snapshot(out)
    for name, (mtime, data) in before.items():
        assert after[name] == (mtime, data), f"finished tile chunk {name} was rewritten"
    # and the result equals an uninterrupted render
    ref = tmp_path / "ref.zarr"
    assert CliRunner().invoke(main, _render_args(dem_path, ref)).exit_code == 0
    np.testing.assert_array_equal(SkyDB.open(ref).read_all(), db.read_all())


def test_new_store_failing_before_its_first_tile_is_removed(dem_path, tmp_path):
    out = tmp_path / "db.zarr"

    def stop_at_once(done, total):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        dbrender.render_database(dem_path, center_xy=(0.0, 0.0), size_m=40.0, step_m=10.0,
                                 spec=RenderSpec(n_azimuth=8), out=out, tile_size=2, progress=False,
                                 on_tile=stop_at_once)
    assert not out.exists()


@pytest.mark.parametrize("extra,message", [
    (["--step", "0"], "--step must be a positive"),
    (["--step", "-5"], "--step must be a positive"),
    (["--center", "5000,0"], "not inside the DEM"),
    (["--azimuths", "0"], "--azimuths must be a positive"),
    (["--height", "-1"], "--height"),
    (["--tile", "0"], "--tile"),
    (["--center", "abc"], "X,Y"),
    (["--elevation-unit", "0.003"], "0.003 deg is not one of 0.01, 0.005"),
])
def test_bad_input_exits_1_and_writes_nothing(dem_path, tmp_path, extra, message):
    out = tmp_path / "db.zarr"
    res = CliRunner().invoke(main, _render_args(dem_path, out, *extra))
    assert res.exit_code == 1, res.output
    assert message in res.output
    assert not out.exists()


def test_refuses_to_resume_a_different_database(dem_path, tmp_path):
    out = tmp_path / "db.zarr"
    runner = CliRunner()
    assert runner.invoke(main, _render_args(dem_path, out)).exit_code == 0
    before = _chunk_snapshot(out)
    res = runner.invoke(main, _render_args(dem_path, out, "--height", "1.5"))
    assert res.exit_code == 1 and "different skyline database" in res.output
    assert _chunk_snapshot(out) == before


def test_horizon_outside_the_dem_is_refused(dem_path):
    res = CliRunner().invoke(main, ["db", "horizon", "--dem", str(dem_path), "--at", "99999,0", "--json"])
    assert res.exit_code == 1 and "the position" in res.output and "not inside the DEM" in res.output


def test_the_progress_bar_says_the_terrain_is_being_prepared_before_the_first_tile(dem_path, tmp_path, capfd):
    """db render used to sit at 0 % while the terrain was built: the bar now opens first and says so."""
    from render_service.dbrender import render_database
    from render_service.renderers.base import RenderSpec

    render_database(dem_path, center_xy=(100.0, -50.0), size_m=40.0, step_m=10.0, spec=RenderSpec(n_azimuth=72),
                    out=tmp_path / "db.zarr", tile_size=3, progress=True)
    err = capfd.readouterr().err
    prep, rend = err.find("preparing the multi-resolution terrain"), err.find("rendering 4 tiles of 9 positions")
    assert 0 <= prep < rend, err
    assert "25/25" in err  # 5 x 5 positions, all counted
