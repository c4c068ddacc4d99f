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


def flagged_sectors(skyline: Skyline, idx: np.ndarray, residual_deg: np.ndarray) -> list[dict]:
    """Masked query columns grouped into sectors of consecutive azimuths (circularly).

    idx : (m,) indices of the masked samples in ``skyline``; residual_deg : (m,) query minus database
    skyline at the fix (degrees; positive: the query's boundary stands above the DEM's skyline).
    Returns ``[{"from_deg", "to_deg", "n", "excess_deg"}]`` in the query's azimuth frame (the mast's,
    degrees clockwise from its heading, as ``skyline.azimuths_deg()``), ``excess_deg`` the mean
    residual of the sector, sorted by ``from_deg``.
    """
    idx = np.asarray(idx, dtype=np.int64)
    if idx.size == 0:
        return []
    order = np.argsort(idx)
    idx, res = idx[order], np.asarray(residual_deg, float)[order]
    breaks = np.flatnonzero(np.diff(idx) > 1) + 1
    groups = [(g, r) for g, r in zip(np.split(idx, breaks), np.split(res, breaks))]
    if len(groups) > 1 and groups[0][0][0] == 0 and groups[-1][0][-1] == skyline.n - 1:  # across 0 deg
        first, last = groups.pop(0), groups.pop()
        groups.append((np.concatenate([last[0], first[0]]), np.concatenate([last[1], first[1]])))
    az = skyline.azimuths_deg()
    out = [{"from_deg": round(float(az[g[0]]) % 360.0, 3), "to_deg": round(float(az[g[-1]]) % 360.0, 3),
            "n": int(g.size), "excess_deg": round(float(np.mean(r)), 3)} for g, r in groups]
    return sorted(out, key=lambda d: d["from_deg"])


def sectors_at_fix(skyline: Skyline, masked: np.ndarray, *, db_skyline_deg: np.ndarray, db_azimuth_start_deg: float,
                   heading_deg: float, pitch_deg: float, roll_deg: float, offset_deg: float
                   ) -> tuple[list[dict], list[dict]]:
    """(above, below): the masked columns of ``skyline`` that the final fix still cannot explain, as sectors.

    masked : (n,) bool over ``skyline``'s samples (the columns masked before the second location).
    The original query is rotated by the fix's pose (heading, pitch, roll, degrees) and compared with
    ``db_skyline_deg`` (the database's skyline interpolated at the fix, ENU azimuths from
    ``db_azimuth_start_deg`` over 360 degrees) less the fitted ``offset_deg``.  Columns more than
    :data:`OUTLIER_MIN_DEG` above it are ``above`` (a near rock, rover hardware, an object not in the
    DEM: a real boundary, but not the DEM's skyline), more than that below it are ``below`` (the
    detector missed the skyline: a far ridge lost in haze, a wrong edge).  Masked columns the final fix
    explains (they only disagreed with the first, pulled fix) are in neither, nor is a lone column less
    than twice that off (the database's interpolation error at a steep edge of the skyline).  Sectors as
    :func:`flagged_sectors`.
    """
    from board.pose.sphere import enu_az_el  # noqa: PLC0415

    idx = np.flatnonzero(np.asarray(masked, bool) & np.isfinite(skyline.elevation_deg))
    db = np.asarray(db_skyline_deg, float)
    if idx.size == 0 or db.size == 0:
        return [], []
    az, el = enu_az_el(skyline.azimuths_deg()[idx], skyline.elevation_deg[idx], heading_deg, pitch_deg, roll_deg)
    step = 360.0 / db.size
    grid = db_azimuth_start_deg + np.arange(db.size + 1) * step
    ref_el = np.interp(np.mod(az - db_azimuth_start_deg, 360.0) + db_azimuth_start_deg, grid, np.append(db, db[0]))
    r = el - offset_deg - ref_el
    up, down = r > OUTLIER_MIN_DEG, r < -OUTLIER_MIN_DEG

    def real(sectors: list[dict]) -> list[dict]:  # one column a little off is a steep edge's interpolation error
        return [x for x in sectors if x["n"] >= 2 or abs(x["excess_deg"]) >= 2.0 * OUTLIER_MIN_DEG]

    return real(flagged_sectors(skyline, idx[up], r[up])), real(flagged_sectors(skyline, idx[down], r[down]))


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
