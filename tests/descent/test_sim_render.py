"""The fast renderer: fused kernel against the numpy path, co-registration through the written sequence,
the altimeter against an independent ray cast, and the ray cast against a dense search."""
import math

import numpy as np
import pytest

from blender_addon.descent.imu import AltimeterParams, simulate_altimeter
from blender_addon.descent.lights import default_lights
from blender_addon.descent.render import AppearanceOptions, DescentRenderer
from blender_addon.descent.simulate import DescentConfig, default_camera, simulate_trial, trial_motion
from blender_addon.descent.terrain import procedural_europa
from board.conventions import rotation_enu_from_camera
from board.descent.sequence import read_sequence

SMALL = dict(terrain_size_m=400.0, terrain_res_m=1.0, width=64, height=48)


@pytest.fixture(scope="module")
def terrain():
    return procedural_europa(5, size_m=120.0, res_m=0.5)


def _dense_first_hit(terrain, origin, d, t_max, step=0.002):
    """First crossing of the ray below the bilinear surface, by dense sampling (numpy, independent)."""
    t = np.arange(0.0, t_max, step)
    p = origin + t[:, None] * d
    f = p[:, 2] - terrain.height_at(p[:, 0], p[:, 1])
    below = np.nonzero(f <= 0)[0]
    return np.nan if below.size == 0 else t[below[0]]


def test_ray_cast_equals_a_dense_search(terrain):
    r = DescentRenderer(terrain, default_lights())
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(25):
        origin = np.array([rng.uniform(-30, 30), rng.uniform(-30, 30), rng.uniform(40, 90)])
        d = np.array([rng.normal(0, 0.25), rng.normal(0, 0.25), -1.0])
        d /= np.linalg.norm(d)
        t_ref = _dense_first_hit(terrain, origin, d, 200.0)
        t = r.range_along(origin, d)
        # the kernel samples every res/2 horizontally: it may miss a sliver thinner than that (rare)
        assert np.isnan(t) == np.isnan(t_ref)
        if np.isfinite(t_ref):
            hits += 1
            assert t == pytest.approx(t_ref, abs=0.01), (origin, d)
    assert hits >= 20


def test_fused_kernel_equals_the_numpy_renderer(terrain):
    for opts in (AppearanceOptions(), AppearanceOptions(shadows=True, rho_s=0.5, k_phong=4.0, ambient=0.3)):
        r = DescentRenderer(terrain, default_lights(sun_elevation_deg=25.0), opts)
        cam = default_camera(80, 60, 50.0)
        R = rotation_enu_from_camera(30.0, 3.0, -2.0)
        p = np.array([5.0, -4.0, 75.0])
        fast, ref = r.render(cam, R, p), r.render_reference(cam, R, p)
        for k in ("visible", "thermal", "range", "x", "y", "z"):
            np.testing.assert_allclose(fast[k], ref[k], rtol=1e-12, atol=1e-9, err_msg=k)
        assert np.isfinite(fast["visible"]).all()
    assert r.lit["sun"].mean() < 0.99          # the low Sun casts shadows on this terrain


def test_hapke_with_cast_shadows_darkens_shadowed_ground(terrain):
    r = DescentRenderer(terrain, default_lights(sun_elevation_deg=15.0), AppearanceOptions(brdf="hapke"))
    out = r.render(default_camera(80, 60, 50.0), rotation_enu_from_camera(0.0), np.array([0.0, 0.0, 80.0]))
    lit = r.sample("lit:sun", out["x"].ravel(), out["y"].ravel()).reshape(out["x"].shape)
    assert np.median(out["visible"][lit < 0.01]) < 0.2 * np.median(out["visible"][lit > 0.99])


