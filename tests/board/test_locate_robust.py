"""Matching that survives bad columns: outlier masking after the first fix (board/locate/robust.py).

Queries are ray-marched off the grid (raymarch_world); a corrupted query has 5 % of its columns moved
by 2-10 degrees in short runs, as a detector that followed a rock's outline would leave them.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from board.conventions import wrap_deg180
from board.locate import LocateOptions, locate
from board.locate.robust import OUTLIER_MIN_DEG, cleaned_query, flagged_sectors, outlier_mask, sectors_at_fix
from board.pose.refine import Refined
from board.skyline import Skyline


def _corrupt(el: np.ndarray, rng: np.random.Generator, fraction: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    out, bad = el.copy(), np.zeros(el.size, bool)
    seen = np.flatnonzero(np.isfinite(el))
    while bad.sum() < round(fraction * seen.size):
        s, run = int(rng.choice(seen)), int(rng.integers(1, 5))
        delta = rng.uniform(2, 10) * (1 if rng.random() < 0.7 else -1)
        for k in range(run):
            j = (s + k) % el.size
            if np.isfinite(el[j]) and not bad[j] and bad.sum() < round(fraction * seen.size):
                out[j], bad[j] = el[j] + delta, True
    return out, bad


def _refined(residual, weights=None) -> Refined:
    r = np.asarray(residual, float)
    rw = r if weights is None else r * np.sqrt(weights)
    return Refined(values={}, offset_deg=0.0, cost=float(rw @ rw), residual=rw, jac=np.zeros((r.size, 0)), free=(),
                   weights=weights)


def test_outlier_mask_finds_the_injected_columns_and_spares_model_error():
    rng = np.random.default_rng(0)
    r = rng.normal(0, 0.1, 300)
    r[[10, 11, 12, 200]] += [4.0, 5.0, -3.0, 8.0]
    assert set(np.flatnonzero(outlier_mask(_refined(r)))) == {10, 11, 12, 200}
    # a column whose large residual the refinement expected (low weight: close horizon, model error) is kept
    w = np.ones(300)
    w[200] = 1e-3
    assert set(np.flatnonzero(outlier_mask(_refined(r, w)))) == {10, 11, 12}
    # small residuals are never outliers, however tight the fit
    tight = np.full(300, 1e-4)
    tight[5] = 0.8 * OUTLIER_MIN_DEG
    assert not outlier_mask(_refined(tight)).any()


def test_cleaned_query_masks_exactly_the_outlier_azimuths():
    el = np.full(360, np.nan)
    el[30:230] = np.linspace(1, 3, 200)
    sky = Skyline(el)
    r = np.zeros(200)
    r[[0, 50, 199]] = [3.0, -4.0, 6.0]
    cleaned, n = cleaned_query(sky, _refined(r + np.random.default_rng(1).normal(0, 0.05, 200)))
    assert n == 3
    assert np.array_equal(np.flatnonzero(sky.seen & ~cleaned.seen), [30, 80, 229])
    assert cleaned_query(sky, _refined(np.random.default_rng(2).normal(0, 0.05, 200))) is None
    # too many "outliers": the fix itself is doubtful, nothing is masked
    assert cleaned_query(sky, _refined(np.where(np.arange(200) % 2, 5.0, 0.0))) is None


def test_masked_columns_are_reported_as_sectors_above_or_below_the_dem_skyline():
    """A level query at heading 30 deg against a known database skyline: boulders (also one across north)
    are above it, a ridge lost in haze below it, and a masked column the fix explains is in neither."""
    db = 3.0 + 2.0 * np.sin(np.radians(np.arange(360) * 3.0))  # ENU azimuths 0..359
    heading, offset = 30.0, 0.4
    theta = np.arange(360.0)
    el = np.interp((theta + heading) % 360.0, np.arange(361), np.append(db, db[0])) + offset
    el[100:160] = np.nan                   # not seen
    rock, north, haze, fine, edge = [40, 41, 42, 43], [358, 359, 0, 1], [220, 221], [250], [270]
    el[rock] += [3.0, 4.0, 4.0, 3.0]
    el[north] += 5.0
    el[haze] -= 2.0
    el[edge] += 1.5                        # a lone column 1.5 deg off: interpolation error, not a rock
    masked = np.zeros(360, bool)
    masked[rock + north + haze + fine + edge] = True
    above, below = sectors_at_fix(Skyline(el), masked, db_skyline_deg=db, db_azimuth_start_deg=0.0,
                                  heading_deg=heading, pitch_deg=0.0, roll_deg=0.0, offset_deg=offset)
    assert [(a["from_deg"], a["to_deg"], a["n"]) for a in above] == [(40.0, 43.0, 4), (358.0, 1.0, 4)]
    assert above[0]["excess_deg"] == pytest.approx(3.5, abs=0.02)
    assert above[1]["excess_deg"] == pytest.approx(5, abs=0.02)
    assert [(b["from_deg"], b["to_deg"], b["n"]) for b in below] == [(220.0, 221.0, 2)]
    assert below[0]["excess_deg"] == pytest.approx(-2.0, abs=0.02)
    none = sectors_at_fix(Skyline(el), np.zeros(360, bool), db_skyline_deg=db, db_azimuth_start_deg=0.0,
                          heading_deg=heading, pitch_deg=0.0, roll_deg=0.0, offset_deg=offset)
    assert none == ([], [])
    assert flagged_sectors(Skyline(el), np.array([], int), np.array([])) == []


def _assert_flags_only_where_the_grid_misses_the_horizon(w, x, y, heading, fix) -> None:
    """Every sector ``fix`` reports for a clean level query at (x, y) lies within 1 deg of an azimuth where the
    database cannot represent the query: interpolated at the true position (as the refinement does, with
    parallax) it is more than OUTLIER_MIN_DEG / 2 from the ray-marched horizon there (the independent truth),
    or the horizon is so near that the fix's position error alone moves the interpolated skyline by that much
    (a near slope, where a metre is a degree).  A flag on a far horizon the database holds would fail this."""
    from board.locate.window import local_db

    row, col = w.db.grid.ij(x, y)
    frow, fcol = w.db.grid.ij(fix.x, fix.y)
    loc = local_db(w.db, int(round(row)), int(round(col)), half=3, parallax=True)
    interp = loc.skyline_at(row, col)
    moved = loc.skyline_at(frow, fcol) if max(abs(frow - row), abs(fcol - col)) <= 2.5 else interp
    az = w.db.meta.azimuths_deg()
    t_az, t_el = w.horizon(x, y)
    err = np.maximum(np.abs(interp - np.interp(az, np.append(t_az, 360.0), np.append(t_el, t_el[0]))),
                     np.abs(moved - interp))
    for s in fix.above_dem + fix.below_dem:
        a0 = (s["from_deg"] + heading - 1.0) % 360.0
        width = (s["to_deg"] - s["from_deg"]) % 360.0 + 2.0
        near = (az - a0) % 360.0 <= width
        assert err[near].max() > 0.5 * OUTLIER_MIN_DEG, (s, err[near])


@pytest.mark.slow
def test_near_rocks_above_the_horizon_are_flagged_and_do_not_move_the_fix(raymarch_world):
    """A query whose boundary follows two boulders standing above the horizon (+2.5 to +6 deg over 6 and 9
    degrees): the fix is where the clean query's is, and the boulders' azimuths are reported above the DEM."""
    w = raymarch_world
    rng = np.random.default_rng(77)
    x, y = w.random_xy(rng)
    h = rng.uniform(0, 360)
    sky = w.query(x, y, heading=h, noise=0.05, rng=rng)
    el = sky.elevation_deg.copy()
    seen = np.flatnonzero(np.isfinite(el))
    rocks = [(int(seen[40]), 6, 4.0), (int(seen[200]), 9, 6.0)]
    for start, width, height in rocks:
        j = (start + np.arange(width)) % el.size
        el[j] += height * np.sin(np.linspace(0.3, np.pi - 0.3, width))  # a rounded outline
    fix = locate(w.db, Skyline(el, sky.azimuth_start_deg, sky.azimuth_step_deg))
    clean = locate(w.db, sky)
    assert math.hypot(fix.x - clean.x, fix.y - clean.y) <= 1.0
    assert abs(float(wrap_deg180(fix.heading_deg - clean.heading_deg))) <= 0.2
    az = sky.azimuths_deg()
    for start, width, _ in rocks:
        mid = float(az[(start + width // 2) % el.size]) % 360.0
        hit = [a for a in fix.above_dem if (mid - a["from_deg"]) % 360.0 <= (a["to_deg"] - a["from_deg"]) % 360.0]
        assert hit and hit[0]["excess_deg"] > 1.0, (mid, fix.above_dem)
    assert len(fix.above_dem) == len(rocks)  # nothing else is called an obstruction
    # a sector below the database is reported only where the database itself misses the true horizon (a near
    # slope the 5 m grid interpolates more than half a degree off at the true position)
    _assert_flags_only_where_the_grid_misses_the_horizon(w, x, y, h, replace(fix, above_dem=[]))
    assert fix.to_json_dict()["above_dem_skyline"] == fix.above_dem
    # the clean query is flagged only where the database itself cannot represent the true horizon: a near
    # slope whose skyline the 5 m grid interpolates more than half a degree off at the true position
    _assert_flags_only_where_the_grid_misses_the_horizon(w, x, y, h, clean)
    # the overlay shades them: one legend entry, spans covering each boulder's world azimuth
    from board.plots import draw_fix

    fig = draw_fix(fix)
    ax = fig.axes[1]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels.count("masked: above the DEM (rock?)") == 1
    spans = [(p.get_x(), p.get_x() + p.get_width()) for p in ax.patches]
    for start, width, _ in rocks:
        world = (float(az[(start + width // 2) % el.size]) + fix.heading_deg) % 360.0
        assert any(u <= world <= v for u, v in spans), (world, spans)
    import matplotlib.pyplot as plt

    plt.close(fig)


@pytest.mark.slow
def test_corrupted_queries_locate_like_clean_ones(raymarch_world):
    w = raymarch_world
    rng = np.random.default_rng(4242)
    worse = []
    for trial in range(6):
        x, y = w.random_xy(rng)
        h = rng.uniform(0, 360)
        sky = w.query(x, y, heading=h, noise=0.05, rng=rng)
        bad_el, bad = _corrupt(sky.elevation_deg, rng)
        fix = locate(w.db, Skyline(bad_el))
        d, dh = math.hypot(fix.x - x, fix.y - y), abs(float(wrap_deg180(fix.heading_deg - h)))
        assert d <= 5.0 and dh <= 1.0, (trial, d, dh, fix.status)
        assert fix.n_outliers >= 0.6 * bad.sum(), (fix.n_outliers, int(bad.sum()))
        plain = locate(w.db, Skyline(bad_el), LocateOptions(robust=False))
        worse.append(math.hypot(plain.x - x, plain.y - y) - d)
        # a clean query is untouched: same fix with and without the robust stage
        c1, c0 = locate(w.db, sky), locate(w.db, sky, LocateOptions(robust=False))
        assert c1.n_outliers == 0 and (c1.x, c1.y, c1.heading_deg) == (c0.x, c0.y, c0.heading_deg)
    assert np.median(worse) > 0  # without the masking the same queries land farther off
