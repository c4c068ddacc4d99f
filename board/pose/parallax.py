"""Parallax-aware interpolation of database skylines between grid nodes.

Blending the skylines of neighbouring nodes (bilinear) cannot move a horizon feature: where the
horizon is close, a step of a few metres shifts it in azimuth (by ``delta / distance`` radians)
and in elevation (the eye moves up or down with the ground), and the blend of two shifted
copies is neither.  Here each node's horizon is turned back into 3-D points with the stored
horizon distances, seen again from the wanted position, and the visible skyline taken as the
upper envelope of the re-projected horizon line; the four corner predictions are then blended.
The eye's height change between nodes is the stored ground heights' (databases since session 26); for
older stores it is estimated from the skylines themselves (a pair of nodes sees the same far points,
shifted in elevation by ``-dz / distance``), an estimate biased low on slopes, where the near horizon
is the ground's own sliding crest rather than a fixed point (docs/matching.md, "Eye heights between nodes").

Units: metres for positions and distances (the database's CRS, x east, y north), degrees for
azimuths (clockwise from grid north) and elevations.  Used by :class:`board.pose.refine.LocalDB`
when the database stores horizon distances.
"""
from __future__ import annotations

import math

import numpy as np

#: horizon distances below this (metres) are clamped: the database quantises them to 10 m
MIN_DISTANCE_M = 5.0
#: pairs of nodes whose re-projected skylines differ by more than this (degrees) at an azimuth do not
#: vote for the eye-height difference there (occlusion changes)
HEIGHT_FIT_MAX_RESIDUAL_DEG = 2.0


def envelope_on_grid(az_deg: np.ndarray, el_deg: np.ndarray, valid: np.ndarray, *, az0_deg: float,
                     n: int) -> np.ndarray:
    """Upper envelope of the closed polyline ``(az_k, el_k)`` sampled on ``n`` regular azimuths from ``az0_deg``.

    Each segment between consecutive valid vertices is taken the short way round and interpolated
    linearly at the grid azimuths it spans; where segments overlap (the re-projected horizon folds
    behind a nearer ridge) the highest wins.  Grid azimuths no segment covers are NaN.
    """
    step = 360.0 / n
    out = np.full(n, -np.inf)
    nxt = np.r_[1:az_deg.size, 0]  # the vertex after each (closed line)
    ok = valid & valid[nxt]
    a0, e0 = az_deg[ok], el_deg[ok]
    a1, e1 = az_deg[nxt][ok], el_deg[nxt][ok]
    da = np.mod(a1 - a0 + 180.0, 360.0) - 180.0
    fwd = da >= 0
    lo = np.where(fwd, a0, a1)
    span = np.abs(da)
    elo = np.where(fwd, e0, e1)
    slope = (np.where(fwd, e1, e0) - elo) / np.maximum(span, 1e-12)
    u_lo = (lo - az0_deg) / step
    k0 = np.ceil(u_lo - 1e-9).astype(np.intp)
    cnt = np.maximum(np.floor(u_lo + span / step + 1e-9).astype(np.intp) - k0 + 1, 0)
    seg = np.repeat(np.arange(cnt.size), cnt)
    kk = np.arange(seg.size) - np.repeat(np.cumsum(cnt) - cnt, cnt) + k0[seg]
    # position along the segment (degrees from its low end), clipped to the segment
    t = np.clip(kk * step - (lo[seg] - az0_deg), 0.0, span[seg])
    np.maximum.at(out, np.mod(kk, n), elo[seg] + slope[seg] * t)
    out[~np.isfinite(out)] = np.nan
    return out


class Reprojector:
    """Re-projects a node's horizon to a nearby eye position (fixed azimuth sampling of the database)."""

    def __init__(self, n: int, az0_deg: float) -> None:
        self.n = n
        self.az0 = az0_deg
        az = np.radians(az0_deg + np.arange(n) * 360.0 / n)
        self.sin, self.cos = np.sin(az), np.cos(az)

    def points(self, el_deg: np.ndarray, dist_m: np.ndarray, dx: float, dy: float, dz: float):
        """(azimuth deg, elevation deg, horizontal distance m, valid) of the node's horizon points seen
        from the node + (dx, dy) metres east/north, with the eye ``dz`` metres higher."""
        d = np.maximum(dist_m, MIN_DISTANCE_M)
        x = d * self.sin - dx
        y = d * self.cos - dy
        h = d * np.tan(np.radians(el_deg)) - dz
        d2 = np.hypot(x, y)
        valid = np.isfinite(dist_m) & np.isfinite(el_deg)
        return np.degrees(np.arctan2(x, y)), np.degrees(np.arctan2(h, d2)), d2, valid

    def skyline(self, el_deg: np.ndarray, dist_m: np.ndarray, dx: float, dy: float, dz: float) -> np.ndarray:
        """(n,) skyline (degrees, NaN where not covered) of the node seen from its offset (dx, dy, dz) metres."""
        az, el, _, valid = self.points(el_deg, dist_m, dx, dy, dz)
        return envelope_on_grid(az, el, valid, az0_deg=self.az0, n=self.n)

    def relative_heights(self, els: list[np.ndarray], dists: list[np.ndarray],
                         offsets: list[tuple[float, float]]) -> np.ndarray:
        """Eye heights (metres, mean zero) of nodes at ``offsets`` (x, y metres) from their skylines.

        For every ordered pair the first node's horizon is re-projected to the second node at equal
        eye height; the remaining elevation differences, ``-dz / distance`` to first order, give the
        height difference by least squares; the pairwise differences are then reconciled.
        """
        k = len(els)
        rows, rhs = [], []
        for i in range(k):
            for j in range(k):
                if i == j:
                    continue
                dx, dy = offsets[j][0] - offsets[i][0], offsets[j][1] - offsets[i][1]
                r = els[j] - self.skyline(els[i], dists[i], dx, dy, 0.0)
                a = (180.0 / math.pi) / np.maximum(dists[j], MIN_DISTANCE_M)  # -d el / d dz, degrees per metre
                m = np.isfinite(r) & (np.abs(r) < HEIGHT_FIT_MAX_RESIDUAL_DEG) & (dists[j] > 4 * MIN_DISTANCE_M)
                if m.sum() < 10:
                    continue
                row = np.zeros(k)
                row[j], row[i] = 1.0, -1.0
                rows.append(row)
                rhs.append(-float(np.sum(r[m] * a[m]) / np.sum(a[m] ** 2)))
        rows.append(np.ones(k))
        rhs.append(0.0)
        z, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
        return z
