"""Locate a rover from its skyline: the public matching API.

``locate(db, skyline, mode=...)`` runs the exhaustive FFT search over the part of the database
the mode allows, refines the best candidates on the sphere (position between grid nodes,
heading, pitch, roll) and attaches a calibrated confidence.  Coordinates are metres in the
database's CRS; angles are degrees (azimuths clockwise from grid north).
"""
from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from board.conventions import wrap_deg180
from board.errors import InvalidInputError
from board.match.fft_score import heading_deg, prepare_query, score_block
from board.match.search import Region, ScoreMap, fill_missing, search
from board.pose.confidence import Thresholds, effective_samples, ellipse_95, map_likelihood
from board.pose.refine import PARAMS, LocalDB, Refined, refine
from board.pose.sphere import enu_az_el, harmonic_to_tilt_matrix, level_skyline
from board.skydb import GridSpec, SkyDB, Tile
from board.skyline import Skyline

log = logging.getLogger(__name__)

MODES = ("lost", "window", "heading")
#: nominal query noise (degrees) used to weigh an IMU tilt prior against the skyline
NOMINAL_NOISE_DEG = 0.1
#: a coarse tilt estimate above this (degrees) triggers a second search with the levelled query
RELEVEL_DEG = 1.5
#: the second (levelled) search only visits positions whose first score is within this factor of the best
RELEVEL_KEEP = 10.0
#: candidates whose coarse score exceeds this factor times the best are not refined
CANDIDATE_FACTOR = 3.0
#: nodes (row, col offsets from the fix's node) the multistart refinement starts from: the node and its
#: four edge neighbours (the 4 diagonal ones changed no fix once the weighted refinement follows)
MULTISTART_OFFSETS = ((0, 0), (-1, 0), (1, 0), (0, -1), (0, 1))
#: final refinement weighted by the grid error at each azimuth (see _reweighted)
REWEIGHT = os.environ.get("SKYLOC_NO_REWEIGHT", "") == ""
#: reweighting: the noise variance is at least this fraction of the unweighted mean squared residual,
#: and at least NOISE_FLOOR_DEG squared
NOISE_FLOOR_FRACTION = 0.1
NOISE_FLOOR_DEG = 0.02
#: 1-sigma floor of the position (grid steps): the interpolated database is not trusted beyond it
POSITION_SIGMA_FLOOR_STEPS = 0.2
#: share of the bilinear grid-error variance kept as model error after re-projection: (0.29 / 0.45)^2,
#: the near-horizon RMS of the two interpolations against ray-marched truth (docs/matching.md)
PARALLAX_RESIDUAL_SHARE = 0.4
#: weighted refinements (each re-estimates the weights at the new fix), and the iteration limit and
#: relative cost tolerance of each
REWEIGHT_ITERATIONS = 2  # one pass: medians 0.17 -> 0.21 m (360 deg), 1.45 -> 1.72 m (120 deg) on 84 trials
REWEIGHT_MAX_ITER = 12
REWEIGHT_FTOL = 1e-5
#: the weighted refinement interpolates with parallax when the database stores horizon distances
PARALLAX = os.environ.get("SKYLOC_NO_PARALLAX", "") == ""


