"""Covariance of the pose bias that a smooth extraction error causes (degrees in, free-parameter units out).

The residual-based covariance (:mod:`board.pose.confidence`) sees only what the fit leaves behind.  An
extraction error that varies slowly around the circle (a clipped sky towards the sun lowers the line
there by a fraction of a pixel; a lens's vignetting, a haze band) is partly absorbed by the pose: it
moves the fix and leaves little residual, so the fix is confident and wrong by metres on a smooth
site (session 9: held-out Aristoteles 43, distorted look, 5 of 14 ``ok`` fixes outside their 95 %
ellipse, each with a 0.03-0.05 deg first harmonic in its extraction error).  Modelled as a stationary
Gaussian process on the azimuth circle, ``k(d) ~ s^2 exp(-d^2 / (2 L^2))`` (:func:`gp_kernel`) with ``s`` a share of the
panorama's pixel and ``L`` tens of degrees, propagated through the least-squares fit like the
database's interpolation error (:func:`board.locate.grid_error.interpolation_bias_cov`).
"""
from __future__ import annotations

import numpy as np

from board.pose.refine import Refined
from board.skyline import Skyline

#: 1-sigma of the smooth extraction error, in panorama pixels
EXTRACTION_BIAS_PX = 0.1
#: its correlation length along the azimuth, degrees
EXTRACTION_BIAS_CORRELATION_DEG = 30.0


def extraction_bias_sigma_deg(skyline: Skyline) -> float:
    """1-sigma (degrees) of the smooth extraction error of ``skyline``: :data:`EXTRACTION_BIAS_PX` of the
    panorama it was extracted from (its ``meta["panorama_step_deg"]``), 0 for a skyline not extracted from
    an image (a rendered or database skyline)."""
    step = skyline.meta.get("panorama_step_deg") if isinstance(skyline.meta, dict) else None
    try:
        step = float(step)
    except (TypeError, ValueError):
        return 0.0
    return EXTRACTION_BIAS_PX * step if np.isfinite(step) and step > 0 else 0.0


def extraction_bias_cov(ref: Refined, *, info_unscaled: np.ndarray, sigma_deg: float,
                        correlation_deg: float = EXTRACTION_BIAS_CORRELATION_DEG) -> np.ndarray:
    """Covariance (free-parameter units squared) of ``delta = (J^T J)^-1 J^T e`` for the smooth error ``e``
    (``sigma_deg``, ``correlation_deg``) at the fit's ENU azimuths, weighted as the fit was."""
    k = len(ref.free)
    zero = np.zeros((k, k))
    az = np.asarray(ref.enu_az_deg, float)
    if sigma_deg <= 0 or az.size == 0:
        return zero
    try:
        pinv = np.linalg.inv(info_unscaled)
    except np.linalg.LinAlgError:
        return zero
    K = gp_kernel(az, sigma_deg, correlation_deg)
    # the Jacobian is of the weighted, offset-free residual: an error e enters the fit as sw * e
    sw = np.ones(az.size) if ref.weights is None else np.sqrt(ref.weights)
    B = pinv @ (ref.jac.T * sw[None, :])     # (k, n): parameter change per unit error of each sample
    return B @ K @ B.T


def gp_kernel(az_deg: np.ndarray, sigma_deg: float, correlation_deg: float) -> np.ndarray:
    """(n, n) covariance (degrees^2) of the smooth error at azimuths ``az_deg``: a Gaussian of the chord
    between the two directions on the unit circle (positive semi-definite on the circle, unlike one of the
    wrapped angle), ``sigma_deg^2 exp(-c^2 / (2 l^2))`` with ``l`` the chord of ``correlation_deg``."""
    a = np.radians(np.asarray(az_deg, float))
    chord = 2.0 * np.abs(np.sin(0.5 * (a[:, None] - a[None, :])))
    ell = 2.0 * np.sin(0.5 * np.radians(min(correlation_deg, 179.0)))
    return (sigma_deg ** 2) * np.exp(-0.5 * (chord / ell) ** 2)
