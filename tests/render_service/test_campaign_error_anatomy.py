"""benchmarks.campaign_error_anatomy's distance breakdown: the horizon's per-direction values carried into the
mast frame as the true skyline is (checked against :func:`board.match.synthetic.observe` and the heading
convention), and the error table by distance band (checked against errors built per band)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.campaign_error_anatomy import distance_parts, distance_table, mast_frame_values
from board.match.synthetic import observe

FINE = 3600
AZ = np.arange(FINE) * 360.0 / FINE


def _horizon() -> np.ndarray:
    """A horizon whose elevation differs from azimuth to azimuth (degrees)."""
    return 4.0 + 3.0 * np.sin(np.radians(AZ)) + 1.5 * np.cos(np.radians(3.0 * AZ + 20.0))


@pytest.mark.parametrize("heading", [0.0, 37.3, 212.8])
def test_level_mast_azimuth_looks_at_heading_plus_azimuth(heading):
    """Level: mast azimuth a (clockwise from forward) looks at ENU azimuth heading + a (clockwise from north)."""
    got = mast_frame_values(AZ, _horizon(), AZ.copy(), heading_deg=heading, n=360)
    want = np.mod(heading + np.arange(360.0), 360.0)
    diff = np.abs((got - want + 180.0) % 360.0 - 180.0)
    assert diff.max() <= 0.05 + 1e-9          # the nearest fine direction: half the 0.1 deg step


@pytest.mark.parametrize(("heading", "pitch", "roll"), [(15.0, 0.0, 0.0), (100.0, 10.0, 0.0), (250.0, 0.0, -10.0)])
def test_elevations_carried_like_the_true_skyline(heading, pitch, roll):
    """The horizon's own elevation, carried by ``mast_frame_values``, is the skyline ``observe`` gives (the
    campaign's truth), to the change of the horizon over half a fine step; its values come from the right
    directions also when the mast is tilted."""
    el = _horizon()
    truth = observe(AZ, el, heading_deg=heading, pitch_deg=pitch, roll_deg=roll, n=360)
    # the value to carry: the ENU elevation; in the mast frame a tilt adds up to +-pitch/roll to it, so compare
    # the carried ENU azimuths instead, mapped back through observe's own rotation
    carried_az = mast_frame_values(AZ, el, AZ.copy(), heading_deg=heading, pitch_deg=pitch, roll_deg=roll, n=360)
    carried_el = np.interp(carried_az, AZ, el, period=360.0)
    back = observe(carried_az, carried_el, heading_deg=heading, pitch_deg=pitch, roll_deg=roll, n=360)
    slope = np.max(np.abs(np.gradient(el, AZ)))                # deg of elevation per deg of azimuth
    assert np.nanmax(np.abs(back - truth)) <= slope * 0.1 + 1e-6
    if pitch == 0.0 and roll == 0.0:
        carried = mast_frame_values(AZ, el, el, heading_deg=heading, n=360)
        assert np.max(np.abs(carried - truth)) <= slope * 0.05 + 1e-9


def test_distance_table_bands():
    """Errors drawn per band come back per band: medians, spreads and the > 0.05 / > 0.1 deg shares."""
    rng = np.random.default_rng(3)
    n = 360
    dist = np.where(np.arange(n) < 180, 1_000.0, 50_000.0)     # half near (0-2 km), half far (32 km-)
    err = np.where(dist < 2_000, 0.002 + rng.normal(0, 0.004, n), 0.02 + rng.normal(0, 0.03, n))
    err[::7] = np.nan                                          # masked samples are left out
    rows = [{"case_id": "c", "err_deg": err.tolist()}]
    table = distance_table(rows, {"c": dist})
    assert [(b["from_m"], b["to_m"]) for b in table] == [(0.0, 2_000.0), (32_000.0, math.inf)]
    for b, m in zip(table, (dist < 2_000, dist >= 32_000)):
        e = err[m & np.isfinite(err)]
        assert b["samples"] == e.size
        assert b["median_deg"] == pytest.approx(np.median(e))
        assert b["mad_deg"] == pytest.approx(np.median(np.abs(e - np.median(e))))
        assert b["over_0_1"] == pytest.approx(np.mean(np.abs(e) > 0.1))
    assert table[1]["mad_deg"] > 3 * table[0]["mad_deg"]


def test_distance_parts_take_out_exactly_what_they_name():
    """Each query of split_by_distance: the far / near medians taken out where they say, the near-only query
    NaN beyond the near horizon (a masked sample's error counts in no median)."""
    rng = np.random.default_rng(5)
    n = 360
    truth = 2.0 + np.sin(np.radians(np.arange(n)) * 3)
    near = np.arange(n) % 3 == 0
    e = np.where(near, 0.004, 0.03) + rng.normal(0, 0.01, n)
    e[::11] = np.nan
    ok = np.isfinite(e)
    q = dict(distance_parts(truth, e, near))
    assert set(q) == {"truth", "near", "far", "offset", "far_offset", "near_far_offsets", "near_only"}
    err = {k: v - truth for k, v in q.items()}
    assert np.array_equal(q["truth"], truth)
    assert np.allclose(err["near"][near & ok], e[near & ok]) and np.all(err["near"][~near] == 0)
    assert np.allclose(err["far"][~near & ok], e[~near & ok]) and np.all(err["far"][near] == 0)
    assert np.allclose(err["offset"], np.median(e[ok]))
    assert abs(np.median(err["far_offset"][~near & ok])) < 1e-12
    assert np.allclose(err["far_offset"][near & ok], e[near & ok])
    for m in (near, ~near):
        assert abs(np.median(err["near_far_offsets"][m & ok])) < 1e-12
    assert np.all(np.isnan(q["near_only"][~near])) and np.allclose(err["near_only"][near & ok], e[near & ok])
