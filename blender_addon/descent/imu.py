"""Inertial and ranging sensors of the lander: IMU (gyro + accelerometer) and altimeter, and the truth.

IMU (rate >= 100 Hz): ``gyro = omega_b + b_g + n_g``, ``accel = R_wb^T (a_w - g_w) + b_a + n_a`` with
white noise of density ``N`` (discrete sigma ``N sqrt(rate)``) and biases that random-walk with density
``K`` (discrete step sigma ``K sqrt(dt)``), starting at zero.  Altimeter: the slant range along the
body's -z axis from the body origin to the true terrain (a ray cast), plus Gaussian noise of
``sigma_m``; with probability ``dropout_prob`` a sample is invalid (range NaN, valid 0).
Ground truth: TUM rows ``t x y z qx qy qz qw`` (R_world_body as a scalar-last quaternion) at the IMU
times.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from board.errors import InvalidInputError

from .trajectories import Motion


@dataclass(frozen=True)
class ImuParams:
    """Noise model (a tactical-grade MEMS IMU): densities and bias random walks, rate in Hz."""

    rate_hz: float = 200.0
    gyro_noise_rad_s_sqrt_hz: float = 5e-5          # 0.17 deg/sqrt(h) angle random walk
    accel_noise_m_s2_sqrt_hz: float = 5e-4          # 0.03 m/s/sqrt(h) velocity random walk
    gyro_bias_rw: float = 1e-6                      # rad/s2/sqrt(Hz)
    accel_bias_rw: float = 1e-5                     # m/s3/sqrt(Hz)

    def __post_init__(self) -> None:
        if self.rate_hz < 100.0:
            raise InvalidInputError(f"IMU rate {self.rate_hz} Hz: use at least 100 Hz")

    def to_dict(self) -> dict:
        return {k: float(v) for k, v in asdict(self).items()}


@dataclass(frozen=True)
class AltimeterParams:
    """Ranging altimeter: 1-sigma noise (m), rate (Hz), dropout probability per sample."""

    sigma_m: float = 0.2
    rate_hz: float = 10.0
    dropout_prob: float = 0.02

    def __post_init__(self) -> None:
        if self.sigma_m < 0 or self.rate_hz <= 0 or not (0 <= self.dropout_prob <= 1):
            raise InvalidInputError("altimeter: sigma_m >= 0, rate_hz > 0 and dropout_prob in [0, 1]")

    def to_dict(self) -> dict:
        return {k: float(v) for k, v in asdict(self).items()}


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions (x, y, z, w), w >= 0, of rotation matrices (n, 3, 3)."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(R)).as_quat()
    return q * np.where(q[:, 3:4] < 0, -1.0, 1.0)


def sample_times(duration_s: float, rate_hz: float) -> np.ndarray:
    """0, 1/rate, ... up to ``duration_s`` inclusive (s)."""
    n = int(math.floor(duration_s * rate_hz + 1e-9)) + 1
    return np.arange(n) / rate_hz


def simulate_imu(motion: Motion, params: ImuParams, gravity_mps2: float, rng: np.random.Generator, *,
                 duration_s: float | None = None, noise: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """IMU samples (n, 7) and ground truth (n, 8) TUM rows at the IMU times (see the module docstring)."""
    t = sample_times(motion.duration_s if duration_s is None else duration_s, params.rate_hz)
    R = motion.rotation(t)
    g_w = np.array([0.0, 0.0, -gravity_mps2])
    f_w = motion.acceleration(t) - g_w
    accel = np.einsum("nji,nj->ni", R, f_w)
    gyro = motion.body_rate(t)
    if noise:
        dt = 1.0 / params.rate_hz
        n = t.size
        bg = np.cumsum(rng.normal(0.0, params.gyro_bias_rw * math.sqrt(dt), (n, 3)), axis=0)
        ba = np.cumsum(rng.normal(0.0, params.accel_bias_rw * math.sqrt(dt), (n, 3)), axis=0)
        gyro = gyro + bg + rng.normal(0.0, params.gyro_noise_rad_s_sqrt_hz * math.sqrt(params.rate_hz), (n, 3))
        accel = accel + ba + rng.normal(0.0, params.accel_noise_m_s2_sqrt_hz * math.sqrt(params.rate_hz), (n, 3))
    imu = np.column_stack([t, gyro, accel])
    truth = np.column_stack([t, motion.position(t), quaternion_from_rotation(R)])
    return imu, truth


def simulate_altimeter(motion: Motion, params: AltimeterParams, range_fn, rng: np.random.Generator, *,
                       duration_s: float | None = None) -> np.ndarray:
    """(n, 3) rows t, range_m, valid: ``range_fn(origin, direction)`` is the true range (m, NaN = miss)."""
    t = sample_times(motion.duration_s if duration_s is None else duration_s, params.rate_hz)
    R = motion.rotation(t)
    p = motion.position(t)
    true = np.array([range_fn(p[i], -R[i][:, 2]) for i in range(t.size)])
    meas = true + rng.normal(0.0, params.sigma_m, t.size)
    valid = np.isfinite(true) & (rng.random(t.size) >= params.dropout_prob)
    return np.column_stack([t, np.where(valid, meas, np.nan), valid.astype(np.float64)])
