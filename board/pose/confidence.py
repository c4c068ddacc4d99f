"""Confidence of a fix: noise from the residual, covariance, 95 % ellipse, ambiguity, status.

Model: the seen query samples are the database skyline at the true pose plus noise of unknown
variance.  The noise variance is estimated from the residual of the best fit; residuals of a
skyline are correlated along azimuth (rendering and extraction errors are smooth), so the
variance is inflated by ``n / n_eff`` with ``n_eff`` from the residual's autocorrelation
(Bartlett's formula).  That gives

* the local covariance of the refined parameters, ``s2 (J^T J)^-1`` (Gauss-Newton), and
* a likelihood over the coarse score map, ``exp(-(S - S_min) / (2 s2_coarse))``, whose spread
  (weighted covariance of the grid positions) and mass far from the best position measure
  how ambiguous the fix is.

The reported position covariance is the sum of both (the local one resolves between grid nodes,
the global one catches secondary minima).

The status policy (:func:`fix_status`) turns those measures into one of :data:`STATUSES`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: chi-square quantile, 2 degrees of freedom, 95 %
CHI2_2D_95 = 5.991464547107979

#: the fix is trustworthy
STATUS_OK = "ok"
#: a pose is given but another place (or heading) fits almost as well, or it is poorly constrained
STATUS_AMBIGUOUS = "ambiguous"
#: the best match does not fit: the skyline is not in this database, or the extraction is wrong
STATUS_FAILED = "failed"
#: every status of a fix, best first
STATUSES = (STATUS_OK, STATUS_AMBIGUOUS, STATUS_FAILED)


@dataclass
class Thresholds:
    """Decision thresholds of the status (defaults documented in docs/matching.md).

    max_rms_deg : a best match with a larger RMS residual (weighted: beyond the database's own interpolation
        error at the fix) is ``failed`` (the skyline is not in this database, or the extraction is wrong)
    max_far_mass : posterior mass farther than the ambiguity radius above which the fix is ``ambiguous``
    ambiguity_radius_steps : radius (grid steps) beyond which a second minimum is a different place ...
    ambiguity_radius_m : ... and never less than this many metres: on a fine grid (a 1 m window
        database) five steps are 5 m, well inside the spread of a right fix, and the campaign calls a
        fix wrong beyond 25 m only (held-out Aristoteles, window mode: 19 of 30 fixes 0.5-2.4 m off
        were ``ambiguous`` because "100 % of the likelihood lies more than 5 m away" with 4-6 m sigmas)
    max_sigma_steps : in heading mode, a 1-sigma position error above this many grid steps is ``ambiguous``
    max_sigma_m : in the other modes, above this many metres, whatever the grid (not in heading mode, where the
        position is given): an ``ok`` fix must be right, and the campaign calls a fix more than 25 m
        off wrong, so an ``ok`` fix's 25 m must be 3.5 sigma or more (a 29.6 m error with a 8.3 m
        sigma on a 76 m/px lunar DEM was reported ``ok`` with the grid-step rule alone)
    max_sigma_heading_deg : a 1-sigma heading error above this is ``ambiguous``
    max_ok_rms_deg : a best match with a larger (weighted) RMS residual is at best ``ambiguous``: the
        covariance assumes the database explains the skyline to the extraction's accuracy (kept samples
        are 0.04 deg off at the median, 0.13 at the 90th percentile), and a loose fit is a place the grid
        does not represent (a cliff metres away) or a skyline partly wrong.  On Mars 402 (30 poses) fixes
        at 0.25-0.38 deg RMS were 7.1 and 4.0 deg off in heading (sigmas 0.85-0.87) or 20.9 m off; the
        204 correct ``ok`` fixes there and on four other sites (Mars 401, St Helens, Baltoro, Aristoteles)
        stayed at or below 0.13 deg.
    """

    max_rms_deg: float = 0.75
    max_far_mass: float = 0.01
    ambiguity_radius_steps: float = 5.0
    ambiguity_radius_m: float = 25.0
    max_sigma_steps: float = 3.0
    max_sigma_m: float = 7.0
    max_sigma_heading_deg: float = 2.0
    max_ok_rms_deg: float = 0.2

    def ambiguity_radius(self, step_m: float) -> float:
        """Radius (metres) beyond which another minimum is another place, on a grid of ``step_m``."""
        return max(self.ambiguity_radius_steps * step_m, self.ambiguity_radius_m)


def effective_samples(residual: np.ndarray) -> float:
    """Effective number of independent samples of a correlated residual.

    ``n / (1 + 2 sum_k rho_k)`` with the autocorrelations ``rho_k`` summed by Geyer's initial
    positive sequence (pairs ``rho_(2m-1) + rho_(2m)`` while positive).  Degrees in, count out.
    """
    r = np.asarray(residual, float) - np.mean(residual)
    n = r.size
    var = float(r @ r) / n
    if n < 4 or var <= 0:
        return float(max(n, 1))
    acc = 0.0
    for k in range(1, n // 2 - 1, 2):
        pair = (float(r[:-k] @ r[k:]) + float(r[:-(k + 1)] @ r[k + 1:])) / (n * var)
        if pair <= 0:
            break
        acc += pair
    return float(max(n / (1.0 + 2.0 * acc), 1.0))


def ellipse_95(cov: np.ndarray) -> tuple[float, float, float]:
    """(semi-major m, semi-minor m, azimuth of the major axis in degrees clockwise from north) of the 95 % ellipse."""
    w, V = np.linalg.eigh(cov)
    w = np.clip(w, 0, None)
    major = V[:, 1]
    az = math.degrees(math.atan2(major[0], major[1])) % 180.0
    return math.sqrt(CHI2_2D_95 * w[1]), math.sqrt(CHI2_2D_95 * w[0]), az


@dataclass
class MapLikelihood:
    """Summary of the likelihood over the coarse score map (metres, the database's CRS)."""

    cov_xy: np.ndarray
    far_mass: float
    best_far_score: float
    best_score: float
    angle_var: float = 0.0

    @property
    def ambiguity_ratio(self) -> float:
        """best score / best score farther than the ambiguity radius, in [0, 1] (1: two equally good places)."""
        if not math.isfinite(self.best_far_score):
            return 0.0
        if self.best_far_score <= 0:
            return 1.0
        return float(min(self.best_score / self.best_far_score, 1.0))


def map_likelihood(score: np.ndarray, xy, *, best_xy: tuple[float, float], s2: float, radius_m: float,
                   step_m: float, angle_deg: np.ndarray | None = None, best_angle_deg: float = 0.0) -> MapLikelihood:
    """Likelihood weights ``exp(-(S - S_min)/(2 s2))`` over a score map (degrees^2).

    score : (nrows, ncols) map, inf where not scored; xy : function (rows, cols) -> (x, y) metres
    of map indices.  ``cov_xy`` is the weighted second moment of the positions about ``best_xy``
    (the fix).  ``angle_deg`` (same shape as ``score``, e.g. each position's best heading) gives
    ``angle_var``, the weighted second moment of ``angle - best_angle_deg`` (wrapped, degrees^2).
    Only positions with a weight above e^-20 are converted to coordinates, and the
    best score farther than ``radius_m`` is found without building coordinate arrays for the
    whole map (a 7 x 7 km map at 5 m has 1.96 M positions).
    """
    s2 = max(s2, 1e-12)
    smin = float(np.min(score))
    sel = np.flatnonzero(score <= smin + 40.0 * s2)
    r, c = np.divmod(sel, score.shape[1])
    xs, ys = xy(r, c)
    w = np.exp(-(score.flat[sel] - smin) / (2.0 * s2))
    w /= w.sum()
    dx, dy = xs - best_xy[0], ys - best_xy[1]
    cov = np.array([[w @ (dx * dx), w @ (dx * dy)], [w @ (dx * dy), w @ (dy * dy)]])
    far = np.hypot(dx, dy) > radius_m
    far_mass = float(w[far].sum())
    angle_var = 0.0
    if angle_deg is not None:
        da = np.mod(angle_deg.flat[sel] - best_angle_deg + 180.0, 360.0) - 180.0
        angle_var = float(w @ (da * da))
    # best score farther than radius_m: everything outside a box around the fix, plus the box's far corners
    x00, y00 = xy(np.array([0]), np.array([0]))
    ci = (y00[0] - best_xy[1]) / step_m  # map row of the fix (rows go south)
    cj = (best_xy[0] - x00[0]) / step_m
    k = int(math.ceil(radius_m / step_m)) + 1
    i0, i1 = max(int(math.floor(ci)) - k, 0), min(int(math.ceil(ci)) + k + 1, score.shape[0])
    j0, j1 = max(int(math.floor(cj)) - k, 0), min(int(math.ceil(cj)) + k + 1, score.shape[1])
    parts = [score[:i0], score[i1:], score[i0:i1, :j0], score[i0:i1, j1:]]
    best_far = min((float(p.min()) for p in parts if p.size), default=math.inf)
    if i1 > i0 and j1 > j0:
        bi, bj = np.mgrid[i0:i1, j0:j1]
        bx, by = xy(bi, bj)
        box = score[i0:i1, j0:j1]
        out = np.hypot(bx - best_xy[0], by - best_xy[1]) > radius_m
        if out.any():
            best_far = min(best_far, float(box[out].min()))
    return MapLikelihood(cov, far_mass, best_far, smin, angle_var)


@dataclass(frozen=True)
class FixEvidence:
    """What the status policy looks at (degrees, metres in the database CRS).

    rms_deg : RMS residual of the best match; far_mass, ambiguity_ratio : see :class:`MapLikelihood`
    (NaN without a score map); sigma_m : the larger 1-sigma position error; sigma_heading_deg : 1-sigma
    heading error; on_search_edge : the refined position is pinned to the edge of the searched area
    (False when the position was not estimated); mode : the search mode; step_m : grid step.
    """

    rms_deg: float
    far_mass: float
    ambiguity_ratio: float
    sigma_m: float
    sigma_heading_deg: float
    on_search_edge: bool
    mode: str
    step_m: float


def fix_status(ev: FixEvidence, th: Thresholds) -> tuple[str, str]:
    """(status, reason) of a fix: the first rule that applies, in the order failed, ambiguous, ok.

    failed: the RMS residual exceeds ``th.max_rms_deg``.  ambiguous: the likelihood mass far from the
    fix exceeds ``th.max_far_mass``; or the position is pinned to the edge of the searched area (the
    likely cause of a large sigma, so said first); or the position's 1-sigma exceeds
    ``th.max_sigma_steps`` grid steps (heading mode) or ``th.max_sigma_m`` metres (the other modes); or the
    heading's 1-sigma exceeds ``th.max_sigma_heading_deg``; or the RMS residual exceeds ``th.max_ok_rms_deg``
    (a loose fit: the sigmas assume a model that fits).  The reason says what and the fix where
    there is one.
    """
    step = ev.step_m
    if ev.rms_deg > th.max_rms_deg:
        return STATUS_FAILED, (f"the best match leaves {ev.rms_deg:.2f} deg RMS residual beyond the database's "
                               f"interpolation error (> {th.max_rms_deg}): the "
                               "skyline does not fit this database (wrong area, or a bad extraction)")
    if math.isfinite(ev.far_mass) and ev.far_mass > th.max_far_mass:
        return STATUS_AMBIGUOUS, (f"{ev.far_mass:.0%} of the likelihood lies more than "
                                  f"{th.ambiguity_radius(step):g} m away "
                                  f"(score ratio {ev.ambiguity_ratio:.2f}): another place fits almost as well")
    if ev.on_search_edge:
        # an optimum pinned to the edge of the searched area says the rover is probably beyond it
        what = "database grid" if ev.mode == "lost" else "search window"
        return STATUS_AMBIGUOUS, (f"the best match lies on the edge of the {what}: the rover is probably "
                                  "outside it" + (" (widen --radius)" if ev.mode != "lost" else ""))
    # in metres outside heading mode: a finer database must not make the same fix less trusted
    limit_m = th.max_sigma_steps * step if ev.mode == "heading" else th.max_sigma_m
    if ev.sigma_m > limit_m:
        return STATUS_AMBIGUOUS, (f"position poorly constrained (1-sigma {ev.sigma_m:.1f} m "
                                  f"> {limit_m:g} m)")
    if ev.sigma_heading_deg > th.max_sigma_heading_deg:
        return STATUS_AMBIGUOUS, f"heading poorly constrained (1-sigma {ev.sigma_heading_deg:.1f} deg)"
    if ev.rms_deg > th.max_ok_rms_deg:
        return STATUS_AMBIGUOUS, (f"the skyline fits this place only loosely ({ev.rms_deg:.2f} deg RMS beyond the "
                                  f"database's interpolation error, > {th.max_ok_rms_deg}): a near horizon the grid "
                                  "does not resolve, or part of the skyline is wrong; the sigmas may be too small")
    return STATUS_OK, ""
