"""The smooth-extraction-error covariance of a fix (board.locate.extraction_bias) against brute force.

Truth: draws of the modelled Gaussian process on the circle pushed through the least-squares
solution one by one (Monte Carlo), and the analytic fact that a constant error is the fit's offset.
"""
from __future__ import annotations

import numpy as np
import pytest

from board.locate.extraction_bias import (
    EXTRACTION_BIAS_PX,
    extraction_bias_cov,
    extraction_bias_sigma_deg,
)
from board.pose.refine import Refined
from board.skyline import Skyline


def _refined(seed: int, weighted: bool) -> Refined:
    """A fit over 250 of 360 azimuths with three free parameters whose Jacobian columns are smooth
    functions of azimuth, weighted-centred as :func:`board.pose.refine._residual` makes them."""
    rng = np.random.default_rng(seed)
    az = np.sort(rng.choice(np.arange(360.0), 250, replace=False))
    a = np.radians(az)
    w = rng.uniform(0.3, 2.0, az.size) if weighted else None
    wv = np.ones(az.size) if w is None else w
    cols = [np.sin(a) + 0.3 * np.cos(3 * a), np.cos(a) - 0.2 * np.sin(2 * a), 0.5 * np.sin(2 * a + 0.4)]
    J = np.stack([np.sqrt(wv) * (c - (wv @ c) / wv.sum()) for c in cols], axis=1)
    return Refined({"row": 0.0, "col": 0.0, "heading": 0.0, "pitch": 0.0, "roll": 0.0}, 0.0, 0.0,
                   np.zeros(az.size), J, ("row", "col", "heading"), np.zeros((3, 3)), 0, az, w)


@pytest.mark.parametrize("weighted", [False, True])
def test_covariance_equals_monte_carlo_through_the_fit(weighted):
    ref = _refined(3, weighted)
    sigma, L = 0.02, 30.0
    info = ref.jac.T @ ref.jac
    cov = extraction_bias_cov(ref, info_unscaled=info, sigma_deg=sigma, correlation_deg=L)
    # brute force: draw the process on the fit's azimuths, solve the weighted least squares for each draw
    az = ref.enu_az_deg
    # the process itself, written out independently: a Gaussian of the chord between the directions
    a = np.radians(az)
    xy = np.stack([np.cos(a), np.sin(a)], axis=1)
    chord = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=2)
    K = sigma ** 2 * np.exp(-0.5 * (chord / (2 * np.sin(np.radians(L) / 2))) ** 2)
    vals, vecs = np.linalg.eigh(K)
    assert vals.min() > -1e-12 * vals.max()           # positive semi-definite on the circle
    rng = np.random.default_rng(11)
    e = vecs @ (np.sqrt(np.clip(vals, 0, None))[:, None] * rng.standard_normal((az.size, 20000)))
    sw = np.ones(az.size) if ref.weights is None else np.sqrt(ref.weights)
    # the fit sees sw * (e - weighted mean of e); the Jacobian's columns are weighted-centred already
    wv = sw * sw
    e_c = e - (wv @ e) / wv.sum()
    delta = np.linalg.solve(info, ref.jac.T @ (sw[:, None] * e_c))
    emp = np.cov(delta)
    np.testing.assert_allclose(cov, emp, rtol=0.06, atol=0.06 * np.abs(emp).max())


def test_a_constant_error_is_the_offset_and_moves_nothing():
    ref = _refined(5, True)
    # a correlation length of half the circle and more: nearly a constant, which the offset takes
    cov_const = extraction_bias_cov(ref, info_unscaled=ref.jac.T @ ref.jac, sigma_deg=0.05, correlation_deg=179.0)
    cov_smooth = extraction_bias_cov(ref, info_unscaled=ref.jac.T @ ref.jac, sigma_deg=0.05, correlation_deg=30.0)
    assert np.trace(cov_const) < 0.5 * np.trace(cov_smooth)
    # exactly constant errors: nothing moves
    sw = np.sqrt(ref.weights)
    delta = np.linalg.solve(ref.jac.T @ ref.jac, ref.jac.T @ (sw * 0.05))
    assert np.abs(delta).max() < 1e-12


def test_sigma_follows_the_panorama_pixel_and_is_zero_without_one():
    sky = Skyline(np.zeros(360), meta={"panorama_step_deg": 0.2})
    assert extraction_bias_sigma_deg(sky) == pytest.approx(EXTRACTION_BIAS_PX * 0.2)
    assert extraction_bias_sigma_deg(Skyline(np.zeros(360))) == 0.0
    assert extraction_bias_sigma_deg(Skyline(np.zeros(360), meta={"panorama_step_deg": "n/a"})) == 0.0
