"""Exhaustive search of a skyline database, streamed tile by tile, with exact pruning.

The search evaluates :func:`board.match.fft_score.score_block` for every position of a region of
the grid and keeps, per position, the best score over the allowed headings and that heading.
Memory is bounded by a few database tiles plus the (region-sized) score map: the database is never
loaded whole (unless the reader caches a small one, see :class:`board.skydb.SkyDB`).

Pruning is exact: for full panoramas the Parseval bound computed in float32 minus its rounding
bound (:func:`board.match.fft_score.lower_bound_full_f32`), for partial ones the float32 scores of
:func:`board.match.fft_score.approx_scores_f32` minus their error bound
(:func:`board.match.fft_score.f32_error_bound`), are lower bounds of the score at every heading, so
a position whose bound exceeds ``prune_factor`` times the best score can never be the argmin, nor
within that factor of it.  Such positions keep their bound (``exact`` False), which only ever
makes the confidence analysis more cautious.  Partial panoramas: the surviving skylines are held
(at most HOLD) and scored in float64 against the final best score; on overflow the ones with the
largest bounds are dropped and their tiles read again at the end if they still survive.

The bounds do not depend on the best score, so WORKERS threads read tiles and compute them while
the calling thread prunes and scores exactly, tile after tile in a fixed order: the result does
not depend on the number of threads.  Work is done in blocks of BLOCK rows so that the working
arrays of a block stay in the CPU cache.
"""
from __future__ import annotations

import logging
import math
import os
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from board.errors import InvalidInputError, NoDataError
from board.match.fft_score import (
    QueryModel,
    approx_scores_f32,
    dft_rows,
    f32_error_bound,
    lower_bound_full_f32,
    score_block,
)
from board.skydb import GridSpec, SkyDB, Tile

log = logging.getLogger(__name__)

#: positions are scored in blocks of at most this many skylines: the dozen (BLOCK, N) working arrays
#: of a block stay in a 2 MB CPU cache (twice as fast as blocks of 1024)
BLOCK = 256
#: partial panoramas: at most this many surviving skylines wait for exact scoring (bounds the memory)
HOLD = 2048
#: threads reading tiles and computing their float32 lower bounds (2 cores on the reference board)
WORKERS = min(2, os.cpu_count() or 1)
#: a database skyline with more missing samples than this fraction is excluded from the search
MAX_MISSING_FRACTION = 0.1


@dataclass(frozen=True)
class Region:
    """Grid window ``rows row0:row0+nrows, cols col0:col0+ncols`` and an optional (nrows, ncols) mask."""

    row0: int
    col0: int
    nrows: int
    ncols: int
    mask: np.ndarray | None = None

    @classmethod
    def whole(cls, grid: GridSpec) -> "Region":
        return cls(0, 0, grid.ny, grid.nx)

    @classmethod
    def disc(cls, grid: GridSpec, xy: tuple[float, float], radius_m: float) -> "Region":
        """Grid positions within ``radius_m`` metres of ``xy`` (at least the 2 x 2 nodes around it)."""
        x0, y0, x1, y1 = grid.bounds()
        step = abs(grid.geotransform[1])
        x, y = float(xy[0]), float(xy[1])
        if not (x0 - step / 2 <= x <= x1 + step / 2 and y0 - step / 2 <= y <= y1 + step / 2):
            raise InvalidInputError(
                f"prior position ({x:.1f}, {y:.1f}) is outside the database grid "
                f"x {x0:.1f}..{x1:.1f}, y {y0:.1f}..{y1:.1f} (metres, the database's CRS): check the prior "
                "and its CRS, or use --mode lost")
        if not (radius_m > 0 and math.isfinite(radius_m)):
            raise InvalidInputError(f"search radius must be a positive number of metres, got {radius_m}")
        fi, fj = grid.ij(x, y)
        r = max(radius_m / step, 1.0)
        i0, i1 = max(int(math.floor(fi - r)), 0), min(int(math.ceil(fi + r)), grid.ny - 1)
        j0, j1 = max(int(math.floor(fj - r)), 0), min(int(math.ceil(fj + r)), grid.nx - 1)
        ii, jj = np.mgrid[i0:i1 + 1, j0:j1 + 1]
        gx, gy = grid.xy(ii, jj)
        mask = np.hypot(gx - x, gy - y) <= max(radius_m, step * math.sqrt(2.0)) + 1e-9
        return cls(i0, j0, i1 - i0 + 1, j1 - j0 + 1, mask)

    def contains(self, i: int, j: int) -> bool:
        ok = self.row0 <= i < self.row0 + self.nrows and self.col0 <= j < self.col0 + self.ncols
        return bool(ok and (self.mask is None or self.mask[i - self.row0, j - self.col0]))