@dataclass
class Fix:
    """A pose estimate with its confidence (metres in the database CRS, degrees).

    status is "ok", "ambiguous" or "failed"; reason says why when it is not "ok".
    cov_xy : 2x2 position covariance (m^2); ellipse95_m : (semi-major, semi-minor, azimuth of major axis).
    """

    x: float
    y: float
    heading_deg: float
    pitch_deg: float
    roll_deg: float
    sigma_x_m: float
    sigma_y_m: float
    sigma_heading_deg: float
    cov_xy: np.ndarray
    status: str
    reason: str
    elapsed_s: float
    mode: str = "lost"
    sigma_pitch_deg: float = float("nan")
    sigma_roll_deg: float = float("nan")
    ellipse95_m: tuple[float, float, float] = (float("nan"),) * 3
    offset_deg: float = 0.0
    rms_residual_deg: float = float("nan")
    noise_deg: float = float("nan")
    n_eff: float = float("nan")
    ambiguity_ratio: float = float("nan")
    far_mass: float = float("nan")
    coverage_deg: float = 0.0
    n_scored: int = 0
    n_pruned: int = 0
    grid_row: float = float("nan")
    grid_col: float = float("nan")
    # for pictures (not serialised)
    score_map: ScoreMap | None = field(default=None, repr=False)
    query_theta_deg: np.ndarray | None = field(default=None, repr=False)
    query_el_deg: np.ndarray | None = field(default=None, repr=False)
    db_skyline_deg: np.ndarray | None = field(default=None, repr=False)
    grid: GridSpec | None = field(default=None, repr=False)
    db_azimuth_start_deg: float = 0.0

    def to_json_dict(self) -> dict:
        """JSON-able dict: the keys of the issue plus the confidence details."""
        def f(v):
            v = float(v)
            return None if not math.isfinite(v) else round(v, 6)

        return {
            "x": f(self.x), "y": f(self.y), "heading_deg": f(self.heading_deg),
            "pitch_deg": f(self.pitch_deg), "roll_deg": f(self.roll_deg),
            "sigma_x_m": f(self.sigma_x_m), "sigma_y_m": f(self.sigma_y_m),
            "sigma_heading_deg": f(self.sigma_heading_deg),
            "sigma_pitch_deg": f(self.sigma_pitch_deg), "sigma_roll_deg": f(self.sigma_roll_deg),
            "cov_xy": [[f(v) for v in row] for row in np.asarray(self.cov_xy)],
            "ellipse95_m": {"semi_major": f(self.ellipse95_m[0]), "semi_minor": f(self.ellipse95_m[1]),
                            "major_azimuth_deg": f(self.ellipse95_m[2])},
            "status": self.status, "reason": self.reason, "elapsed_s": f(self.elapsed_s), "mode": self.mode,
            "offset_deg": f(self.offset_deg), "rms_residual_deg": f(self.rms_residual_deg),
            "noise_deg": f(self.noise_deg), "n_eff": f(self.n_eff),
            "ambiguity_ratio": f(self.ambiguity_ratio), "far_mass": f(self.far_mass),
            "coverage_deg": f(self.coverage_deg), "positions_scored": self.n_scored,
            "positions_pruned": self.n_pruned, "grid_row": f(self.grid_row), "grid_col": f(self.grid_col),
        }


def _validate(db: SkyDB, sky: Skyline) -> None:
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


def _local_db(db: SkyDB, row: int, col: int, half: int = 2, *, parallax: bool = False) -> LocalDB:
    """Node skylines within ``half`` nodes of (row, col); with ``parallax`` and stored horizon distances,
    a window that interpolates with parallax (see :mod:`board.pose.parallax`)."""
    g = db.grid
    r0, c0 = max(row - half, 0), max(col - half, 0)
    r1, c1 = min(row + half + 1, g.ny), min(col + half + 1, g.nx)
    win = Tile(-1, -1, r0, c0, r1 - r0, c1 - c0)
    el = db.read_tile(win).astype(np.float64)
    flat = el.reshape(-1, el.shape[2])
    fill_missing(flat)
    if not np.isfinite(flat).all():
        # a neighbour without a skyline: replace by the candidate's own (keeps the window usable)
        own = flat[(row - r0) * (c1 - c0) + (col - c0)]
        bad = ~np.isfinite(flat).all(axis=1)
        flat[bad] = own
    dist = db.read_distance(win) if parallax and db.meta.has_distance else None
    if dist is None:
        return LocalDB(flat.reshape(el.shape), r0, c0, db.meta.azimuth_start_deg)
    return LocalDB(flat.reshape(el.shape), r0, c0, db.meta.azimuth_start_deg, dist=dist.astype(np.float64),
                   cell_m=(g.geotransform[1], g.geotransform[5]))


def _candidates(smap: ScoreMap, k: int, sep: int) -> list[tuple[int, int]]:
    """Up to ``k`` best positions at least ``sep`` nodes apart (non-maximum suppression), grid (row, col)."""
    s = smap.score
    order = np.argsort(s, axis=None)[: max(200, 50 * k)]
    out: list[tuple[int, int]] = []
    for f in order:
        if not np.isfinite(s.flat[f]):
            break
        r, c = divmod(int(f), s.shape[1])
        if all(abs(r - a) >= sep or abs(c - b) >= sep for a, b in out):
            out.append((r, c))
            if len(out) == k:
                break
    return [(r + smap.region.row0, c + smap.region.col0) for r, c in out]


