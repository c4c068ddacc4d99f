"""The database's grid error at a fix: how far a skyline between nodes departs from the interpolated one.

Near close horizons the skyline changes fast between grid nodes, so the interpolated database is
least reliable there.  The estimates below (degrees, per sample at ENU azimuths) serve the weighted
refinement (:func:`board.locate.refinement.reweighted`), the coarse likelihood's variance floor and
the covariance of the parameter bias the interpolation causes (docs/matching.md).
"""
from __future__ import annotations

import math

import numpy as np

from board.pose.refine import LocalDB, Refined

#: bilinear interpolation error at mid-cell relative to the error of predicting a node from its two
#: neighbours: 1/4 for smoothly varying skylines, about 1/2 where silhouettes jump; we take the latter
INTERP_ERROR_FACTOR = 1.0
#: mid-cell bilinear interpolation error relative to a node's second difference over two steps
#: (exact for skylines varying quadratically with position: h^2 f''/8 against h^2 f''/2)
MIDCELL_FACTOR = 0.25
#: share of the bilinear grid-error variance kept as model error after re-projection: (0.29 / 0.45)^2,
#: the near-horizon RMS of the two interpolations against ray-marched truth (docs/matching.md)
PARALLAX_RESIDUAL_SHARE = 0.4


def second_differences(local: LocalDB, row: float, col: float, az_deg: np.ndarray) -> np.ndarray | None:
    """(4, n) second differences of the node skylines about the node nearest (row, col), degrees.

    Along rows, columns and both diagonals: the error of predicting the node from its two
    neighbours, read at ENU azimuths ``az_deg`` and centred (the fit removes the mean offset).
    None when the window is narrower than 3 nodes or there is no azimuth.
    """
    nr, nc, _ = local.el.shape
    if nr < 3 or nc < 3 or az_deg.size == 0:
        return None
    i = int(np.clip(round(row - local.row0), 1, nr - 2))
    j = int(np.clip(round(col - local.col0), 1, nc - 2))
    e = local.el
    d = np.stack([local.sample(e[i, j] - 0.5 * (e[i - di, j - dj] + e[i + di, j + dj]), az_deg)
                  for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1))])
    return d - d.mean(axis=1, keepdims=True)


def corner_deviations(local: LocalDB, row: float, col: float, az_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parallax mode: (4, n) deviations of the corners' re-projections from their blend at ENU azimuths
    ``az_deg`` (centred, degrees), and the corners' weights (4,)."""
    preds, w = local.corner_predictions(row, col)
    dev = np.stack([local.sample(p, az_deg) for p in preds])
    dev -= w @ dev
    return dev - dev.mean(axis=1, keepdims=True), w


def interpolation_bias_cov(local: LocalDB, ref: Refined, *, info_unscaled: np.ndarray) -> np.ndarray:
    """Covariance of the parameter bias caused by the database's interpolation error here.

    Realisations of that error, read at the fix's azimuths, are propagated through the
    least-squares fit, ``delta = (J^T J)^-1 J^T eps``: with parallax interpolation the deviations
    of the four corners' re-projections from their blend (weighted like the blend); otherwise the
    error of predicting a node's skyline from its two neighbours (along rows, along columns and
    both diagonals, two independent directions' worth), scaled to a mid-cell error.  Systematic
    errors like these are what a noise-only covariance misses.  Units of the free parameters
    (grid nodes, degrees) squared.
    """
    zero = np.zeros((len(ref.free),) * 2)
    v = ref.values
    d2 = None if "row" not in ref.free else second_differences(local, v["row"], v["col"], ref.enu_az_deg)
    if d2 is None:
        return zero
    try:
        pinv = np.linalg.inv(info_unscaled)
    except np.linalg.LinAlgError:
        return zero
    if local.parallax:
        errors, weights = corner_deviations(local, v["row"], v["col"], ref.enu_az_deg)
    else:
        errors, weights = d2 * INTERP_ERROR_FACTOR, np.full(len(d2), 0.5)  # four directions, two independent
    if ref.weights is not None:
        errors = errors * np.sqrt(ref.weights)
    out = zero
    for wk, ej in zip(weights, errors):
        delta = pinv @ (ref.jac.T @ ej)
        out = out + wk * np.outer(delta, delta)
    return out


def grid_error_samples(local: LocalDB, row: float, col: float, az_deg: np.ndarray) -> np.ndarray:
    """Per-sample variance (degrees^2) of the database's grid error near (row, col), at ENU azimuths ``az_deg``.

    The second differences of the node skylines (:func:`second_differences`) times
    :data:`MIDCELL_FACTOR` estimate how far a skyline between nodes departs from the bilinear
    interpolation of the grid.  It is large where the horizon is close (parallax) and small where
    it is far.
    """
    d2 = second_differences(local, row, col, az_deg)
    if d2 is None:
        return np.zeros(az_deg.size)
    return MIDCELL_FACTOR ** 2 * np.mean(d2 * d2, axis=0)


def model_error_samples(local: LocalDB, row: float, col: float, az_deg: np.ndarray) -> np.ndarray:
    """Per-sample variance (degrees^2) of the interpolated database skyline at (row, col), ENU azimuths.

    With parallax interpolation: the weighted spread of the four corners' re-projections about
    their blend; otherwise the bilinear grid error of :func:`grid_error_samples`.
    """
    if not local.parallax:
        return grid_error_samples(local, row, col, az_deg)
    dev, w = corner_deviations(local, row, col, az_deg)
    # the corners share errors their spread cannot show (quantised distances, terrain hidden at every
    # corner): keep the share of the bilinear grid error that re-projection left on the benchmark terrain
    return w @ (dev * dev) + PARALLAX_RESIDUAL_SHARE * grid_error_samples(local, row, col, az_deg)


def grid_error_var(local: LocalDB, ref: Refined) -> float:
    """Mean per-sample grid-error variance (degrees^2) at the fix (see :func:`grid_error_samples`).

    Near close horizons it dwarfs the query noise; the coarse score map's likelihood uses it as a
    variance floor so that a place whose grid nodes miss the truth by that much is not ruled out
    (the look-elsewhere effect of a 65-degree frame).
    """
    if ref.enu_az_deg.size == 0:
        return 0.0
    v = ref.values
    return float(np.mean(grid_error_samples(local, v["row"], v["col"], ref.enu_az_deg)))


def noise_given_weights(r2: np.ndarray, g2: np.ndarray, dof: int) -> float:
    """Noise variance s (degrees^2) with sum(r2 / (s + g2)) = dof (residuals r2, grid-error variances g2)."""
    lo, hi = 1e-8, max(float(r2.mean()), 1e-6) * 4.0
    if float(np.sum(r2 / (lo + g2))) <= dof:
        return lo
    for _ in range(60):  # bisection in log space: the sum decreases with s
        mid = math.sqrt(lo * hi)
        if float(np.sum(r2 / (mid + g2))) > dof:
            lo = mid
        else:
            hi = mid
    return hi
