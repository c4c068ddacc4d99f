"""Skyline extraction on Blender-rendered panoramas, one test per scene difficulty of issue 11.

Every scene is rendered by Blender (Cycles, dressed terrain, few samples, 720 x 180 pixels over
elevations -40..50 deg, 0.5 deg per pixel) at one pose of a procedural Mars DEM, and its truth is
the ray-marcher's horizon (``render_service.renderers.raymarch.horizon_at``) on the same
multi-resolution terrain, every 0.1 deg, turned into the mast frame
(:func:`benchmarks.detector_labels.true_skyline`).  The checks are the issue's three figures,
at test tolerances: a skyline is returned, enough of the seen azimuths are kept, the kept samples
are accurate (median within half a pixel) and hardly ever more than 1 degree off (a wrong kept
column is worse than a masked one): at most 2 % here, where 1 degree is only 2 pixels; the issue's
0.5 % is measured at 1440 px by ``benchmarks/bench_detector.py``.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("bpy")

from benchmarks.bench_detector import in_view, truth_on_grid  # noqa: E402
from benchmarks.detector_labels import LabelCase, load_label, make_label  # noqa: E402
from blender_addon.core import degrade  # noqa: E402
from blender_addon.core.degrade import RockParams, SensorParams, SkyParams  # noqa: E402
from board.acquisition import load_panorama  # noqa: E402
from board.extraction import STATUS_FAILED, extract_from_panorama  # noqa: E402

pytestmark = [pytest.mark.blender, pytest.mark.slow]

DEM = "procedural:mars:55:4000:5"
X, Y, HEADING = 137.3, -88.9, 61.0


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The multi-resolution terrain around the pose, built once in the Blender scene."""
    from blender_addon.scene import build_terrain, reset_scene
    from blender_addon.terrain.dem import resolve_dem
    from blender_addon.terrain.multires import build_multires

    terrain = build_multires(resolve_dem(DEM, cache_dir=tmp_path_factory.mktemp("dem")), (X, Y), grid_half_m=50.0)
    reset_scene()
    build_terrain(terrain)
    return terrain, tmp_path_factory.mktemp("scenes")


def _case(preset: str, *, sun_az_rel: float = 150.0, sun_el: float = 35.0, pitch: float = 0.0, roll: float = 0.0,
          seed: int = 3) -> LabelCase:
    return LabelCase(split="test", dem=DEM, x=X, y=Y, heading_deg=HEADING, pitch_deg=pitch, roll_deg=roll,
                     preset=preset, sun_azimuth_deg=(HEADING + sun_az_rel) % 360.0, sun_elevation_deg=sun_el,
                     seed=seed, texture_seed=17, width=720, samples=4)


def _render(site, name: str, case: LabelCase, **kw):
    terrain, root = site
    folder = make_label(case, terrain=terrain, out=root / name, build=False, **kw)
    _, fine, _ = load_label(folder)
    pano = load_panorama(folder / "pano")
    res = extract_from_panorama(pano)
    truth = truth_on_grid(fine)
    return res, truth, in_view(truth, pano.geometry)


def _check(res, truth, view, *, min_kept: float, max_median_deg: float = 0.25, max_bad: float = 0.02):
    assert res.status != STATUS_FAILED, res.reason
    assert view.sum() > 300                                     # the true horizon is in view
    el = res.skyline.elevation_deg
    kept = view & np.isfinite(el)
    assert kept.sum() / view.sum() >= min_kept, res.reason
    err = np.abs(el[kept] - truth[kept])
    assert np.median(err) <= max_median_deg
    assert np.mean(err > 1.0) <= max_bad, f"{np.sum(err > 1.0)} kept samples more than 1 deg off"
    return err


def test_haze_and_dust_gradient(site):
    deg = replace(degrade.get_degradation("realistic"), sky=SkyParams(dust_tau=1.5))
    _check(*_render(site, "dust", _case("realistic"), degradation=deg), min_kept=0.9)


def test_sun_and_halo_in_view(site):
    # a low sun straight ahead: its halo touches the horizon on a clear and on a dusty sky
    for preset in ("clean", "realistic"):
        _check(*_render(site, f"sun_{preset}", _case(preset, sun_az_rel=0.0, sun_el=10.0)), min_kept=0.9)


def test_dark_lunar_sky(site):
    # airless: where shaded slopes are as black as the sky the boundary cannot be measured and is masked
    # (a third of the azimuths at this pose with a 20-degree sun in session 3, 4.4 % in session 15)
    _check(*_render(site, "lunar", _case("clean", sun_el=20.0), dark_sky=True), min_kept=0.85)


def test_black_sky_of_the_moons_own_look(site):
    # realistic-moon-black: no sky light, the sky black to the sensor's noise and the regolith lit by the sun and
    # by itself.  A black window has no colour: the "sky coloured like the ground" check leaves it alone (before
    # session 32 it masked 30 % of this view's lit horizon on the log(blue / red) of noise)
    res, truth, view = _render(site, "black", _case("realistic-moon-black", sun_az_rel=20.0, sun_el=35.0))
    pano = load_panorama(site[1] / "black" / "pano")
    el = pano.geometry.elevations_deg()
    assert np.mean(pano.image[el > 45.0]) < 4.0                  # a black sky (8-bit levels)
    assert res.diagnostics["sky_coloured_like_ground_fraction"] == 0.0
    _check(res, truth, view, min_kept=0.88)


def test_bright_sky_as_grey_as_sunlit_ground(site):
    # the clean look: a bright blue-white sky, the regolith in front of it about as bright in grey
    _check(*_render(site, "bright", _case("clean", sun_el=55.0)), min_kept=0.9)


