"""Analytic descent scenes for testing the filter: a trajectory with closed-form derivatives, its IMU,
altimeter and ground truth, landmarks as 3-D points, and (numpy + OpenCV only) image pairs of a
textured height field -- an independent truth for the filter, not the simulator of issue 14.

Frames as in :mod:`board.descent.imu_propagation`: world x east, y north, z up (m); body x forward,
y left, z up; both cameras look down the body's -z axis with ``R_BODY_CAM_DOWN`` (image top towards
the body's +x).  Attitude ``R_wb = Rz(yaw) @ Ry(pitch) @ Rx(roll)``; body rate
``w = Rx^T Ry^T (0, 0, yaw') + Rx^T (0, pitch', 0) + (roll', 0, 0)``.

IMU samples are stamped at the start of their interval and hold the rate and specific force at the
interval's midpoint (the mean over the interval to second order), so that the filter's zero-order-hold
propagation integrates them to O(dt^2).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from board.camera import CameraModel
from board.conventions import BODIES
from board.descent.quaternion import quat_from_rot, quat_to_xyzw

#: Camera axes in the body frame for a camera looking down (columns: image right, image down, optical axis).
R_BODY_CAM_DOWN = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
EUROPA_G = 1.315  # m/s^2


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


@dataclass(frozen=True)
class AnalyticTrajectory:
    """``p(t) = p0 + v0 t + a0 t^2 / 2 + amp * sin(w t)`` (m, per axis) and sinusoidal attitude (rad).

    yaw(t) = yaw0 + yaw_rate t + yaw_amp sin(att_w t); pitch(t) = pitch_amp sin(att_w t + 1);
    roll(t) = roll_amp sin(att_w t + 2).
    """

    p0: tuple = (0.0, 0.0, 150.0)
    v0: tuple = (2.0, 0.5, -0.4)
    a0: tuple = (0.0, 0.0, 0.0)
    amp: tuple = (3.0, 4.0, 1.0)
    w: tuple = (0.05, 0.07, 0.09)
    yaw0: float = 0.3
    yaw_rate: float = 0.002
    yaw_amp: float = 0.05
    pitch_amp: float = 0.03
    roll_amp: float = 0.03
    att_w: float = 0.2

    def position(self, t):
        t = np.asarray(t, float)[..., None]
        return (np.array(self.p0) + np.array(self.v0) * t + 0.5 * np.array(self.a0) * t * t
                + np.array(self.amp) * np.sin(np.array(self.w) * t))

    def velocity(self, t):
        t = np.asarray(t, float)[..., None]
        w = np.array(self.w)
        return np.array(self.v0) + np.array(self.a0) * t + np.array(self.amp) * w * np.cos(w * t)

    def acceleration(self, t):
        t = np.asarray(t, float)[..., None]
        w = np.array(self.w)
        return np.array(self.a0) - np.array(self.amp) * w * w * np.sin(w * t) + 0 * t

    def _angles(self, t):
        aw = self.att_w
        yaw = self.yaw0 + self.yaw_rate * t + self.yaw_amp * np.sin(aw * t)
        pitch = self.pitch_amp * np.sin(aw * t + 1.0)
        roll = self.roll_amp * np.sin(aw * t + 2.0)
        dyaw = self.yaw_rate + self.yaw_amp * aw * np.cos(aw * t)
        dpitch = self.pitch_amp * aw * np.cos(aw * t + 1.0)
        droll = self.roll_amp * aw * np.cos(aw * t + 2.0)
        return yaw, pitch, roll, dyaw, dpitch, droll

    def rotation(self, t: float) -> np.ndarray:
        """R_world_body at ``t`` (s)."""
        yaw, pitch, roll, *_ = self._angles(float(t))
        return _rz(yaw) @ _ry(pitch) @ _rx(roll)

    def body_rate(self, t: float) -> np.ndarray:
        """Angular rate in the body frame (rad/s) at ``t``."""
        yaw, pitch, roll, dyaw, dpitch, droll = self._angles(float(t))
        Rx, Ry = _rx(roll), _ry(pitch)
        return Rx.T @ Ry.T @ np.array([0, 0, dyaw]) + Rx.T @ np.array([0, dpitch, 0]) + np.array([droll, 0, 0])


@dataclass(frozen=True)
class ImuSpec:
    """IMU model: rate (Hz), white-noise densities and bias random walks (per sqrt(Hz)), initial biases."""

    rate_hz: float = 200.0
    gyro_noise: float = 1e-4
    accel_noise: float = 2e-3
    gyro_bias_rw: float = 1e-6
    accel_bias_rw: float = 1e-5
    bg0: tuple = (0.0, 0.0, 0.0)
    ba0: tuple = (0.0, 0.0, 0.0)


def simulate_imu(traj: AnalyticTrajectory, t_end: float, spec: ImuSpec, g: float, rng: np.random.Generator
                 ) -> np.ndarray:
    """IMU rows (n, 7) ``t, gx, gy, gz, ax, ay, az`` from 0 to ``t_end`` (s), with noise and bias walks."""
    dt = 1.0 / spec.rate_hz
    n = int(round(t_end * spec.rate_hz)) + 1
    t = np.arange(n) * dt
    out = np.zeros((n, 7))
    out[:, 0] = t
    g_w = np.array([0.0, 0.0, -g])
    bg, ba = np.array(spec.bg0, float), np.array(spec.ba0, float)
    for i, ti in enumerate(t):
        tm = ti + 0.5 * dt
        R = traj.rotation(tm)
        out[i, 1:4] = traj.body_rate(tm) + bg + rng.normal(0, spec.gyro_noise / np.sqrt(dt), 3)
        out[i, 4:7] = R.T @ (traj.acceleration(tm) - g_w) + ba + rng.normal(0, spec.accel_noise / np.sqrt(dt), 3)
        bg = bg + rng.normal(0, spec.gyro_bias_rw * np.sqrt(dt), 3)
        ba = ba + rng.normal(0, spec.accel_bias_rw * np.sqrt(dt), 3)
    return out


def groundtruth_rows(traj: AnalyticTrajectory, times: np.ndarray) -> np.ndarray:
    """TUM rows (n, 8) ``t x y z qx qy qz qw`` of the trajectory at ``times`` (s)."""
    rows = np.zeros((len(times), 8))
    for i, t in enumerate(times):
        rows[i, 0] = t
        rows[i, 1:4] = traj.position(t)
        rows[i, 4:8] = quat_to_xyzw(quat_from_rot(traj.rotation(t)))
    return rows


# -- a textured height field and its images ---------------------------------------------------------
def _multiscale_noise(n: int, sigmas_px: tuple, rng: np.random.Generator) -> np.ndarray:
    out = np.zeros((n, n), np.float32)
    for s in sigmas_px:
        f = cv2.GaussianBlur(rng.standard_normal((n, n)).astype(np.float32), (0, 0), s)
        out += f / (f.std() + 1e-12)
    return out / len(sigmas_px)


@dataclass
class TexturedTerrain:
    """Height (m), visible albedo and thermal temperature (K) on a square grid; x east, y north.

    Grid cell ``[i, j]`` is at ``x = x0 + (j + 0.5) res``, ``y = y0 + (i + 0.5) res``.
    """

    height: np.ndarray
    albedo: np.ndarray
    temperature: np.ndarray
    x0: float
    y0: float
    res_m: float
    _slopes: tuple | None = field(default=None, repr=False)

    def slopes(self) -> tuple[np.ndarray, np.ndarray]:
        """(-dh/dx, -dh/dy) grids (float32), computed once."""
        if self._slopes is None:
            gy, gx = np.gradient(self.height, self.res_m)
            self._slopes = ((-gx).astype(np.float32), (-gy).astype(np.float32))
        return self._slopes

    @classmethod
    def procedural(cls, seed: int, *, size_m: float = 400.0, res_m: float = 0.3, relief_m: float = 10.0
                   ) -> "TexturedTerrain":
        rng = np.random.default_rng(seed)
        n = int(round(size_m / res_m))
        h = cv2.resize(_multiscale_noise(n // 8, (10.0, 20.0), rng), (n, n), interpolation=cv2.INTER_CUBIC)
        h = relief_m * (h - h.min()) / max(float(np.ptp(h)), 1e-9)
        albedo = 0.6 + 0.25 * np.tanh(2.0 * _multiscale_noise(n, (2.0, 5.0, 12.0), rng))
        gy, gx = np.gradient(h, res_m)
        # thermal: sun-facing slopes warmer, plus a texture of its own (different from the albedo's)
        temp = 100.0 + 40.0 * gx + 6.0 * np.tanh(2.0 * _multiscale_noise(n, (3.0, 8.0), rng)) + 10 * (1 - albedo)
        return cls(h.astype(np.float32), albedo.astype(np.float32), temp.astype(np.float32),
                   -size_m / 2, -size_m / 2, res_m)

    def sample(self, grid: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear sample of ``grid`` at world ``(x, y)`` (m), border-replicated."""
        mx = ((x - self.x0) / self.res_m - 0.5).astype(np.float32)
        my = ((y - self.y0) / self.res_m - 0.5).astype(np.float32)
        return cv2.remap(grid, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def intersect(self, origin: np.ndarray, dirs: np.ndarray, iterations: int = 8) -> np.ndarray:
        """World points (..., 3) where rays from ``origin`` along ``dirs`` (..., 3, downward) hit the terrain.

        Fixed-point iteration on the ray length (converges where slope x tan(off-nadir angle) < 1).
        """
        dirs32 = dirs.astype(np.float32)
        idz = (-1.0 / dirs32[..., 2]).astype(np.float32)
        s = (np.float32(origin[2]) - np.float32(self.height.mean())) * idz
        for _ in range(iterations):
            x = np.float32(origin[0]) + s * dirs32[..., 0]
            y = np.float32(origin[1]) + s * dirs32[..., 1]
            z = self.sample(self.height, x, y)
            s = (np.float32(origin[2]) - z) * idz
        return origin + s[..., None].astype(np.float64) * dirs


def render_pair(terrain: TexturedTerrain, camera: CameraModel, p: np.ndarray, R_wb: np.ndarray, R_bc: np.ndarray,
                t_bc: np.ndarray, rng: np.random.Generator, *, sun_w=(0.5, 0.2, 0.84)) -> tuple[np.ndarray, np.ndarray]:
    """Visible (uint8, Lambert-shaded albedo) and thermal (uint16, 10 mK counts) images of the terrain."""
    u, v = camera.pixel_grid()
    d_c = camera.unproject(u, v)
    d_w = d_c @ (R_wb @ R_bc).T
    o = p + R_wb @ t_bc
    X = terrain.intersect(o, d_w)
    sx, sy = terrain.slopes()
    nx = terrain.sample(sx, X[..., 0], X[..., 1])
    ny = terrain.sample(sy, X[..., 0], X[..., 1])
    nrm = np.sqrt(nx * nx + ny * ny + 1.0)
    sun = np.asarray(sun_w, float) / np.linalg.norm(sun_w)
    shade = np.clip((nx * sun[0] + ny * sun[1] + sun[2]) / nrm, 0.0, 1.0)
    vis = terrain.sample(terrain.albedo, X[..., 0], X[..., 1]) * (0.15 + 0.85 * shade) * 255.0
    vis = np.clip(vis + rng.normal(0, 2.0, vis.shape), 0, 255).astype(np.uint8)
    temp = terrain.sample(terrain.temperature, X[..., 0], X[..., 1])
    th = np.clip((temp + rng.normal(0, 0.05, temp.shape)) * 100.0, 0, 65535).astype(np.uint16)
    return vis, th


@dataclass
class SyntheticCamera:
    """Duck type of ``board.descent.sequence.DescentCamera``."""

    model: CameraModel
    R_body_cam: np.ndarray
    t_body_cam: np.ndarray
    radiometric: dict | None = None


@dataclass
class SyntheticSequence:
    """An in-memory descent sequence with the attributes of ``board.descent.sequence.DescentSequence``."""

    meta: dict
    cameras: dict
    frame_times: np.ndarray
    imu: np.ndarray
    altimeter: np.ndarray
    groundtruth: np.ndarray
    gravity_w: np.ndarray
    frames: dict = field(default_factory=dict)  # mode -> list of 2-D arrays
    path: Path | None = None

    def load_frame(self, mode: str, i: int) -> np.ndarray:
        return self.frames[mode][i]


def make_sequence(seed: int, *, n_frames: int = 40, frame_rate_hz: float = 1.0,
                  traj: AnalyticTrajectory | None = None, imu_spec: ImuSpec | None = None,
                  altimeter_sigma_m: float = 0.3, altimeter_rate_hz: float = 5.0, dropout_prob: float = 0.05,
                  terrain: TexturedTerrain | None = None, hfov_deg: float = 60.0) -> SyntheticSequence:
    """A whole synthetic descent (images, IMU, altimeter by ray cast on the terrain, ground truth)."""
    rng = np.random.default_rng(seed)
    traj = traj or AnalyticTrajectory()
    imu_spec = imu_spec or ImuSpec()
    terrain = terrain or TexturedTerrain.procedural(seed)
    cam = CameraModel.from_fov(640, 480, hfov_deg)
    t_vis = t_th = np.array([0.1, 0.0, -0.2])  # co-registered cameras (the memorandum's set-up)
    cameras = {"visible": SyntheticCamera(cam, R_BODY_CAM_DOWN.copy(), t_vis),
               "thermal": SyntheticCamera(cam, R_BODY_CAM_DOWN.copy(), t_th,
                                          {"unit": "K", "scale": 0.01, "offset": 0.0, "band_um": [8.0, 14.0]})}
    times = np.arange(n_frames) / frame_rate_hz
    t_end = float(times[-1])
    imu = simulate_imu(traj, t_end, imu_spec, EUROPA_G, rng)
    ta = np.arange(0.0, t_end + 1e-9, 1.0 / altimeter_rate_hz)
    alt = np.zeros((len(ta), 3))
    for i, t in enumerate(ta):
        p, R = traj.position(t), traj.rotation(t)
        b = R @ np.array([0.0, 0.0, -1.0])
        X = terrain.intersect(p, b[None, :])[0]
        valid = rng.random() >= dropout_prob
        alt[i] = (t, float(np.linalg.norm(X - p)) + rng.normal(0, altimeter_sigma_m) if valid else 0.0, float(valid))
    frames = {"visible": [], "thermal": []}
    for t in times:
        p, R = traj.position(t), traj.rotation(t)
        vis, th = render_pair(terrain, cam, p, R, R_BODY_CAM_DOWN, t_vis, rng)
        frames["visible"].append(vis)
        frames["thermal"].append(th)
    meta = {"format": "skyloc-descent-sequence", "version": 1,
            "body": {"name": "europa", "radius_m": BODIES["europa"].radius_m, "gravity_mps2": EUROPA_G},
            "frame_rate_hz": frame_rate_hz,
            "imu": {"file": "imu.csv", "rate_hz": imu_spec.rate_hz, "gyro_noise_rad_s_sqrt_hz": imu_spec.gyro_noise,
                    "accel_noise_m_s2_sqrt_hz": imu_spec.accel_noise, "gyro_bias_rw": imu_spec.gyro_bias_rw,
                    "accel_bias_rw": imu_spec.accel_bias_rw},
            "altimeter": {"file": "altimeter.csv", "sigma_m": altimeter_sigma_m, "rate_hz": altimeter_rate_hz,
                          "dropout_prob": dropout_prob},
            "trajectory": {"id": 0, "name": "synthetic"}, "trial": 0, "seed": seed,
            "models": {"brdf": "lambert-synthetic", "thermal": "synthetic"}}
    return SyntheticSequence(meta, cameras, times, imu, alt, groundtruth_rows(traj, times),
                             np.array([0.0, 0.0, -EUROPA_G]), frames)
