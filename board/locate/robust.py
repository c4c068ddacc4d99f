"""Outlier rejection after the coarse search: skyline columns the best fix cannot explain are masked, and the
query is located again without them.

A detector can keep a few wrong columns (a rock above the horizon, an edge followed for a few degrees):
with 5 % of the columns wrong by 2-10 degrees, the least-squares refinement is pulled metres away and
the status policy sees a large residual.  After the first fix, a column is an outlier when its
residual is both larger than :data:`OUTLIER_MIN_DEG` and more than :data:`OUTLIER_Z` robust standard
deviations (1.4826 x the median absolute deviation of the residuals, each normalised by the weight the
final refinement gave it, i.e. by its expected model error) from the median.  When outliers are found
(at most :data:`MAX_OUTLIER_FRACTION` of the seen columns, and at least :data:`MIN_INLIERS` left), the
query is located again with them masked (NaN), exactly like a shorter skyline.  A clean query has no
such column, so its fix, status and speed are unchanged.  Angles are degrees.
"""
from __future__ import annotations

import numpy as np

from board.pose.refine import Refined
from board.skyline import Skyline

#: a column is an outlier only if its residual exceeds this (degrees): below, it is noise or model error
OUTLIER_MIN_DEG = 1.0
#: ... and this many robust standard deviations of the normalised residuals
OUTLIER_Z = 5.0
#: more outliers than this share of the seen columns: the fix itself is doubtful, nothing is masked
MAX_OUTLIER_FRACTION = 0.25
#: fewest seen columns left after masking
MIN_INLIERS = 20
#: floor of the robust standard deviation (degrees): a perfect fit does not make every column an outlier
SIGMA_FLOOR_DEG = 0.05


def outlier_mask(ref: Refined) -> np.ndarray:
    """(n_seen,) bool: the query columns the refined fix ``ref`` cannot explain (see the module docstring)."""
    r = np.asarray(ref.unweighted_residual, dtype=float)
    if r.size == 0:
        return np.zeros(0, bool)
    rw = np.asarray(ref.residual, dtype=float)  # residual x sqrt(weight): normalised by the model error
    med = float(np.median(rw))
    sigma = max(1.4826 * float(np.median(np.abs(rw - med))), SIGMA_FLOOR_DEG)
    return (np.abs(r - float(np.median(r))) > OUTLIER_MIN_DEG) & (np.abs(rw - med) > OUTLIER_Z * sigma)


def cleaned_query(skyline: Skyline, ref: Refined) -> tuple[Skyline, int] | None:
    """The query with the outlier columns of ``ref`` masked, and how many; None when nothing is masked."""
    bad = outlier_mask(ref)
    seen_idx = np.flatnonzero(skyline.seen)
    n_bad = int(bad.sum())
    if bad.size != seen_idx.size or n_bad == 0:
        return None
    if n_bad > MAX_OUTLIER_FRACTION * seen_idx.size or seen_idx.size - n_bad < MIN_INLIERS:
        return None
    el = skyline.elevation_deg.copy()
    el[seen_idx[bad]] = np.nan
    meta = dict(skyline.meta)
    meta["outliers_masked"] = n_bad
    return Skyline(el, skyline.azimuth_start_deg, skyline.azimuth_step_deg, meta), n_bad
