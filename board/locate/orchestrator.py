"""The matcher's orchestration: coarse FFT search, refinement of the best candidates, re-levelled search,
weighted refinement, then the fix with its confidence.

Coordinates are metres in the database's CRS; angles are degrees (azimuths clockwise from grid north).
"""
from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from board.conventions import wrap_deg180
from board.errors import InvalidInputError
from board.locate.alignment import aligned_query
from board.locate.assemble import make_fix
from board.locate.fix import Fix
from board.locate.options import DEFAULT_RADIUS_M, LocateOptions
from board.locate.refinement import (
    allowed_shifts,
    candidates,
    coarse_init,
    competitive,
    harmonic_tilt,
    multistart,
    noise_from_score,
    reweighted,
    walk_refine,
)
from board.locate.robust import cleaned_query, sectors_at_fix
from board.locate.window import local_db
from board.match.fft_score import QueryModel, heading_deg, prepare_query, score_block
from board.match.search import Region, ScoreMap, search
from board.pose.refine import LocalDB, Refined, refine
from board.pose.sphere import level_skyline
from board.skydb import SkyDB
from board.skyline import Skyline

log = logging.getLogger(__name__)

#: nominal query noise (degrees) used to weigh an IMU tilt prior against the skyline
NOMINAL_NOISE_DEG = 0.1
#: a coarse tilt estimate above this (degrees) triggers a second search with the levelled query
RELEVEL_DEG = 1.5
#: the second (levelled) search only visits positions whose first score is within this factor of the best
RELEVEL_KEEP = 10.0
#: candidates whose coarse score exceeds this factor times the best are not refined
CANDIDATE_FACTOR = 3.0


def validate_query(db: SkyDB, sky: Skyline) -> None:
    """Raise :class:`InvalidInputError` when ``sky`` cannot be matched against ``db`` (and say how to fix it)."""
    if not sky.seen.any():
        raise InvalidInputError("the query skyline has no seen sample (all null/NaN): nothing to match; "
                                "check the extraction")
    if sky.n != db.meta.n_azimuth or not math.isclose(sky.azimuth_step_deg, db.meta.azimuth_step_deg,
                                                       rel_tol=0, abs_tol=1e-9):
        raise InvalidInputError(
            f"the skyline is sampled every {sky.azimuth_step_deg:g} degrees ({sky.n} samples) but the database "
            f"{db.path} every {db.meta.azimuth_step_deg:g} ({db.meta.n_azimuth}): resample the skyline to the "
            "database's azimuth step")
    if sky.seen.sum() < 10:
        raise InvalidInputError(f"the query skyline has only {int(sky.seen.sum())} seen samples; at least 10 are "
                                "needed to locate (a single frame of 65 degrees gives 65 at 1 degree)")
    if not db.complete:
        log.warning("database %s is not complete (%d of %d tiles): unrendered positions are skipped",
                    db.path, db.n_tiles_done(), len(db.tiles))


@dataclass(frozen=True)
class _Query:
    """One call's fixed inputs: the database, the query and what the options make of them."""

    db: SkyDB
    skyline: Skyline
    opts: LocateOptions
    region: Region
    allowed: np.ndarray | None
    theta: np.ndarray  # (n_seen,) azimuths of the seen samples relative to the heading, degrees
    el: np.ndarray  # (n_seen,) their elevations, degrees
    ridge: float
    progress: Callable[[int, int], None] | None


def _coarse(c: _Query, level: tuple[float, float], reg: Region) -> tuple[QueryModel, ScoreMap | None]:
    """The query levelled by ``level`` (pitch, roll degrees) and its score map over ``reg`` (None: exact position)."""
    sky, opts = c.skyline, c.opts
    e = sky.elevation_deg if level == (0.0, 0.0) else level_skyline(sky.elevation_deg, sky.azimuths_deg(), *level)
    q = prepare_query(e, azimuth_start_deg=sky.azimuth_start_deg, model=opts.model, ridge=c.ridge)
    if opts.fixed_position:
        return q, None
    return q, search(c.db, q, region=reg, allowed_shifts=c.allowed, prune=opts.prune, progress=c.progress)


