"""Trajectory metrics against hand-made trajectories with known errors."""
import numpy as np
import pytest

from board.descent.metrics import ate_m, distance_travelled, error_growth_percent, pose_nees, position_error, rpe_m
from board.descent.quaternion import exp_so3, quat_from_rot, quat_to_xyzw
from board.errors import InvalidInputError


def _traj(n=50, speed=2.0):
    t = np.arange(n, dtype=float)
    rows = np.zeros((n, 8))
    rows[:, 0] = t
    rows[:, 1] = speed * t
    rows[:, 2] = 5 * np.sin(0.1 * t)
    rows[:, 3] = 100 - 0.5 * t
    for k in range(n):
        rows[k, 4:8] = quat_to_xyzw(quat_from_rot(exp_so3([0.01 * k, 0.0, 0.02 * k])))
    return rows


def test_error_growth_is_the_slope_in_percent_with_a_free_intercept():
    gt = _traj()
    d = distance_travelled(gt)
    est = gt.copy()
    direction = np.array([0.6, 0.0, 0.8])
    est[:, 1:4] += np.outer(0.7 + 0.03 * d, direction)  # 0.7 m at the start, 3 % of the distance after
    E, icpt = error_growth_percent(est, gt)
    assert E == pytest.approx(3.0, abs=1e-9) and icpt == pytest.approx(0.7, abs=1e-9)
    assert d[-1] == pytest.approx(np.sum(np.linalg.norm(np.diff(gt[:, 1:4], axis=0), axis=1)))


def test_ate_without_alignment_and_rpe_of_a_rigid_offset():
    gt = _traj()
    est = gt.copy()
    est[:, 1:4] += [3.0, -4.0, 0.0]  # a constant translation: ATE 5 m, relative motions exact
    assert ate_m(est, gt) == pytest.approx(5.0)
    assert rpe_m(est, gt) == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(position_error(est, gt), 5.0)


def test_rpe_of_a_scale_error_grows_with_the_pair_length():
    gt = _traj()
    est = gt.copy()
    est[:, 1:4] = gt[0, 1:4] + 1.1 * (gt[:, 1:4] - gt[0, 1:4])  # 10 % scale error
    assert rpe_m(est, gt, fractions=(0.5,)) > rpe_m(est, gt, fractions=(0.1,)) > 0
    # pairs at 10 %: the relative error is 10 % of the ground-truth relative translation (~10 % of the length)
    L = distance_travelled(gt)[-1]
    assert rpe_m(est, gt, fractions=(0.1,)) == pytest.approx(0.1 * 0.1 * L, rel=0.15)


def test_nees_of_a_known_error():
    gt = _traj(5)
    est = gt.copy()
    est[:, 1] += 2.0
    P = np.repeat(np.diag([4.0, 1, 1, 1, 1, 1])[None], 5, axis=0)
    np.testing.assert_allclose(pose_nees(est, gt, P), 1.0)


def test_mismatched_rows_are_refused():
    gt = _traj(5)
    with pytest.raises(InvalidInputError, match="same"):
        ate_m(gt[:4], gt)
    bad = gt.copy()
    bad[:, 0] += 0.5
    with pytest.raises(InvalidInputError, match="times"):
        ate_m(bad, gt)