def _coarse_init(db: SkyDB, q, row: int, col: int, allowed, level: tuple[float, float], query_start: float):
    """Heading and tilt at a grid node from the coarse model (fitted harmonic -> pitch, roll)."""
    sky = db.read_tile(Tile(-1, -1, row, col, 1, 1)).reshape(1, -1).astype(np.float64)
    fill_missing(sky)
    blk = score_block(q, sky)
    sc = blk.scores[0] + (0.0 if allowed is None else np.where(allowed, 0.0, np.inf))
    a = int(np.argmin(sc))
    pitch, roll = level
    if q.n_params == 3:
        coef = q.minv @ blk.b[:, 0, a]
        dp, dr = harmonic_to_tilt_matrix() @ coef[1:]
        pitch, roll = pitch + dp, roll + dr
    h = float(heading_deg(a, n=q.n, db_start_deg=db.meta.azimuth_start_deg, query_start_deg=query_start))
    return {"row": float(row), "col": float(col), "heading": h, "pitch": float(pitch), "roll": float(roll)}


def _position_limits(grid: GridSpec, region: Region) -> dict[str, tuple[float, float]]:
    """Fractional (row, col) limits of a refined position: the region's bounding box plus half a node,
    inside the grid."""
    return {"row": (max(region.row0 - 0.5, 0), min(region.row0 + region.nrows - 0.5, grid.ny - 1)),
            "col": (max(region.col0 - 0.5, 0), min(region.col0 + region.ncols - 0.5, grid.nx - 1))}


