"""From the refined pose to a :class:`Fix`: covariance (local, interpolation bias, score-map spread) and status.

The confidence model is :mod:`board.pose.confidence`'s; the database's grid error enters through
:mod:`board.locate.grid_error`.  Metres in the database CRS, degrees.
"""
from __future__ import annotations

import math
import time

import numpy as np

from board.locate.extraction_bias import extraction_bias_cov, extraction_bias_sigma_deg
from board.locate.fix import Fix, FixPictures
from board.locate.grid_error import grid_error_var, interpolation_bias_cov
from board.locate.options import LocateOptions
from board.locate.window import near_grid_edge, on_limits, position_limits
from board.match.fft_score import QueryModel, heading_deg
from board.match.search import Region, ScoreMap
from board.pose.confidence import FixEvidence, effective_samples, ellipse_95, fix_status, map_likelihood
from board.pose.refine import LocalDB, Refined
from board.skydb import SkyDB
from board.skyline import Skyline

#: 1-sigma floor of the position (grid steps): the interpolated database is not trusted beyond it
POSITION_SIGMA_FLOOR_STEPS = 0.2


def make_fix(db: SkyDB, skyline: Skyline, q: QueryModel, smap: ScoreMap | None, ref: Refined, local: LocalDB, *,
             opts: LocateOptions, t0: float, region: Region) -> Fix:
    """The fix at ``ref`` with its covariance and status; ``t0`` is the ``time.perf_counter()`` of the start."""
    th = opts.thresholds
    mode = opts.mode
    g = db.grid
    step = abs(g.geotransform[1])
    v = ref.values
    x, y = g.xy(v["row"], v["col"])
    n = ref.residual.size
    k = len(ref.free) + 1
    s2 = ref.cost / max(n - k, 1)
    n_eff = effective_samples(ref.residual)
    infl = max(n / n_eff, 1.0)
    J = ref.jac
    info = J.T @ J / (s2 * infl) + (ref.prior_info / s2 if ref.prior_info.size else 0.0)
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        cov = np.full(info.shape, np.inf)
    idx = {name: i for i, name in enumerate(ref.free)}

    def var(name):
        return float(cov[idx[name], idx[name]]) if name in idx else 0.0

    # systematic errors the residual cannot show: the database's interpolation, the extraction's smooth error
    info_unscaled = J.T @ J + ref.prior_info
    cov = cov + interpolation_bias_cov(local, ref, info_unscaled=info_unscaled)
    cov = cov + extraction_bias_cov(ref, info_unscaled=info_unscaled, sigma_deg=extraction_bias_sigma_deg(skyline))
    cov_xy = np.full((2, 2), np.nan)  # heading mode: the position is given, not estimated
    if "row" in idx:
        T = np.array([[0.0, g.geotransform[1]], [g.geotransform[5], 0.0]])  # d(x, y) / d(row, col)
        sub = cov[np.ix_([idx["row"], idx["col"]], [idx["row"], idx["col"]])]
        cov_xy = T @ sub @ T.T + np.eye(2) * (POSITION_SIGMA_FLOOR_STEPS * step) ** 2
    rms = math.sqrt(ref.cost / n)
    far_mass, ratio = float("nan"), float("nan")
    heading_var_map = 0.0
    if smap is not None:
        s2c = float(np.min(smap.score)) / max(q.n_seen - q.n_params, 1) * infl
        # a perfect coarse match (noise-free grid node) must not make the likelihood infinitely sharp, and
        # grid nodes near the truth elsewhere may miss it by the grid's interpolation error
        # (the coarse scores are unweighted sums: compare with the unweighted residual of the fix)
        res_unw = ref.unweighted_residual
        s2_unw = float(res_unw @ res_unw) / max(n - k, 1)
        s2c = max(s2c, (s2_unw + grid_error_var(local, ref)) * infl)
        r0, c0 = smap.region.row0, smap.region.col0
        # each position's best heading: its likelihood-weighted spread about the fix widens the heading sigma
        hmap = heading_deg(smap.shift, n=db.meta.n_azimuth, db_start_deg=db.meta.azimuth_start_deg,
                           query_start_deg=skyline.azimuth_start_deg)
        lk = map_likelihood(smap.score, lambda r, c: g.xy(r + r0, c + c0), best_xy=(float(x), float(y)), s2=s2c,
                            radius_m=th.ambiguity_radius(step), step_m=step, angle_deg=hmap,
                            best_angle_deg=float(v["heading"]))
        del hmap
        cov_xy = cov_xy + lk.cov_xy
        heading_var_map = lk.angle_var
        far_mass, ratio = lk.far_mass, lk.ambiguity_ratio
    sig_x, sig_y = math.sqrt(max(cov_xy[0, 0], 0)), math.sqrt(max(cov_xy[1, 1], 0))
    sig_h = math.sqrt(max(var("heading"), 0) + heading_var_map)
    position_free = "row" in ref.free
    status, reason = fix_status(FixEvidence(
        rms_deg=rms, far_mass=far_mass, ambiguity_ratio=ratio, sigma_m=max(sig_x, sig_y), sigma_heading_deg=sig_h,
        on_search_edge=position_free and on_limits(v, position_limits(g, region), 1e-3), mode=mode, step_m=step), th)
    pictures = FixPictures(score_map=smap, query_theta_deg=skyline.azimuths_deg(), query_el_deg=skyline.elevation_deg,
                           db_skyline_deg=local.skyline_at(v["row"], v["col"]), grid=g,
                           db_azimuth_start_deg=db.meta.azimuth_start_deg)
    return Fix(
        x=float(x), y=float(y), heading_deg=float(v["heading"]), pitch_deg=float(v["pitch"]), roll_deg=float(v["roll"]),
        sigma_x_m=sig_x, sigma_y_m=sig_y, sigma_heading_deg=sig_h,
        cov_xy=cov_xy, status=status, reason=reason, elapsed_s=time.perf_counter() - t0, mode=mode,
        sigma_pitch_deg=math.sqrt(max(var("pitch"), 0)) if "pitch" in idx else float("nan"),
        sigma_roll_deg=math.sqrt(max(var("roll"), 0)) if "roll" in idx else float("nan"),
        ellipse95_m=ellipse_95(cov_xy), offset_deg=ref.offset_deg, rms_residual_deg=rms,
        noise_deg=math.sqrt(s2), n_eff=n_eff, ambiguity_ratio=ratio, far_mass=far_mass,
        coverage_deg=skyline.coverage_deg, n_scored=0 if smap is None else smap.n_scored,
        n_pruned=0 if smap is None else smap.n_pruned, grid_row=float(v["row"]), grid_col=float(v["col"]),
        at_grid_edge=position_free and near_grid_edge(g, v["row"], v["col"]), pictures=pictures,
    )