def test_both_cameras_see_the_same_ground_point_at_the_same_pixel(tmp_path):
    cfg = DescentConfig(terrain="procedural:europa:3", trajectory=9, trial=2, frames=3, **SMALL)
    seq = read_sequence(simulate_trial(cfg, tmp_path / "trial"))
    gt = seq.groundtruth
    from scipy.spatial.transform import Rotation

    from blender_addon.descent.simulate import cached_renderer

    renderer = cached_renderer(cfg.terrain, cfg.terrain_res_m, cfg.terrain_size_m, tuple(cfg.lights), cfg.appearance)
    for i, t in enumerate(seq.frame_times):
        row = gt[np.argmin(np.abs(gt[:, 0] - t))]
        assert row[0] == pytest.approx(t)
        R_wb = Rotation.from_quat(row[4:8]).as_matrix()
        p_wb = row[1:4]
        out = renderer.render(seq.cameras["visible"], R_wb, p_wb)
        ground = np.stack([out["x"], out["y"], out["z"]], axis=-1)          # the ground point of every pixel
        assert np.isfinite(ground).all()
        for mode in ("visible", "thermal"):
            cam = seq.cameras[mode]
            c = p_wb + R_wb @ cam.t_body_cam
            dirs_cam = (ground - c) @ (R_wb @ cam.R_body_cam)
            u, v = cam.model.project(dirs_cam)
            uu, vv = cam.model.pixel_grid()
            np.testing.assert_allclose(u, uu, atol=1e-6)
            np.testing.assert_allclose(v, vv, atol=1e-6)
        # the stored frames are those renders (the pose read back from the TUM file is rounded to 1e-9:
        # a count may flip at a rounding boundary)
        stored = seq.load_frame("thermal", i).astype(int)
        assert np.abs(stored - seq.cameras["thermal"].radiometric.to_counts(out["thermal"], 14)).max() <= 1


def test_altimeter_equals_an_independent_ray_cast(terrain):
    cfg = DescentConfig(trajectory=6, duration_s=20.0)
    r = DescentRenderer(terrain, default_lights())
    motion = trial_motion(cfg, terrain)
    exact = simulate_altimeter(motion, AltimeterParams(sigma_m=0.0, rate_hz=1.0, dropout_prob=0.0), r.range_along,
                               np.random.default_rng(0))
    for t, rng_m, valid in exact:
        R = motion.rotation([t])[0]
        p = motion.position([t])[0]
        assert valid == 1.0
        assert rng_m == pytest.approx(_dense_first_hit(terrain, p, -R[:, 2], 300.0), abs=0.01)
        # at these small tilts the slant range is close to the height above the ground below
        assert rng_m * R[2, 2] == pytest.approx(p[2] - terrain.height_at(p[0], p[1]), abs=2.0)
    noisy = simulate_altimeter(motion, AltimeterParams(sigma_m=0.3, rate_hz=50.0, dropout_prob=0.1), r.range_along,
                               np.random.default_rng(1))
    ok = noisy[:, 2] == 1
    n = len(noisy)
    assert abs((~ok).sum() - 0.1 * n) < 4 * math.sqrt(n * 0.1 * 0.9) and np.isnan(noisy[~ok, 1]).all()
    true = np.array([r.range_along(motion.position([t])[0], -motion.rotation([t])[0][:, 2]) for t in noisy[ok, 0]])
    res = noisy[ok, 1] - true
    # chi-square bounds (99.9 %) on the residual variance and a 4-sigma bound on its mean
    from scipy.stats import chi2

    k = res.size
    assert chi2.ppf(0.0005, k) < np.sum(res ** 2) / 0.3 ** 2 < chi2.ppf(0.9995, k)
    assert abs(res.mean()) < 4 * 0.3 / math.sqrt(k)


@pytest.mark.slow
def test_every_trajectory_keeps_the_whole_view_on_the_terrain():
    from blender_addon.descent.simulate import cached_renderer
    from blender_addon.descent.trajectories import TRAJECTORIES

    cfg = DescentConfig(terrain="procedural:europa:2", terrain_res_m=1.0)
    r = cached_renderer(cfg.terrain, cfg.terrain_res_m, cfg.terrain_size_m, tuple(cfg.lights), cfg.appearance)
    cam = cfg.cameras()["visible"]
    w, h = cam.model.width, cam.model.height
    corners = cam.model.unproject(np.array([0, w - 1, 0, w - 1]), np.array([0, 0, h - 1, h - 1]))
    for tid in TRAJECTORIES:
        for trial in (0, 29):
            m = trial_motion(DescentConfig(terrain=cfg.terrain, terrain_res_m=1.0, trajectory=tid, trial=trial),
                             r.terrain)
            for t in np.linspace(0.0, cfg.duration_s, 21):
                R, p = m.rotation([t])[0], m.position([t])[0]
                for d in corners @ (R @ cam.R_body_cam).T:
                    assert np.isfinite(r.range_along(p + R @ cam.t_body_cam, d)), (tid, trial, t)
