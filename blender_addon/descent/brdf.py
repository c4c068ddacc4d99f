"""Visible reflectance models: the memorandum's quasi-Phong BRDF (its eq. 9) and Hapke's model.

Vectors are unit world vectors (..., 3): ``n`` the surface normal, ``l`` towards the light, ``v``
towards the viewer.  Both models return a brightness per unit of the source's irradiance relative to
the Sun's, so that the visible "radiance" of a pixel is ``sum_s (E_s / E_sun) * model_s`` (the
camera's exposure turns it into counts).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from board.conventions import RAD_PER_DEG

from .constants import HAPKE_B0, HAPKE_G, HAPKE_H, HAPKE_THETA_BAR_DEG, HAPKE_W


def _dot(a, b):
    a = np.asarray(a)
    b = np.asarray(b)
    if b.ndim == 1:
        return a @ b
    if a.ndim == 1:
        return b @ a
    return np.einsum("...i,...i->...", a, b)


def phong_alpha(l, v) -> np.ndarray:
    """Weight of the diffuse term in eq. 9: ``alpha = (1 + l.v) / 2``, 1 at zero phase, 0 when l and v oppose.

    The memorandum only says alpha is "a weighting function of the inverse phase angle that is zero
    when the lighting and view vectors oppose"; (1 + cos g) / 2 is the simplest such function.
    """
    return 0.5 * (1.0 + np.clip(_dot(l, v), -1.0, 1.0))


def eq9(ndl, ndv, cos_g, rho_a, rho_d, rho_s, k, lit):
    """Memorandum eq. 9 on cosines, elementwise (numpy arrays, or scalars inside numba kernels).

    ``E = rho_a + lit * [alpha rho_d max(N.L, 0) + (1 - alpha) rho_s max(R.V, 0)^k [N.L > 0]]`` with
    ``R.V = 2 (N.L)(N.V) - L.V`` (R the mirror direction of L) and ``alpha = (1 + L.V) / 2``
    (:func:`phong_alpha`).  ndl = N.L, ndv = N.V, cos_g = L.V (cosine of the phase angle).
    """
    alpha = 0.5 * (1.0 + cos_g)
    ndl_p = 0.5 * (ndl + abs(ndl))
    rdv = 2.0 * ndl * ndv - cos_g
    rdv_p = 0.5 * (rdv + abs(rdv))
    return rho_a + lit * (alpha * rho_d * ndl_p + (1.0 - alpha) * rho_s * rdv_p ** k * (ndl > 0.0))


def quasi_phong(n, l, v, *, rho_a, rho_d, rho_s: float = 0.2, k: float = 10.0, lit=1.0) -> np.ndarray:
    """Memorandum eq. 9: ``E = rho_a + alpha rho_d (N.L) + (1 - alpha) rho_s (R.V)^k`` (unitless).

    n, l, v : (..., 3) unit vectors; rho_a, rho_d : ambient and diffuse albedos (arrays or floats;
    the memorandum sets rho_a = rho_d); rho_s : specular albedo; k : Phong sharpness.
    R = 2 (N.L) N - L is the mirror direction of L; N.L and R.V are clipped at 0 (no light from
    behind the facet).  ``lit`` (0..1) scales the direct terms (cast shadows; 1 = N.L only, as in
    the memorandum).  Computed by :func:`eq9`.
    """
    n = np.asarray(n, dtype=np.float64)
    return eq9(_dot(n, l), _dot(n, v), np.clip(_dot(l, v), -1.0, 1.0), rho_a, rho_d, rho_s, k, lit)


@dataclass(frozen=True)
class HapkeParams:
    """Hapke's parameters: single-scattering albedo w, opposition surge B0 and width h, roughness (deg),
    Henyey-Greenstein asymmetry g (negative: backscattering).  Defaults: Europa (constants.py)."""

    w: float = HAPKE_W
    b0: float = HAPKE_B0
    h: float = HAPKE_H
    theta_bar_deg: float = HAPKE_THETA_BAR_DEG
    g: float = HAPKE_G


def hapke_h_function(x, w) -> np.ndarray:
    """Chandrasekhar's H function for isotropic scatterers, Hapke's (2002, eq. 13) approximation (< 1 % error).

    x : cosine (0..1]; w : single-scattering albedo.
    """
    x = np.clip(np.asarray(x, dtype=np.float64), 1e-9, None)
    gamma = math.sqrt(1.0 - w) if np.isscalar(w) else np.sqrt(1.0 - np.asarray(w))
    r0 = (1.0 - gamma) / (1.0 + gamma)
    return 1.0 / (1.0 - w * x * (r0 + (1.0 - 2.0 * r0 * x) / 2.0 * np.log((1.0 + x) / x)))


def _roughness(mu0, mu, cos_g, theta_bar_rad):
    """Hapke (1984) macroscopic roughness: effective cosines (mu0e, mue) and the shadowing function S."""
    i = np.arccos(np.clip(mu0, -1, 1))
    e = np.arccos(np.clip(mu, -1, 1))
    if theta_bar_rad <= 0:
        return mu0, mu, np.ones_like(mu0)
    sin_i, sin_e = np.sin(i), np.sin(e)
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_psi = np.where((sin_i > 1e-9) & (sin_e > 1e-9), (cos_g - mu0 * mu) / (sin_i * sin_e), 1.0)
    cos_psi = np.clip(cos_psi, -1.0, 1.0)
    psi = np.arccos(cos_psi)
    sin2_half_psi = np.sin(psi / 2.0) ** 2
    tb = math.tan(theta_bar_rad)
    chi = 1.0 / math.sqrt(1.0 + math.pi * tb * tb)
    with np.errstate(divide="ignore", over="ignore"):
        ti, te = np.tan(np.maximum(i, 1e-6)), np.tan(np.maximum(e, 1e-6))
        e1i, e1e = np.exp(-2.0 / (math.pi * tb * ti)), np.exp(-2.0 / (math.pi * tb * te))
        e2i, e2e = np.exp(-1.0 / (math.pi * tb * tb * ti * ti)), np.exp(-1.0 / (math.pi * tb * tb * te * te))
    eta_i = chi * (mu0 + sin_i * tb * e2i / (2.0 - e1i))
    eta_e = chi * (mu + sin_e * tb * e2e / (2.0 - e1e))
    f = np.exp(-2.0 * np.tan(np.minimum(psi, math.pi - 1e-6) / 2.0))
    le = i <= e
    d_le = 2.0 - e1e - psi / math.pi * e1i
    d_gt = 2.0 - e1i - psi / math.pi * e1e
    mu0e = np.where(le, chi * (mu0 + sin_i * tb * (cos_psi * e2e + sin2_half_psi * e2i) / d_le),
                    chi * (mu0 + sin_i * tb * (e2i - sin2_half_psi * e2e) / d_gt))
    mue = np.where(le, chi * (mu + sin_e * tb * (e2e - sin2_half_psi * e2i) / d_le),
                   chi * (mu + sin_e * tb * (cos_psi * e2i + sin2_half_psi * e2e) / d_gt))
    s = mue / eta_e * mu0 / eta_i * chi / (1.0 - f + f * chi * np.where(le, mu0 / eta_i, mu / eta_e))
    return mu0e, mue, s


def hapke_reflectance(n, l, v, params: HapkeParams = HapkeParams(), *, w=None) -> np.ndarray:
    """Hapke's bidirectional reflectance r(i, e, g) (1/sr) with opposition surge and roughness.

    r = w / (4 pi) * mu0e / (mu0e + mue) * [(1 + B(g)) p(g) + H(mu0e) H(mue) - 1] * S(i, e, g)
    (Hapke 1981 eq. 37, 1984 roughness, 1986 surge B(g) = B0 / (1 + tan(g/2) / h), 2002 H function),
    p(g) the one-term Henyey-Greenstein function.  0 where the facet faces away from l or v.
    ``w`` overrides ``params.w`` (per pixel, e.g. scaled by an albedo map).
    """
    n = np.asarray(n, dtype=np.float64)
    mu0 = _dot(n, l)
    mu = _dot(n, v)
    cos_g = np.clip(_dot(l, v), -1.0, 1.0)
    ww = params.w if w is None else np.asarray(w, dtype=np.float64)
    ok = (mu0 > 0) & (mu > 0)
    mu0c, muc = np.clip(mu0, 1e-6, 1.0), np.clip(mu, 1e-6, 1.0)
    mu0e, mue, s = _roughness(mu0c, muc, cos_g, params.theta_bar_deg * RAD_PER_DEG)
    g = np.arccos(cos_g)
    b = params.b0 / (1.0 + np.tan(g / 2.0) / params.h)
    p = (1.0 - params.g ** 2) / (1.0 + 2.0 * params.g * cos_g + params.g ** 2) ** 1.5
    r = ww / (4.0 * math.pi) * mu0e / (mu0e + mue) * ((1.0 + b) * p + hapke_h_function(mu0e, ww)
                                                      * hapke_h_function(mue, ww) - 1.0) * s
    return np.where(ok, r, 0.0)


def hapke_brightness(n, l, v, params: HapkeParams = HapkeParams(), *, w=None, lit=1.0) -> np.ndarray:
    """Radiance factor ``pi r`` of :func:`hapke_reflectance` times ``lit`` (cast shadows, 0..1): unitless."""
    return math.pi * hapke_reflectance(n, l, v, params, w=w) * lit
