"""Extraction validated on rendered horizons: the ray-marcher's horizon (H2) and Blender's binary
panoramas (H5a) of the same analytic terrain.  Truth = ``render_service.renderers.raymarch.horizon_at``
sampled at the rover skyline's azimuths (heading + j degrees)."""
from __future__ import annotations

import numpy as np
import pytest

from board.acquisition import Panorama, PanoramaGeometry
from board.conventions import Body
from board.extraction import STATUS_OK, extract_from_panorama
from board.synthetic import render_directions

raymarch = pytest.importorskip("render_service.renderers.raymarch")
model = pytest.importorskip("blender_addon.terrain.model")
from render_service.renderers.base import RenderSpec  # noqa: E402

HILLS = [(800, 300, 120, 250), (-600, 900, 200, 400), (-900, -700, 90, 200), (300, -1200, 250, 500),
         (1500, 1500, 300, 500), (-200, 400, 15, 30)]
RADIUS = 3_389_500.0
POSE = (10.0, -20.0)
EYE_M = 2.0


def _heights(X, Y):
    z = np.zeros_like(X)
    for cx, cy, h, s in HILLS:
        z += h * np.exp(-((X - cx) ** 2 + (Y - cy) ** 2) / (2 * s * s))
    return z


@pytest.fixture(scope="module")
def terrain():
    levels = []
    for half, cell in [(500, 2.0), (4000, 10.0)]:
        n = int(round(2 * half / cell))
        xs = -half + (np.arange(n) + 0.5) * cell
        ys = half - (np.arange(n) + 0.5) * cell
        X, Y = np.meshgrid(xs, ys)
        levels.append(model.TerrainLevel(_heights(X, Y).astype(np.float32), -half, half, cell))
    return model.MultiResTerrain(levels, 'LOCAL_CS["analytic"]', Body("custom", RADIUS), (0.0, 0.0))


def _truth(terrain, heading_deg, n=360):
    spec = RenderSpec(camera_height_m=EYE_M, n_azimuth=n, azimuth_start_deg=heading_deg, body_radius_m=RADIUS)
    _, el, _ = raymarch.horizon_at(terrain, *POSE, spec)
    return el


@pytest.fixture(scope="module")
def fine_horizon(terrain):
    """The ray-marched horizon every 0.1 degree from north."""
    return _truth(terrain, 0.0, n=3600)


@pytest.mark.slow
@pytest.mark.parametrize("heading", [0.0, 37.5])
def test_skyline_of_a_ray_marched_horizon(terrain, fine_horizon, heading):
    fine = fine_horizon

    def skyline(az_rel):                                  # periodic linear interpolation of the rendered horizon
        x = np.mod(np.asarray(az_rel, dtype=float) + heading, 360.0) * 10.0
        i0 = np.floor(x).astype(int) % 3600
        t = x - np.floor(x)
        return (1 - t) * fine[i0] + t * fine[(i0 + 1) % 3600]

    g = PanoramaGeometry.full_circle(1800, 300, elevation_top_deg=25.0, elevation_bottom_deg=-5.0)
    img = render_directions(g.azimuths_deg()[None, :], g.elevations_deg()[:, None], skyline,
                            pixel_deg=g.elevation_step_deg)
    img = img + np.random.default_rng(0).normal(0, 0.01, img.shape)
    res = extract_from_panorama(Panorama((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8), g))
    assert res.status == STATUS_OK
    err_px = (res.skyline.elevation_deg - _truth(terrain, heading)) / g.elevation_step_deg
    assert res.skyline.seen.mean() >= 0.97
    assert np.nanmean(np.abs(err_px)) <= 1.0


@pytest.mark.slow
@pytest.mark.blender
def test_blender_binary_panorama_matches_ray_marched_horizon(terrain, tmp_path):
    pytest.importorskip("bpy")
    from blender_addon.core.acquire import Pose
    from blender_addon.scene.panorama import make_panorama

    heading = 30.0
    out = make_panorama(terrain, Pose(*POSE, heading_deg=heading), tmp_path / "pano", height_m=EYE_M, width=2048,
                        binary=True)
    res = extract_from_panorama(out)
    assert res.status == STATUS_OK
    step = res.panorama.geometry.elevation_step_deg
    err_px = (res.skyline.elevation_deg - _truth(terrain, heading)) / step
    assert res.skyline.seen.mean() >= 0.97
    assert np.nanmean(np.abs(err_px)) <= 1.0
