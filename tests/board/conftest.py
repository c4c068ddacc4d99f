"""Fixtures for the matching tests: skyline databases and an independent horizon function to query.

``mountain_world``: analytic hills (board.match.synthetic), exact horizons anywhere.
``raymarch_world``: a procedural Mars DEM, its database rendered by the ray-marcher, and queries
ray-marched at 0.25 degree at arbitrary (off-grid) positions.  ``real_world``: the same on a real DEM.
Queries are made independently of the grid: rendered at the query position, then rotated on the
sphere by the mast's pitch/roll, resampled, noised and masked.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pytest

from board.conventions import BODIES, curvature_drop_m
from board.match.synthetic import MountainField, mask_arc, observe
from board.skydb import GridSpec, SkyDB, SkyDBMeta, SkyDBWriter
from board.skyline import Skyline


@dataclass
class World:
    """A database and a function (x, y) -> (azimuths, elevations) of the true horizon, degrees."""

    db: SkyDB
    horizon: Callable[[float, float], tuple[np.ndarray, np.ndarray]]
    name: str

    @property
    def step(self) -> float:
        return abs(self.db.grid.geotransform[1])

    def random_xy(self, rng, margin_steps: float = 2.0) -> tuple[float, float]:
        x0, y0, x1, y1 = self.db.grid.bounds()
        m = margin_steps * self.step
        return float(rng.uniform(x0 + m, x1 - m)), float(rng.uniform(y0 + m, y1 - m))

    def query(self, x, y, *, heading, pitch=0.0, roll=0.0, noise=0.0, arc=360.0, arc_start=0.0, rng=None) -> Skyline:
        az, el = self.horizon(x, y)
        q = observe(az, el, heading_deg=heading, pitch_deg=pitch, roll_deg=roll, n=self.db.meta.n_azimuth)
        if noise > 0:
            q = q + rng.normal(0.0, noise, q.size)
        if arc < 360:
            q = mask_arc(q, start_deg=arc_start, width_deg=arc)
        return Skyline(q)


def _write_db(path, grid: GridSpec, fn, n_az=360) -> SkyDB:
    meta = SkyDBMeta(grid=grid, camera_height_m=2.0, n_azimuth=n_az, tile_size=16, renderer="analytic")
    w = SkyDBWriter.create(path, meta)
    az = meta.azimuths_deg()
    for t in w.tiles:
        ii, jj = np.mgrid[t.row0:t.row0 + t.nrows, t.col0:t.col0 + t.ncols]
        x, y = grid.xy(ii, jj)
        w.write_tile(t, fn(x.ravel(), y.ravel(), az).reshape(t.nrows, t.ncols, n_az))
    return w.finalize()


@pytest.fixture(scope="session")
def mountain_world(tmp_path_factory) -> World:
    mf = MountainField.random(21, r_min=500.0)
    grid = GridSpec.from_center((1000.0, 2000.0), 150.0, 5.0)
    mf = MountainField(mf.px + 1000.0, mf.py + 2000.0, mf.height, mf.width)
    db = _write_db(tmp_path_factory.mktemp("mw") / "db.zarr", grid, mf.horizon_chunked)
    fine = np.arange(0.0, 360.0, 0.25)
    return World(db, lambda x, y: (fine, mf.horizon(x, y, fine)[0]), "mountains")


@pytest.fixture(scope="session")
def far_ridges_world(tmp_path_factory):
    """Hills 1.5-20 km away, 0.5-1.4 deg wide: skylines with structure finer than the database's 1-degree
    step (as a DEM seen across a crater floor), a 100 m database at 5 m."""
    rng = np.random.default_rng(5)
    n = 150
    d = np.exp(rng.uniform(np.log(1500.0), np.log(20000.0), n))
    a = rng.uniform(0.0, 2.0 * np.pi, n)
    h = d * np.tan(np.radians(rng.uniform(0.5, 6.0, n))) + curvature_drop_m(d, BODIES["mars"].radius_m)
    mf = MountainField(d * np.sin(a), d * np.cos(a), h, d * rng.uniform(0.004, 0.012, n))
    db = _write_db(tmp_path_factory.mktemp("far") / "db.zarr", GridSpec.from_center((0.0, 0.0), 100.0, 5.0),
                   mf.horizon_chunked)
    return db, mf


def _raymarched(tmp, dem, center, size_m, step_m) -> World:
    from render_service.dbrender import load_terrain, prepare_job, render_database
    from render_service.renderers.base import RenderSpec
    from render_service.renderers.raymarch import render_positions

    spec = RenderSpec(camera_height_m=2.0, n_azimuth=360)
    db = render_database(dem, center_xy=center, size_m=size_m, step_m=step_m, spec=spec, out=tmp / "db.zarr",
                         terrain_dir=tmp / "terrain", progress=False, tile_size=16)
    job = prepare_job(dem, center_xy=center, size_m=size_m, step_m=step_m, spec=spec)
    terrain = load_terrain(job, terrain_dir=tmp / "terrain")
    fine = RenderSpec(camera_height_m=2.0, n_azimuth=1440, body_radius_m=db.meta.body_radius_m,
                      refraction_k=db.meta.refraction_k)

    def horizon(x, y):
        el, _ = render_positions(terrain, np.array([x]), np.array([y]), fine)
        return fine.azimuths_deg(), el[0].astype(np.float64)

    return World(db, horizon, f"raymarch:{dem.name}")


@pytest.fixture(scope="session")
def raymarch_world(tmp_path_factory) -> World:
    """Procedural Mars terrain (8 km at 5 m, seed 11), database 200 m x 200 m at 5 m (41 x 41)."""
    pytest.importorskip("numba")
    from blender_addon.terrain.procedural import synthesize

    tmp = tmp_path_factory.mktemp("rw")
    dem = synthesize("mars", size_m=8000.0, res_m=5.0, seed=11, out_path=tmp / "mars.tif")
    return _raymarched(tmp, dem, (0.0, 0.0), 200.0, 5.0)


@pytest.fixture(scope="session")
def real_world(tmp_path_factory, real_dem) -> World:
    """Mount St Helens (USGS 30 m DEM), database 300 m x 300 m at 10 m around the DEM's centre."""
    pytest.importorskip("numba")
    from blender_addon.terrain.dem import dem_info

    dem = real_dem("earth_sthelens_1980_usgs30m.dem")
    b = dem_info(dem).bounds
    center = (round((b[0] + b[2]) / 2.0 - 1500.0), round((b[1] + b[3]) / 2.0))
    return _raymarched(tmp_path_factory.mktemp("real"), dem, center, 300.0, 10.0)
