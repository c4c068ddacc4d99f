"""Binary panoramas rendered by Blender against independent geometry.

* a camera at a known pose (with pitch and roll) inside an analytic crater: the terrain/sky
  boundary of every column is where a numpy ray-caster on the analytic surface puts it (1 px);
* a flat plain on a small sphere seen from a camera far from the scene origin: the horizon dips
  by acos(R / (R + h)) in every direction (curvature and the camera's local vertical);
* a real DEM: the binary panorama agrees with the ray-marcher within 1 px;
* `skyloc sim panorama --binary` writes a valid panorama folder;
* a band render (only the rows where the skyline can be) is the whole sphere's rows, pixel for pixel.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("bpy")

from blender_addon import scene as S  # noqa: E402
from blender_addon.core.terrain_mesh import sample_height  # noqa: E402
from blender_addon.terrain.model import MultiResTerrain, TerrainLevel  # noqa: E402
from board.conventions import BODIES, Body, horizon_dip_deg, rotation_enu_from_camera  # noqa: E402

pytestmark = pytest.mark.blender


def _crater_height(x, y):
    """Rim of radius 40 m, Gaussian profile 6 m wide, height 10 +- 4 m varying with azimuth."""
    r = np.hypot(x, y)
    th = np.arctan2(x, y)
    return (10.0 + 4.0 * np.sin(3 * th)) * np.exp(-(((r - 40.0) / 6.0) ** 2))


def _crater_terrain(cell=0.5, half=100.0) -> MultiResTerrain:
    n = int(2 * half / cell)
    c = -half + (np.arange(n) + 0.5) * cell
    X, Y = np.meshgrid(c, -c)
    return MultiResTerrain([TerrainLevel(_crater_height(X, Y).astype(np.float32), -half, half, cell)], "",
                           BODIES["mars"], (0.0, 0.0))


def _boundary_from_image(img: np.ndarray) -> np.ndarray:
    """Elevation (deg) of the top edge of the first terrain pixel of each column of a full-sphere panorama."""
    h = img.shape[0]
    t = img >= 0.5
    first = np.where(t.any(0), np.argmax(t, axis=0), h)
    return 90.0 - first * 180.0 / h


def _reference_boundary(cam, rot, alphas_deg, *, lo=-40.0, hi=60.0, max_d=95.0, step=0.05):
    """Bisection per column on 'does the ray at this camera-frame elevation hit the analytic terrain'."""
    a = np.radians(alphas_deg)[:, None]
    lo_el = np.full(len(alphas_deg), lo)
    hi_el = np.full(len(alphas_deg), hi)
    t = np.arange(step, max_d, step)[None, :]
    for _ in range(22):
        mid = np.radians((lo_el + hi_el) / 2)[:, None]
        body = np.stack(np.broadcast_arrays(np.cos(mid) * np.cos(a), -np.cos(mid) * np.sin(a), np.sin(mid)), -1)
        d = body @ rot.T                                        # (ncol, 1, 3) world directions
        px, py, pz = (cam[i] + d[..., i] * t for i in range(3))
        ok = np.hypot(px, py) < max_d
        hit = np.any(ok & (pz < _crater_height(px, py)), axis=1)
        lo_el = np.where(hit, (lo_el + hi_el) / 2, lo_el)
        hi_el = np.where(hit, hi_el, (lo_el + hi_el) / 2)
    return (lo_el + hi_el) / 2


def test_crater_skyline_at_a_tilted_pose_within_one_pixel(tmp_path):
    terrain = _crater_terrain()
    S.reset_scene()
    S.build_terrain(terrain, refine=False)          # 0.5 m cells on a smooth rim: triangles are exact enough
    x, y, heading, pitch, roll = 3.0, -2.0, 33.0, 7.0, -4.0
    z = sample_height(terrain, x, y) + 1.5
    S.place_camera(x, y, z, heading, pitch, roll)
    S.configure_binary()
    w = 256
    img = S.read_image(S.render_equirect(tmp_path / "p.png", width=w, height=w // 2))
    assert set(np.unique(img).tolist()) <= {0.0, 1.0}          # exactly binary
    got = _boundary_from_image(img)
    alphas = -180.0 + (np.arange(w) + 0.5) * 360.0 / w
    ref = _reference_boundary(np.array([x, y, z]), rotation_enu_from_camera(heading, pitch, roll), alphas)
    px = 180.0 / (w // 2)
    err = np.abs(got - ref)
    assert err.max() <= px, f"worst column off by {err.max() / px:.2f} px"
    assert np.ptp(ref) > 8 * px                                 # the pose really tilts the skyline


def test_curved_plain_horizon_dip_far_from_the_scene_origin():
    from blender_addon.skyline_renderer import BlenderSkylineOptions, render_position

    R, h = 100_000.0, 30.0
    n = 200
    terrain = MultiResTerrain([TerrainLevel(np.zeros((n, n), np.float32), -20_000.0, 20_000.0, 200.0)], "",
                              Body("custom", R), (0.0, 0.0))
    az = np.arange(0, 360, 5.0)
    el, dist = render_position(terrain, 6000.0, -4000.0, az, camera_height_m=h, radius_m=R,
                         options=BlenderSkylineOptions(deg_per_px=0.02))
    # parabolic drop d^2/2R: the horizon is at atan(sqrt(2h/R)) below the local horizontal
    expect = -math.degrees(math.atan(math.sqrt(2 * h / R)))
    assert expect == pytest.approx(-horizon_dip_deg(h, R), abs=0.01)
    np.testing.assert_allclose(el, expect, atol=0.03)
    # the ray just below the boundary lands short of the tangent point, sqrt(2 R h) away
    assert np.all((dist > 0.75 * np.sqrt(2 * R * h)) & (dist <= 1.01 * np.sqrt(2 * R * h)))


def test_dem_panorama_matches_the_ray_marcher(real_dem, tmp_path):
    from blender_addon.core.acquire import Pose
    from blender_addon.scene.panorama import make_panorama
    from blender_addon.terrain.multires import build_multires
    from board.acquisition import load_panorama
    from render_service.renderers.base import RenderSpec
    from render_service.renderers.raymarch import horizon_at

    dem = real_dem("mars_gale_hirise_1m_mmgis_missionDEM.tif")
    site = (8142580.0, -276620.0)
    terrain = build_multires(dem, site, grid_half_m=20.0)
    pose = Pose(site[0] + 3.0, site[1] - 4.0, heading_deg=20.0)
    w = 512
    out = make_panorama(terrain, pose, tmp_path / "pano", height_m=2.0, width=w, binary=True)
    pano = load_panorama(out)
    g = pano.geometry
    got = _boundary_from_image(np.asarray(pano.image, dtype=float) / 255.0)
    spec = RenderSpec(camera_height_m=2.0, n_azimuth=w, azimuth_start_deg=(pose.heading_deg + g.azimuth_col0_deg) % 360,
                      body_radius_m=terrain.body.radius_m)
    _, ref, _ = horizon_at(terrain, pose.x, pose.y, spec)
    px = g.elevation_step_deg
    err = np.abs(got - ref)
    assert np.percentile(err, 99) <= px and np.median(err) <= px / 2


def test_sim_panorama_cli_writes_a_valid_binary_folder(tmp_path):
    from click.testing import CliRunner

    from board.acquisition import load_panorama
    from skyloc.cli import main

    out = tmp_path / "pano"
    args = ["sim", "panorama", "--dem", "procedural:mars:3:2000:10", "--at", "50,-30", "--height", "2",
            "--heading", "45", "--pitch", "6", "--roll", "-5", "--width", "128", "--binary", "--out", str(out)]
    res = CliRunner().invoke(main, args, env={"XDG_CACHE_HOME": str(tmp_path / "cache")})
    assert res.exit_code == 0, res.output
    pano = load_panorama(out)
    assert pano.geometry.kind == "binary" and pano.geometry.width == 128
    assert set(np.unique(pano.image).tolist()) <= {0, 255}
    assert pano.truth.pitch_deg == 6.0 and pano.truth.roll_deg == -5.0
    bad = CliRunner().invoke(main, [*args[:-3], "--preset", "clean", "--binary", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 1 and not (tmp_path / "bad").exists()


def test_a_band_is_the_whole_spheres_rows_pixel_for_pixel(tmp_path):
    """Binary renders are centre rays: the band -45..45 of a 256 px panorama is rows 32..95 of the whole
    sphere's, exactly; and its skyline is where the analytic ray-caster puts it."""
    from blender_addon.scene.panorama import panorama_band, panorama_geometry

    terrain = _crater_terrain()
    S.reset_scene()
    S.build_terrain(terrain, refine=False)
    x, y, heading, pitch, roll = -6.0, 4.0, 120.0, -5.0, 8.0
    z = sample_height(terrain, x, y) + 1.5
    S.place_camera(x, y, z, heading, pitch, roll)
    S.configure_binary()
    w = 256
    full = S.read_image(S.render_equirect(tmp_path / "full.png", width=w, height=w // 2))
    g = panorama_geometry(w, binary=True, elevation_range_deg=(-45.0, 45.0))
    assert (g.height, g.el_of_row(0), g.el_of_row(g.height - 1)) == (64, pytest.approx(45 - 0.703125),
                                                                      pytest.approx(-45 + 0.703125))
    band = S.read_image(S.render_equirect(tmp_path / "band.png", width=w, height=g.height,
                                          el_range_deg=(-45.0, 45.0)))
    np.testing.assert_array_equal(band, full[32:96])
    t = band >= 0.5
    first = np.argmax(t, axis=0)                                # the band starts in the sky everywhere here
    assert not t[0].any() and t[-1].all()
    got = 45.0 - first * 90.0 / g.height
    alphas = -180.0 + (np.arange(w) + 0.5) * 360.0 / w
    ref = _reference_boundary(np.array([x, y, z]), rotation_enu_from_camera(heading, pitch, roll), alphas)
    assert np.abs(got - ref).max() <= g.elevation_step_deg
    # a band that is not a whole number of square pixels widens downwards, but never past the nadir
    assert panorama_band(w, (-44.0, 45.0)) == (64, -45.0, 45.0)
    h, bottom, top = panorama_band(w, (-90.0, 10.0))                # 71.1 rows: 71, the nadir not passed
    assert (h, top) == (71, 10.0) and bottom == pytest.approx(-89.84375)


def test_sim_panorama_cli_renders_a_band_and_refuses_a_bad_one(tmp_path):
    from click.testing import CliRunner

    from board.acquisition import load_panorama
    from skyloc.cli import main

    env = {"XDG_CACHE_HOME": str(tmp_path / "cache")}
    base = ["sim", "panorama", "--dem", "procedural:mars:3:2000:10", "--at", "50,-30", "--heading", "45",
            "--width", "128", "--binary"]
    res = CliRunner().invoke(main, [*base, "--band=-22.5,33.75", "--out", str(tmp_path / "band")], env=env)
    assert res.exit_code == 0, res.output
    assert "128 x 20" in res.output
    full = CliRunner().invoke(main, [*base, "--out", str(tmp_path / "full")], env=env)
    assert full.exit_code == 0, full.output
    b, f = load_panorama(tmp_path / "band"), load_panorama(tmp_path / "full")
    assert b.geometry.el_of_row(0) == pytest.approx(33.75 - 1.40625)
    np.testing.assert_array_equal(b.image, f.image[20:40])      # 90 - 33.75 = 20 rows of 2.8125 deg
    for bad in ("--band=10,-10", "--band=-95,10", "--band=low,high"):
        r = CliRunner().invoke(main, [*base, bad, "--out", str(tmp_path / "bad")], env=env)
        assert r.exit_code == 1 and "--band" in r.output and not (tmp_path / "bad").exists()


def test_perspective_frame_matches_the_camera_model(tmp_path):
    """render_frame with an off-centre principal point: the crater's skyline lies where
    board.camera.CameraModel.unproject + the pose put it (within 1 px per column)."""
    import dataclasses

    from board.camera import CameraModel

    terrain = _crater_terrain()
    S.reset_scene()
    S.build_terrain(terrain, refine=False)          # 0.5 m cells on a smooth rim: triangles are exact enough
    x, y, heading, pitch, roll = -4.0, 6.0, 250.0, 9.0, 5.0
    z = sample_height(terrain, x, y) + 1.2
    S.place_camera(x, y, z, heading, pitch, roll)
    S.configure_binary()
    model = dataclasses.replace(CameraModel.from_fov(160, 120, 70.0), cx=70.5, cy=66.0)
    img = S.read_image(S.render_frame(tmp_path / "f.png", model, color_mode="BW"))
    assert img.shape == (120, 160) and set(np.unique(img).tolist()) <= {0.0, 1.0}
    t = img >= 0.5
    got = np.where(t.any(0), np.argmax(t, axis=0), 120).astype(float)   # first terrain row (its top edge)
    rot = rotation_enu_from_camera(heading, pitch, roll)
    cam = np.array([x, y, z])
    u = np.arange(160, dtype=float)
    lo, hi = np.full(160, -0.5), np.full(160, 119.5)            # v of pixel-centre rows (OpenCV)
    ts = np.arange(0.05, 95, 0.05)[None, :]
    for _ in range(20):
        v = (lo + hi) / 2
        dc = model.unproject(u, v)                              # camera frame: x right, y down, z forward
        body = np.stack([dc[:, 2], -dc[:, 0], -dc[:, 1]], -1)
        d = body @ rot.T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        px, py, pz = (cam[i] + d[:, i:i + 1] * ts for i in range(3))
        hit = np.any((np.hypot(px, py) < 95) & (pz < _crater_height(px, py)), axis=1)
        hi = np.where(hit, v, hi)
        lo = np.where(hit, lo, v)
    ref = (lo + hi) / 2 + 0.5                                   # boundary in row-edge units (row r spans r..r+1)
    inside = (ref > 1) & (ref < 119)
    assert inside.sum() > 100
    assert np.max(np.abs(got[inside] - ref[inside])) <= 1.0


@pytest.mark.slow
def test_sim_panorama_dressed_preset_is_reproducible_and_stored_bgr(tmp_path):
    """--preset uses H5b's dressing: same seed, same bytes; written in OpenCV's BGR order (Mars is red)."""
    pytest.importorskip("blender_addon.scene.dressing")
    from click.testing import CliRunner

    from board.acquisition import load_panorama
    from skyloc.cli import main

    outs = []
    for k in range(2):
        out = tmp_path / f"pano{k}"
        args = ["sim", "panorama", "--dem", "procedural:mars:3:2000:10", "--at", "50,-30", "--heading", "45",
                "--width", "64", "--preset", "realistic", "--samples", "2", "--seed", "5", "--out", str(out)]
        res = CliRunner().invoke(main, args, env={"XDG_CACHE_HOME": str(tmp_path / "cache")})
        assert res.exit_code == 0, res.output
        outs.append(out)
    assert (outs[0] / "panorama.png").read_bytes() == (outs[1] / "panorama.png").read_bytes()
    pano = load_panorama(outs[0])
    assert pano.geometry.kind == "intensity" and pano.meta["preset"] == "realistic"
    # at least 2 rays per pixel, up to 4 x as many where Cycles still sees noise (adaptive sampling)
    assert (pano.meta["samples"], pano.meta["samples_max"], pano.meta["adaptive"]) == (2, 8, True)
    bgr = pano.image.reshape(-1, 3).astype(float).mean(axis=0)
    assert bgr[2] > bgr[0]                                      # red above blue, in BGR storage