@dataclass
class ScoreMap:
    """Best score per position over the allowed headings, for a region of the grid.

    score : (nrows, ncols) float64, degrees^2 (inf: excluded or outside the region)
    shift : (nrows, ncols) int16, best heading shift (see board.match.fft_score)
    exact : (nrows, ncols) bool, False where pruned (score then holds a lower bound)
    """

    region: Region
    score: np.ndarray
    shift: np.ndarray
    exact: np.ndarray
    n_scored: int = 0
    n_pruned: int = 0

    def argmin(self) -> tuple[int, int]:
        """Grid (row, col) of the best position."""
        k = int(np.argmin(self.score))
        r, c = divmod(k, self.score.shape[1])
        return r + self.region.row0, c + self.region.col0


def fill_missing(block: np.ndarray) -> np.ndarray:
    """Fill NaN samples of database skylines (P, N) by periodic linear interpolation.

    Rows with more than MAX_MISSING_FRACTION missing stay NaN (the caller excludes them).
    """
    bad = ~np.isfinite(block)
    rows = np.flatnonzero(bad.any(axis=1))
    n = block.shape[1]
    for r in rows:
        m = bad[r]
        if m.sum() > MAX_MISSING_FRACTION * n:
            continue
        k = np.flatnonzero(~m)
        block[r, m] = np.interp(np.flatnonzero(m), k, block[r, k], period=n)
    return block


def _tiles_in(db: SkyDB, region: Region) -> list[Tile]:
    r1, c1 = region.row0 + region.nrows, region.col0 + region.ncols
    return [t for t in db.tiles if t.row0 < r1 and t.row0 + t.nrows > region.row0
            and t.col0 < c1 and t.col0 + t.ncols > region.col0]


