"""Database samples as the horizon averaged over their azimuth step (``azimuth_subsamples``).

Truth: the same ray-marcher traced ray by ray (a K-ray sample is the mean of K point renders), a dense
render (0.01 deg) averaged over each step, and the extraction's own sampling of a perfect camera (the
dense horizon averaged over 0.1-degree pixel columns, then :func:`board.extraction.panorama_line_to_skyline`).
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from skyloc_service_test_helpers import analytic_terrain

from blender_addon.terrain.model import MultiResTerrain
from board.acquisition import PanoramaGeometry
from board.errors import FormatError, InvalidInputError
from board.extraction import panorama_line_to_skyline
from board.skydb import AZIMUTH_SUBSAMPLES, GridSpec, SkyDB, SkyDBMeta, SkyDBWriter, plan_tiles
from render_service.renderers import raymarch
from render_service.renderers.base import RenderSpec, render_tile_sampled

R_RING_M = 4000.0      # a jagged crater rim this far from the eye (relief changing every few tenths of a degree)


def _rim(X, Y):
    r = np.hypot(X, Y)
    th = np.arctan2(X, Y)
    h = 250.0 + 30.0 * np.sin(5 * th) + 12.0 * np.sin(173 * th + 1.0) + 8.0 * np.sin(617 * th + 2.0)
    return h * np.exp(-((r - R_RING_M) / 120.0) ** 2)


@pytest.fixture(scope="module")
def rim_terrain() -> MultiResTerrain:
    return analytic_terrain(_rim, [(4600.0, 4.0)], radius_m=1.0e7)


def test_bad_subsample_counts_are_refused_with_the_range():
    for bad in (0, 65, 1.5):
        with pytest.raises(InvalidInputError, match="azimuth_subsamples"):
            RenderSpec(azimuth_subsamples=bad)


def test_the_rays_of_a_sample_are_centred_on_its_azimuth():
    spec = RenderSpec(n_azimuth=360, azimuth_start_deg=10.0, azimuth_subsamples=4)
    rays = spec.ray_spec()
    assert rays.n_azimuth == 1440 and rays.azimuth_subsamples == 1
    az = rays.azimuths_deg().reshape(360, 4)
    np.testing.assert_allclose(az.mean(axis=1), spec.azimuths_deg(), atol=1e-9)
    np.testing.assert_allclose(az[:, 0], spec.azimuths_deg() - 0.375, atol=1e-9)
    np.testing.assert_allclose(np.diff(az, axis=1), 0.25, atol=1e-9)
    assert RenderSpec(azimuth_subsamples=1).ray_spec() == RenderSpec()


def test_a_k_ray_sample_is_the_mean_of_k_point_renders(rim_terrain):
    grid = GridSpec.from_center((30.0, -20.0), size_m=20.0, step_m=10.0, crs_wkt='LOCAL_CS["rim"]')
    tile = plan_tiles(grid, 8)[0]
    spec = RenderSpec(camera_height_m=2.0, n_azimuth=90, azimuth_start_deg=0.0, body_radius_m=1.0e7,
                      azimuth_subsamples=3)
    box = render_tile_sampled(raymarch.render_tile, rim_terrain, grid, tile, spec)
    step = 4.0
    singles = [raymarch.render_tile(rim_terrain, grid, tile, RenderSpec(
        camera_height_m=2.0, n_azimuth=90, azimuth_start_deg=o * step, body_radius_m=1.0e7))
        for o in (-1 / 3, 0, 1 / 3)]
    want = np.mean([s.elevation_deg for s in singles], axis=0)
    # the march samples each ray at distances seeded by the previous azimuth's horizon: the same ray traced
    # between other neighbours agrees to the march's sampling accuracy, not bit for bit
    np.testing.assert_allclose(box.elevation_deg, want, atol=5e-3)
    assert np.mean(np.abs(box.elevation_deg - want)) < 5e-4
    assert box.elevation_deg.shape == (tile.nrows, tile.ncols, 90)
    rays = raymarch.render_tile(rim_terrain, grid, tile, spec.ray_spec()).elevation_deg
    np.testing.assert_allclose(box.elevation_deg, rays.reshape(tile.nrows, tile.ncols, 90, 3).mean(axis=-1), atol=1e-5)


def _dense(terrain, x, y, n=36000):
    spec = RenderSpec(camera_height_m=2.0, n_azimuth=n, azimuth_start_deg=0.5 * 360.0 / n, body_radius_m=1.0e7)
    return raymarch.horizon_at(terrain, x, y, spec)[1]       # sample i at (i + 0.5) * 0.01 deg


def test_four_rays_are_the_step_average_and_the_extraction_measures_that_not_the_point(rim_terrain):
    x, y = 13.0, -7.0
    dense = _dense(rim_terrain, x, y)                         # 0.01 deg, centred in 0.01-degree bins
    # the horizon averaged over each 1-degree step centred on its azimuth (dense bins [j - 0.5, j + 0.5))
    box_truth = np.roll(dense, 50).reshape(360, 100).mean(axis=1)

    def db_samples(k):
        spec = RenderSpec(camera_height_m=2.0, n_azimuth=360, body_radius_m=1.0e7, azimuth_subsamples=k)
        rays = raymarch.horizon_at(rim_terrain, x, y, spec.ray_spec())[1]
        return spec.box_mean(rays[None, :])[0].astype(np.float64)

    point, box = db_samples(1), db_samples(AZIMUTH_SUBSAMPLES)
    rms = lambda a: float(np.sqrt(np.mean(a ** 2)))  # noqa: E731
    assert rms(point - box_truth) > 0.01              # the rim is jagged at sub-degree scales
    assert rms(box - box_truth) < 0.25 * rms(point - box_truth)
    # a perfect camera: 0.1-degree columns, each the horizon averaged over its width; the extraction's samples
    cols = dense.reshape(3600, 10).mean(axis=1)      # column c covers [0.1 c, 0.1 c + 0.1), centre 0.1 c + 0.05
    geom = PanoramaGeometry(3600, 900, 0.05, 0.1, 45.0, 0.1)
    line = (geom.elevation_row0_deg - cols) / geom.elevation_step_deg
    extracted = panorama_line_to_skyline(line, geom, n_azimuth=360, azimuth_start_deg=0.0).elevation_deg
    assert rms(extracted - box) < 0.3 * rms(extracted - point)


def _meta(**kw):
    grid = GridSpec.from_center((0.0, 0.0), size_m=10.0, step_m=5.0, crs_wkt='LOCAL_CS["t"]')
    return SkyDBMeta(grid=grid, camera_height_m=2.0, n_azimuth=36, tile_size=2, dem_sha256="abc", **kw)


def test_the_store_says_how_its_samples_were_made_and_old_stores_are_point_samples(tmp_path):
    w = SkyDBWriter.create(tmp_path / "box.zarr", _meta(azimuth_subsamples=4))
    for t in w.tiles:
        w.write_tile(t, np.zeros((t.nrows, t.ncols, 36)))
    db = w.finalize()
    assert SkyDB.open(tmp_path / "box.zarr").meta.azimuth_subsamples == 4
    assert db.summary()["azimuth_subsamples"] == 4
    # a store from before the attribute: point samples
    attrs_file = tmp_path / "box.zarr" / "zarr.json"
    doc = json.loads(attrs_file.read_text())
    del doc["attributes"]["azimuth_subsamples"]
    attrs_file.write_text(json.dumps(doc))
    assert SkyDB.open(tmp_path / "box.zarr").meta.azimuth_subsamples == 1
    doc["attributes"]["azimuth_subsamples"] = 0
    attrs_file.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="azimuth_subsamples"):
        SkyDB.open(tmp_path / "box.zarr")


def test_resuming_with_other_samples_is_refused_naming_the_field(tmp_path):
    w = SkyDBWriter.create(tmp_path / "db.zarr", _meta(azimuth_subsamples=4))
    w.write_tile(w.tiles[0], np.zeros((w.tiles[0].nrows, w.tiles[0].ncols, 36)))
    with pytest.raises(InvalidInputError, match="azimuth_subsamples"):
        SkyDBWriter.create(tmp_path / "db.zarr", _meta(azimuth_subsamples=1))
    assert math.isclose(SkyDB.open(tmp_path / "db.zarr").meta.azimuth_subsamples, 4)
