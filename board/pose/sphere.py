"""Skyline directions on the sphere: body frame <-> ENU, levelling a tilted skyline.

A query skyline sample at relative azimuth ``theta`` (degrees clockwise from the optical axis at
pan 0) and elevation ``el`` (degrees above the mast's x-y plane) is the body-frame direction
``(cos el cos theta, -cos el sin theta, sin el)`` (x forward, y left, z up; see
:func:`board.conventions.rotation_enu_from_camera`).  Its ENU direction for a pose
(heading, pitch, roll) is ``R(heading, pitch, roll) @ v_body``.
"""
from __future__ import annotations

import functools

import numpy as np

from board.conventions import az_el_from_enu_deg, enu_from_az_el_deg, rotation_enu_from_camera


def body_from_rel_az_el(theta_deg, el_deg) -> np.ndarray:
    """Body-frame unit vectors (..., 3) of relative azimuth/elevation in degrees."""
    v = enu_from_az_el_deg(theta_deg, el_deg)  # (east, north, up) with "north" = forward
    return np.stack([v[..., 1], -v[..., 0], v[..., 2]], axis=-1)


def rel_az_el_from_body(v) -> tuple[np.ndarray, np.ndarray]:
    """Relative azimuth (degrees, [0, 360)) and elevation (degrees) of body-frame vectors (..., 3)."""
    v = np.asarray(v, dtype=float)
    return az_el_from_enu_deg(np.stack([-v[..., 1], v[..., 0], v[..., 2]], axis=-1))


def enu_az_el(theta_deg, el_deg, heading_deg: float, pitch_deg: float = 0.0, roll_deg: float = 0.0):
    """ENU azimuth/elevation (degrees) of query samples seen at pose (heading, pitch, roll)."""
    R = rotation_enu_from_camera(heading_deg, pitch_deg, roll_deg)
    return az_el_from_enu_deg(body_from_rel_az_el(theta_deg, el_deg) @ R.T)


def resample_periodic(az_deg: np.ndarray, el_deg: np.ndarray, at_deg: np.ndarray, *, max_gap_deg: float) -> np.ndarray:
    """Linear interpolation of a curve sampled at azimuths ``az_deg`` onto ``at_deg`` (periodic).

    Points between two samples farther apart than ``max_gap_deg`` (unseen arcs) get NaN.
    """
    order = np.argsort(np.mod(az_deg, 360.0))
    a = np.mod(az_deg, 360.0)[order]
    e = np.asarray(el_deg, dtype=float)[order]
    a_ext = np.concatenate([a[-1:] - 360.0, a, a[:1] + 360.0])
    e_ext = np.concatenate([e[-1:], e, e[:1]])
    x = np.mod(at_deg, 360.0)
    idx = np.clip(np.searchsorted(a_ext, x, side="right") - 1, 0, a_ext.size - 2)
    a0, a1 = a_ext[idx], a_ext[idx + 1]
    t = np.where(a1 > a0, (x - a0) / np.where(a1 > a0, a1 - a0, 1.0), 0.0)
    out = e_ext[idx] * (1 - t) + e_ext[idx + 1] * t
    out[(a1 - a0) > max_gap_deg] = np.nan
    return out


def level_skyline(el_deg: np.ndarray, theta_deg: np.ndarray, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Remove a known pitch/roll: the skyline as a level mast would see it, on the same azimuths.

    Rotates every seen sample on the sphere (exact, no small-angle approximation) and
    resamples onto ``theta_deg``; NaN stays where nothing was seen.
    """
    el = np.asarray(el_deg, dtype=float)
    seen = np.isfinite(el)
    step = 360.0 / el.size
    R = rotation_enu_from_camera(0.0, pitch_deg, roll_deg)  # body -> level (heading 0)
    v = body_from_rel_az_el(theta_deg[seen], el[seen]) @ R.T  # level ENU with heading 0: az = relative az
    az, e = az_el_from_enu_deg(v)
    return resample_periodic(az, e, theta_deg, max_gap_deg=1.5 * step + 1e-9)


@functools.lru_cache(maxsize=1)
def harmonic_to_tilt_matrix() -> np.ndarray:
    """2x2 matrix M with (pitch, roll) = M @ (alpha, beta) for small tilts.

    ``alpha cos(theta) + beta sin(theta)`` is the first-order change of a query skyline's
    elevation caused by a pitch/roll of the mast; derived numerically from the rotation
    convention so that it can never disagree with it.
    """
    theta = np.arange(0.0, 360.0, 1.0)
    cols = []
    d = 1e-3
    for pitch, roll in ((d, 0.0), (0.0, d)):
        R = rotation_enu_from_camera(0.0, pitch, roll)
        _, e = rel_az_el_from_body(enu_from_az_el_deg(theta, 0.0) @ R)  # body = R^T enu
        t = np.radians(theta)
        X = np.stack([np.cos(t), np.sin(t)], axis=1)
        cols.append(np.linalg.lstsq(X, e / d, rcond=None)[0])
    A = np.stack(cols, axis=1)  # (alpha, beta) per unit (pitch, roll)
    return np.linalg.inv(A)
