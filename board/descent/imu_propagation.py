"""Vehicle state and its IMU propagation (strapdown mechanisation + error-state transition).

Frames and units
----------------
World: the terrain's local metric frame, x east, y north, z up (m).  Body: x forward, y left, z up.
The IMU is at the body origin.  Gyro: body angular rate (rad/s); accelerometer: specific force in the
body frame (m/s^2), ``f = R_wb^T (a_w - g_w)`` with ``g_w = (0, 0, -g)``.

Nominal state (the memorandum's X = (r, q, v, omega), eqs. 1-4, with the angular rate taken from the
gyro rather than carried in the state, and the two IMU biases added):
``p`` position of the body origin in world (m), ``R`` = R_world_body, ``v`` velocity in world (m/s),
``bg`` gyro bias (rad/s), ``ba`` accelerometer bias (m/s^2).

Error state (15): ``[dp(3), dtheta(3), dv(3), dbg(3), dba(3)]`` with the multiplicative attitude
error in the body frame, ``R_true = R @ exp(dtheta)`` (see :mod:`board.descent.quaternion`).
Continuous-time error dynamics (Sola, "Quaternion kinematics for the error-state KF", 2017, eq. 236
with a local-frame angular error)::

    dp'  = dv
    dv'  = -R [a]x dtheta - R dba - R n_a
    dth' = -[w]x dtheta - dbg - n_g
    dbg' = n_bg,   dba' = n_ba

with ``a = f_m - ba`` and ``w = w_m - bg``.  The discrete transition over one IMU interval is
``Phi = I + F dt + (F dt)^2 / 2``; the noise is ``Q = G Qc G^T dt``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from board.descent.quaternion import exp_so3, orthonormalise, skew

#: Slices of the vehicle error state.
IP, ITH, IV, IBG, IBA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15)
N_VEHICLE = 15


@dataclass
class VehicleState:
    """Nominal vehicle state (world frame, SI units; see the module docstring)."""

    p: np.ndarray
    R: np.ndarray
    v: np.ndarray
    bg: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ba: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def copy(self) -> "VehicleState":
        return VehicleState(self.p.copy(), self.R.copy(), self.v.copy(), self.bg.copy(), self.ba.copy())

    def boxplus(self, dx: np.ndarray) -> "VehicleState":
        """The state corrected by the error ``dx`` (15,): additive except the attitude (right-multiplied)."""
        return VehicleState(self.p + dx[IP], self.R @ exp_so3(dx[ITH]), self.v + dx[IV],
                            self.bg + dx[IBG], self.ba + dx[IBA])


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time IMU noise densities.

    gyro_noise : rad/s/sqrt(Hz); accel_noise : m/s^2/sqrt(Hz);
    gyro_bias_rw : rad/s^2/sqrt(Hz); accel_bias_rw : m/s^3/sqrt(Hz).
    """

    gyro_noise: float
    accel_noise: float
    gyro_bias_rw: float
    accel_bias_rw: float


def imu_step(x: VehicleState, gyro: np.ndarray, accel: np.ndarray, dt: float, g_w: np.ndarray
             ) -> tuple[VehicleState, np.ndarray, np.ndarray]:
    """Propagate the nominal state over one IMU interval ``dt`` (s) with measurements held constant.

    Returns ``(x_next, F, G)``: the continuous-time error Jacobians (15, 15) and noise input (15, 12)
    evaluated at the start of the interval (noise order: n_g, n_a, n_bg, n_ba).
    """
    w = np.asarray(gyro, dtype=np.float64) - x.bg
    a = np.asarray(accel, dtype=np.float64) - x.ba
    acc_w = x.R @ a + g_w
    p = x.p + x.v * dt + 0.5 * acc_w * dt * dt
    v = x.v + acc_w * dt
    R = x.R @ exp_so3(w * dt)
    F = np.zeros((N_VEHICLE, N_VEHICLE))
    F[IP, IV] = np.eye(3)
    F[IV, ITH] = -x.R @ skew(a)
    F[IV, IBA] = -x.R
    F[ITH, ITH] = -skew(w)
    F[ITH, IBG] = -np.eye(3)
    G = np.zeros((N_VEHICLE, 12))
    G[IV, 0:3] = 0.0
    G[IV, 3:6] = -x.R
    G[ITH, 0:3] = -np.eye(3)
    G[IBG, 6:9] = np.eye(3)
    G[IBA, 9:12] = np.eye(3)
    return VehicleState(p, R, v, x.bg.copy(), x.ba.copy()), F, G


def propagate(x: VehicleState, imu: np.ndarray, t0: float, t1: float, g_w: np.ndarray, noise: ImuNoise
              ) -> tuple[VehicleState, np.ndarray, np.ndarray]:
    """Propagate from ``t0`` to ``t1`` (s) through the IMU rows ``imu`` (n, 7: t, gx, gy, gz, ax, ay, az).

    Each IMU sample is held from its time to the next (zero-order hold); the first interval starts at
    ``t0`` with the last sample at or before it.  Returns ``(x1, Phi, Qd)``: the nominal state at
    ``t1``, the error-state transition (15, 15) and the accumulated discrete noise (15, 15).
    """
    Phi = np.eye(N_VEHICLE)
    Qd = np.zeros((N_VEHICLE, N_VEHICLE))
    if t1 <= t0:
        return x.copy(), Phi, Qd
    # G Qc G^T is diagonal and constant: the accelerometer noise enters as R n_a with isotropic n_a
    gqg = np.zeros(N_VEHICLE)
    gqg[ITH] = noise.gyro_noise ** 2
    gqg[IV] = noise.accel_noise ** 2
    gqg[IBG] = noise.gyro_bias_rw ** 2
    gqg[IBA] = noise.accel_bias_rw ** 2
    eye = np.eye(N_VEHICLE)
    ts = imu[:, 0]
    i = max(int(np.searchsorted(ts, t0, side="right")) - 1, 0)
    t = t0
    while t < t1 - 1e-12:
        t_next = min(ts[i + 1] if i + 1 < len(ts) else t1, t1)
        if t_next <= t:  # duplicate time stamps
            i += 1
            continue
        dt = t_next - t
        x, F, _ = imu_step(x, imu[i, 1:4], imu[i, 4:7], dt, g_w)
        Fd = F * dt
        phi = eye + Fd + 0.5 * Fd @ Fd
        Qd = phi @ Qd @ phi.T
        Qd[np.diag_indices(N_VEHICLE)] += gqg * dt
        Phi = phi @ Phi
        t = t_next
        if t_next >= (ts[i + 1] if i + 1 < len(ts) else np.inf):
            i += 1
    x.R = orthonormalise(x.R)
    return x, Phi, Qd