def test_over_exposure(site):
    deg = replace(degrade.get_degradation("clean"), sensor=SensorParams(exposure_ev=1.5))
    _check(*_render(site, "over", _case("clean"), degradation=deg), min_kept=0.5)


def test_under_exposure(site):
    deg = replace(degrade.get_degradation("realistic"),
                  sensor=SensorParams(exposure_ev=-3.0, full_well_e=12_000.0, read_noise_e=15.0))
    _check(*_render(site, "under", _case("realistic"), degradation=deg), min_kept=0.6)


def test_vignetting_and_dispersion(site):
    # the distorted look's optics applied per 45-degree frame tile: channel misregistration, light fall-off
    _check(*_render(site, "optics", _case("distorted")), min_kept=0.9)


def test_sensor_noise(site):
    deg = replace(degrade.get_degradation("realistic"), sensor=SensorParams(full_well_e=1_500.0, read_noise_e=40.0))
    _check(*_render(site, "noise", _case("realistic"), degradation=deg), min_kept=0.6)


def test_low_contrast_distant_ridges(site):
    # thick dust fades the distant ridges towards the sky: they are kept right or masked, never replaced
    deg = replace(degrade.get_degradation("realistic"), sky=SkyParams(dust_tau=3.0))
    _check(*_render(site, "faint", _case("realistic"), degradation=deg), min_kept=0.8)


def test_tilted_mast(site):
    for name, kw in (("pitch", {"pitch": 10.0}), ("roll", {"roll": -10.0})):
        _check(*_render(site, name, _case("clean", **kw)), min_kept=0.9)


def test_near_rocks_do_not_give_wrong_columns(site):
    # five boulders of 2-3 m within 4 m of the mast.  Their outline is kept when it is the sky/ground
    # boundary (the fix then flags it as above the DEM's skyline: tests/board/test_locate_robust.py);
    # where they stand below the horizon, as here, they must not pull the line off it.
    rocks = RockParams(density_per_m2=0.0, near_count=5, near_distance_m=(2.5, 4.0), near_diameter_m=(2.0, 3.0))
    deg = replace(degrade.get_degradation("realistic"), rocks=rocks)
    _check(*_render(site, "rocks", _case("realistic", seed=8), degradation=deg), min_kept=0.7)


def test_earth_sunlight_is_exposed_for_and_not_clipped(site):
    """The Earth look has 2.3 times Mars' sunlight: with the NavCam's auto-exposure the sunlit slopes and the
    sky near the horizon keep their tones (nearly nothing at full scale) and the skyline is kept; with a fixed
    exposure (auto_exposure off, the look before) they clip to white."""
    from board.acquisition import load_panorama as _load

    earth = degrade.get_degradation("realistic-earth")
    fixed = replace(earth, sensor=replace(earth.sensor, auto_exposure=False))
    clipped = {}
    for name, deg in (("earth", earth), ("earth-fixed", fixed)):
        res, truth, view = _render(site, name, _case("realistic", sun_el=50.0), degradation=deg)
        img = np.asarray(_load(site[1] / name / "pano").image)
        clipped[name] = float(np.mean(img.reshape(-1, img.shape[-1]).max(axis=1) >= 250))
        if name == "earth":
            _check(res, truth, view, min_kept=0.75)
    assert clipped["earth"] < 0.01, clipped
    assert clipped["earth-fixed"] > 5 * max(clipped["earth"], 0.01), clipped  # the control: it clips without


def test_clipped_sky_line_is_moved_to_its_edge(site):
    """The Moon look's bright sky clips towards a high sun: the clipped half of the blurred step is gone and
    the line found lies below the edge there (0.1-0.3 px, more the higher the clipped band above it), also
    where the mixed row just above the line is not itself clipped (the band is counted over it).  The
    extraction's model (board.clipped_sky, fitted on other renders: Aristoteles 114) moves it back: against
    the ray-marched truth, the clipped samples' mean error is less than half what it was."""
    from board.extraction import ExtractionOptions

    terrain, root = site
    case = replace(_case("realistic-moon", sun_az_rel=150.0, sun_el=60.0), width=1800)
    folder = make_label(case, terrain=terrain, out=root / "moon-clip", build=False)
    _, fine, _ = load_label(folder)
    pano = load_panorama(folder / "pano")
    truth = truth_on_grid(fine)
    view = in_view(truth, pano.geometry)
    g = pano.geometry
    means, bands = {}, {}
    for gain in (0.0, ExtractionOptions().clipped_sky_gain):
        res = extract_from_panorama(pano, options=replace(ExtractionOptions(), clipped_sky_gain=gain))
        el = res.skyline.elevation_deg
        n = el.size
        rel = np.mod(np.arange(n) * 360.0 / n + 180.0, 360.0) - 180.0
        cols = np.rint((rel - g.azimuth_col0_deg) / g.azimuth_step_deg).astype(int) % g.width
        band = res.detection.clipped_rows[cols] * abs(g.elevation_step_deg)
        err = (el - truth) / g.elevation_step_deg                     # elevation pixels, + = line too high
        clipped = view & np.isfinite(err) & (band > 0)
        assert clipped.sum() > 100                                    # a high sun: most of the circle clips
        means[gain] = float(np.mean(err[clipped]))
        bands[gain] = float(np.median(band[clipped]))
    off, on = means[0.0], means[ExtractionOptions().clipped_sky_gain]
    assert off < -0.08, (means, bands)                                # the clipped line lies below the edge
    # ... and is moved back towards it: the model is an empirical fit of the band's height (another terrain and
    # sky: this view is over-corrected by about 0.08 px, from 0.21 px low)
    assert abs(on) < 0.5 * abs(off), (means, bands)
