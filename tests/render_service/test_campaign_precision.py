"""benchmarks.campaign_precision: the geometric precision of a pose, against analytic geometry.

The terrain is a circular rim (a Gaussian ridge of radius RIM_R) on a flat plane, sampled on nested
levels as the ray-marcher takes it.  The gradient of the horizon with the position comes from the
envelope theorem on the analytic surface (a dense 1-D search finds each azimuth's tangent point q;
d elevation / d p = (grad z(q) - grad z(p)) / (d (1 + t^2)), t the tangent's slope), not from finite
differences: the module's central differences of the ray-marcher must agree with it.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from skyloc_service_test_helpers import analytic_terrain

from benchmarks.campaign_precision import horizon_jacobian, main, precision_from_jacobian, share_within
from render_service.renderers import raymarch
from render_service.renderers.base import RenderSpec

RIM_R, RIM_H, RIM_W = 2000.0, 120.0, 300.0          # metres
EYE_H, N_AZ = 2.0, 72


def rim(x, y):
    return RIM_H * np.exp(-((np.hypot(x, y) - RIM_R) / RIM_W) ** 2)


def rim_grad(x, y):
    r = max(math.hypot(x, y), 1e-9)
    dz_dr = float(rim(x, y)) * (-2.0 * (r - RIM_R) / RIM_W ** 2)
    return np.array([dz_dr * x / r, dz_dr * y / r])


@pytest.fixture(scope="module")
def terrain():
    return analytic_terrain(rim, [(3200.0, 4.0), (12800.0, 32.0)], radius_m=1e12)


def horizon_fn(terrain):
    spec = RenderSpec(camera_height_m=EYE_H, n_azimuth=N_AZ, body_radius_m=1e12)
    return lambda x, y: raymarch.horizon_at(terrain, x, y, spec)[1]


def analytic_gradient(x, y, n=200_000, d_max=6000.0):
    """(N_AZ, 2) d elevation / d (x, y), degrees per metre, by the envelope theorem."""
    d = np.linspace(d_max / n, d_max, n)
    z_eye = float(rim(x, y)) + EYE_H
    gp = rim_grad(x, y)
    out = []
    for a in np.radians(np.arange(N_AZ) * 360.0 / N_AZ):
        u = np.array([math.sin(a), math.cos(a)])
        s = (rim(x + d * u[0], y + d * u[1]) - z_eye) / d
        k = int(np.argmax(s))
        t, dk = float(s[k]), float(d[k])
        g = (rim_grad(x + dk * u[0], y + dk * u[1]) - gp) / (dk * (1.0 + t * t))
        out.append(np.degrees(g))
    return np.array(out)


def test_the_horizon_gradient_is_the_envelope_theorems(terrain):
    x, y = 310.0, -190.0
    jac = horizon_jacobian(horizon_fn(terrain), x, y, N_AZ)
    want = analytic_gradient(x, y)
    err = np.linalg.norm(jac[:, :2] - want) / np.linalg.norm(want)
    assert err < 0.03, err
    # the rim is nearer to the south-west of this pose: moving away from it (north-east) lowers that side
    assert np.sign(jac[N_AZ * 5 // 8, 0]) == np.sign(want[N_AZ * 5 // 8, 0]) != 0


def test_a_circular_rim_seen_from_its_centre_cannot_tell_position_from_tilt(terrain):
    """From the centre a step moves the rim's distance as sin / cos of the azimuth: exactly what a tilt does,
    so with pitch and roll free the position is (nearly) unknown while a known tilt pins it.  Off the centre
    the rim's second harmonic separates a radial step from a tilt; a step along the rim stays a turn of the
    whole view (the rim is round), i.e. the heading, whatever is known of the tilt."""
    h = horizon_fn(terrain)
    centre = precision_from_jacobian(horizon_jacobian(h, 0.0, 0.0, N_AZ))
    off = precision_from_jacobian(horizon_jacobian(h, 600.0, 0.0, N_AZ))
    assert centre.sigma_per_mdeg_m.min() > 20.0 * centre.sigma_fixed_tilt_per_mdeg_m.max()
    assert off.sigma_per_mdeg_m[0] < centre.sigma_per_mdeg_m[0] / 10.0          # radial (x): separated
    assert off.sigma_fixed_tilt_per_mdeg_m[1] > 10.0 * off.sigma_fixed_tilt_per_mdeg_m[0]  # along the rim (y)


def test_share_within_is_the_rayleigh_law_and_matches_sampling_when_elliptic():
    s, r = 1.3, 2.5
    assert share_within(np.diag([s * s, s * s]), r) == pytest.approx(1.0 - math.exp(-r * r / (2 * s * s)), abs=1e-6)
    cov = np.array([[4.0, 1.2], [1.2, 0.8]])
    pts = np.random.default_rng(7).multivariate_normal([0.0, 0.0], cov, size=200_000)
    assert share_within(cov, r) == pytest.approx(float(np.mean(np.hypot(*pts.T) <= r)), abs=0.005)


def test_the_precision_scales_with_the_noise_and_refuses_bad_input(tmp_path, capsys):
    jac = np.random.default_rng(3).normal(size=(360, 6))
    p = precision_from_jacobian(jac)
    np.testing.assert_allclose(np.sqrt(np.diag(p.covariance_m2(0.002))), 2.0 * p.sigma_per_mdeg_m, rtol=1e-9)
    assert main([str(tmp_path / "nothing")]) == 2
    assert "not a finished campaign folder" in capsys.readouterr().err
    assert main([str(tmp_path), "--noise-deg", "0"]) == 2
