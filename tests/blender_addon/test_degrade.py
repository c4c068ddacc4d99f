"""Degradations: noise statistics, distortion against board.camera, dispersion, seeds, parameters."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from blender_addon.core.degrade import (
    PRESETS,
    Degradation,
    add_glare,
    add_sensor_noise,
    degrade_frame,
    distort_image,
    gaussian_blur,
    get_degradation,
    render_camera_for,
    srgb_decode,
    srgb_encode,
)
from board.camera import CameraModel
from board.errors import InvalidInputError

CAM = CameraModel(160, 120, 150.0, 152.0, 81.3, 58.2, k1=-0.15, k2=0.03, p1=5e-4, p2=-4e-4, k3=0.0)


def _dot_render(pinhole: CameraModel, dirs: np.ndarray, sigma: float = 1.2) -> np.ndarray:
    """A pinhole image of Gaussian dots at the given camera-frame directions (analytic projection)."""
    u, v = pinhole.pixel_grid()
    img = np.zeros((pinhole.height, pinhole.width), np.float32)
    x = dirs[:, 0] / dirs[:, 2] * pinhole.fx + pinhole.cx
    y = dirs[:, 1] / dirs[:, 2] * pinhole.fy + pinhole.cy
    for xi, yi in zip(x, y):
        img += np.exp(-((u - xi) ** 2 + (v - yi) ** 2) / (2 * sigma ** 2)).astype(np.float32)
    return img


def _centroids(img: np.ndarray, guesses_u, guesses_v, r: int = 5):
    out = []
    for gu, gv in zip(guesses_u, guesses_v):
        u0, v0 = int(round(gu)), int(round(gv))
        win = img[v0 - r:v0 + r + 1, u0 - r:u0 + r + 1].astype(float)
        vv, uu = np.mgrid[v0 - r:v0 + r + 1, u0 - r:u0 + r + 1]
        out.append(((win * uu).sum() / win.sum(), (win * vv).sum() / win.sum()))
    return np.array(out)


def test_remapped_dots_land_where_camera_projects_them():
    pinhole = render_camera_for(CAM)
    # directions spread over the whole distorted image, corners included
    us, vs = np.meshgrid(np.linspace(12, CAM.width - 13, 6), np.linspace(12, CAM.height - 13, 5))
    dirs = CAM.unproject(us.ravel(), vs.ravel())
    out = distort_image(_dot_render(pinhole, dirs), pinhole, CAM)
    assert out.shape == (CAM.height, CAM.width)
    u_true, v_true = CAM.project(dirs)
    c = _centroids(out, u_true, v_true)
    err = np.hypot(c[:, 0] - u_true, c[:, 1] - v_true)
    assert err.max() < 0.1, err


def test_render_camera_holds_every_ray():
    pinhole = render_camera_for(CAM, dispersion=0.01)
    u, v = CAM.pixel_grid()
    d = CAM.unproject(u, v)
    for s in (0.99, 1.01):
        x = d[..., 0] / d[..., 2] * s * pinhole.fx + pinhole.cx
        y = d[..., 1] / d[..., 2] * s * pinhole.fy + pinhole.cy
        assert x.min() >= 1 and x.max() <= pinhole.width - 2
        assert y.min() >= 1 and y.max() <= pinhole.height - 2
    # barrel distortion sees more than the undistorted pinhole of the same size
    assert pinhole.width > CAM.width and pinhole.height > CAM.height


def test_dispersion_magnifies_red_and_shrinks_blue():
    pinhole = render_camera_for(CAM, dispersion=0.01)
    d0 = CAM.unproject(np.array([150.0]), np.array([100.0]))      # off-centre point
    img = np.repeat(_dot_render(pinhole, d0)[..., None], 3, axis=2)
    out = distort_image(img, pinhole, CAM, dispersion=0.01)
    cs = [_centroids(out[..., c], [150.0], [100.0])[0] for c in range(3)]
    rg = np.hypot(cs[1][0] - CAM.cx, cs[1][1] - CAM.cy)
    rr = np.hypot(cs[0][0] - CAM.cx, cs[0][1] - CAM.cy)
    rb = np.hypot(cs[2][0] - CAM.cx, cs[2][1] - CAM.cy)
    # red samples the ray magnified by 1.01, so the dot appears closer to the centre in red
    assert rr < rg < rb
    assert np.hypot(cs[1][0] - 150.0, cs[1][1] - 100.0) < 0.1   # green is the calibrated channel


@pytest.mark.parametrize("signal", [0.05, 0.3, 0.7])
def test_noise_mean_and_variance_follow_shot_plus_read(signal):
    fw, rn = 5000.0, 12.0
    img = np.full((400, 500), signal, np.float32)
    out = add_sensor_noise(img, np.random.default_rng(1), full_well_e=fw, read_noise_e=rn)
    expected_var = signal / fw + (rn / fw) ** 2
    assert out.mean() == pytest.approx(signal, abs=4 * np.sqrt(expected_var / img.size))
    # sample variance of 200k draws: relative standard error ~ sqrt(2/n) = 0.3 %
    assert out.var() == pytest.approx(expected_var, rel=0.02)


def test_noise_clips_at_full_well_and_seeds_reproduce():
    img = np.full((50, 50), 3.0, np.float32)
    out = add_sensor_noise(img, np.random.default_rng(0), full_well_e=1000, read_noise_e=5)
    assert out.max() == 1.0 and out.min() > 0.9
    r = np.random.default_rng(0).random((40, 60, 3)).astype(np.float32)
    deg = PRESETS["distorted"]
    pin = render_camera_for(CAM, dispersion=deg.lens.dispersion)
    big = np.random.default_rng(5).random((pin.height, pin.width, 3)).astype(np.float32)
    a = degrade_frame(big, pin, CAM, deg, np.random.default_rng(42))
    b = degrade_frame(big, pin, CAM, deg, np.random.default_rng(42))
    c = degrade_frame(big, pin, CAM, deg, np.random.default_rng(43))
    assert a.dtype == np.uint8 and a.shape == (CAM.height, CAM.width, 3)
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()
    assert r.shape == (40, 60, 3)


def test_exposure_saturates_and_binary_stays_binary():
    pin = render_camera_for(CameraModel.from_fov(64, 48, 60))
    cam = CameraModel.from_fov(64, 48, 60)
    flat = np.full((pin.height, pin.width, 3), 0.3, np.float32)
    over = Degradation.from_dict({"sensor": {"exposure_ev": 2.0}})
    out = degrade_frame(flat, pin, cam, over, np.random.default_rng(0))
    assert (out == 255).all()                    # 0.3 * 4 clips
    under = degrade_frame(flat, pin, cam, Degradation.from_dict({"sensor": {"exposure_ev": -1.0}}),
                          np.random.default_rng(0))
    assert srgb_decode(under / 255.0).mean() == pytest.approx(0.15, abs=0.003)
    half = flat.copy()
    half[: pin.height // 2] = 0.0
    half[pin.height // 2:] = 1.0
    b = degrade_frame(half, pin, cam, get_degradation("binary"), np.random.default_rng(0))
    assert set(np.unique(b)) == {0, 255}


def test_srgb_round_trip_and_blur_preserves_mean():
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(srgb_decode(srgb_encode(x)), x, atol=1e-12)
    img = np.random.default_rng(3).random((60, 80)).astype(np.float32)
    bl = gaussian_blur(img, 1.5)
    assert bl.std() < img.std()
    assert bl.mean() == pytest.approx(img.mean(), abs=0.01)


def test_glare_peaks_towards_the_sun():
    cam = CameraModel.from_fov(80, 60, 60)
    img = np.zeros((60, 80), np.float32)
    sun = np.array([0.8, 0.0, 1.0])        # to the right, outside the 60 deg field (38.7 deg off axis)
    g = add_glare(img, cam, sun, 1.0)
    assert g[:, -1].mean() > g[:, 0].mean() * 2
    assert np.argmax(g[30]) == 79


def test_parameter_errors_name_the_fix():
    with pytest.raises(InvalidInputError, match="unknown setting 'k9'"):
        Degradation.from_dict({"lens": {"k9": 1}})
    with pytest.raises(InvalidInputError, match="dust optical depth"):
        Degradation.from_dict({"sky": {"dust_tau": -1}})
    with pytest.raises(InvalidInputError, match="expected a number"):
        Degradation.from_dict({"sensor": {"exposure_ev": "lots"}})
    with pytest.raises(InvalidInputError, match="whole number"):
        Degradation.from_dict({"rocks": {"near_count": 2.5}})
    with pytest.raises(InvalidInputError, match="use one of"):
        get_degradation("foggy")
    with pytest.raises(InvalidInputError, match="not invertible"):
        render_camera_for(CameraModel.from_fov(100, 100, 120, k1=-0.9))
    d = Degradation.from_dict({"rocks": {"near_count": 3, "near_distance_m": [1.5, 3]}}, base=PRESETS["realistic"])
    assert d.rocks.near_count == 3 and d.rocks.near_distance_m == (1.5, 3.0)
    assert d.rocks.density_per_m2 == PRESETS["realistic"].rocks.density_per_m2


def test_bilinear_matches_a_pixel_by_pixel_reference():
    from blender_addon.core.degrade import bilinear

    rng = np.random.default_rng(0)
    img = rng.random((50, 70, 3)).astype(np.float32)
    u = rng.uniform(-2, 72, (30, 40))
    v = rng.uniform(-2, 52, (30, 40))
    u[0, 0] = np.nan
    ref = np.zeros(u.shape + (3,))
    for i in np.ndindex(u.shape):
        if not np.isfinite(u[i]):
            continue
        x, y = min(max(u[i], 0), 69), min(max(v[i], 0), 49)
        x0, y0 = min(int(x), 68), min(int(y), 48)
        fx, fy = x - x0, y - y0
        ref[i] = (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
                  + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)
    out = bilinear(img, u, v)
    assert out.dtype == np.float32 and out[0, 0].tolist() == [0.0, 0.0, 0.0]
    np.testing.assert_allclose(out, ref, atol=1e-6)
    np.testing.assert_allclose(bilinear(img[..., 1], u, v), ref[..., 1], atol=1e-6)


def test_every_body_has_its_look_and_a_foreign_look_is_named(caplog):
    """A realistic look per body (Earth, Mars, Moon, Europa); a look used on another body's terrain is warned
    about with the look to use; body-free looks (binary, clean) fit any body."""
    import logging

    from blender_addon.core.degrade import PRESETS, check_look_body, look_for_body
    from board.conventions import BODIES

    for body in BODIES:
        name = look_for_body(body)
        assert name is not None and PRESETS[name].body == body
        assert check_look_body(PRESETS[name], body) is None
    assert look_for_body("mars") == "realistic"
    with caplog.at_level(logging.WARNING, logger="blender_addon.core.degrade"):
        msg = check_look_body(PRESETS["realistic"], "earth")
    assert "made for Mars" in msg and "'realistic-earth'" in msg and msg in caplog.text
    assert check_look_body(PRESETS["binary"], "europa") is None and check_look_body(PRESETS["clean"], "moon") is None
    # sunlight follows the inverse square of the distance to the Sun (semi-major axes 1.000, 1.524, 5.203 AU)
    sun = {b: PRESETS[look_for_body(b)].sun.strength for b in BODIES}
    assert sun["earth"] / sun["mars"] == pytest.approx(1.524 ** 2, rel=0.01)
    assert sun["europa"] / sun["mars"] == pytest.approx((1.524 / 5.203) ** 2, rel=0.02)
    assert sun["moon"] == sun["earth"]


def test_realistic_and_distorted_take_the_body_of_the_terrain():
    """A campaign's realistic/distorted looks on a body are that body's look (the Mars dust is not put on the
    Moon); distorted keeps its lens; body-free looks and a body's own look are unchanged."""
    from blender_addon.core.degrade import PRESETS, check_look_body, look_on_body
    from board.conventions import BODIES

    for body in BODIES:
        real, dist = look_on_body("realistic", body), look_on_body("Distorted", body)
        assert real.body == body and dist.body == body
        assert check_look_body(real, body) is None and check_look_body(dist, body) is None
        assert dist.lens == PRESETS["distorted"].lens and dist.sky == real.sky and dist.sensor == real.sensor
        assert dist.rocks == real.rocks and dist.regolith_albedo == real.regolith_albedo
        for other in ("binary", "clean", "realistic-earth"):
            assert look_on_body(other, body) is PRESETS[other]
    assert look_on_body("realistic", "mars") is PRESETS["realistic"]
    assert look_on_body("distorted", "mars") is PRESETS["distorted"]
    assert look_on_body("realistic", "moon").name == "realistic-moon"
    assert look_on_body("distorted", "moon").name == "distorted-moon"
    assert look_on_body("realistic", "moon").sky.dust_tau == 0.0  # no dust on an airless body
    with pytest.raises(InvalidInputError, match="unknown degradation preset"):
        look_on_body("foggy", "mars")


