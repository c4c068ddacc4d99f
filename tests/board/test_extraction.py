"""Extraction end to end: acquisitions and panoramas of known skylines -> Skyline samples; failures
reported with a reason, never a made-up skyline; the `skyloc extract` CLI."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from board.acquisition import GroundTruth, Panorama, PanoramaGeometry, write_panorama
from board.camera import CameraModel
from board.errors import InvalidInputError
from board.extraction import (
    STATUS_DEGRADED,
    STATUS_FAILED,
    STATUS_OK,
    ExtractionOptions,
    extract_from_acquisition,
    extract_from_panorama,
    panorama_line_to_skyline,
)
from board.skyline import Skyline
from board.synthetic import SkylineFunction, frame_plan, synth_acquisition, synth_panorama

GEOM = PanoramaGeometry.full_circle(1200, 300, elevation_top_deg=30.0, elevation_bottom_deg=-15.0)


def _u8(img):
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


@pytest.fixture(scope="module")
def acquisition(tmp_path_factory):
    f = SkylineFunction.random(17)
    d = tmp_path_factory.mktemp("acq")
    cam = CameraModel.from_fov(320, 240, 60.0, k1=-0.2, k2=0.05, p1=0.001)
    synth_acquisition(d, cam, frame_plan(8, (5.0,)), f, pitch_deg=-3.0, roll_deg=5.0, noise_sigma=0.01, seed=3)
    return d, f


def test_acquisition_to_skyline_point_samples(acquisition):
    d, f = acquisition
    res = extract_from_acquisition(d)
    assert res.status == STATUS_OK and res.skyline is not None
    sk = res.skyline
    assert sk.n == 360 and sk.azimuth_start_deg == 0.0 and sk.azimuth_step_deg == 1.0
    step = res.panorama.geometry.elevation_step_deg
    err_px = (sk.elevation_deg - f(sk.azimuths_deg())) / step
    assert sk.seen.mean() >= 0.97
    assert np.nanmean(np.abs(err_px)) <= 1.0           # REF requirement: <= 1 px
    assert sk.meta["azimuth_reference"] == "heading"
    json.dumps(res.to_json_dict())


def test_other_azimuth_grids(acquisition):
    from board.extraction import ExtractionOptions

    d, f = acquisition
    res = extract_from_acquisition(d, options=ExtractionOptions(n_azimuth=720, azimuth_start_deg=0.25))
    sk = res.skyline
    assert sk.n == 720 and sk.azimuths_deg()[1] == pytest.approx(0.75)
    err = sk.elevation_deg - f(sk.azimuths_deg())
    assert np.nanmean(np.abs(err)) <= res.panorama.geometry.elevation_step_deg


def test_sampling_keywords_as_locate_uses_them(acquisition):
    # `skyloc locate --acquisition` asks for the database's azimuth step
    d, f = acquisition
    res = extract_from_acquisition(d, azimuth_step_deg=0.5)
    assert res.skyline.n == 720 and res.skyline.azimuth_step_deg == 0.5
    assert res.panorama.geometry.azimuth_step_deg < 0.25          # the panorama keeps its own resolution
    with pytest.raises(InvalidInputError, match="does not divide 360"):
        extract_from_acquisition(d, azimuth_step_deg=0.7)


def test_fine_samples_are_the_same_estimator_on_a_finer_grid(acquisition):
    """The skyline's fine samples (about the panorama's step, an integer fraction of the skyline's) are the
    coarse samples at every k-th azimuth, and read the true skyline as well between them (the matcher
    samples the query there, board.locate.alignment)."""
    d, f = acquisition
    res = extract_from_acquisition(d)
    sk = res.skyline
    assert sk.has_fine
    k = round(sk.azimuth_step_deg / sk.fine_step_deg)
    assert k >= 2 and sk.fine_step_deg <= 1.5 * res.panorama.geometry.azimuth_step_deg
    np.testing.assert_array_equal(sk.fine_elevation_deg[::k], sk.elevation_deg)
    step = res.panorama.geometry.elevation_step_deg
    between = np.arange(sk.fine_elevation_deg.size) % k != 0
    az = sk.azimuth_start_deg + np.arange(sk.fine_elevation_deg.size) * sk.fine_step_deg
    err_px = (sk.fine_elevation_deg - f(az))[between] / step
    assert np.nanmean(np.abs(err_px)) <= 1.0
    shifted = sk.resampled(0.37)
    assert np.nanmean(np.abs(shifted.elevation_deg - f(0.37 + np.arange(360.0)))) <= step
    off = extract_from_acquisition(d, options=ExtractionOptions(fine_samples=False)).skyline
    assert not off.has_fine and np.array_equal(off.elevation_deg, sk.elevation_deg, equal_nan=True)


def test_point_sampling_is_exact_for_a_linear_line():
    g = PanoramaGeometry.full_circle(720, 100, elevation_top_deg=10, elevation_bottom_deg=-10)
    # line whose elevation is linear in azimuth between column centres: el = 0.01 * az (mod the seam)
    az = g.azimuths_deg()
    rows = g.row_of_el(0.01 * az)
    sk = panorama_line_to_skyline(rows, g, n_azimuth=36, azimuth_start_deg=5.0)
    np.testing.assert_allclose(sk.elevation_deg, 0.01 * sk.azimuths_deg(), atol=1e-9)
    # a masked column poisons only the samples that need it
    rows2 = rows.copy()
    k = int(np.argmin(np.abs(az - 95.0)))       # column centred at 95.25 deg: neighbours 94.75/95.25
    rows2[k] = np.nan
    sk2 = panorama_line_to_skyline(rows2, g, n_azimuth=36, azimuth_start_deg=5.0)
    assert np.isnan(sk2.elevation_deg[9]) and np.isfinite(sk2.elevation_deg).sum() == 35


def _brute_force_fit(el_col, col_az, a, half_deg, period=360.0):
    """Reference: np.polyfit of the finite columns within ``half_deg`` of azimuth ``a`` (wrapped)."""
    d = (col_az - a + period / 2) % period - period / 2
    m = (np.abs(d) <= half_deg + 1e-9) & np.isfinite(el_col)
    return np.polyval(np.polyfit(d[m], el_col[m], 1), 0.0)


def test_samples_fit_the_columns_within_half_a_step():
    """Independent column errors (sigma): a line through the 4 columns of a 1-degree step at 1440 px
    (offsets +-0.5, +-1.5 columns) has intercept noise sigma / 2; interpolation between the two columns
    around the sample (fit_half_steps = 0, the control) sigma / sqrt 2.  A curved line is biased by at
    most |el''| w**2 / 2 (w = half a step, degrees)."""
    g = PanoramaGeometry.full_circle(1440, 200, elevation_top_deg=20, elevation_bottom_deg=-20)
    rng = np.random.default_rng(4)
    sigma = 0.1
    e_fit, e_int = [], []
    for _ in range(20):
        el = rng.normal(0.0, sigma, g.width)
        rows = g.row_of_el(el)
        e_fit.append(panorama_line_to_skyline(rows, g).elevation_deg)
        e_int.append(panorama_line_to_skyline(rows, g, fit_half_steps=0.0).elevation_deg)
    rms_fit = float(np.sqrt(np.mean(np.square(e_fit))))
    rms_int = float(np.sqrt(np.mean(np.square(e_int))))
    assert rms_fit == pytest.approx(sigma / 2, rel=0.05)
    assert rms_int == pytest.approx(sigma / np.sqrt(2), rel=0.05)
    # the fit equals the brute-force least squares of the same columns
    el = rng.normal(0.0, sigma, g.width)
    sk = panorama_line_to_skyline(g.row_of_el(el), g, azimuth_start_deg=0.3)
    ref = [_brute_force_fit(el, g.azimuths_deg(), a, 0.5) for a in sk.azimuths_deg()]
    np.testing.assert_allclose(sk.elevation_deg, ref, atol=1e-9)
    # curvature: el = A sin(2 pi az / P), |el''| <= A (2 pi / P)**2
    A, P = 2.0, 20.0
    for start in (0.0, 0.1, 0.375):
        sk = panorama_line_to_skyline(g.row_of_el(A * np.sin(2 * np.pi * g.azimuths_deg() / P)), g,
                                      azimuth_start_deg=start)
        err = sk.elevation_deg - A * np.sin(2 * np.pi * sk.azimuths_deg() / P)
        bound = A * (2 * np.pi / P) ** 2 * 0.5**2 / 2
        assert np.max(np.abs(err)) <= bound
        assert np.max(np.abs(err)) > bound / 10      # the bound is not vacuous: there is a bias


def _brute_force_quad(el_col, col_az, a, half_deg, period=360.0):
    """Reference: np.polyfit of degree 2 of the finite columns within ``half_deg`` of azimuth ``a`` (wrapped)."""
    d = (col_az - a + period / 2) % period - period / 2
    m = (np.abs(d) <= half_deg + 1e-9) & np.isfinite(el_col)
    return np.polyval(np.polyfit(d[m], el_col[m], 2), 0.0)


def test_parabola_samples_remove_the_curvature_bias_at_a_price_in_noise():
    """``fit_degree=2``: each sample the intercept of the least-squares parabola through the same columns
    (brute force: np.polyfit).  On a curved line the line's bias (up to |el''| w**2 / 6) is gone; on
    independent column errors the noise grows by about 1.5 (the parabola's intercept over ~11 columns of a
    3600 px step)."""
    g = PanoramaGeometry.full_circle(3600, 200, elevation_top_deg=20, elevation_bottom_deg=-20)
    az = g.azimuths_deg()
    rng = np.random.default_rng(8)
    el = rng.normal(0.0, 0.1, g.width)
    sk = panorama_line_to_skyline(g.row_of_el(el), g, azimuth_start_deg=0.3, fit_degree=2)
    ref = [_brute_force_quad(el, az, a, 0.5) for a in sk.azimuths_deg()]
    np.testing.assert_allclose(sk.elevation_deg, ref, atol=1e-9)
    A, P = 1.0, 6.0
    curved = A * np.sin(2 * np.pi * az / P)
    for start in (0.0, 0.37):
        lin = panorama_line_to_skyline(g.row_of_el(curved), g, azimuth_start_deg=start)
        par = panorama_line_to_skyline(g.row_of_el(curved), g, azimuth_start_deg=start, fit_degree=2)
        want = A * np.sin(2 * np.pi * lin.azimuths_deg() / P)
        e_lin, e_par = np.abs(lin.elevation_deg - want).max(), np.abs(par.elevation_deg - want).max()
        assert e_lin > 0.01 and e_par < e_lin / 20, (e_lin, e_par)
    noise = {1: [], 2: []}
    for _ in range(10):
        rows = g.row_of_el(rng.normal(0.0, 0.1, g.width))
        for k in noise:
            noise[k].append(panorama_line_to_skyline(rows, g, fit_degree=k).elevation_deg)
    ratio = np.sqrt(np.mean(np.square(noise[2]))) / np.sqrt(np.mean(np.square(noise[1])))
    assert 1.3 < ratio < 1.7, ratio


def test_sample_fit_ignores_masked_columns_and_the_edge_of_a_partial_view():
    g = PanoramaGeometry.full_circle(1440, 200, elevation_top_deg=20, elevation_bottom_deg=-20)
    rng = np.random.default_rng(9)
    el = 0.05 * np.sin(np.radians(g.azimuths_deg()) * 3) + rng.normal(0, 0.05, g.width)
    az = g.azimuths_deg()
    masked = el.copy()
    # around the sample at 100 deg (columns centred 99.625 .. 100.375): mask an outer column only
    outer = int(np.argmin(np.abs(az - 99.625)))
    masked[outer] = np.nan
    sk = panorama_line_to_skyline(g.row_of_el(masked), g)
    assert np.isfinite(sk.elevation_deg[100])
    assert sk.elevation_deg[100] == pytest.approx(_brute_force_fit(masked, az, 100.0, 0.5), abs=1e-9)
    # a masked neighbour of the sample still masks it (the rule of the interpolation is unchanged)
    masked[int(np.argmin(np.abs(az - 100.125)))] = np.nan
    assert np.isnan(panorama_line_to_skyline(g.row_of_el(masked), g).elevation_deg[100])
    assert np.isfinite(panorama_line_to_skyline(g.row_of_el(masked), g).elevation_deg[[99, 101]]).all()
    # partial view: 100 columns from 50 deg, the sample at the first column-pair uses only inside columns
    part = PanoramaGeometry(100, 200, 50.125, 0.25, g.elevation_row0_deg, g.elevation_step_deg)
    pel = el[200:300]
    paz = part.azimuths_deg()
    sk = panorama_line_to_skyline(part.row_of_el(pel), part)
    assert np.isnan(sk.elevation_deg[:51]).all() and np.isnan(sk.elevation_deg[75:]).all()
    assert np.isfinite(sk.elevation_deg[51:75]).all()
    # samples 0.3 column inside the left edge and 0.3 inside the right one: their windows are cut by the edge
    for start, j in ((0.2, 50), (0.8, 74)):
        sk = panorama_line_to_skyline(part.row_of_el(pel), part, azimuth_start_deg=start)
        a = start + j
        assert sk.elevation_deg[j] == pytest.approx(_brute_force_fit(pel, paz, a, 0.5, period=1e9), abs=1e-9)
    with pytest.raises(InvalidInputError, match="fit_half_steps"):
        panorama_line_to_skyline(g.row_of_el(el), g, fit_half_steps=-1.0)


def test_partial_panorama_nan_outside():
    f = SkylineFunction.random(23)
    img = _u8(synth_panorama(GEOM, f, noise_sigma=0.01))
    seen = np.zeros(img.shape, bool)
    az = GEOM.azimuths_deg()
    seen[:, (az > 100) & (az < 220)] = True
    img[~seen] = 0
    res = extract_from_panorama(Panorama(img, GEOM, seen))
    assert res.status == STATUS_OK
    sk = res.skyline
    saz = sk.azimuths_deg()
    assert np.all(np.isnan(sk.elevation_deg[(saz < 99) | (saz > 221)]))
    assert np.isfinite(sk.elevation_deg[(saz > 103) & (saz < 217)]).all()


@pytest.mark.parametrize("case,reason", [
    ("black", "black picture"),
    ("overexposed", "over-exposed"),
    ("all_sky", "all sky"),
    ("all_ground", "all ground"),
    ("flat_grey", "all sky"),
])
def test_failures_have_a_reason_and_no_skyline(case, reason):
    f = SkylineFunction.random(29)
    rng = np.random.default_rng(1)
    if case == "black":
        img = synth_panorama(GEOM, f, noise_sigma=0.003) * 0.02
    elif case == "overexposed":
        img = synth_panorama(GEOM, f, noise_sigma=0.003) * 6.0
    elif case == "all_sky":
        img = synth_panorama(GEOM, lambda a: np.full(np.shape(a), -40.0), noise_sigma=0.01)
    elif case == "all_ground":
        img = synth_panorama(GEOM, lambda a: np.full(np.shape(a), 50.0), noise_sigma=0.01)
    else:
        img = 0.5 + rng.normal(0, 0.01, (GEOM.height, GEOM.width))
    res = extract_from_panorama(Panorama(_u8(img), GEOM))
    assert res.status == STATUS_FAILED and res.skyline is None
    assert reason in res.reason


def test_a_view_with_sky_in_a_fifth_of_its_columns_is_not_refused():
    """The picture-level "no contrast" gate looks at the best tenth of the columns: in a NavCam view whose
    near slopes fill most frames (held-out Baltoro, 2 of 6 acquisitions refused with 170 deg of horizon in
    view) the median column has no contrast.  The columns without one are masked, not guessed."""
    f = SkylineFunction.random(29)
    img = synth_panorama(GEOM, f, noise_sigma=0.01)
    flat = np.arange(GEOM.width) >= 0.2 * GEOM.width
    img[:, flat] = 0.5 + np.random.default_rng(1).normal(0, 0.01, (GEOM.height, int(flat.sum())))
    res = extract_from_panorama(Panorama(_u8(img), GEOM))
    assert res.diagnostics["separation"] < ExtractionOptions().min_separation      # the median column: none
    assert res.status == STATUS_DEGRADED
    det = res.detection
    assert not det.valid[flat].any() and det.valid[~flat].mean() >= 0.9
    truth = GEOM.row_of_el(f(GEOM.azimuths_deg()))
    assert np.nanmean(np.abs(det.line_row - truth)) <= 0.5


def test_camera_tilted_into_the_ground(tmp_path):
    # frames looking 35 deg down at terrain with a skyline near 0 deg: the top of the view is below the line
    f = SkylineFunction(8.0, ((3, 1.0, 0.0),))
    cam = CameraModel.from_fov(160, 120, 50.0)
    synth_acquisition(tmp_path, cam, frame_plan(8, (-35.0,)), f, noise_sigma=0.01)
    res = extract_from_acquisition(tmp_path)
    assert res.status == STATUS_FAILED and "ground" in res.reason


def test_north_referenced_panorama(tmp_path):
    f = SkylineFunction.random(31)
    g = PanoramaGeometry.full_circle(1200, 300, elevation_top_deg=30.0, elevation_bottom_deg=-15.0,
                                     azimuth_reference="north", kind="intensity")
    write_panorama(tmp_path, _u8(synth_panorama(g, f, noise_sigma=0.01)), g, truth=GroundTruth(0, 0, 40.0))
    res = extract_from_panorama(tmp_path)
    assert res.skyline.meta["azimuth_reference"] == "north"
    err = res.skyline.elevation_deg - f(res.skyline.azimuths_deg())
    assert np.nanmean(np.abs(err)) <= g.elevation_step_deg


# -- CLI --------------------------------------------------------------------------------------
def _cli():
    from skyloc.cli import main

    return main


def test_cli_extract_panorama_with_debug_picture(tmp_path):
    f = SkylineFunction.random(37)
    pano_dir = tmp_path / "pano"
    write_panorama(pano_dir, _u8(synth_panorama(GEOM, f, noise_sigma=0.01)), GEOM)
    out, dbg, rep = tmp_path / "sky.json", tmp_path / "dbg.png", tmp_path / "rep.json"
    r = CliRunner().invoke(_cli(), ["extract", "--panorama", str(pano_dir), "--out", str(out), "--debug", str(dbg),
                                    "--report", str(rep)])
    assert r.exit_code == 0, r.output
    sk = Skyline.load(out)
    assert np.nanmean(np.abs(sk.elevation_deg - f(sk.azimuths_deg()))) <= GEOM.elevation_step_deg
    assert dbg.stat().st_size > 10_000 and dbg.read_bytes()[:4] == b"\x89PNG"
    assert json.loads(rep.read_text())["status"] == "ok"


def test_cli_extract_acquisition(acquisition, tmp_path):
    d, _ = acquisition
    out = tmp_path / "sky.json"
    r = CliRunner().invoke(_cli(), ["extract", "--acquisition", str(d), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert Skyline.load(out).coverage_deg >= 350


def test_cli_failure_writes_nothing(tmp_path):
    pano_dir = tmp_path / "pano"
    write_panorama(pano_dir, np.zeros((GEOM.height, GEOM.width), np.uint8), GEOM)
    out = tmp_path / "sky.json"
    r = CliRunner().invoke(_cli(), ["extract", "--panorama", str(pano_dir), "--out", str(out)])
    assert r.exit_code == 1 and "black picture" in r.output
    assert not out.exists()
    r = CliRunner().invoke(_cli(), ["extract", "--out", str(out)])
    assert r.exit_code == 2 and "exactly one" in r.output
