"""Replacement of lost landmarks by spatial diversity (the memorandum's sec. 3.3, eq. 8).

Candidates (new keypoints not matched to a tracked landmark) are weighted by their Shannon surprise
under a Gaussian kernel density estimate of the tracked landmarks' image positions::

    D(l) = -log f(l),   f(l) = 1/n sum_i N(l; u_i, h^2 I)   (pixels)

and drawn without replacement with probabilities proportional to ``D``; with no tracked landmark the
draw is uniform.  A minimum spacing keeps two new landmarks (or a new one and a tracked one) apart.
"""
from __future__ import annotations

import numpy as np


def diversity_score(cand_uv: np.ndarray, tracked_uv: np.ndarray, bandwidth_px: float) -> np.ndarray:
    """``D(l) = -log f(l)`` (nats, f in 1/px^2) of each candidate (k, 2) given the tracked positions (n, 2)."""
    cand_uv = np.asarray(cand_uv, float).reshape(-1, 2)
    tracked_uv = np.asarray(tracked_uv, float).reshape(-1, 2)
    if tracked_uv.shape[0] == 0:
        return np.ones(cand_uv.shape[0])
    d2 = ((cand_uv[:, None, :] - tracked_uv[None, :, :]) ** 2).sum(axis=2)
    e = -0.5 * d2 / bandwidth_px ** 2
    mx = e.max(axis=1, keepdims=True)
    log_f = mx[:, 0] + np.log(np.exp(e - mx).sum(axis=1)) - np.log(tracked_uv.shape[0] * 2 * np.pi * bandwidth_px ** 2)
    return -log_f


def sample_new(cand_uv: np.ndarray, tracked_uv: np.ndarray, k: int, rng: np.random.Generator, *,
               bandwidth_px: float = 60.0, min_spacing_px: float = 20.0, weighting: str = "diversity"
               ) -> np.ndarray:
    """Indices of up to ``k`` candidates to initialise as landmarks.

    weighting : "diversity" (eq. 8) or "uniform" (Brunner et al. 2011), for comparison.
    """
    cand_uv = np.asarray(cand_uv, float).reshape(-1, 2)
    tracked = np.asarray(tracked_uv, float).reshape(-1, 2)
    if k <= 0 or cand_uv.shape[0] == 0:
        return np.zeros(0, int)
    if tracked.shape[0]:
        dmin = np.sqrt(((cand_uv[:, None, :] - tracked[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
        ok = dmin >= min_spacing_px
    else:
        ok = np.ones(cand_uv.shape[0], bool)
    chosen: list[int] = []
    avail = np.flatnonzero(ok)
    while len(chosen) < k and avail.size:
        if weighting == "diversity":
            w = np.maximum(diversity_score(cand_uv[avail], tracked, bandwidth_px), 1e-12)
        else:
            w = np.ones(avail.size)
        j = int(rng.choice(avail, p=w / w.sum()))
        chosen.append(j)
        tracked = np.vstack([tracked, cand_uv[j]])
        d = np.sqrt(((cand_uv[avail] - cand_uv[j]) ** 2).sum(axis=1))
        avail = avail[d >= min_spacing_px]
    return np.array(chosen, int)
