"""Trajectory metrics of a descent run (positions in metres, world frame; TUM rows t x y z qx qy qz qw).

* ``E`` (the memorandum's sec. 5): the slope of the ordinary least-squares line of the position error
  norm against the distance travelled (along the ground truth, from the first frame), in percent.
  Intercept convention: the line has a free intercept (the initial error is not forced to zero), so
  E measures the growth of the error, not its starting value.
* ATE: RMS of the position error with no alignment (the filter starts in the world frame; aligning
  would hide its drift).
* RPE (evo's convention, ``(Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` translation part): RMS over all frame pairs
  whose travelled distance is 10, 20, 30, 40 and 50 % of the trajectory's length (the nearest frame).
* NEES of the pose error ``[dp, dtheta]`` (6 dof) with the filter's covariance.
"""
from __future__ import annotations

import numpy as np

from board.descent.quaternion import log_so3, quat_from_xyzw, rot_from_quat
from board.errors import InvalidInputError

RPE_FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5)


def _check(est: np.ndarray, gt: np.ndarray) -> None:
    if est.shape != gt.shape or est.ndim != 2 or est.shape[1] != 8:
        raise InvalidInputError(f"estimate {est.shape} and ground truth {gt.shape} must be the same (n, 8) TUM rows "
                                "(one per frame)")
    if not np.allclose(est[:, 0], gt[:, 0], atol=1e-6):
        raise InvalidInputError("estimate and ground truth times differ: associate them frame by frame first")


def groundtruth_at(gt: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Ground-truth TUM rows at ``times`` (s): positions interpolated linearly, quaternions by normalised lerp.

    ``gt`` may be denser than the frames (the simulator writes it at the IMU rate); times outside its
    span are refused.
    """
    gt = np.asarray(gt, float)
    times = np.asarray(times, float)
    if times.min() < gt[0, 0] - 1e-6 or times.max() > gt[-1, 0] + 1e-6:
        raise InvalidInputError(f"frame times {times.min():.3f}..{times.max():.3f} s lie outside the ground truth "
                                f"({gt[0, 0]:.3f}..{gt[-1, 0]:.3f} s)")
    j = np.clip(np.searchsorted(gt[:, 0], times, side="right") - 1, 0, len(gt) - 2) if len(gt) > 1 else \
        np.zeros(len(times), int)
    out = np.empty((len(times), 8))
    out[:, 0] = times
    if len(gt) == 1:
        out[:, 1:] = gt[0, 1:]
        return out
    t0, t1 = gt[j, 0], gt[j + 1, 0]
    w = np.clip((times - t0) / np.maximum(t1 - t0, 1e-12), 0.0, 1.0)[:, None]
    out[:, 1:4] = (1 - w) * gt[j, 1:4] + w * gt[j + 1, 1:4]
    q0, q1 = gt[j, 4:8], gt[j + 1, 4:8]
    q1 = np.where((np.sum(q0 * q1, axis=1) < 0)[:, None], -q1, q1)
    q = (1 - w) * q0 + w * q1
    out[:, 4:8] = q / np.linalg.norm(q, axis=1, keepdims=True)
    return out


def distance_travelled(gt: np.ndarray) -> np.ndarray:
    """Cumulative path length (m) along the ground-truth positions, 0 at the first row."""
    d = np.linalg.norm(np.diff(gt[:, 1:4], axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(d)])


def position_error(est: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Norm of the position error per frame (m)."""
    _check(est, gt)
    return np.linalg.norm(est[:, 1:4] - gt[:, 1:4], axis=1)


def error_growth_percent(est: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """``(E, intercept)``: OLS slope (in %) and intercept (m) of the error norm against distance travelled."""
    e = position_error(est, gt)
    d = distance_travelled(gt)
    if d[-1] <= 0 or len(d) < 2:
        raise InvalidInputError("the ground truth does not move: E (error per distance travelled) is undefined")
    A = np.column_stack([d, np.ones_like(d)])
    (slope, icpt), *_ = np.linalg.lstsq(A, e, rcond=None)
    return 100.0 * float(slope), float(icpt)


def ate_m(est: np.ndarray, gt: np.ndarray) -> float:
    """Absolute trajectory error: RMS position error (m), no alignment."""
    e = position_error(est, gt)
    return float(np.sqrt(np.mean(e * e)))


def _se3(row: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rot_from_quat(quat_from_xyzw(row[4:8]))
    T[:3, 3] = row[1:4]
    return T


def rpe_m(est: np.ndarray, gt: np.ndarray, fractions=RPE_FRACTIONS) -> float:
    """Relative pose error (translation, m): RMS over the pairs at the given fractions of the length."""
    _check(est, gt)
    d = distance_travelled(gt)
    L = d[-1]
    Te = [_se3(r) for r in est]
    Tg = [_se3(r) for r in gt]
    errs = []
    for f in fractions:
        for i in range(len(d)):
            j = int(np.searchsorted(d, d[i] + f * L))
            if j >= len(d):
                break
            E = np.linalg.inv(np.linalg.inv(Tg[i]) @ Tg[j]) @ (np.linalg.inv(Te[i]) @ Te[j])
            errs.append(float(np.linalg.norm(E[:3, 3])))
    if not errs:
        return float("nan")
    return float(np.sqrt(np.mean(np.square(errs))))


def pose_nees(est: np.ndarray, gt: np.ndarray, pose_cov: np.ndarray) -> np.ndarray:
    """NEES (6 dof) per frame of ``[p_est - p_true, log(R_est^T R_true)]`` with the (n, 6, 6) covariances."""
    _check(est, gt)
    out = np.empty(len(est))
    for k, (a, b, P) in enumerate(zip(est, gt, pose_cov)):
        Re = rot_from_quat(quat_from_xyzw(a[4:8]))
        Rt = rot_from_quat(quat_from_xyzw(b[4:8]))
        e = np.concatenate([a[1:4] - b[1:4], log_so3(Re.T @ Rt)])
        out[k] = float(e @ np.linalg.solve(P, e))
    return out
