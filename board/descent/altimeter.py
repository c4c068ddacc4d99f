"""The ranging altimeter as a terrain-facet measurement, and the depth prior of new landmarks.

The altimeter measures the slant range (m) from the body origin along the body's -z axis to the
terrain.  The filter has no terrain map, so the terrain under the beam is the facet (triangle plane)
of the three mapped landmarks nearest to the beam; the predicted range is the distance along the
beam ``b = R_wb (0, 0, -1)`` from ``p`` to that plane::

    n = (X2 - X1) x (X3 - X1),   h = n . (X1 - p) / (n . b)

(a ray-plane intersection; a flat-ground model would be ``h = (p_z - z_ground) / -b_z``).  Its
Jacobians are taken wrt the vehicle error ``[dp, dtheta]`` and the three world points; the filter
chains them to the landmarks' own parameters.
"""
from __future__ import annotations

import numpy as np

from board.descent.quaternion import skew

#: The altimeter beam in the body frame (body -z).
BEAM_BODY = np.array([0.0, 0.0, -1.0])


def facet_range(p: np.ndarray, R_wb: np.ndarray, X1: np.ndarray, X2: np.ndarray, X3: np.ndarray
                ) -> tuple[float, np.ndarray, list[np.ndarray]]:
    """Range (m) along the beam to the plane of ``X1, X2, X3`` and its Jacobians.

    Returns ``(h, Jx, [J1, J2, J3])``: ``Jx`` (6,) wrt ``[dp, dtheta]`` and ``Jk`` (3,) wrt ``Xk``.
    ``h`` is NaN when the beam is parallel to the facet.
    """
    b = R_wb @ BEAM_BODY
    e2, e3 = X2 - X1, X3 - X1
    n = np.cross(e2, e3)
    D = float(n @ b)
    if abs(D) < 1e-9 * max(float(np.linalg.norm(n)), 1e-30):
        return float("nan"), np.zeros(6), [np.zeros(3)] * 3
    h = float(n @ (X1 - p)) / D
    Jx = np.empty(6)
    Jx[0:3] = -n / D
    # b(dtheta) = R (e + dtheta x e) = b - R [e]x dtheta
    Jx[3:6] = h / D * (n @ R_wb @ skew(BEAM_BODY))
    dh_dn = ((X1 - p) - h * b) / D
    J2 = dh_dn @ (-skew(e3))
    J3 = dh_dn @ skew(e2)
    J1 = n / D - J2 - J3
    return h, Jx, [J1, J2, J3]


def beam_ground_height(p: np.ndarray, R_wb: np.ndarray, range_m: float) -> float:
    """World height (m) of the terrain point the altimeter beam hits, from the position and a range (m)."""
    return float(p[2] + range_m * (R_wb @ BEAM_BODY)[2])


def inverse_depth_prior(r_cam: np.ndarray, ray_w: np.ndarray, ground_z: float, *, rel_sigma: float = 0.3,
                        rho_min: float = 1e-4) -> tuple[float, float]:
    """Prior inverse depth (1/m) and its sigma for a ray ``ray_w`` (unit, world) from ``r_cam`` (m).

    The depth is where the ray meets the horizontal plane at the beam's ground height ``ground_z``
    (m, from :func:`beam_ground_height`); ``rel_sigma`` is the relative sigma of the inverse depth,
    wide enough to cover the relief between the beam's ground point and the landmark's.
    """
    dz = ground_z - float(r_cam[2])
    if ray_w[2] >= -1e-6 or dz >= -1e-3:  # ray not downward or camera below the ground estimate
        return rho_min * 10.0, rho_min * 10.0
    s = dz / float(ray_w[2])
    rho = 1.0 / s
    return rho, rel_sigma * rho
