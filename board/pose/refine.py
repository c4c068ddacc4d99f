"""Continuous pose refinement: position between grid nodes, heading, pitch and roll.

The database skyline at a fractional grid position is the bilinear interpolation of the four
surrounding nodes' skylines, read at any azimuth by periodic linear interpolation.  Every seen
query sample is rotated on the sphere by the candidate pose (exact, no small-angle model) and
compared with that skyline at its ENU azimuth; the mean offset is removed, as in the coarse
score.  Levenberg-Marquardt with a numerical Jacobian minimises the sum of squared residuals
(plus an optional IMU prior on pitch and roll).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from board.conventions import rotation_enu_from_camera
from board.pose.parallax import Reprojector
from board.pose.sphere import body_from_rel_az_el

log = logging.getLogger(__name__)

PARAMS = ("row", "col", "heading", "pitch", "roll")
_DIFF_STEP = {"row": 0.02, "col": 0.02, "heading": 0.02, "pitch": 0.02, "roll": 0.02}
#: steps of the reported Jacobian (grid nodes, degrees): secants over a quarter node, so that the kinks of
#: the interpolated skyline (cell edges, occlusion changes) do not make the covariance spuriously small
_REPORT_STEP = {"row": 0.25, "col": 0.25, "heading": 0.05, "pitch": 0.05, "roll": 0.05}


@dataclass
class LocalDB:
    """A window of database skylines: ``el`` (nr, nc, N) degrees at grid rows/cols from (row0, col0).

    With ``dist`` (horizon distances, metres, same shape) and ``cell_m`` (metres per column step
    east, metres per row step north: the geotransform's x step and y step), :meth:`skyline_at`
    interpolates with parallax (:mod:`board.pose.parallax`) instead of blending the skylines.
    ``ground`` (nr, nc), the ground heights under the nodes (metres; a store's ``ground`` array), moves
    the eye between nodes by their true height differences; without it (or where a corner's is NaN)
    they are estimated from the skylines, which reads a slope's height steps at a half or less of
    their size (docs/matching.md, "Eye heights between nodes").
    """

    el: np.ndarray
    row0: int
    col0: int
    az_start_deg: float
    dist: np.ndarray | None = None
    cell_m: tuple[float, float] | None = None
    ground: np.ndarray | None = None
    _rep: Reprojector | None = field(default=None, repr=False)
    _heights: dict = field(default_factory=dict, repr=False)  # cell corners -> relative eye heights (m)
    _last: tuple = field(default=(None, None), repr=False)  # (row, col) -> skyline of the last call

    @property
    def n(self) -> int:
        return self.el.shape[2]

    @property
    def parallax(self) -> bool:
        return self.dist is not None and self.cell_m is not None

    def _cell(self, row: float, col: float):
        """Fractional window position (clamped), the 4 surrounding nodes and their bilinear weights."""
        nr, nc, _ = self.el.shape
        fr = min(max(float(row) - self.row0, 0.0), nr - 1.0)
        fc = min(max(float(col) - self.col0, 0.0), nc - 1.0)
        i0, j0 = min(int(fr), max(nr - 2, 0)), min(int(fc), max(nc - 2, 0))
        i1, j1 = min(i0 + 1, nr - 1), min(j0 + 1, nc - 1)
        ti, tj = fr - i0, fc - j0
        corners = ((i0, j0), (i0, j1), (i1, j0), (i1, j1))
        w = np.array([(1 - ti) * (1 - tj), (1 - ti) * tj, ti * (1 - tj), ti * tj])
        return fr, fc, corners, w

    def skyline_at(self, row: float, col: float) -> np.ndarray:
        """(N,) skyline at fractional (row, col) (clamped to the window), degrees.

        Bilinear blend of the four surrounding node skylines, or with :attr:`parallax` the blend of
        their re-projections to the position (:meth:`corner_predictions`).
        """
        key = (float(row), float(col))
        if self._last[0] == key:
            return self._last[1]
        if self.parallax:
            preds, w = self.corner_predictions(row, col)
        else:
            _, _, corners, w = self._cell(row, col)
            preds = np.stack([self.el[a, b] for a, b in corners])
        out = w @ preds
        self._last = (key, out)
        return out

    def corner_predictions(self, row: float, col: float) -> tuple[np.ndarray, np.ndarray]:
        """Parallax mode: the four surrounding nodes' skylines re-projected to (row, col), (4, N) degrees,
        and their bilinear weights (4,).

        Horizons are moved by their stored distances and the eye by the heights estimated from the
        skylines (:class:`board.pose.parallax.Reprojector`); azimuths a re-projection does not cover
        keep the bilinear blend.  The spread of the four about their blend measures the
        interpolation's own error.
        """
        if not self.parallax:
            raise ValueError("corner predictions need horizon distances (parallax mode)")
        fr, fc, corners, w = self._cell(row, col)
        nodes = np.stack([self.el[a, b] for a, b in corners])
        dists = [self.dist[a, b] for a, b in corners]
        bilinear = w @ nodes
        sx, sy = self.cell_m
        if self._rep is None:
            self._rep = Reprojector(self.n, self.az_start_deg)
        z = self._heights.get(corners)
        if z is None:
            z = self._heights[corners] = self.corner_heights(corners, nodes, dists)
        zp = float(w @ z)
        preds = np.empty_like(nodes)
        for k, (a, b) in enumerate(corners):
            sk = self._rep.skyline(nodes[k], dists[k], (fc - b) * sx, (fr - a) * sy, zp - z[k])
            preds[k] = np.where(np.isfinite(sk), sk, bilinear)
        return preds, w

    def corner_heights(self, corners, nodes: np.ndarray, dists: list[np.ndarray]) -> np.ndarray:
        """Eye heights (metres, mean zero) of the cell's four ``corners`` (window indices): the stored ground
        heights when all four are known, else estimated from their skylines (``nodes``, ``dists``)."""
        if self.ground is not None:
            z = np.array([self.ground[a, b] for a, b in corners], dtype=np.float64)
            if np.isfinite(z).all():
                return z - z.mean()
        sx, sy = self.cell_m
        return self._rep.relative_heights(list(nodes), dists, [(b * sx, a * sy) for a, b in corners])

    def sample(self, sky: np.ndarray, az_deg: np.ndarray) -> np.ndarray:
        """Skyline ``sky`` (N,) read at azimuths ``az_deg`` (periodic linear interpolation)."""
        n = self.n
        u = np.mod((az_deg - self.az_start_deg) * (n / 360.0), n)
        f = np.floor(u)
        k0 = f.astype(np.intp)
        k0[k0 >= n] -= n  # u == n after rounding
        t = u - f
        k1 = k0 + 1
        k1[k1 == n] = 0
        return sky[k0] + (sky[k1] - sky[k0]) * t


@dataclass
class Refined:
    """Result of :func:`refine`.

    values : dict of the 5 pose parameters (row/col fractional grid indices, degrees for angles)
    offset_deg : fitted mean elevation offset; cost : sum of squared (weighted) residuals, degrees^2
    residual : (n_seen,) degrees (times the square root of the weights when weighted);
    jac : (n_seen, n_free) d residual / d free parameter; weights : the relative sample weights or None
    free : names of the refined parameters; prior_info : (n_free, n_free) information of the prior
    """

    values: dict
    offset_deg: float
    cost: float
    residual: np.ndarray
    jac: np.ndarray
    free: tuple[str, ...]
    prior_info: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    n_iter: int = 0
    enu_az_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    weights: np.ndarray | None = None

    @property
    def unweighted_residual(self) -> np.ndarray:
        """(n_seen,) residual in degrees without the sample weights."""
        return self.residual if self.weights is None else self.residual / np.sqrt(self.weights)


def _enu_az(vb: np.ndarray, v: dict) -> np.ndarray:
    u = vb @ rotation_enu_from_camera(v["heading"], v["pitch"], v["roll"]).T
    return np.degrees(np.arctan2(u[:, 0], u[:, 1]))


def _residual(local: LocalDB, vb: np.ndarray, v: dict, sw: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Offset-free residual (degrees) of body-frame query directions ``vb`` (n, 3) at pose ``v``.

    ``sw`` : optional square roots of per-sample weights (the offset is then the weighted mean).
    """
    u = vb @ rotation_enu_from_camera(v["heading"], v["pitch"], v["roll"]).T
    az = np.degrees(np.arctan2(u[:, 0], u[:, 1]))
    e = np.degrees(np.arcsin(np.clip(u[:, 2], -1.0, 1.0)))
    r = e - local.sample(local.skyline_at(v["row"], v["col"]), az)
    if sw is None:
        mu = float(r.mean())
        return r - mu, mu
    w = sw * sw
    mu = float(w @ r / w.sum())
    return (r - mu) * sw, mu


def refine(local: LocalDB, theta_deg: np.ndarray, el_deg: np.ndarray, init: dict, *,
           free: tuple[str, ...] = PARAMS, tilt_prior: tuple[float, float, float] | None = None,
           noise_deg: float = 0.1, bounds: dict | None = None, max_iter: int = 40,
           weights: np.ndarray | None = None, ftol: float = 1e-10) -> Refined:
    """Levenberg-Marquardt refinement of ``init`` (dict of PARAMS) on the seen query samples.

    theta_deg, el_deg : seen query samples (relative azimuth, elevation), degrees
    tilt_prior : (pitch, roll, sigma) degrees from an IMU, weighted against ``noise_deg``
    bounds : {name: (lo, hi)} box constraints (e.g. the fractional grid window)
    weights : optional (n_seen,) relative weights of the samples (1 = nominal noise)
    ftol : stop when an iteration lowers the cost by less than this fraction
    """
    sw = None if weights is None else np.sqrt(np.asarray(weights, float))
    v = {k: float(init[k]) for k in PARAMS}
    bounds = bounds or {}
    free = tuple(free)
    w_prior = 0.0
    if tilt_prior is not None:
        w_prior = noise_deg / max(float(tilt_prior[2]), 1e-6)

    def clamp(vv):
        for k, (lo, hi) in bounds.items():
            vv[k] = min(max(float(vv[k]), lo), hi)
        return vv

    def prior_res(vv):
        if tilt_prior is None:
            return np.zeros(0)
        return np.array([w_prior * (vv[k] - tilt_prior[i]) for i, k in enumerate(("pitch", "roll")) if k in free])

    vb = body_from_rel_az_el(theta_deg, el_deg)

    def full_res(vv):
        r, _ = _residual(local, vb, vv, sw)
        return np.concatenate([r, prior_res(vv)])

    def jacobian(vv, r0, central=True):
        # forward differences while iterating (half the cost), central secants for the reported Jacobian
        J = np.empty((r0.size, len(free)))
        for c, k in enumerate(free):
            h = (_REPORT_STEP if central else _DIFF_STEP)[k]
            vp = dict(vv)
            vp[k] += h
            if central:
                vm = dict(vv)
                vm[k] -= h
                J[:, c] = (full_res(vp) - full_res(vm)) / (2 * h)
            else:
                J[:, c] = (full_res(vp) - r0) / h
        return J

    v = clamp(v)
    r = full_res(v)
    cost = float(r @ r)
    lam = 1e-3
    it = 0
    for it in range(1, max_iter + 1):
        J = jacobian(v, r, central=False)
        A = J.T @ J
        g = J.T @ r
        improved = False
        for _ in range(10):
            step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-9), -g)
            cand = dict(v)
            for c, k in enumerate(free):
                cand[k] += step[c]
            cand = clamp(cand)
            rc = full_res(cand)
            cc = float(rc @ rc)
            if cc < cost:
                improved = True
                v, r, dc, cost = cand, rc, cost - cc, cc
                lam = max(lam / 3, 1e-7)
                break
            lam *= 4
        if not improved or dc < ftol * max(cost, 1e-12):
            break
    res, mu = _residual(local, vb, v, sw)
    J = jacobian(v, r)
    n = res.size
    pinfo = J[n:].T @ J[n:] if J.shape[0] > n else np.zeros((len(free), len(free)))
    v["heading"] = float(np.mod(v["heading"], 360.0))
    return Refined(v, mu, float(res @ res), res, J[:n], free, pinfo, it, _enu_az(vb, v),
                   None if weights is None else np.asarray(weights, float))