def _refine_at_prior(c: _Query, q: QueryModel, level: tuple[float, float]) -> tuple[Refined, LocalDB]:
    """Heading mode with an exact position: heading (and tilt) fitted at ``prior_xy``."""
    db, opts = c.db, c.opts
    hp, hw = opts.heading_prior_deg, opts.heading_window_deg
    fi, fj = db.grid.ij(*opts.prior_xy)
    local = local_db(db, int(round(fi)), int(round(fj)))
    sky = local.skyline_at(fi, fj)[None]
    blk = score_block(q, sky)
    sc = blk.scores[0] + np.where(c.allowed, 0.0, np.inf)
    a = int(np.argmin(sc))
    pitch, roll = harmonic_tilt(q, blk, a, level)
    h0 = float(heading_deg(a, n=db.meta.n_azimuth, db_start_deg=db.meta.azimuth_start_deg,
                           query_start_deg=c.skyline.azimuth_start_deg))
    # unwrapped next to the prior so that the heading bounds below are contiguous
    init = {"row": fi, "col": fj, "pitch": pitch, "roll": roll, "heading": hp + float(wrap_deg180(h0 - hp))}
    free = ("heading", "pitch", "roll") if opts.model == "tilt" else ("heading",)
    noise = noise_from_score(float(sc[a]), q)
    return refine(local, c.theta, c.el, init, free=free, tilt_prior=opts.tilt_prior, noise_deg=noise,
                  bounds={"heading": (hp - hw - 1, hp + hw + 1)}), local


def _refine_candidates(c: _Query, q: QueryModel, smap: ScoreMap, level: tuple[float, float]) -> tuple[Refined, LocalDB]:
    """The best of the refined coarse candidates (walk, then multistart from the winner)."""
    db, opts = c.db, c.opts
    free = opts.free
    best = None
    cands = candidates(smap, opts.n_candidates, sep=3)
    noise = noise_from_score(float(np.min(smap.score)), q)
    s0 = smap.score[cands[0][0] - smap.region.row0, cands[0][1] - smap.region.col0]
    for r, col in cands:
        if smap.score[r - smap.region.row0, col - smap.region.col0] > CANDIDATE_FACTOR * s0 + 1e-12:
            break
        init = coarse_init(db, q, r, col, c.allowed, level, c.skyline.azimuth_start_deg)
        ref, local = walk_refine(db, r, col, init, c.theta, c.el, free=free, tilt_prior=opts.tilt_prior,
                                 noise_deg=noise, region=smap.region)
        if best is None or ref.cost < best[0].cost:
            best = (ref, local)
    polished = multistart(db, best[0], c.theta, c.el, free=free, tilt_prior=opts.tilt_prior, noise_deg=noise,
                          region=smap.region)
    if polished is not None and polished[0].cost < best[0].cost:
        log.info("multistart refinement: cost %.3g -> %.3g deg^2", best[0].cost, polished[0].cost)
        best = polished
    return best


def _best_refined(c: _Query, q: QueryModel, smap: ScoreMap | None, level: tuple[float, float]):
    if c.opts.fixed_position:
        return _refine_at_prior(c, q, level)
    return _refine_candidates(c, q, smap, level)


def _search_region(db: SkyDB, opts: LocateOptions) -> Region:
    """The grid positions the mode allows (grid indices)."""
    g = db.grid
    if opts.mode == "lost":
        return Region.whole(g)
    if opts.mode == "window":
        return Region.disc(g, opts.prior_xy, DEFAULT_RADIUS_M if opts.radius_m is None else opts.radius_m)
    # the given position is a prior: position and heading are estimated together within its uncertainty
    # (a heading from a wrong position is off by the horizon's parallax, position error / distance)
    return Region.disc(g, opts.prior_xy, max(opts.position_sigma_m, abs(g.geotransform[1])))