def search(db: SkyDB, q: QueryModel, *, region: Region | None = None, allowed_shifts: np.ndarray | None = None,
           prune: bool = True, prune_factor: float = 4.0, progress=None, workers: int | None = None) -> ScoreMap:
    """Score every position of ``region`` (default: the whole grid) against query ``q``.

    allowed_shifts : (N,) bool, headings the search may return (None: all)
    prune : skip the inverse DFTs of positions whose exact lower bound exceeds ``prune_factor``
        times the best score so far (full panoramas; the argmin is unchanged, see module doc)
    progress : optional callable(n_done_tiles, n_tiles)
    workers : threads that read tiles and compute their lower bounds (default WORKERS); the result
        does not depend on it
    """
    if q.n != db.meta.n_azimuth:
        raise InvalidInputError(f"query has {q.n} azimuth samples, the database {db.meta.n_azimuth}")
    region = region or Region.whole(db.grid)
    shape = (region.nrows, region.ncols)
    out = ScoreMap(region, np.full(shape, np.inf), np.zeros(shape, np.int16), np.zeros(shape, bool))
    penalty = None
    if allowed_shifts is not None:
        allowed_shifts = np.asarray(allowed_shifts, bool)
        if not allowed_shifts.any():
            raise InvalidInputError("no heading is allowed by the heading window")
        penalty = np.where(allowed_shifts, 0.0, np.inf)
    use_prune = prune and q.full  # the bound holds for every heading, so also under a heading window
    # partial panoramas: float32 scores minus their error bound are the lower bounds
    use_f32 = prune and not q.full
    penalty32 = None if penalty is None else penalty.astype(np.float32)
    ones_n = np.full(q.n, 1.0 / q.n)
    best = np.inf
    tiles = _tiles_in(db, region)

    def load(t: Tile):
        """Read one tile (clipped to the region): its rows (degrees, float32, or float64 where missing samples
        were filled) and their region offsets, excluded rows dropped."""
        r0, r1 = max(t.row0, region.row0), min(t.row0 + t.nrows, region.row0 + region.nrows)
        c0, c1 = max(t.col0, region.col0), min(t.col0 + t.ncols, region.col0 + region.ncols)
        el = db.read_tile(Tile(t.ti, t.tj, r0, c0, r1 - r0, c1 - c0)).reshape(-1, q.n)
        oi, oj = np.mgrid[r0 - region.row0:r1 - region.row0, c0 - region.col0:c1 - region.col0]
        oi, oj = oi.ravel(), oj.ravel()
        keep = None if region.mask is None else region.mask[oi, oj]
        if not cv2.checkRange(el)[0]:  # some sample is NaN (missing): fill (in float64) or exclude its row
            el = fill_missing(el.astype(np.float64))
            ok = np.isfinite(el).all(axis=1)
            keep = ok if keep is None else keep & ok
        if keep is not None and not keep.all():
            el, oi, oj = el[keep], oi[keep], oj[keep]
        return el, oi, oj

    def load_bounds(t: Tile):
        """Worker: read tile ``t`` and compute the float32 lower bounds of its rows (they do not depend on
        the best score), a block of BLOCK rows at a time so that the working arrays stay in the CPU cache.

        Returns (rows, row offsets, col offsets, lower bounds or None, float32 best scores or None).
        """
        el, oi, oj = load(t)
        if not prune:
            return el, oi, oj, None, None
        lb = np.empty(el.shape[0])
        amin = np.empty(el.shape[0]) if use_f32 else None
        for b0 in range(0, el.shape[0], BLOCK):
            s0 = el[b0:b0 + BLOCK]
            # centred in the tile's own precision (scores are offset-invariant; the bounds allow the rounding)
            s32 = s0 - (s0 @ ones_n.astype(s0.dtype))[:, None]
            s32 = s32 if s32.dtype == np.float32 else s32.astype(np.float32)
            if use_f32:
                approx = approx_scores_f32(q, s32)
                if penalty32 is not None:
                    approx += penalty32
                amin[b0:b0 + BLOCK] = approx.min(axis=1)
                lb[b0:b0 + BLOCK] = amin[b0:b0 + BLOCK] - f32_error_bound(q, s32)
            else:
                lb[b0:b0 + BLOCK] = lower_bound_full_f32(q, s32)
        np.maximum(lb, 0.0, out=lb)
        return el, oi, oj, lb, amin

    def centred(rows: np.ndarray) -> np.ndarray:
        s = rows.astype(np.float64)
        s -= (s @ ones_n)[:, None]
        return s

    def exact_rows(s: np.ndarray, bi: np.ndarray, bj: np.ndarray) -> float:
        """Exact scores of centred rows ``s`` into ``out``, BLOCK rows at a time; returns their best score."""
        b = np.inf
        for c0 in range(0, s.shape[0], BLOCK):
            r = s[c0:c0 + BLOCK]
            b = min(b, exact(r, dft_rows(r), bi[c0:c0 + BLOCK], bj[c0:c0 + BLOCK]))
        return b

    def exact(s: np.ndarray, sc: np.ndarray, bi: np.ndarray, bj: np.ndarray) -> float:
        """Exact scores of centred rows ``s`` (spectra ``sc``) into ``out``; returns their best score."""
        scores = score_block(q, s, want_b=False, sc=sc).scores
        if penalty is not None:
            scores = scores + penalty
        a = np.argmin(scores, axis=1)
        smin = scores[np.arange(a.size), a]
        out.score[bi, bj] = smin
        out.shift[bi, bj] = a
        out.exact[bi, bj] = True
        out.n_scored += a.size
        return float(smin.min())

    def prune_rows(lb: np.ndarray, bi: np.ndarray, bj: np.ndarray, best: float) -> np.ndarray:
        """Store the bound of the rows that cannot come within ``prune_factor`` of ``best``; True = keep."""
        todo = lb <= prune_factor * best
        pr = ~todo
        out.score[bi[pr], bj[pr]] = lb[pr]
        return todo

    # partial panoramas: rows that survive their float32 bound wait in ``held`` (at most HOLD rows)
    # and are scored exactly at the end, against the final best score, which prunes most of them.
    # On overflow the rows with the largest bounds are dropped and marked ``deferred``: if they
    # still survive at the end, their tiles are read again.
    held: list[tuple[np.ndarray, ...]] = []
    deferred = np.zeros(shape, bool)

    def hold(s: np.ndarray, bi: np.ndarray, bj: np.ndarray, lb: np.ndarray, best: float) -> None:
        held.append((s, bi, bj, lb))
        for h, (hs, hi, hj, hl) in enumerate(held):  # the best may have improved
            keep = prune_rows(hl, hi, hj, best)
            if not keep.all():
                held[h] = (hs[keep], hi[keep], hj[keep], hl[keep])
        if sum(h[0].shape[0] for h in held) > HOLD:
            hs, hi, hj, hl = (np.concatenate(x) for x in zip(*held))
            order = np.argsort(hl, kind="stable")
            keep, drop = order[:HOLD // 2], order[HOLD // 2:]
            out.score[hi[drop], hj[drop]] = hl[drop]
            deferred[hi[drop], hj[drop]] = True
            held[:] = [(hs[keep], hi[keep], hj[keep], hl[keep])]

    # tiles are read and bounded by ``workers`` threads (OpenCV and numpy release the GIL) while this
    # thread prunes and scores exactly, in tile order; at most ``workers`` tiles wait (bounded memory)
    n_workers = max(1, min(WORKERS if workers is None else int(workers), len(tiles)))
    pool = ThreadPoolExecutor(max_workers=n_workers)
    queue = deque(pool.submit(load_bounds, t) for t in tiles[:n_workers])
    try:
        for it in range(len(tiles)):
            el, oi, oj, lb, amin = queue.popleft().result()
            if it + n_workers < len(tiles):
                queue.append(pool.submit(load_bounds, tiles[it + n_workers]))
            for b0 in range(0, el.shape[0], BLOCK):
                blk = slice(b0, b0 + BLOCK)
                bi, bj = oi[blk], oj[blk]
                if use_f32:
                    blb, bam = lb[blk], amin[blk]
                    k = int(np.argmin(bam))
                    exact_k = bam[k] < best  # the block's likely best row may improve the best: score it now
                    if exact_k:
                        s = centred(el[b0 + k:b0 + k + 1])
                        best = min(best, exact(s, dft_rows(s), bi[k:k + 1], bj[k:k + 1]))
                        blb = blb.copy()
                        blb[k] = -np.inf  # keeps its exact score
                    todo = prune_rows(blb, bi, bj, best)
                    if exact_k:
                        todo[k] = False  # row k is exact: neither pruned nor held
                    if todo.any():
                        hold(centred(el[blk][todo]), bi[todo], bj[todo], blb[todo], best)
                    continue
                if use_prune and np.isfinite(best):
                    todo = prune_rows(lb[blk], bi, bj, best)
                    if not todo.any():
                        continue
                    s, bi, bj = el[blk][todo].astype(np.float64), bi[todo], bj[todo]
                else:
                    s = el[blk].astype(np.float64)
                sc = dft_rows(s)
                if not q.full:  # partial query without pruning: centre the rows (the mean from DFT bin 0)
                    s -= (sc[:, 0] / q.n)[:, None]
                sc[:, 0] = 0.0  # scores are offset-invariant (a full panorama's score reads the spectrum only)
                best = min(best, exact(s, sc, bi, bj))
            if progress is not None:
                progress(it + 1, len(tiles))
    finally:
        pool.shutdown(cancel_futures=True)
    if held:
        s, bi, bj, lb = (np.concatenate(x) for x in zip(*held))
        todo = prune_rows(lb, bi, bj, best)
        if todo.any():
            s, bi, bj = s[todo], bi[todo], bj[todo]
            best = min(best, exact_rows(s, bi, bj))
    again = deferred & (out.score <= prune_factor * best)
    if again.any():
        log.info("scoring %d deferred positions exactly (tiles read again)", int(again.sum()))
        for t in tiles:
            r0, c0 = max(t.row0 - region.row0, 0), max(t.col0 - region.col0, 0)
            if not again[r0:t.row0 + t.nrows - region.row0, c0:t.col0 + t.ncols - region.col0].any():
                continue
            el, oi, oj = load(t)
            sel = again[oi, oj]
            if sel.any():
                s = centred(el[sel])
                exact_rows(s, oi[sel], oj[sel])
    out.n_pruned = int((np.isfinite(out.score) & ~out.exact).sum())
    if not np.isfinite(out.score).any():
        raise NoDataError("no database skyline in the search area could be scored (missing tiles or "
                          "positions?): check that the database render is complete (`skyloc db info`)")
    log.info("scored %d positions, pruned %d", out.n_scored, out.n_pruned)
    return out
