"""Landmark parametrisations and the camera measurement model with their Jacobians.

Inverse depth (Montiel, Civera and Davison, "Unified inverse depth parametrization for monocular
SLAM", RSS 2006, eqs. 3-5): ``y = (x0, y0, z0, theta, phi, rho)`` -- the world position (m) of the
optical centre that first saw the landmark, the azimuth ``theta`` and elevation ``phi`` (rad) of the
ray in the world frame and the inverse depth ``rho`` (1/m) along it::

    X = (x0, y0, z0) + m(theta, phi) / rho,   m = (cos(phi) sin(theta), -sin(phi), cos(phi) cos(theta))

``m`` is singular only along the world's +-y axis (horizontal), which a downward camera never sees.
Euclidean landmarks are ``X = (x, y, z)`` (m, world).

Camera measurement: the optical centre is ``r_c = p + R_wb t_bc`` and the landmark in the camera frame
(OpenCV axes) is, for inverse depth (scaled by ``rho``, which leaves the projection unchanged)::

    h_c = R_bc^T (R_wb^T (rho (r_i - p) + m) - rho t_bc)

and ``h_c = R_bc^T (R_wb^T (X - p) - t_bc)`` for an XYZ landmark.  The pixel is the undistorted
pinhole ``(fx hx / hz + cx, fy hy / hz + cy)``.  Jacobians are with respect to the vehicle error
``[dp, dtheta]`` (dtheta body-frame, right-multiplied; :mod:`board.descent.imu_propagation`) and to the
landmark's own parameters.
"""
from __future__ import annotations

import numpy as np

from board.descent.quaternion import skew

#: Parameters of an inverse-depth and of a Euclidean landmark.
ID_SIZE, XYZ_SIZE = 6, 3


