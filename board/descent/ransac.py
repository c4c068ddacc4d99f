"""1-point RANSAC with the rescue of high-innovation inliers (Civera, Grasa, Davison and Montiel,
"1-point RANSAC for EKF filtering", J. Field Robotics 2010, algorithm 1).

Each hypothesis is the state corrected by one match alone; the matches it predicts within
``inlier_px`` are its support.  The largest support ("low-innovation inliers") updates the filter;
then every other match is predicted again from the updated state and covariance and is rescued if
its innovation passes the chi-square gate (``5.99``: 2 dof, 95 %).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from board.descent.ekf import DescentEKF, Prediction


@dataclass
class Match:
    """A landmark's prediction and the measured (undistorted) pixel it was matched to."""

    pred: Prediction
    z: np.ndarray  # (2,)


@dataclass
class RansacResult:
    low_inliers: int
    rescued: int
    rejected: int
    hypotheses: int


def _update(ekf: DescentEKF, matches: list[Match]) -> None:
    preds = [m.pred for m in matches]
    H = ekf.dense_H(preds)
    r = np.concatenate([m.z - m.pred.uv for m in matches])
    R = np.diag(np.concatenate([np.full(2, ekf.cameras[m.pred.lm.camera].sigma_px ** 2) for m in matches]))
    ekf.update(r, H, R)


def one_point_ransac(ekf: DescentEKF, matches: list[Match], rng: np.random.Generator, *, inlier_px: float = 2.5,
                     p_success: float = 0.99, max_hypotheses: int = 60, rescue_chi2: float = 5.99
                     ) -> tuple[RansacResult, set[int]]:
    """Update ``ekf`` with the consistent subset of ``matches``; returns the counts and the inliers' uids."""
    if not matches:
        return RansacResult(0, 0, 0, 0), set()
    lms = [m.pred.lm for m in matches]
    Z = np.array([m.z for m in matches])
    best: np.ndarray = np.zeros(len(matches), bool)
    n_hyp, i = max_hypotheses, 0
    order = rng.permutation(len(matches))
    while i < min(n_hyp, max_hypotheses):
        j = int(order[i % len(matches)])
        i += 1
        m = matches[j]
        H = ekf.dense_H([m.pred])
        R = np.eye(2) * ekf.cameras[m.pred.lm.camera].sigma_px ** 2
        dx = ekf.correction(m.z - m.pred.uv, H, R)
        x_h, m_h = ekf.apply_correction(dx)
        uv = ekf.project_all(lms, x_h, m_h)
        err = np.linalg.norm(uv - Z, axis=1)
        sup = np.nan_to_num(err, nan=np.inf) < inlier_px
        if sup.sum() > best.sum():
            best = sup
            eps = best.mean()
            if eps >= 1.0:
                n_hyp = i
            else:
                n_hyp = int(np.ceil(np.log(1 - p_success) / np.log(1 - eps))) if eps > 0 else max_hypotheses
        if i >= len(matches) and i >= n_hyp:
            break
    low = [m for m, b in zip(matches, best) if b]
    inliers = {m.pred.lm.uid for m in low}
    if low:
        _update(ekf, low)
    # rescue: re-predict the others from the updated filter
    rescued = []
    for m, b in zip(matches, best):
        if b:
            continue
        pr = ekf.predict(m.pred.lm)
        if pr is None:
            continue
        r = m.z - pr.uv
        if float(r @ np.linalg.solve(pr.S, r)) < rescue_chi2:
            rescued.append(Match(pr, m.z))
    if rescued:
        _update(ekf, rescued)
        inliers |= {m.pred.lm.uid for m in rescued}
    return RansacResult(len(low), len(rescued), len(matches) - len(low) - len(rescued), i), inliers
