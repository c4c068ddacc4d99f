"""Analytic horizon worlds for tests, benchmarks and demos (numpy only).

A :class:`MountainField` is a set of Gaussian hills on a sphere around a site.  The horizon
seen from ``(x, y)`` at azimuth ``az`` is the highest hill silhouette,
``atan((H exp(-(d sin da)^2 / 2 W^2) - (d cos da)^2 / 2R) / (d cos da))``, so skylines change
with position with true parallax (near hills move, far ones barely), unlike random vectors.
It is not a DEM ray-march (tests that need one use the ray-marcher); it is an independent,
exact and fast horizon function for databases of any size.  Metres and degrees.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from board.conventions import BODIES, azimuth_grid_deg, curvature_drop_m, enu_from_az_el_deg, rotation_enu_from_camera
from board.pose.sphere import rel_az_el_from_body, resample_periodic


@dataclass
class MountainField:
    """Hills at (px, py) metres with heights H (m above the eye level) and widths W (m, Gaussian sigma)."""

    px: np.ndarray
    py: np.ndarray
    height: np.ndarray
    width: np.ndarray
    radius_m: float = BODIES["mars"].radius_m
    base_deg: float = -0.5

    @classmethod
    def random(cls, seed: int, *, center=(0.0, 0.0), n_hills: int = 80, r_min: float = 300.0,
               r_max: float = 15000.0) -> "MountainField":
        """Hills spread around ``center`` between ``r_min`` and ``r_max`` metres (log-uniform distance)."""
        rng = np.random.default_rng(seed)
        d = np.exp(rng.uniform(np.log(r_min), np.log(r_max), n_hills))
        a = rng.uniform(0, 2 * np.pi, n_hills)
        h = d * np.tan(np.radians(rng.uniform(1.0, 12.0, n_hills))) + curvature_drop_m(d, BODIES["mars"].radius_m)
        w = d * rng.uniform(0.03, 0.22, n_hills)  # W << d: the hills never reach the observer
        return cls(center[0] + d * np.sin(a), center[1] + d * np.cos(a), h, w)

    def horizon(self, x, y, az_deg) -> np.ndarray:
        """Elevation (degrees) of the horizon at positions ``x, y`` (P,) and azimuths ``az_deg`` (N,): (P, N)."""
        x = np.atleast_1d(np.asarray(x, float))[:, None, None]
        y = np.atleast_1d(np.asarray(y, float))[:, None, None]
        az = np.radians(np.asarray(az_deg, float))[None, :, None]
        dx, dy = self.px[None, None] - x, self.py[None, None] - y
        d = np.hypot(dx, dy)
        da = np.arctan2(dx, dy) - az
        along = d * np.cos(da)
        across = d * np.sin(da)
        z = self.height * np.exp(-0.5 * (across / self.width) ** 2) - curvature_drop_m(along, self.radius_m)
        el = np.degrees(np.arctan2(z, np.maximum(along, 1.0)))
        el = np.where(along > 1.0, el, -90.0)
        return np.maximum(el.max(axis=2), self.base_deg)

    def horizon_chunked(self, x, y, az_deg, chunk: int = 256) -> np.ndarray:
        out = np.empty((np.size(x), np.size(az_deg)))
        x, y = np.ravel(x), np.ravel(y)
        for i in range(0, x.size, chunk):
            out[i:i + chunk] = self.horizon(x[i:i + chunk], y[i:i + chunk], az_deg)
        return out


def observe(az_deg: np.ndarray, el_deg: np.ndarray, *, heading_deg: float, pitch_deg: float = 0.0,
            roll_deg: float = 0.0, n: int = 360, start_deg: float = 0.0) -> np.ndarray:
    """The skyline a mast at (heading, pitch, roll) sees of an ENU horizon sampled finely at ``az_deg``.

    Rotates every horizon direction into the body frame (exact) and resamples on ``n`` relative
    azimuths from ``start_deg``.  Degrees.
    """
    R = rotation_enu_from_camera(heading_deg, pitch_deg, roll_deg)
    v = enu_from_az_el_deg(az_deg, el_deg) @ R  # body = R^T enu
    th, e = rel_az_el_from_body(v)
    return resample_periodic(th, e, azimuth_grid_deg(n, start_deg), max_gap_deg=360.0)


def mask_arc(el: np.ndarray, *, start_deg: float, width_deg: float) -> np.ndarray:
    """Copy of a skyline (1 degree per sample x n/360) keeping only the arc [start, start + width)."""
    n = el.size
    theta = np.arange(n) * 360.0 / n
    keep = np.mod(theta - start_deg, 360.0) < width_deg
    return np.where(keep, el, np.nan)
