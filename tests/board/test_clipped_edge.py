"""What the detector measures of a clipped sky (board.detect.clipped_edge) and the line model
(board.clipped_sky), against brute force and analytic edges."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import erf

from board.clipped_sky import EDGE_WIDTH_FALLBACK_PX, MAX_BAND_DEG, clipped_line_offset_px
from board.detect.clipped_edge import clipped_run_above, edge_width_px


def test_clipped_run_above_counts_the_saturated_rows_just_above_the_line():
    rng = np.random.default_rng(4)
    H, W = 40, 300
    grey = rng.uniform(0.0, 1.0, (H, W)).astype(np.float32)
    # runs of saturated rows of random heights above random lines
    b = rng.integers(0, H + 1, W)
    for c in range(W):
        top = rng.integers(0, max(b[c], 1))
        grey[top:b[c], c] = 1.0
    got = clipped_run_above(grey, b, 0.98)
    want = np.zeros(W, int)
    for c in range(W):                                   # brute force: walk up from the line
        r = b[c] - 1
        while r >= 0 and grey[r, c] >= 0.98:
            want[c] += 1
            r -= 1
    np.testing.assert_array_equal(got, want)


def _brute_run(grey: np.ndarray, b: np.ndarray, level: float, gap: int) -> np.ndarray:
    """Walk up from the line: step over up to ``gap`` unsaturated rows, then count the saturated ones."""
    H, W = grey.shape
    want = np.zeros(W, int)
    for c in range(W):
        r = b[c] - 1
        skipped = 0
        while r >= 0 and grey[r, c] < level and skipped < gap:
            r -= 1
            skipped += 1
        while r >= 0 and grey[r, c] >= level:
            want[c] += 1
            r -= 1
    return want


@pytest.mark.parametrize("gap", [1, 2])
def test_clipped_run_above_steps_over_the_mixed_rows_just_above_the_line(gap):
    rng = np.random.default_rng(11 + gap)
    H, W = 40, 400
    grey = rng.uniform(0.0, 0.97, (H, W)).astype(np.float32)
    b = rng.integers(0, H + 1, W)
    for c in range(W):
        if b[c] < 2:
            continue
        top = rng.integers(0, b[c] - 1)
        grey[top:b[c] - rng.integers(0, 4), c] = 1.0     # a clipped run ending 0-3 rows above the line
    got = clipped_run_above(grey, b, 0.98, gap)
    np.testing.assert_array_equal(got, _brute_run(grey, b, 0.98, gap))
    assert (got > clipped_run_above(grey, b, 0.98)).any()    # the gap finds runs the plain count misses


def test_a_clipped_blurred_sky_is_counted_whatever_the_edge_phase():
    """A sky three times full scale, blurred (sigma 0.55 px) and clipped: where the edge's sub-pixel phase
    leaves the row just above the line part ground (unclipped), the band is still counted over it."""
    lin, edge = _blurred_step(0.55, sky=3.0, ground=0.3)
    grey = np.minimum(lin, 1.0)
    grey[:20] = 0.9                                       # the sky falls below full scale 10 rows above the edge
    # the line as a classifier of the clipped picture draws it: the first row closer to the ground than to
    # the (clipped) sky; the row above it can be part ground, below full scale
    b = np.argmax(grey < 0.5 * (1.0 + 0.3), axis=0)
    plain = clipped_run_above(grey, b, 0.98)
    stepped = clipped_run_above(grey, b, 0.98, 1)
    assert (plain == 0).mean() > 0.2                      # the mixed row hides the band from the plain count
    assert (stepped >= 9).all() and (stepped <= 11).all()    # rows 20 to the edge (30 +- 0.5)


def _blurred_step(sigma: float, *, width: int = 600, height: int = 60, sky: float = 0.8, ground: float = 0.1,
                  seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(linear image, edge row per column): a step at a random sub-pixel row per column, integrated exactly over
    each pixel after a Gaussian PSF of ``sigma`` pixels; sky above (small rows)."""
    rng = np.random.default_rng(seed)
    edge = 30.0 + rng.uniform(-0.5, 0.5, width)
    r = np.arange(height)[:, None]

    def big_phi(t):                                       # antiderivative of the normal CDF
        return t * 0.5 * (1 + erf(t / math.sqrt(2))) + np.exp(-t * t / 2) / math.sqrt(2 * math.pi)

    ground_frac = sigma * (big_phi((r + 0.5 - edge[None, :]) / sigma) - big_phi((r - 0.5 - edge[None, :]) / sigma))
    return (sky + (ground - sky) * ground_frac).astype(np.float32), edge


def test_edge_width_is_the_psf_sigma_with_the_pixel_area_and_grows_with_it():
    sigmas = [0.3, 0.5, 0.7, 1.0, 1.2, 1.5]
    widths = []
    for s in sigmas:
        lin, edge = _blurred_step(s)
        b = np.floor(edge + 0.5).astype(int)               # the first ground row
        widths.append(edge_width_px(lin, b, np.zeros(lin.shape[1], int)))
    assert np.all(np.diff(widths) > 0), widths
    # a wide PSF: the pixel's area adds its variance (1/12); a sharp edge: the steepest one-row difference is
    # at most the step, so the width has a floor of 1 / sqrt(2 pi) = 0.40 px (about 0.55 px over sub-pixel phases)
    for s, w in zip(sigmas, widths):
        if s >= 1.0:
            assert w == pytest.approx(math.sqrt(s ** 2 + 1 / 12), rel=0.06)
    assert 1 / math.sqrt(2 * math.pi) < widths[0] < 0.65


def test_edge_width_leaves_out_clipped_columns_and_needs_enough_clean_ones():
    lin, edge = _blurred_step(0.8, width=120)
    b = np.floor(edge + 0.5).astype(int)
    assert math.isnan(edge_width_px(lin, b, np.ones(120, int)))          # every column clipped
    assert math.isfinite(edge_width_px(lin, b, np.zeros(120, int)))


def test_line_offset_model_grows_with_the_band_and_the_width_and_falls_back():
    band_rows = np.array([0, 10, 20, 40, 400])
    off = clipped_line_offset_px(band_rows, 0.2, 0.6)
    assert off[0] == 0.0 and np.all(np.diff(off[:4]) > 0)
    np.testing.assert_allclose(off[2], 2 * off[1])                     # linear in the band's height ...
    assert off[4] == pytest.approx(off[1] * MAX_BAND_DEG / 2.0)        # ... up to MAX_BAND_DEG
    np.testing.assert_allclose(clipped_line_offset_px(band_rows, 0.2, 0.9), off * (0.9 / 0.6) ** 2)
    np.testing.assert_allclose(clipped_line_offset_px(band_rows, 0.2, float("nan")),
                               clipped_line_offset_px(band_rows, 0.2, EDGE_WIDTH_FALLBACK_PX))
    # the same sky in degrees at twice the resolution: the same offset in pixels
    np.testing.assert_allclose(clipped_line_offset_px(2 * band_rows, 0.1, 0.6), off)
