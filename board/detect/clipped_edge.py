"""What the detector measures of a saturated sky at the line (bpy-free, numpy only).

A sky brighter than full scale is clipped after the optics have blurred the edge: the sky's half of the
blurred step is cut off, and the steepest remaining grey step (where the line is placed) lies below the edge,
on the ground side.  How far depends on how far the sky exceeds full scale, which the picture does not show
where it is clipped, and on the width of the camera's line spread function.  Two things the picture does show
stand in for them, per column and per view:

* the height of the clipped band of sky directly above the line (:func:`clipped_run_above`): the sky
  brightens towards the horizon and the sun, so the further it exceeds full scale at the horizon, the
  higher the band it clips;
* the width of the unclipped sky/ground steps of the same view (:func:`edge_width_px`), the camera's
  line spread function as a Gaussian-equivalent sigma.

:mod:`board.clipped_sky` turns them into the line's offset (calibrated on rendered views).
"""
from __future__ import annotations

import math

import numpy as np


def clipped_run_above(grey: np.ndarray, b: np.ndarray, level: float, gap: int = 0) -> np.ndarray:
    """Per column, the number of rows directly above row ``b`` (rows ``< b``) whose grey level is at least
    ``level`` (fraction of full scale, as ``grey``), up to the first row below it.  (W,) int32 rows.

    ``gap`` : up to this many unsaturated rows directly above the line are stepped over before the run is
    counted (the mixed pixels of a blurred edge: a sky clipped two rows above the line is clipped although
    the row between, part sky and part ground, is not); the rows stepped over are not counted."""
    H, W = grey.shape
    sat = grey >= np.float32(level)
    # index of the last unsaturated row at or above each row (-1 where none)
    idx = np.where(sat, np.int32(-1), np.arange(H, dtype=np.int32)[:, None])
    np.maximum.accumulate(idx, axis=0, out=idx)
    cols = np.arange(W)
    bi = np.asarray(b, dtype=np.int64)
    run = np.zeros(W, dtype=np.int64)
    open_ = np.ones(W, dtype=bool)      # every row between the line and row bi - 1 - k is unsaturated
    for k in range(int(gap) + 1):
        if k:                           # row bi - k is stepped over only where it is unsaturated too
            open_ &= (bi - k >= 0) & ~sat[np.clip(bi - k, 0, H - 1), cols]
        top = np.clip(bi - 1 - k, -1, H - 1)
        last_unsat = np.where(top >= 0, idx[np.maximum(top, 0), cols], -1)
        run = np.where((run == 0) & open_, np.where(top >= 0, top - last_unsat, 0), run)
    return run.astype(np.int32)


def edge_width_px(lin: np.ndarray, b: np.ndarray, clipped: np.ndarray, *, window: int = 5,
                  min_step: float = 0.05, min_columns: int = 50) -> float:
    """Gaussian-equivalent sigma (pixels) of the view's unclipped sky/ground steps, NaN when fewer than
    ``min_columns`` clean steps are seen.

    lin : (H, W) linear grey, not blurred by the detector; b : the line's row per column (the boundary just
    above row b); clipped : per column, the clipped rows above the line (:func:`clipped_run_above`).
    Per column: step height ``A`` (mean of rows ``b-window..b-3`` minus mean of rows ``b+2..b+window``) and
    the steepest one-row difference ``g`` within 2 rows of the line; a Gaussian blurred step of sigma s has
    ``g = A / (sqrt(2 pi) s)``.  With the pixel's area that is ``sqrt(sigma^2 + 1/12)`` for a PSF of sigma
    1 px and more; a sharper edge puts most of its step in one row and the width has a floor of about
    0.55 px (the simulator's renders without lens blur: 0.53-0.57; with the distorted look's 0.6 px blur:
    0.74-0.78).  Columns whose two sides are not flat (texture, a second step) are left out; the median over
    the others is returned.
    """
    H, W = lin.shape
    cols = np.arange(W)
    bi = np.asarray(b, dtype=np.int64)
    ok = (clipped == 0) & (bi - window >= 0) & (bi + window < H)
    if ok.sum() < min_columns:
        return float("nan")
    c, r = cols[ok], bi[ok]
    up = lin[r[None, :] + np.arange(-window, -2)[:, None], c[None, :]]
    dn = lin[r[None, :] + np.arange(2, window + 1)[:, None], c[None, :]]
    A = up.mean(axis=0) - dn.mean(axis=0)
    flat = (np.ptp(up, axis=0) < 0.2 * np.abs(A)) & (np.ptp(dn, axis=0) < 0.2 * np.abs(A))
    rows = r[None, :] + np.arange(-2, 3)[:, None]
    g = (lin[rows - 1, c[None, :]] - lin[rows, c[None, :]]) * np.sign(A)[None, :]
    gmax = g.max(axis=0)
    good = flat & (np.abs(A) >= min_step) & (gmax > 0)
    if good.sum() < min_columns:
        return float("nan")
    return float(np.median(np.abs(A[good]) / gmax[good]) / math.sqrt(2.0 * math.pi))


__all__ = ["clipped_run_above", "edge_width_px"]