def test_the_camera_exposes_for_the_scene_on_every_body():
    """Auto-exposure: gain 1 for the Mars looks (the reference), and sunlight x albedo compensated elsewhere:
    the sunlit ground of every body's look is exposed as Mars regolith in Mars sunlight."""
    from blender_addon.core.degrade import AUTO_EXPOSURE_REFERENCE, PRESETS, auto_exposure_gain, look_for_body
    from board.conventions import BODIES

    for name in ("clean", "realistic", "distorted", "binary"):
        assert auto_exposure_gain(PRESETS[name]) == pytest.approx(1.0)
    for body in BODIES:
        d = PRESETS[look_for_body(body)]
        ground = d.regolith_albedo * d.sun.strength * auto_exposure_gain(d)
        assert ground == pytest.approx(AUTO_EXPOSURE_REFERENCE)
    earth = PRESETS["realistic-earth"]
    assert auto_exposure_gain(earth) == pytest.approx(0.22 / (0.25 * 1.52 ** 2), rel=0.01)  # 1.2 stops down
    manual = replace(earth, sensor=replace(earth.sensor, auto_exposure=False))
    assert auto_exposure_gain(manual) == 1.0  # a fixed exposure: Earth's sunlight over-exposes


def test_a_look_names_a_known_body():
    from blender_addon.core.degrade import Degradation

    assert Degradation.from_dict({"body": "Moon"}).body == "moon"
    with pytest.raises(InvalidInputError, match="body: expected one of earth, mars, moon, europa"):
        Degradation.from_dict({"body": "pluto"})


def test_the_black_sky_is_airless_and_the_moons_own():
    from blender_addon.core.degrade import Degradation, check_look_body, look_on_body

    black = look_on_body("realistic-moon-black", "moon")
    assert black.sky.black and black.sky.dust_tau == 0.0 and check_look_body(black, "moon") is None
    assert look_on_body("realistic", "moon").name == "realistic-moon"      # the Moon's default look is unchanged
    with pytest.raises(InvalidInputError, match="black .*no dust"):
        Degradation.from_dict({"sky": {"black": True, "dust_tau": 0.5}})
