"""Shortest left-to-right path through a column-staged pixel graph, by dynamic programming.

The graph is the one of the reference report: a node per pixel ``(r, c)``; from every node a
move to the next column (rows ``r - 1``, ``r``, ``r + 1``) and moves within the column (``r +- 1``).
All costs are non-negative, so within a column an optimal path only goes up or only goes
down; both sweeps are prefix minima (``np.minimum.accumulate``), which makes every column one
handful of vectorised numpy operations instead of a Dijkstra over millions of nodes.

Costs
-----
node_cost : (H, W) paid on entering a node (also the start node).
pair_cost : (3, H, W) or None; ``pair_cost[d + 1, r, c]`` is paid on the move
            ``(r + d, c - 1) -> (r, c)``, d in {-1, 0, 1}.
vert_cost : (H, W) or None; ``vert_cost[r, c]`` is paid on a move between ``(r - 1, c)`` and
            ``(r, c)`` in either direction (row 0 unused).

With ``wrap=True`` (a 360-degree panorama) the columns are treated as a circle: the DP runs
over the columns with ``margin`` columns of overlap on each side and keeps the middle,
which closes the circle as long as the optimal path forgets its start within the margin.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from board.errors import InvalidInputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PathResult:
    """rows_top / rows_exit : (W,) int, topmost row of the path in each column and the row it leaves by;
    cost : total path cost."""

    rows_top: np.ndarray
    rows_exit: np.ndarray
    cost: float


def _argmin_so_far(val: np.ndarray, runmin: np.ndarray, idx: np.ndarray) -> np.ndarray:
    return np.maximum.accumulate(np.where(val <= runmin, idx, 0))


def shortest_path_dp(node_cost: np.ndarray, *, pair_cost: np.ndarray | None = None,
                     vert_cost: np.ndarray | None = None, vertical_moves: bool = True, wrap: bool = False,
                     margin: int = 200) -> PathResult:
    """Minimum-cost path crossing every column once, left to right (see the module docstring).

    Returns the topmost and the exit row of the path in every column.
    """
    node = np.asarray(node_cost, dtype=np.float32)
    if node.ndim != 2 or min(node.shape) < 1:
        raise InvalidInputError(f"node_cost must be a non-empty (H, W) array, got shape {node.shape}")
    H, W = node.shape
    if pair_cost is not None and pair_cost.shape != (3, H, W):
        raise InvalidInputError(f"pair_cost must have shape (3, {H}, {W}), got {pair_cost.shape}")
    if vert_cost is not None and vert_cost.shape != (H, W):
        raise InvalidInputError(f"vert_cost must have shape ({H}, {W}), got {vert_cost.shape}")

    if wrap and W > 1:
        m = int(min(W, max(1, margin)))
        cols = np.concatenate([np.arange(W - m, W), np.arange(W), np.arange(m)])
    else:
        m = 0
        cols = np.arange(W)
    n = cols.size
    # column-major copies: each DP step reads one contiguous row of these
    nodeT = np.ascontiguousarray(node.T[cols])
    pairT = (None if pair_cost is None
             else np.ascontiguousarray(np.transpose(pair_cost, (2, 0, 1))[cols], dtype=np.float32))
    if vertical_moves:
        v = np.zeros((H, W), np.float32) if vert_cost is None else np.asarray(vert_cost, dtype=np.float32)
        # down into r from r-1: v[r] + node[r]; up into r from r+1: v[r+1] + node[r]
        step = np.zeros((n, H), dtype=np.float64)
        step[:, 1:] = v.T[cols, 1:] + nodeT[:, 1:]
        s_down = np.cumsum(step, axis=1).astype(np.float32)
        step[:, 1:] = 0.0
        step[:, :-1] = v.T[cols, 1:] + nodeT[:, :-1]
        s_up = np.cumsum(step[:, ::-1], axis=1)[:, ::-1].astype(np.float32)
        del step, v
    idx = np.arange(H)
    itype = np.int16 if H < 32767 else np.int32
    pred = np.empty((n, H), dtype=itype)    # row in column k-1 the entry node of column k came from
    entry = np.empty((n, H), dtype=itype)   # row where the path entered column k, for each exit row
    inf = np.inf
    D = nodeT[0].astype(np.float64)
    pred[0] = idx
    cand = np.empty((3, H))
    for k in range(n):
        if k > 0:
            cand[0, 1:] = D[:-1]   # from r-1
            cand[0, 0] = inf
            cand[1] = D
            cand[2, :-1] = D[1:]   # from r+1
            cand[2, -1] = inf
            if pairT is not None:
                cand += pairT[k]
            a = np.argmin(cand, axis=0)
            D = cand[a, idx] + nodeT[k]
            pred[k] = idx + a - 1
        if vertical_moves:
            sd = s_down[k].astype(np.float64)
            su = s_up[k].astype(np.float64)
            vd = D - sd
            rd = np.minimum.accumulate(vd)
            ed = _argmin_so_far(vd, rd, idx)
            vu = (D - su)[::-1]
            ru = np.minimum.accumulate(vu)
            eu = (H - 1 - _argmin_so_far(vu, ru, idx))[::-1]
            dd = rd + sd
            du = ru[::-1] + su
            use_up = du < dd
            entry[k] = np.where(use_up, eu, ed)
            D = np.where(use_up, du, dd)
        else:
            entry[k] = idx
    # backtrack
    r = int(np.argmin(D))
    cost = float(D[r])
    top = np.empty(n, dtype=np.int64)
    exit_ = np.empty(n, dtype=np.int64)
    for k in range(n - 1, -1, -1):
        e = int(entry[k, r])
        exit_[k] = r
        top[k] = min(e, r)
        r = int(pred[k, e])
    if m:
        top = top[m:m + W]
        exit_ = exit_[m:m + W]
    return PathResult(top, exit_, cost)


def _l1_transform(D: np.ndarray, lam_fb: np.ndarray, idx2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """min_{r'} D(r') + lam |r - r'| and its argmin, by a forward and a backward prefix minimum.

    lam_fb : (2, H) = (-lam * r, +lam * r reversed); idx2 : (2, H) row indices.  Both sweeps run in
    one accumulate call on a (2, H) array.
    """
    H = D.size
    v = np.empty((2, H))
    v[0] = D
    v[1] = D[::-1]
    v += lam_fb
    run = np.minimum.accumulate(v, axis=1)
    arg = np.maximum.accumulate(np.where(v <= run, idx2, 0), axis=1)
    df = run[0] - lam_fb[0]
    db = (run[1] - lam_fb[1])[::-1]
    ab = (H - 1 - arg[1])[::-1]
    use_b = db < df
    return np.where(use_b, db, df), np.where(use_b, ab, arg[0])


def shortest_path_l1(node_cost: np.ndarray, *, jump_cost: float, wrap: bool = False, margin: int = 200,
                     offsets: np.ndarray | None = None) -> PathResult:
    """Path with one node per column minimising ``sum node_cost + jump_cost * sum |r_c - r_{c-1}|``.

    Any jump between neighbouring columns is allowed (cliffs) at ``jump_cost`` per row; the min over
    jumps is an L1 distance transform, two prefix minima per column.  ``wrap`` as in
    :func:`shortest_path_dp`.  rows_top == rows_exit == the row of each column.

    offsets : (W,) int or None; row ``r`` of column ``c`` of ``node_cost`` is row ``r + offsets[c]`` of
    the image (a band of rows that follows a line): the jumps are then counted in image rows,
    ``|r_c + offsets[c] - r_{c-1} - offsets[c-1]|``, exactly (rows outside the band are not nodes).
    The returned rows are band rows.
    """
    node = np.asarray(node_cost, dtype=np.float32)
    if node.ndim != 2 or min(node.shape) < 1:
        raise InvalidInputError(f"node_cost must be a non-empty (H, W) array, got shape {node.shape}")
    if not jump_cost >= 0:
        raise InvalidInputError(f"jump_cost must be >= 0, got {jump_cost}")
    H, W = node.shape
    m = int(min(W, max(1, margin))) if (wrap and W > 1) else 0
    cols = np.concatenate([np.arange(W - m, W), np.arange(W), np.arange(m)]) if m else np.arange(W)
    nodeT = np.ascontiguousarray(node.T[cols])
    n = cols.size
    idx = np.arange(H)
    lam = jump_cost * idx.astype(np.float64)
    if offsets is None:
        delta = np.zeros(max(n - 1, 0), dtype=np.int64)
    else:
        off = np.asarray(offsets, dtype=np.int64)
        if off.shape != (W,):
            raise InvalidInputError(f"offsets must have shape ({W},), got {off.shape}")
        delta = np.diff(off[cols])
    # forward: the cost D_k of every row of every column (float64, kept for the backtrack).  The L1
    # transform min_r' D(r') + lam |r - r'| is the smaller of a forward and a backward prefix minimum,
    # both swept by one accumulate call on a (2, H) buffer: row 0 holds D - lam, row 1 (D + lam) reversed.
    # The loop is bound by numpy's per-call overhead (H is 30-600 rows), so every step is one call.
    Ds = np.empty((n, H))
    Ds[0] = nodeT[0]
    lam_r = lam[::-1].copy()
    lam_pm = np.stack([lam, -lam_r])
    ramp = jump_cost * np.arange(H + 1)        # the transform past the band's end row: + jump_cost per row
    v = np.empty((2, H))
    vf, vb_rev = v[0], v[1]
    vb = vb_rev[::-1]
    tmp = np.empty(H)
    dl = delta.tolist()
    for k in range(1, n):
        D = Ds[k - 1]
        np.subtract(D, lam, out=vf)
        np.add(D[::-1], lam_r, out=vb_rev)
        np.minimum.accumulate(v, axis=1, out=v)
        v += lam_pm
        d = dl[k - 1]
        out = Ds[k]
        if d == 0:
            np.minimum(vf, vb, out=out)
        elif 0 < d < H:
            # image row r + off[k] seen from the band of column k - 1: band row r + d; beyond the
            # band the transform grows linearly from its end row
            np.minimum(vf, vb, out=tmp)
            out[:H - d] = tmp[d:]
            np.add(ramp[1:d + 1], tmp[H - 1], out=out[H - d:])
        elif -H < d < 0:
            np.minimum(vf, vb, out=tmp)
            out[-d:] = tmp[:H + d]
            np.add(ramp[-d:0:-1], tmp[0], out=out[:-d])
        else:  # the whole column outside the previous band
            np.minimum(vf, vb, out=tmp)
            x = idx + d
            xc = np.clip(x, 0, H - 1)
            np.add(tmp[xc], jump_cost * np.abs(x - xc), out=out)
        out += nodeT[k]
    r = int(np.argmin(Ds[-1]))
    cost = float(Ds[-1, r])
    rows = np.empty(n, dtype=np.int64)
    rows[-1] = r
    # backtrack: the row of column k - 1 the transform took for row r of column k (same sums, same ties:
    # forward the nearest row at or above, backward the nearest at or below, forward on equal costs).
    # D - lam and D + lam are formed a block of columns at a time (one call each, not two per column).
    lam_l = lam.tolist()
    block = 256
    for k1 in range(n - 1, 0, -block):
        k0 = max(k1 - block, 0)                 # columns k0 .. k1 - 1 are the "k - 1" of this block
        Dm = Ds[k0:k1] - lam
        Dp = Ds[k0:k1] + lam
        for k in range(k1, k0, -1):
            j = k - 1 - k0
            x = min(max(r + dl[k - 1], 0), H - 1)
            rf = x - int(Dm[j, x::-1].argmin())   # the method: np.argmin's wrapper costs as much again
            rb = x + int(Dp[j, x:].argmin())
            r = rb if (Dp[j, rb] - lam_l[x]) < (Dm[j, rf] + lam_l[x]) else rf
            rows[k - 1] = r
    if m:
        rows = rows[m:m + W]
    return PathResult(rows, rows.copy(), cost)