def _box(row: int, col: int, half: float, limits: dict[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
    """Refinement bounds: +-``half`` nodes around (row, col), within ``limits``."""
    return {k: (max(c - half, limits[k][0]), min(c + half, limits[k][1])) for k, c in (("row", row), ("col", col))}


def _walk_refine(db: SkyDB, r: int, c: int, init: dict, theta, el, *, free, tilt_prior, noise_deg: float,
                 region: Region, max_moves: int = 6) -> tuple[Refined, LocalDB]:
    """Refine from node (r, c) within +-1.5 nodes; while the optimum sits on that box's edge, move the box.

    Lets the refinement follow a long, flat valley of the score instead of stopping at the edge
    of the first window.  Positions stay inside the search region's bounding box (plus half a node).
    """
    limits = _position_limits(db.grid, region)
    seen_nodes = set()
    for _ in range(max_moves):
        seen_nodes.add((r, c))
        local = _local_db(db, r, c)
        bounds = _box(r, c, 1.5, limits)
        ref = refine(local, theta, el, init, free=free, tilt_prior=tilt_prior, noise_deg=noise_deg, bounds=bounds)
        v = ref.values
        at_edge = any(min(v[k] - lo, hi - v[k]) < 1e-6 for k, (lo, hi) in bounds.items())
        nr, nc = int(round(v["row"])), int(round(v["col"]))
        if not at_edge or (nr, nc) in seen_nodes or (nr, nc) == (r, c):
            break
        r, c, init = nr, nc, dict(v)
    return ref, local


def _multistart(db: SkyDB, ref: Refined, theta, el, *, free, tilt_prior, noise_deg: float, region: Region,
                half: int = 3) -> tuple[Refined, LocalDB] | None:
    """Refine again from the fix's node and its edge neighbours (same angles); the lowest cost wins.

    The bilinearly interpolated database makes the cost piecewise smooth in position, with kinks on
    the grid lines and small local minima near close horizons: one start can stop a few metres
    from a deeper minimum in the next cell (the demo's 242-degree query stopped 9.3 m off at cost
    12.5 deg^2; starting one node over reaches 5.3 deg^2, 5.5 m off).  Returns None when the
    position is not free.
    """
    if "row" not in free:
        return None
    v0 = ref.values
    r0, c0 = int(round(v0["row"])), int(round(v0["col"]))
    local = _local_db(db, r0, c0, half=half)
    bounds = _box(r0, c0, half - 0.5, _position_limits(db.grid, region))
    best = None
    for dr, dc in MULTISTART_OFFSETS:
        init = dict(v0, row=float(r0 + dr), col=float(c0 + dc))
        if not (bounds["row"][0] <= init["row"] <= bounds["row"][1]
                and bounds["col"][0] <= init["col"] <= bounds["col"][1]):
            continue
        r = refine(local, theta, el, init, free=free, tilt_prior=tilt_prior, noise_deg=noise_deg, bounds=bounds)
        if best is None or r.cost < best.cost:
            best = r
    return None if best is None else (best, local)


def _competitive(smap: ScoreMap, factor: float) -> Region:
    """The positions of ``smap`` scoring within ``factor`` of its best, as a masked region (grid indices)."""
    # pruned positions hold lower bounds above the pruning factor times the best: they cannot compete
    keep = smap.exact & (smap.score <= factor * float(np.min(smap.score)) + 1e-12)
    rows, cols = np.flatnonzero(keep.any(axis=1)), np.flatnonzero(keep.any(axis=0))
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    return Region(smap.region.row0 + int(r0), smap.region.col0 + int(c0), int(r1 - r0), int(c1 - c0),
                  keep[r0:r1, c0:c1].copy())


def _noise_from_score(score: float, q) -> float:
    """Per-sample noise (degrees) implied by a coarse best score: weighs an IMU prior against the skyline."""
    return max(math.sqrt(max(score, 0.0) / max(q.n_seen - q.n_params, 1)), 0.02)


def _allowed_shifts(n: int, db_start: float, query_start: float, prior: float, window: float) -> np.ndarray:
    h = heading_deg(np.arange(n), n=n, db_start_deg=db_start, query_start_deg=query_start)
    return np.abs(wrap_deg180(h - prior)) <= window + 1e-9


def locate(db: SkyDB | str | os.PathLike, skyline: Skyline, *, mode: str = "lost",
           prior_xy: tuple[float, float] | None = None, radius_m: float | None = None,
           heading_prior_deg: float | None = None, heading_window_deg: float = 10.0,
           tilt_prior: tuple[float, float, float] | None = None, model: str = "tilt", prune: bool = True,
           n_candidates: int = 5, thresholds: Thresholds | None = None, position_sigma_m: float = 20.0,
           progress=None) -> Fix:
    """Estimate position, heading and tilt from a query skyline.

    Parameters
    ----------
    db : SkyDB or path of a skyline database (Zarr)
    skyline : query skyline, azimuths relative to the heading, degrees; NaN where unseen
    mode : "lost" (whole grid), "window" (within ``radius_m`` of ``prior_xy``, default 30 m),
        "heading" (position ``prior_xy`` known to ``position_sigma_m``; heading within ``heading_window_deg``
        of ``heading_prior_deg``)
    prior_xy : (x, y) metres in the database CRS
    heading_prior_deg : heading prior (degrees clockwise from grid north); restricts the heading in
        "heading" mode, and in the other modes too when given
    tilt_prior : (pitch, roll, sigma) degrees from an IMU
    model : coarse score, "tilt" (invariant to small pitch/roll) or "offset" (the report's metric)
    prune : exact Parseval pruning for full panoramas (the result is identical either way)
    position_sigma_m : heading mode: uncertainty of the given position (metres); position and heading are
        estimated together within it (0: the position is taken as exact and only the heading and tilt fitted)
    """
    t0 = time.perf_counter()
    if not isinstance(db, SkyDB):
        db = SkyDB.open(db)
    if mode not in MODES:
        raise InvalidInputError(f"unknown mode {mode!r}: use one of {', '.join(MODES)}")
    _validate(db, skyline)
    th = thresholds or Thresholds()
    g = db.grid
    step = abs(g.geotransform[1])
    n = db.meta.n_azimuth
    q0 = skyline.azimuth_start_deg
    if mode in ("window", "heading") and prior_xy is None:
        raise InvalidInputError(f"mode {mode!r} needs a prior position: pass --prior X,Y")
    if mode == "heading" and heading_prior_deg is None:
        raise InvalidInputError("mode 'heading' needs --heading-prior DEG")
    if tilt_prior is not None and not (len(tilt_prior) == 3 and tilt_prior[2] > 0):
        raise InvalidInputError("tilt prior must be (pitch_deg, roll_deg, sigma_deg) with sigma > 0")

    allowed = None
    if heading_prior_deg is not None:
        allowed = _allowed_shifts(n, db.meta.azimuth_start_deg, q0, heading_prior_deg, heading_window_deg)
    if mode == "lost":
        region = Region.whole(g)
    elif mode == "window":
        region = Region.disc(g, prior_xy, 30.0 if radius_m is None else radius_m)
    else:
        # the given position is a prior: position and heading are estimated together within its uncertainty
        # (a heading from a wrong position is off by the horizon's parallax, position error / distance)
        region = Region.disc(g, prior_xy, max(position_sigma_m, step))
    fixed_position = mode == "heading" and position_sigma_m <= 0

    theta_all = skyline.azimuths_deg()
    seen = skyline.seen
    theta, el = theta_all[seen], skyline.elevation_deg[seen]
    level = (0.0, 0.0) if tilt_prior is None else (float(tilt_prior[0]), float(tilt_prior[1]))
    ridge = 0.0 if tilt_prior is None else (NOMINAL_NOISE_DEG / tilt_prior[2]) ** 2

    def coarse(level, reg=region):
        e = skyline.elevation_deg if level == (0.0, 0.0) else level_skyline(skyline.elevation_deg, theta_all, *level)
        q = prepare_query(e, azimuth_start_deg=q0, model=model, ridge=ridge)
        if fixed_position:
            return q, None
        return q, search(db, q, region=reg, allowed_shifts=allowed, prune=prune, progress=progress)

    def best_refined(q, smap, level):
        if fixed_position:
            fi, fj = g.ij(*prior_xy)
            local = _local_db(db, int(round(fi)), int(round(fj)))
            sky = local.skyline_at(fi, fj)[None]
            blk = score_block(q, sky)
            sc = blk.scores[0] + np.where(allowed, 0.0, np.inf)
            a = int(np.argmin(sc))
            pitch, roll = level
            if q.n_params == 3:
                dp, dr = harmonic_to_tilt_matrix() @ (q.minv @ blk.b[:, 0, a])[1:]
                pitch, roll = pitch + dp, roll + dr
            h0 = float(heading_deg(a, n=n, db_start_deg=db.meta.azimuth_start_deg, query_start_deg=q0))
            # unwrapped next to the prior so that the heading bounds below are contiguous
            init = {"row": fi, "col": fj, "pitch": pitch, "roll": roll,
                    "heading": heading_prior_deg + float(wrap_deg180(h0 - heading_prior_deg))}
            free = ("heading", "pitch", "roll") if model == "tilt" else ("heading",)
            noise = _noise_from_score(float(sc[a]), q)
            return refine(local, theta, el, init, free=free, tilt_prior=tilt_prior, noise_deg=noise,
                          bounds={"heading": (heading_prior_deg - heading_window_deg - 1,
                                              heading_prior_deg + heading_window_deg + 1)}), local
        best = None
        cands = _candidates(smap, n_candidates, sep=3)
        noise = _noise_from_score(float(np.min(smap.score)), q)
        s0 = smap.score[cands[0][0] - smap.region.row0, cands[0][1] - smap.region.col0]
        for r, c in cands:
            if smap.score[r - smap.region.row0, c - smap.region.col0] > CANDIDATE_FACTOR * s0 + 1e-12:
                break
            init = _coarse_init(db, q, r, c, allowed, level, q0)
            ref, local = _walk_refine(db, r, c, init, theta, el, free=PARAMS if model == "tilt" else
                                      ("row", "col", "heading"), tilt_prior=tilt_prior, noise_deg=noise,
                                      region=smap.region)
            if best is None or ref.cost < best[0].cost:
                best = (ref, local)
        polished = _multistart(db, best[0], theta, el, free=PARAMS if model == "tilt" else ("row", "col", "heading"),
                               tilt_prior=tilt_prior, noise_deg=noise, region=smap.region)
        if polished is not None and polished[0].cost < best[0].cost:
            log.info("multistart refinement: cost %.3g -> %.3g deg^2", best[0].cost, polished[0].cost)
            best = polished
        return best

    q, smap = coarse(level)
    ref, local = best_refined(q, smap, level)
    tilt_est = math.hypot(ref.values["pitch"] - level[0], ref.values["roll"] - level[1])
    if model == "tilt" and tilt_est > RELEVEL_DEG:
        # the first-harmonic model is first order: search again with the query levelled by the estimate
        level2 = (ref.values["pitch"], ref.values["roll"])
        log.info("tilt %.1f deg: second search with the levelled query", tilt_est)
        q2, smap2 = coarse(level2, None if smap is None else _competitive(smap, RELEVEL_KEEP))
        ref2, local2 = best_refined(q2, smap2, level2)
        if ref2.cost <= ref.cost:
            q, smap, ref, local = q2, smap2, ref2, local2
        elif smap2 is not None:
            smap = smap2
    if REWEIGHT and smap is not None:
        rew = _reweighted(db, ref, theta, el, free=PARAMS if model == "tilt" else ("row", "col", "heading"),
                          tilt_prior=tilt_prior, region=smap.region)
        if rew is not None:
            ref, local = rew
    return _make_fix(db, skyline, q, smap, ref, local, mode=mode, th=th, t0=t0, region=region)


#: bilinear interpolation error at mid-cell relative to the error of predicting a node from its two
#: neighbours: 1/4 for smoothly varying skylines, about 1/2 where silhouettes jump; we take the latter
INTERP_ERROR_FACTOR = 1.0


def _second_differences(local: LocalDB, row: float, col: float, az_deg: np.ndarray) -> np.ndarray | None:
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


def _corner_deviations(local: LocalDB, row: float, col: float, az_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parallax mode: (4, n) deviations of the corners' re-projections from their blend at ENU azimuths
    ``az_deg`` (centred, degrees), and the corners' weights (4,)."""
    preds, w = local.corner_predictions(row, col)
    dev = np.stack([local.sample(p, az_deg) for p in preds])
    dev -= w @ dev
    return dev - dev.mean(axis=1, keepdims=True), w


def _interpolation_bias_cov(local: LocalDB, ref: Refined, *, info_unscaled: np.ndarray) -> np.ndarray:
    """Covariance of the parameter bias caused by the database's interpolation error here.

    Realisations of that error, read at the fix's azimuths, are propagated through the
    least-squares fit, ``delta = (J^T J)^-1 J^T eps``: with parallax interpolation the deviations
    of the four corners' re-projections from their blend (weighted like the blend); otherwise the
    error of predicting a node's skyline from its two neighbours (along rows, along columns and
    both diagonals, two independent directions' worth), scaled to a mid-cell error.  Systematic
    errors like these are what a noise-only covariance misses.
    """
    zero = np.zeros((len(ref.free),) * 2)
    v = ref.values
    d2 = None if "row" not in ref.free else _second_differences(local, v["row"], v["col"], ref.enu_az_deg)
    if d2 is None:
        return zero
    try:
        pinv = np.linalg.inv(info_unscaled)
    except np.linalg.LinAlgError:
        return zero
    if local.parallax:
        errors, weights = _corner_deviations(local, v["row"], v["col"], ref.enu_az_deg)
    else:
        errors, weights = d2 * INTERP_ERROR_FACTOR, np.full(len(d2), 0.5)  # four directions, two independent
    if ref.weights is not None:
        errors = errors * np.sqrt(ref.weights)
    out = zero
    for wk, ej in zip(weights, errors):
        delta = pinv @ (ref.jac.T @ ej)
        out = out + wk * np.outer(delta, delta)
    return out


#: mid-cell bilinear interpolation error relative to a node's second difference over two steps
#: (exact for skylines varying quadratically with position: h^2 f''/8 against h^2 f''/2)
MIDCELL_FACTOR = 0.25


def _grid_error_samples(local: LocalDB, row: float, col: float, az_deg: np.ndarray) -> np.ndarray:
    """Per-sample variance (degrees^2) of the database's grid error near (row, col), at ENU azimuths ``az_deg``.

    The second differences of the node skylines (:func:`_second_differences`) times
    :data:`MIDCELL_FACTOR` estimate how far a skyline between nodes departs from the bilinear
    interpolation of the grid.  It is large where the horizon is close (parallax) and small where
    it is far.
    """
    d2 = _second_differences(local, row, col, az_deg)
    if d2 is None:
        return np.zeros(az_deg.size)
    return MIDCELL_FACTOR ** 2 * np.mean(d2 * d2, axis=0)


def _model_error_samples(local: LocalDB, row: float, col: float, az_deg: np.ndarray) -> np.ndarray:
    """Per-sample variance (degrees^2) of the interpolated database skyline at (row, col), ENU azimuths.

    With parallax interpolation: the weighted spread of the four corners' re-projections about
    their blend; otherwise the bilinear grid error of :func:`_grid_error_samples`.
    """
    if not local.parallax:
        return _grid_error_samples(local, row, col, az_deg)
    dev, w = _corner_deviations(local, row, col, az_deg)
    # the corners share errors their spread cannot show (quantised distances, terrain hidden at every
    # corner): keep the share of the bilinear grid error that re-projection left on the benchmark terrain
    return w @ (dev * dev) + PARALLAX_RESIDUAL_SHARE * _grid_error_samples(local, row, col, az_deg)


def _grid_error_var(local: LocalDB, ref: Refined) -> float:
    """Mean per-sample grid-error variance (degrees^2) at the fix (see :func:`_grid_error_samples`).

    Near close horizons it dwarfs the query noise; the coarse score map's likelihood uses it as a
    variance floor so that a place whose grid nodes miss the truth by that much is not ruled out
    (the look-elsewhere effect of a 65-degree frame).
    """
    if ref.enu_az_deg.size == 0:
        return 0.0
    v = ref.values
    return float(np.mean(_grid_error_samples(local, v["row"], v["col"], ref.enu_az_deg)))


def _noise_given_weights(r2: np.ndarray, g2: np.ndarray, dof: int) -> float:
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


def _reweighted(db: SkyDB, ref: Refined, theta, el, *, free, tilt_prior, region: Region,
                iterations: int = REWEIGHT_ITERATIONS) -> tuple[Refined, LocalDB] | None:
    """Refine again with each sample weighted by 1 / (noise + model error at its azimuth).

    The database is interpolated with parallax when it stores horizon distances
    (:mod:`board.pose.parallax`); the model error is :func:`_model_error_samples`.  Azimuths whose
    horizon is close change fast between grid nodes, so the interpolated database is least
    reliable there; down-weighting them (iteratively reweighted least squares, the noise variance
    solved so that the weighted chi-square equals its degrees of freedom) lets the well-represented
    horizon fix the position.  The weights passed to :func:`refine` are relative (1 where the model
    error is nil) so that its cost still estimates the noise variance.  Position stays within
    +-2.5 nodes of the starting fix.  Returns None when the position is not free.
    """
    if "row" not in free:
        return None
    limits = _position_limits(db.grid, region)
    cur = ref
    local = None
    for _ in range(iterations):
        v = cur.values
        r0, c0 = int(round(v["row"])), int(round(v["col"]))
        local = _local_db(db, r0, c0, half=3, parallax=PARALLAX)
        g2 = _model_error_samples(local, v["row"], v["col"], cur.enu_az_deg)
        res_unw = cur.unweighted_residual
        s_n = _noise_given_weights(res_unw ** 2, g2, max(res_unw.size - len(free) - 1, 1))
        # the model-error estimate must not explain the whole residual away (weights would all vanish)
        s_n = max(s_n, NOISE_FLOOR_FRACTION * float(np.mean(res_unw ** 2)), NOISE_FLOOR_DEG ** 2)
        w_abs = s_n / (s_n + g2)
        bounds = _box(r0, c0, 2.5, limits)
        # the re-projected skyline has kinks (occlusion changes): stop once steps gain little
        cur = refine(local, theta, el, dict(v), free=free, tilt_prior=tilt_prior, noise_deg=math.sqrt(s_n),
                     bounds=bounds, weights=w_abs, max_iter=REWEIGHT_MAX_ITER, ftol=REWEIGHT_FTOL)
    return cur, local


def _make_fix(db: SkyDB, skyline: Skyline, q, smap: ScoreMap | None, ref: Refined, local: LocalDB, *, mode: str,
              th: Thresholds, t0: float, region: Region) -> Fix:
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

    cov = cov + _interpolation_bias_cov(local, ref, info_unscaled=J.T @ J + ref.prior_info)
    cov_xy = np.full((2, 2), np.nan)  # heading mode: the position is given, not estimated
    if "row" in idx:
        T = np.array([[0.0, g.geotransform[1]], [g.geotransform[5], 0.0]])  # d(x, y) / d(row, col)
        sub = cov[np.ix_([idx["row"], idx["col"]], [idx["row"], idx["col"]])]
        cov_xy = T @ sub @ T.T + np.eye(2) * (POSITION_SIGMA_FLOOR_STEPS * step) ** 2
    rms = math.sqrt(ref.cost / n)
    status, reason = "ok", ""
    far_mass, ratio = float("nan"), float("nan")
    heading_var_map = 0.0
    if smap is not None:
        smin = float(np.min(smap.score))
        s2c = smin / max(q.n_seen - q.n_params, 1) * infl
        # a perfect coarse match (noise-free grid node) must not make the likelihood infinitely sharp, and
        # grid nodes near the truth elsewhere may miss it by the grid's interpolation error
        # (the coarse scores are unweighted sums: compare with the unweighted residual of the fix)
        res_unw = ref.unweighted_residual
        s2_unw = float(res_unw @ res_unw) / max(n - k, 1)
        s2c = max(s2c, (s2_unw + _grid_error_var(local, ref)) * infl)
        r0, c0 = smap.region.row0, smap.region.col0
        # each position's best heading: its likelihood-weighted spread about the fix widens the heading sigma
        hmap = heading_deg(smap.shift, n=db.meta.n_azimuth, db_start_deg=db.meta.azimuth_start_deg,
                           query_start_deg=skyline.azimuth_start_deg)
        lk = map_likelihood(smap.score, lambda r, c: g.xy(r + r0, c + c0), best_xy=(float(x), float(y)), s2=s2c,
                            radius_m=th.ambiguity_radius_steps * step, step_m=step, angle_deg=hmap,
                            best_angle_deg=float(v["heading"]))
        del hmap
        cov_xy = cov_xy + lk.cov_xy
        heading_var_map = lk.angle_var
        far_mass, ratio = lk.far_mass, lk.ambiguity_ratio
    sig_x, sig_y = math.sqrt(max(cov_xy[0, 0], 0)), math.sqrt(max(cov_xy[1, 1], 0))
    if rms > th.max_rms_deg:
        status, reason = "failed", (f"the best match leaves {rms:.2f} deg RMS residual beyond the database's "
                                    f"interpolation error (> {th.max_rms_deg}): the "
                                    "skyline does not fit this database (wrong area, or a bad extraction)")
    elif math.isfinite(far_mass) and far_mass > th.max_far_mass:
        status, reason = "ambiguous", (f"{far_mass:.0%} of the likelihood lies more than "
                                       f"{th.ambiguity_radius_steps * step:g} m away (score ratio {ratio:.2f}): "
                                       "another place fits almost as well")
    elif max(sig_x, sig_y) > th.max_sigma_steps * step:
        status, reason = "ambiguous", (f"position poorly constrained (1-sigma {max(sig_x, sig_y):.1f} m "
                                       f"> {th.max_sigma_steps * step:g} m)")
    sig_h = math.sqrt(max(var("heading"), 0) + heading_var_map)
    if status == "ok" and "row" in ref.free:
        # an optimum pinned to the edge of the searched area says the rover is probably beyond it
        if any(min(v[k] - lo, hi - v[k]) < 1e-3 for k, (lo, hi) in _position_limits(g, region).items()):
            what = "database grid" if mode == "lost" else "search window"
            status, reason = "ambiguous", (f"the best match lies on the edge of the {what}: the rover is probably "
                                           "outside it" + (" (widen --radius)" if mode != "lost" else ""))
    if status == "ok" and sig_h > th.max_sigma_heading_deg:
        status, reason = "ambiguous", f"heading poorly constrained (1-sigma {sig_h:.1f} deg)"
    az, _ = enu_az_el(skyline.azimuths_deg(), np.nan_to_num(skyline.elevation_deg), v["heading"], v["pitch"],
                      v["roll"])
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
        score_map=smap, query_theta_deg=skyline.azimuths_deg(), query_el_deg=skyline.elevation_deg,
        db_skyline_deg=local.skyline_at(v["row"], v["col"]), grid=g, db_azimuth_start_deg=db.meta.azimuth_start_deg,
    )
