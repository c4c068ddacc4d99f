"""The ten descent trajectories and their per-trial actuation noise.

A trajectory gives the body's position (world, m) and attitude (heading clockwise from north, pitch
nose-up, roll right-side-down, degrees: :func:`board.conventions.rotation_enu_from_camera` with the
body frame x forward, y left, z up) as smooth functions of time.  Heights are above the terrain's
highest point (``z_top``), so every trajectory clears the terrain; horizontal positions are relative
to the terrain's centre and drawn for a 400 m terrain (scaled with ``scale_xy`` for other sizes).  The memorandum's set: two linear motions, S-shapes, a half-ellipse and
half-circles (its curved paths "do not necessarily represent feasible descent trajectories"), plus a
vertical descent, a wobbling linear and a spiral.  Each trial adds the memorandum's additive Gaussian
actuation noise as a smooth perturbation: per axis a sum of sinusoids with Gaussian amplitudes
(position 1-sigma ``noise_pos_m``, attitude ``noise_att_deg``) and random frequencies and phases.

Derivatives (velocity, acceleration, body rates) are central differences of these analytic functions
(h = 1e-3 s for position, 1e-4 s for attitude; errors < 1e-6 m/s2 and 1e-9 rad/s).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from board.conventions import az_from_en_deg
from board.errors import InvalidInputError

DEFAULT_DURATION_S = 200.0


def _lerp(a, b, s):
    return a + (b - a) * s


# paths: s in [0, 1] -> (x, y, height above the terrain top), metres
def _linear1(s):
    return _lerp(-100.0, 100.0, s), np.zeros_like(s), _lerp(110.0, 30.0, s)


def _linear2(s):
    return _lerp(-75.0, 75.0, s), _lerp(-75.0, 75.0, s), _lerp(130.0, 25.0, s)


def _s_shape(s):
    return _lerp(-100.0, 100.0, s), 45.0 * np.sin(2 * math.pi * s), _lerp(90.0, 35.0, s)


def _half_ellipse(s):
    a = math.pi * (1.0 - s)
    return 105.0 * np.cos(a), -45.0 + 80.0 * np.sin(a), _lerp(85.0, 40.0, s)


def _half_circle(s):
    a = math.pi * (1.0 - s)
    return 85.0 * np.cos(a), -40.0 + 85.0 * np.sin(a), _lerp(75.0, 35.0, s)


def _vertical(s):
    return 15.0 * np.sin(math.pi * s), -10.0 * s, _lerp(160.0, 20.0, s)


def _s_shape_descent(s):
    return 60.0 * np.sin(2 * math.pi * s), _lerp(-100.0, 100.0, s), _lerp(140.0, 25.0, s)


def _half_circle_low(s):
    a = math.pi * s
    return -80.0 * np.cos(a), 40.0 - 80.0 * np.sin(a), _lerp(50.0, 25.0, s)


def _linear_wobble(s):
    return _lerp(90.0, -90.0, s), _lerp(-40.0, 40.0, s), _lerp(100.0, 30.0, s)


def _spiral(s):
    a = 2.5 * math.pi * s
    r = _lerp(70.0, 15.0, s)
    return r * np.cos(a), r * np.sin(a), _lerp(130.0, 25.0, s)


@dataclass(frozen=True)
class TrajectorySpec:
    """id (1..10), name, path s -> (x, y, height over the terrain top), heading: "track" (along the
    horizontal velocity) or a fixed heading (deg); wobble_deg : amplitude of a 0.05 Hz pitch/roll sway."""

    id: int
    name: str
    path: Callable
    heading: str | float = "track"
    wobble_deg: float = 0.0


TRAJECTORIES: dict[int, TrajectorySpec] = {t.id: t for t in (
    TrajectorySpec(1, "linear-east", _linear1, 90.0),
    TrajectorySpec(2, "linear-diagonal", _linear2, "track"),
    TrajectorySpec(3, "s-shape", _s_shape, "track"),
    TrajectorySpec(4, "half-ellipse", _half_ellipse, "track"),
    TrajectorySpec(5, "half-circle", _half_circle, 0.0),
    TrajectorySpec(6, "vertical-descent", _vertical, 30.0),
    TrajectorySpec(7, "s-shape-descent", _s_shape_descent, "track"),
    TrajectorySpec(8, "half-circle-low", _half_circle_low, "track"),
    TrajectorySpec(9, "linear-wobble", _linear_wobble, 300.0, wobble_deg=4.0),
    TrajectorySpec(10, "spiral", _spiral, "track"),
)}


def trajectory_spec(trajectory_id: int) -> TrajectorySpec:
    if int(trajectory_id) not in TRAJECTORIES:
        raise InvalidInputError(f"trajectory {trajectory_id}: use 1 to {len(TRAJECTORIES)}")
    return TRAJECTORIES[int(trajectory_id)]


def rotations_enu_from_body(heading_deg, pitch_deg, roll_deg) -> np.ndarray:
    """(n, 3, 3) body -> ENU rotations: :func:`board.conventions.rotation_enu_from_camera` for arrays of angles.

    The same composition Rz(heading) Ry(pitch) Rx(roll) in the conventions' sign choices, vectorised
    (a trajectory needs ~10^5 of them); tests/descent/test_sim_imu.py checks it against the scalar one.
    """
    h, p, r = (np.radians(np.asarray(a, dtype=np.float64)) for a in (heading_deg, pitch_deg, roll_deg))
    n = np.broadcast(h, p, r).shape
    zero, one = np.zeros(n), np.ones(n)
    sh, ch, sp, cp, sr, cr = np.sin(h), np.cos(h), np.sin(p), np.cos(p), np.sin(r), np.cos(r)
    R_h = np.stack([np.stack([sh, -ch, zero], -1), np.stack([ch, sh, zero], -1), np.stack([zero, zero, one], -1)], -2)
    R_p = np.stack([np.stack([cp, zero, -sp], -1), np.stack([zero, one, zero], -1), np.stack([sp, zero, cp], -1)], -2)
    R_r = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, cr, -sr], -1), np.stack([zero, sr, cr], -1)], -2)
    return R_h @ R_p @ R_r


@dataclass(frozen=True)
class _Sines:
    """Sum of sinusoids per axis: amp (axes, k), freq (axes, k) Hz, phase (axes, k) rad."""

    amp: np.ndarray
    freq: np.ndarray
    phase: np.ndarray

    def __call__(self, t):
        t = np.asarray(t, dtype=np.float64)[..., None, None]
        return np.sum(self.amp * np.sin(2 * math.pi * self.freq * t + self.phase), axis=-1)


def _draw_sines(rng, axes, k, sigma, f_lo, f_hi):
    # each term carries sigma / sqrt(k) so the sum has 1-sigma ``sigma`` per axis
    return _Sines(rng.normal(0.0, sigma / math.sqrt(k), (axes, k)), rng.uniform(f_lo, f_hi, (axes, k)),
                  rng.uniform(0, 2 * math.pi, (axes, k)))


@dataclass
class Motion:
    """A trajectory flown in one trial: position and attitude as functions of time (see module docstring)."""

    spec: TrajectorySpec
    duration_s: float
    z_top: float
    centre_xy: tuple[float, float] = (0.0, 0.0)
    scale_xy: float = 1.0
    noise_pos: _Sines | None = None
    noise_att: _Sines | None = None
    _track_heading: Callable | None = field(default=None, repr=False)

    def _nominal(self, t):
        s = np.asarray(t, dtype=np.float64) / self.duration_s      # not clipped: smooth through t = 0 and the end
        x, y, h = self.spec.path(s)
        k = self.scale_xy
        return np.stack(np.broadcast_arrays(k * x + self.centre_xy[0], k * y + self.centre_xy[1], h + self.z_top),
                        axis=-1)

    def position(self, t) -> np.ndarray:
        """(n, 3) body origin in the world, m."""
        p = self._nominal(t)
        return p if self.noise_pos is None else p + self.noise_pos(t)

    def angles_deg(self, t) -> np.ndarray:
        """(n, 3) heading, pitch, roll (degrees)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if self.spec.heading == "track":
            h = 1e-3
            dp = self._nominal(t + h) - self._nominal(t - h)
            heading = az_from_en_deg(dp[..., 0], dp[..., 1])
            heading = np.degrees(np.unwrap(np.radians(heading)))
        else:
            heading = np.full(t.shape, float(self.spec.heading))
        w = self.spec.wobble_deg
        pitch = w * np.sin(2 * math.pi * 0.05 * t)
        roll = w * np.sin(2 * math.pi * 0.035 * t + 1.0)
        ang = np.stack([heading, pitch, roll], axis=-1)
        return ang if self.noise_att is None else ang + self.noise_att(t)

    def rotation(self, t) -> np.ndarray:
        """(n, 3, 3) R_world_body."""
        a = self.angles_deg(t)
        return rotations_enu_from_body(a[:, 0], a[:, 1], a[:, 2])

    def velocity(self, t, h: float = 1e-3) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        return (self.position(t + h) - self.position(t - h)) / (2 * h)

    def acceleration(self, t, h: float = 1e-3) -> np.ndarray:
        """(n, 3) world acceleration, m/s2."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        return (self.position(t + h) - 2 * self.position(t) + self.position(t - h)) / (h * h)

    def body_rate(self, t, h: float = 1e-4) -> np.ndarray:
        """(n, 3) angular velocity in the body frame, rad/s: vee(R^T dR/dt)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        R = self.rotation(t)
        dR = (self.rotation(t + h) - self.rotation(t - h)) / (2 * h)
        W = np.einsum("nji,njk->nik", R, dR)
        return np.stack([0.5 * (W[:, 2, 1] - W[:, 1, 2]), 0.5 * (W[:, 0, 2] - W[:, 2, 0]),
                         0.5 * (W[:, 1, 0] - W[:, 0, 1])], axis=-1)


def make_motion(trajectory_id: int, trial: int, *, seed: int = 0, z_top: float, centre_xy=(0.0, 0.0),
                scale_xy: float = 1.0, duration_s: float = DEFAULT_DURATION_S, noise_pos_m: float = 2.0,
                noise_att_deg: float = 1.0) -> Motion:
    """The motion of ``trajectory_id`` in ``trial`` (noise drawn from (seed, trajectory, trial)).

    scale_xy : horizontal scale of the path (the paths are drawn for the memorandum's 400 m terrain;
    ``terrain side / 400`` keeps them over a smaller or larger one).
    """
    spec = trajectory_spec(trajectory_id)
    if duration_s <= 0:
        raise InvalidInputError(f"duration {duration_s} s must be positive")
    rng = np.random.Generator(np.random.PCG64([int(seed), int(trajectory_id), int(trial), 1414]))
    npos = _draw_sines(rng, 3, 4, noise_pos_m, 0.004, 0.03) if noise_pos_m > 0 else None
    natt = _draw_sines(rng, 3, 4, noise_att_deg, 0.01, 0.1) if noise_att_deg > 0 else None
    return Motion(spec, float(duration_s), float(z_top), tuple(centre_xy), float(scale_xy), npos, natt)
