"""The confidence is calibrated: 95 % regions hold the truth, wrong fixes are not `ok`."""
import math

import numpy as np
import pytest

from board.locate import locate
from board.pose.confidence import CHI2_2D_95, effective_samples, ellipse_95


def test_effective_samples_white_and_correlated():
    rng = np.random.default_rng(0)
    n = 4000
    white = rng.normal(size=n)
    assert 0.8 * n <= effective_samples(white) <= 1.2 * n
    rho = 0.8  # AR(1): n_eff = n (1 - rho) / (1 + rho)
    ar = np.empty(n)
    ar[0] = rng.normal()
    for i in range(1, n):
        ar[i] = rho * ar[i - 1] + rng.normal() * math.sqrt(1 - rho ** 2)
    want = n * (1 - rho) / (1 + rho)
    assert 0.6 * want <= effective_samples(ar) <= 1.5 * want


def test_ellipse_95_axes():
    a, b, az = ellipse_95(np.array([[4.0, 0.0], [0.0, 1.0]]))  # sigma_x 2 m, sigma_y 1 m
    assert a == pytest.approx(2.0 * math.sqrt(CHI2_2D_95)) and b == pytest.approx(math.sqrt(CHI2_2D_95))
    assert az == pytest.approx(90.0)  # major axis along x = east


def _trial(w, rng, inside=True):
    if inside:
        x, y = w.random_xy(rng)
    else:  # an impostor: a place outside the database's grid (its truth is not in the database)
        a, d = rng.uniform(0, 2 * np.pi), rng.uniform(250.0, 550.0)
        x0, y0, x1, y1 = w.db.grid.bounds()
        x, y = (x0 + x1) / 2 + d * math.sin(a), (y0 + y1) / 2 + d * math.cos(a)
    h = rng.uniform(0, 360)
    tilt, phi = rng.choice([0.0, 5.0, 10.0]), rng.uniform(0, 2 * np.pi)
    arc = rng.choice([65, 120, 242, 360])
    sky = w.query(x, y, heading=h, pitch=tilt * math.cos(phi), roll=tilt * math.sin(phi),
                  noise=rng.choice([0.03, 0.1, 0.2]), arc=arc, arc_start=rng.uniform(0, 360), rng=rng)
    fix = locate(w.db, sky)
    d = np.array([fix.x - x, fix.y - y])
    m2 = float(d @ np.linalg.solve(fix.cov_xy, d)) if np.linalg.det(fix.cov_xy) > 0 else math.inf
    return float(np.hypot(*d)), m2, fix.status


@pytest.mark.slow
def test_calibration_over_many_synthetic_trials(raymarch_world):
    """Ray-marched queries (off grid, 0-10 deg tilt, 65-360 deg seen, 0.03-0.2 deg noise) and impostors."""
    w = raymarch_world
    rng = np.random.default_rng(2026)
    inside = [_trial(w, rng) for _ in range(50)]
    impostors = [_trial(w, rng, inside=False) for _ in range(15)]
    err, m2, status = (np.array(v) for v in zip(*inside))
    assert np.mean(m2 <= CHI2_2D_95) >= 0.9  # the 95 % region holds the truth
    wrong_status = [s for e, _, s in inside + impostors if e > 5 * w.step]
    assert len(wrong_status) >= 10  # the impostors alone are wrong by construction
    assert np.mean([s != "ok" for s in wrong_status]) >= 0.9
    assert np.mean(status[err <= 5 * w.step] == "ok") >= 0.6  # and the matcher is not merely shy


def test_map_likelihood_matches_a_direct_evaluation():
    from board.pose.confidence import map_likelihood
    from board.skydb import GridSpec

    g = GridSpec.from_center((500.0, -300.0), 300.0, 5.0)
    rng = np.random.default_rng(3)
    score = rng.uniform(5.0, 50.0, size=(g.ny, g.nx))
    score[30, 20] = 1.0
    score[33, 22] = 1.5  # a close second minimum (inside the radius)
    score[5, 50] = 2.0   # and a far one
    best = g.xy(30, 20)
    lk = map_likelihood(score, g.xy, best_xy=best, s2=0.5, radius_m=25.0, step_m=5.0)
    rr, cc = np.mgrid[0:g.ny, 0:g.nx]
    x, y = g.xy(rr, cc)
    w = np.exp(-(score - 1.0) / 1.0)
    w /= w.sum()
    dx, dy = x - best[0], y - best[1]
    far = np.hypot(dx, dy) > 25.0
    assert lk.best_far_score == pytest.approx(score[far].min())
    assert lk.far_mass == pytest.approx(w[far].sum(), rel=1e-6)
    np.testing.assert_allclose(lk.cov_xy, [[(w * dx * dx).sum(), (w * dx * dy).sum()],
                                           [(w * dx * dy).sum(), (w * dy * dy).sum()]], rtol=1e-6)
    assert lk.ambiguity_ratio == pytest.approx(0.5)


def test_grid_error_is_the_bilinear_midcell_error_of_a_quadratic_field():
    """Skylines varying quadratically with position: the estimate equals the true mid-cell error."""
    from board.locate.grid_error import grid_error_samples as _grid_error_samples
    from board.pose.refine import LocalDB

    rng = np.random.default_rng(5)
    n = 360
    a, b, c = rng.normal(0, 0.4, n), rng.normal(0, 0.4, n), rng.normal(5, 2, n)
    ii, jj = np.mgrid[0:5, 0:5]
    el = a[None, None] * ii[..., None] ** 2 + b[None, None] * jj[..., None] ** 2 + c[None, None]
    local = LocalDB(el, 10, 20, 0.0)
    az = np.arange(n, dtype=float)
    got = _grid_error_samples(local, 12.0, 22.0, az)
    # brute force: bilinear interpolation vs the field at the midpoints of the cell edges and centre
    errs = []
    for di, dj in ((0.5, 0.0), (0.0, 0.5), (0.5, 0.5), (0.5, -0.5)):
        r, s = 12.0 + di, 22.0 + dj
        truth = a * (r - 10) ** 2 + b * (s - 20) ** 2 + c
        e = local.skyline_at(r, s) - truth
        errs.append((e - e.mean()) ** 2)
    assert np.allclose(got, np.mean(errs, axis=0), rtol=1e-9, atol=1e-12)


def test_noise_given_weights_solves_the_weighted_chi_square():
    from board.locate.grid_error import noise_given_weights as _noise_given_weights

    rng = np.random.default_rng(6)
    g2 = rng.uniform(0, 0.5, 300) ** 2
    r2 = (rng.normal(size=300) * np.sqrt(0.01 + g2)) ** 2
    s = _noise_given_weights(r2, g2, 295)
    assert float(np.sum(r2 / (s + g2))) == pytest.approx(295, rel=1e-6)
    assert 0.005 < s < 0.02  # recovers the simulated noise variance 0.01
    # without grid error it is the usual residual variance
    assert _noise_given_weights(r2, np.zeros(300), 295) == pytest.approx(r2.sum() / 295, rel=1e-6)