def ray_direction(theta: float, phi: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit world direction ``m(theta, phi)`` and its derivatives ``dm/dtheta``, ``dm/dphi`` (rad)."""
    ct, st, cp, sp = np.cos(theta), np.sin(theta), np.cos(phi), np.sin(phi)
    m = np.array([cp * st, -sp, cp * ct])
    dm_dt = np.array([cp * ct, 0.0, -cp * st])
    dm_dp = np.array([-sp * st, -cp, -sp * ct])
    return m, dm_dt, dm_dp


def angles_of_direction(m: np.ndarray) -> tuple[float, float, np.ndarray]:
    """``(theta, phi)`` (rad) of a world direction ``m`` (any length) and their Jacobian (2, 3) wrt ``m``."""
    mx, my, mz = float(m[0]), float(m[1]), float(m[2])
    rxz2 = mx * mx + mz * mz
    rxz = np.sqrt(rxz2)
    n2 = rxz2 + my * my
    theta = float(np.arctan2(mx, mz))
    phi = float(np.arctan2(-my, rxz))
    J = np.zeros((2, 3))
    J[0] = [mz / rxz2, 0.0, -mx / rxz2]
    J[1] = [mx * my / (n2 * rxz), -rxz / n2, mz * my / (n2 * rxz)]
    return theta, phi, J


def id_to_xyz(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World point (3,) of an inverse-depth landmark ``y`` (6,) and its Jacobian (3, 6)."""
    m, dm_dt, dm_dp = ray_direction(y[3], y[4])
    rho = y[5]
    X = y[0:3] + m / rho
    J = np.zeros((3, 6))
    J[:, 0:3] = np.eye(3)
    J[:, 3] = dm_dt / rho
    J[:, 4] = dm_dp / rho
    J[:, 5] = -m / (rho * rho)
    return X, J


def camera_point_id(y: np.ndarray, p: np.ndarray, R_wb: np.ndarray, R_bc: np.ndarray, t_bc: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``h_c`` (3,) of an inverse-depth landmark, its Jacobian wrt ``[dp, dtheta]`` (3, 6) and wrt ``y`` (3, 6)."""
    m, dm_dt, dm_dp = ray_direction(y[3], y[4])
    rho = y[5]
    R_cw = R_bc.T @ R_wb.T
    d = y[0:3] - p
    a = R_wb.T @ (rho * d + m)
    h = R_bc.T @ (a - rho * t_bc)
    Jx = np.empty((3, 6))
    Jx[:, 0:3] = -rho * R_cw
    Jx[:, 3:6] = R_bc.T @ skew(a)
    Jy = np.empty((3, 6))
    Jy[:, 0:3] = rho * R_cw
    Jy[:, 3] = R_cw @ dm_dt
    Jy[:, 4] = R_cw @ dm_dp
    Jy[:, 5] = R_cw @ d - R_bc.T @ t_bc
    return h, Jx, Jy


def camera_point_xyz(X: np.ndarray, p: np.ndarray, R_wb: np.ndarray, R_bc: np.ndarray, t_bc: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``h_c`` (3,) of a Euclidean landmark, its Jacobian wrt ``[dp, dtheta]`` (3, 6) and wrt ``X`` (3, 3)."""
    R_cw = R_bc.T @ R_wb.T
    a = R_wb.T @ (X - p)
    h = R_bc.T @ (a - t_bc)
    Jx = np.empty((3, 6))
    Jx[:, 0:3] = -R_cw
    Jx[:, 3:6] = R_bc.T @ skew(a)
    return h, Jx, R_cw


def pinhole(h: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel ``(u, v)`` of the camera-frame point ``h`` (hz > 0) and its Jacobian (2, 3)."""
    iz = 1.0 / h[2]
    uv = np.array([fx * h[0] * iz + cx, fy * h[1] * iz + cy])
    J = np.array([[fx * iz, 0.0, -fx * h[0] * iz * iz], [0.0, fy * iz, -fy * h[1] * iz * iz]])
    return uv, J


def init_inverse_depth(uv: np.ndarray, rho0: float, p: np.ndarray, R_wb: np.ndarray, R_bc: np.ndarray,
                       t_bc: np.ndarray, fx: float, fy: float, cx: float, cy: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A new inverse-depth landmark from an undistorted pixel ``uv`` and a prior inverse depth ``rho0`` (1/m).

    Returns ``(y, Jx, Jz, Jrho)``: the landmark (6,), its Jacobians wrt the vehicle error
    ``[dp, dtheta]`` (6, 6), the pixel (6, 2) and ``rho0`` (6,) -- the terms of the undistorted
    initialisation's covariance, ``P_yy = Jx P_xx Jx^T + Jz R Jz^T + Jrho s_rho^2 Jrho^T`` and
    ``P_yx = Jx P_x.`` (Civera et al. 2008, sec. III-C).
    """
    d_c = np.array([(uv[0] - cx) / fx, (uv[1] - cy) / fy, 1.0])
    R_wc = R_wb @ R_bc
    m = R_wc @ d_c
    theta, phi, Jang = angles_of_direction(m)
    y = np.empty(6)
    y[0:3] = p + R_wb @ t_bc
    y[3], y[4], y[5] = theta, phi, rho0
    Jx = np.zeros((6, 6))
    Jx[0:3, 0:3] = np.eye(3)
    Jx[0:3, 3:6] = -R_wb @ skew(t_bc)
    Jx[3:5, 3:6] = Jang @ (-R_wb @ skew(R_bc @ d_c))
    Jz = np.zeros((6, 2))
    Jz[3:5, :] = Jang @ R_wc @ np.array([[1.0 / fx, 0.0], [0.0, 1.0 / fy], [0.0, 0.0]])
    Jrho = np.zeros(6)
    Jrho[5] = 1.0
    return y, Jx, Jz, Jrho


def linearity_index(y: np.ndarray, sigma_rho: float, r_cam: np.ndarray) -> float:
    """Civera's linearity index of the inverse-depth -> XYZ switch (IEEE T-RO 2008, eq. 19).

    ``L = 4 sigma_d / d1 * |cos(alpha)|`` with ``sigma_d = sigma_rho / rho^2``, ``d1`` the distance from
    the current optical centre ``r_cam`` to the point and ``alpha`` the angle between the first ray and
    the current one.  Below ~0.1 the XYZ form is linear enough to replace the inverse depth.
    """
    m, _, _ = ray_direction(y[3], y[4])
    X = y[0:3] + m / y[5]
    h = X - r_cam
    d1 = float(np.linalg.norm(h))
    sigma_d = sigma_rho / (y[5] * y[5])
    cos_a = float(m @ h) / max(d1, 1e-12)
    return 4.0 * sigma_d / max(d1, 1e-12) * abs(cos_a)
