"""Matching that survives bad columns: outlier masking after the first fix (board/locate/robust.py).

Queries are ray-marched off the grid (raymarch_world); a corrupted query has 5 % of its columns moved
by 2-10 degrees in short runs, as a detector that followed a rock's outline would leave them.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from board.conventions import wrap_deg180
from board.locate import LocateOptions, locate
from board.locate.robust import OUTLIER_MIN_DEG, cleaned_query, outlier_mask
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