def locate(db: SkyDB | str | os.PathLike, skyline: Skyline, options: LocateOptions | None = None, *,
           progress: Callable[[int, int], None] | None = None, **overrides) -> Fix:
    """Estimate position, heading and tilt from a query skyline.

    Parameters
    ----------
    db : SkyDB or path of a skyline database (Zarr)
    skyline : query skyline, azimuths relative to the heading, degrees; NaN where unseen
    options : :class:`LocateOptions` (defaults when None)
    progress : called with (tiles done, tiles total) while the coarse search runs
    **overrides : fields of :class:`LocateOptions` replacing those of ``options``
        (``locate(db, sky, mode="window", prior_xy=(x, y))``)

    Returns
    -------
    Fix : metres in the database CRS, degrees; its status says whether to trust it.

    A skyline with fine samples is located twice (``options.align``): the second time sampled on the
    database's own azimuths at the first fix's heading (:mod:`board.locate.alignment`).
    """
    t0 = time.perf_counter()
    opts = LocateOptions.from_keywords(options, **overrides) if overrides else (options or LocateOptions())
    if not isinstance(db, SkyDB):
        db = SkyDB.open(db)
    opts.validate()
    validate_query(db, skyline)
    fix = _locate_once(db, skyline, opts, progress=progress, t0=t0)
    if opts.align and fix.status != "failed":
        aligned = aligned_query(db.meta, skyline, fix.heading_deg)
        if aligned is not None:
            fix = _locate_once(db, aligned[0], opts, progress=progress, t0=t0)
            fix.aligned_shift_deg = aligned[1]
    fix.elapsed_s = time.perf_counter() - t0
    return fix


def _locate_once(db: SkyDB, skyline: Skyline, opts: LocateOptions, *,
                 progress: Callable[[int, int], None] | None, t0: float) -> Fix:
    """:func:`locate` for one sampling of the query (options and query already validated; ``t0`` is the
    ``time.perf_counter()`` of the call's start)."""
    n = db.meta.n_azimuth
    allowed = None
    if opts.heading_prior_deg is not None:
        allowed = allowed_shifts(n, db.meta.azimuth_start_deg, skyline.azimuth_start_deg, opts.heading_prior_deg,
                                 opts.heading_window_deg)
    region = _search_region(db, opts)
    tp = opts.tilt_prior
    seen = skyline.seen
    c = _Query(db=db, skyline=skyline, opts=opts, region=region, allowed=allowed,
               theta=skyline.azimuths_deg()[seen], el=skyline.elevation_deg[seen],
               ridge=0.0 if tp is None else (NOMINAL_NOISE_DEG / tp[2]) ** 2, progress=progress)
    level = (0.0, 0.0) if tp is None else (float(tp[0]), float(tp[1]))

    q, smap = _coarse(c, level, region)
    ref, local = _best_refined(c, q, smap, level)
    tilt_est = math.hypot(ref.values["pitch"] - level[0], ref.values["roll"] - level[1])
    if opts.model == "tilt" and tilt_est > RELEVEL_DEG:
        # the first-harmonic model is first order: search again with the query levelled by the estimate
        level2 = (ref.values["pitch"], ref.values["roll"])
        log.info("tilt %.1f deg: second search with the levelled query", tilt_est)
        q2, smap2 = _coarse(c, level2, None if smap is None else competitive(smap, RELEVEL_KEEP))
        ref2, local2 = _best_refined(c, q2, smap2, level2)
        if ref2.cost <= ref.cost:
            q, smap, ref, local = q2, smap2, ref2, local2
        elif smap2 is not None:
            smap = smap2
    if opts.reweight and smap is not None:
        rew = reweighted(db, ref, c.theta, c.el, free=opts.free, tilt_prior=tp, region=smap.region,
                         parallax=opts.parallax, stored_heights=opts.stored_heights)
        if rew is not None:
            ref, local = rew
    if opts.robust and smap is not None:
        cleaned = cleaned_query(skyline, ref)
        if cleaned is not None:
            # columns the fix cannot explain (a rock, a wrong edge): locate again without them
            log.info("%d query column(s) inconsistent with the fix: located again without them", cleaned[1])
            fix = _locate_once(db, cleaned[0], replace(opts, robust=False), progress=progress, t0=t0)
            fix.n_outliers = cleaned[1]
            pics = fix.pictures
            if pics is not None and pics.db_skyline_deg is not None:
                fix.above_dem, fix.below_dem = sectors_at_fix(
                    skyline, skyline.seen & ~cleaned[0].seen, db_skyline_deg=pics.db_skyline_deg,
                    db_azimuth_start_deg=pics.db_azimuth_start_deg, heading_deg=fix.heading_deg,
                    pitch_deg=fix.pitch_deg, roll_deg=fix.roll_deg, offset_deg=fix.offset_deg)
            return fix
    return make_fix(db, skyline, q, smap, ref, local, opts=opts, t0=t0, region=region)
