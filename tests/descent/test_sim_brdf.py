"""Visible reflectance against hand-computed values and independent references."""
import math

import numpy as np
import pytest

from blender_addon.descent.brdf import HapkeParams, hapke_h_function, hapke_reflectance, phong_alpha, quasi_phong


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def test_a_facet_radiance_equals_eq9_by_hand():
    # level facet, Sun in the east at 30 deg elevation, camera straight above
    n, l, v = np.array([0.0, 0.0, 1.0]), np.array([math.cos(math.radians(30)), 0.0, 0.5]), np.array([0.0, 0.0, 1.0])
    # N.L = 0.5, L.V = 0.5 -> alpha = 0.75; R = 2 (N.L) N - L = (-0.866, 0, 0.5) -> R.V = 0.5
    # E = 0.6 + 0.75 * 0.6 * 0.5 + 0.25 * 0.2 * 0.5**10
    assert quasi_phong(n, l, v, rho_a=0.6, rho_d=0.6, rho_s=0.2, k=10) == pytest.approx(0.825048828125, abs=1e-12)
    # a facet tilted 20 deg towards the Sun, viewed from 10 deg west of the zenith
    n2 = _unit([math.sin(math.radians(20)), 0.0, math.cos(math.radians(20))])
    v2 = _unit([-math.sin(math.radians(10)), 0.0, math.cos(math.radians(10))])
    ndl, ndv, ldv = math.cos(math.radians(40)), math.cos(math.radians(30)), math.cos(math.radians(70))
    rdv = 2 * ndl * ndv - ldv
    hand = 0.5 + (1 + ldv) / 2 * 0.7 * ndl + (1 - (1 + ldv) / 2) * 0.3 * rdv ** 5
    assert quasi_phong(n2, l, v2, rho_a=0.5, rho_d=0.7, rho_s=0.3, k=5) == pytest.approx(hand, abs=1e-12)


def test_eq9_alpha_vanishes_when_light_and_view_oppose_and_back_facets_keep_only_the_ambient():
    assert phong_alpha([0, 0, 1.0], [0, 0, -1.0]) == 0.0 and phong_alpha([0, 0, 1.0], [0, 0, 1.0]) == 1.0
    n = np.array([0.0, 0.0, 1.0])
    assert quasi_phong(n, [0.6, 0, -0.8], [0, 0, 1.0], rho_a=0.4, rho_d=0.6) == pytest.approx(0.4)
    assert quasi_phong(n, [0.6, 0, 0.8], [0, 0, 1.0], rho_a=0.4, rho_d=0.6, lit=0.0) == pytest.approx(0.4)


def _chandrasekhar_h(mu, w, n=64, iters=400):
    """Isotropic-scattering H function solved by iterating its integral equation (Gauss-Legendre)."""
    x, wt = np.polynomial.legendre.leggauss(n)
    x, wt = 0.5 * (x + 1), 0.5 * wt
    h = np.ones(n)
    for _ in range(iters):
        h = 1.0 / (1.0 - 0.5 * w * x * np.sum(wt * h / (x[:, None] + x), axis=1))
    mu = np.atleast_1d(mu)
    return 1.0 / (1.0 - 0.5 * w * mu * np.sum(wt * h / (mu[:, None] + x), axis=1))


@pytest.mark.parametrize("w", [0.5, 0.9, 0.96])
def test_hapke_h_function_within_its_stated_one_percent_of_chandrasekhar(w):
    mu = np.linspace(0.05, 1.0, 12)
    np.testing.assert_allclose(hapke_h_function(mu, w), _chandrasekhar_h(mu, w), rtol=0.01)


def test_hapke_reduces_to_the_isotropic_lommel_seeliger_h_form_and_is_reciprocal():
    p = HapkeParams(w=0.8, b0=0.0, h=0.05, theta_bar_deg=0.0, g=0.0)
    n = np.array([0.0, 0.0, 1.0])
    l, v = _unit([0.5, 0.1, 0.7]), _unit([-0.2, 0.3, 0.9])
    mu0, mu = l[2], v[2]
    hand = 0.8 / (4 * math.pi) * mu0 / (mu0 + mu) * hapke_h_function(mu0, 0.8) * hapke_h_function(mu, 0.8)
    assert hapke_reflectance(n, l, v, p) == pytest.approx(hand, rel=1e-12)
    rough = HapkeParams(theta_bar_deg=20.0)
    rng = np.random.default_rng(1)
    for _ in range(20):
        a, b = _unit(rng.normal(size=3) * [1, 1, 0.3] + [0, 0, 1]), _unit(rng.normal(size=3) * [1, 1, 0.3] + [0, 0, 1])
        # Helmholtz reciprocity holds for the BRDF r / mu0
        assert hapke_reflectance(n, a, b, rough) / a[2] == pytest.approx(hapke_reflectance(n, b, a, rough) / b[2],
                                                                       rel=1e-9)


def test_hapke_opposition_surge_brightens_zero_phase():
    n = np.array([0.0, 0.0, 1.0])
    l = _unit([0.3, 0.0, 1.0])
    surge = hapke_reflectance(n, l, l, HapkeParams())
    none = hapke_reflectance(n, l, l, HapkeParams(b0=0.0))
    assert surge / none > 1.1
    off = _unit([-0.3, 0.0, 1.0])          # 33 deg of phase: the surge (h = 0.0016) is gone
    assert hapke_reflectance(n, l, off, HapkeParams()) == pytest.approx(
        hapke_reflectance(n, l, off, HapkeParams(b0=0.0)), rel=2e-3)
