"""The query sampled on the database's azimuths (board.locate.alignment, Skyline fine samples)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from board.errors import InvalidInputError
from board.locate import locate
from board.locate.alignment import alignment_shift_deg
from board.match.synthetic import observe
from board.skyline import Skyline


def _sine_skyline(start_deg: float = 0.0) -> tuple[Skyline, callable]:
    f = lambda az: 3.0 + 2.0 * np.sin(np.radians(3 * az)) + 0.5 * np.cos(np.radians(7 * az))  # noqa: E731
    coarse = f(start_deg + np.arange(360) * 1.0)
    fine = f(start_deg + np.arange(3600) * 0.1)
    return Skyline(coarse, start_deg, 1.0, {"azimuth_reference": "heading"}, fine, 0.1), f


def test_resampled_reads_the_fine_samples_where_asked():
    """A skyline resampled from another start equals the function there, to the linear interpolation of
    0.1-degree samples (|f''| h^2 / 8 < 2e-5 deg for this function); NaN next to an unseen fine sample."""
    sky, f = _sine_skyline(0.0)
    for start in (0.37, -0.42, 0.05):
        r = sky.resampled(start)
        assert r.azimuth_start_deg == start and r.azimuth_step_deg == 1.0 and not r.has_fine
        np.testing.assert_allclose(r.elevation_deg, f(start + np.arange(360)), atol=2e-5)
    np.testing.assert_array_equal(sky.resampled(0.0).elevation_deg, sky.elevation_deg)
    hole = np.where(np.arange(3600) == 1005, np.nan, sky.fine_elevation_deg)
    holed = Skyline(sky.elevation_deg, 0.0, 1.0, {}, hole, 0.1)
    r = holed.resampled(0.45)            # sample 100 at 100.45 deg lies between fine samples 1004 and 1005
    assert np.isnan(r.elevation_deg[100]) and np.isfinite(np.delete(r.elevation_deg, 100)).all()


def test_fine_samples_survive_the_json_file_and_bad_ones_are_refused(tmp_path):
    sky, _ = _sine_skyline(0.0)
    sky.save(tmp_path / "s.json")
    back = Skyline.load(tmp_path / "s.json")
    np.testing.assert_allclose(back.fine_elevation_deg, sky.fine_elevation_deg, atol=1e-6)
    assert back.fine_step_deg == 0.1
    assert "fine" not in json.loads(json.dumps(Skyline(sky.elevation_deg).to_dict()))
    with pytest.raises(InvalidInputError, match="integer fraction"):
        Skyline(sky.elevation_deg, 0.0, 1.0, {}, np.zeros(1200), 0.3)      # 1 / 0.3 is not an integer
    with pytest.raises(InvalidInputError, match="both"):
        Skyline(sky.elevation_deg, 0.0, 1.0, {}, sky.fine_elevation_deg, None)


@pytest.mark.parametrize("heading,start,db_start", [(123.37, 0.0, 0.0), (10.8, 0.25, 0.5), (359.96, -0.3, 0.0)])
def test_alignment_shift_puts_the_samples_on_the_database_azimuths(heading, start, db_start):
    class Meta:
        azimuth_start_deg = db_start

    sky = Skyline(np.zeros(360), start, 1.0)
    s = alignment_shift_deg(Meta, sky, heading)
    assert -0.5 <= s < 0.5
    enu = heading + start + s + np.arange(360)
    np.testing.assert_allclose(np.mod(enu - db_start + 0.5, 1.0) - 0.5, 0.0, atol=1e-9)


def test_aligned_second_pass_removes_the_azimuth_interpolation_error(far_ridges_world):
    """Level queries at random off-grid positions and headings, observed exactly (0.02-degree horizons
    resampled by the mast model) with fine samples every 0.1 degree.  Read between its azimuths, the
    database's linear interpolation misses the narrow ridges; sampled on them (the second pass) the fit
    leaves about half the residual and the fixes are several times closer.  No fix more than 25 m off
    is `ok` either way."""
    db, mf = far_ridges_world
    rng = np.random.default_rng(7)
    fine_az = np.arange(0.0, 360.0, 0.02)
    out = {False: [], True: []}
    for _ in range(8):
        x, y = rng.uniform(-30.0, 30.0, 2)
        heading = float(rng.uniform(0.0, 360.0))
        el = mf.horizon(x, y, fine_az)[0]
        sky = Skyline(observe(fine_az, el, heading_deg=heading, n=360), 0.0, 1.0, {},
                      observe(fine_az, el, heading_deg=heading, n=3600), 0.1)
        for align in (False, True):
            fix = locate(db, sky, align=align)
            err = float(np.hypot(fix.x - x, fix.y - y))
            out[align].append((err, fix.rms_residual_deg))
            assert not (err > 25.0 and fix.status == "ok")
            assert -0.5 <= fix.aligned_shift_deg < 0.5 and (align or fix.aligned_shift_deg == 0.0)
    (e0, r0), (e1, r1) = (np.median(np.array(out[a]), axis=0) for a in (False, True))
    assert r1 <= 0.6 * r0
    assert e1 <= 0.5 * e0


@pytest.mark.parametrize("mode", ["window", "heading", "heading_exact"])
def test_second_pass_in_every_mode(far_ridges_world, mode):
    """Window and heading modes (also with an exact position) take the second pass too: the shifted query
    (its start no longer 0) keeps the heading prior's window and the fixed-position fit right."""
    db, mf = far_ridges_world
    rng = np.random.default_rng(11)
    fine_az = np.arange(0.0, 360.0, 0.02)
    x, y = (float(v) for v in rng.uniform(-20.0, 20.0, 2))
    heading = 211.37
    el = mf.horizon(x, y, fine_az)[0]
    sky = Skyline(observe(fine_az, el, heading_deg=heading, n=360), 0.0, 1.0, {},
                  observe(fine_az, el, heading_deg=heading, n=3600), 0.1)
    kw = {"window": dict(mode="window", prior_xy=(x + 8.0, y - 6.0), radius_m=25.0),
          "heading": dict(mode="heading", prior_xy=(x + 8.0, y - 6.0), heading_prior_deg=heading + 3.0),
          "heading_exact": dict(mode="heading", prior_xy=(x, y), heading_prior_deg=heading + 3.0,
                                position_sigma_m=0.0)}[mode]
    fix = locate(db, sky, **kw)
    assert fix.aligned_shift_deg != 0.0 and fix.status != "failed"
    assert abs((fix.heading_deg - heading + 180.0) % 360.0 - 180.0) <= 0.1
    if mode != "heading_exact":
        assert np.hypot(fix.x - x, fix.y - y) <= 10.0
