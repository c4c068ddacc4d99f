"""Consistency of the descent EKF on a noise-only case: NEES of the pose within its chi-square bounds.

Truth: an analytic trajectory (board.descent.synthetic) over 3-D points on the ground; IMU from the
trajectory's analytic derivatives with white noise and bias walks; pixels = pinhole projections of
the points plus Gaussian noise; known data association (no images), so that only the estimator's
linearisation and noise bookkeeping are under test.
"""
import numpy as np
import pytest
from scipy import stats

from board.camera import CameraModel
from board.descent.altimeter import inverse_depth_prior
from board.descent.ekf import DescentEKF, FilterCamera
from board.descent.imu_propagation import ImuNoise
from board.descent.inverse_depth import id_to_xyz
from board.descent.runner import RunConfig, initial_state
from board.descent.synthetic import (
    EUROPA_G,
    R_BODY_CAM_DOWN,
    AnalyticTrajectory,
    ImuSpec,
    groundtruth_rows,
    simulate_imu,
)
from board.descent.quaternion import log_so3

SIGMA_PX = 1.0
N_LM = 24


def _points(rng, traj, t_end):
    c = traj.position(np.linspace(0, t_end, 20))
    lo, hi = c[:, :2].min(0) - 120, c[:, :2].max(0) + 120
    n = 3000
    xy = rng.uniform(lo, hi, (n, 2))
    return np.column_stack([xy, rng.uniform(0, 10, n)])


def _project(X, p, R, cam: FilterCamera):
    h = (X - (p + R @ cam.t_bc)) @ (R @ cam.R_bc)
    uv = np.column_stack([cam.fx * h[:, 0] / h[:, 2] + cam.cx, cam.fy * h[:, 1] / h[:, 2] + cam.cy])
    inside = (h[:, 2] > 0) & (uv[:, 0] > 10) & (uv[:, 0] < cam.width - 10) & (uv[:, 1] > 10) & (uv[:, 1] < cam.height - 10)
    return uv, inside


def _run(seed, n_frames=16):
    rng = np.random.default_rng(seed)
    traj = AnalyticTrajectory()
    spec = ImuSpec(rate_hz=100.0)
    imu = simulate_imu(traj, n_frames - 1, spec, EUROPA_G, rng)
    times = np.arange(n_frames, dtype=float)
    gt = groundtruth_rows(traj, np.array([0.0, 0.05, 0.1]))  # fine samples at t0: initial velocity
    X = _points(rng, traj, n_frames)
    m = CameraModel.from_fov(640, 480, 60.0)
    cam = FilterCamera("visible", 640, 480, m.fx, m.fy, m.cx, m.cy, R_BODY_CAM_DOWN, np.array([0.1, 0.0, -0.2]),
                       SIGMA_PX)
    x0, P0 = initial_state(gt, RunConfig(), rng)
    noise = ImuNoise(spec.gyro_noise, spec.accel_noise, spec.gyro_bias_rw, spec.accel_bias_rw)
    ekf = DescentEKF(x0, P0, np.array([0, 0, -EUROPA_G]), noise, {"visible": cam})
    owner = {}  # landmark uid -> point index
    nees = []
    for k, t in enumerate(times):
        if k:
            ekf.propagate(imu, times[k - 1], t)
        p, R = traj.position(t), traj.rotation(t)
        uv, inside = _project(X, p, R, cam)
        z = uv + rng.normal(0, SIGMA_PX, uv.shape)
        gone = [lm for lm in ekf.landmarks if not inside[owner[lm.uid]]]
        ekf.delete_landmarks(gone)
        if ekf.landmarks:
            preds = [ekf.predict(lm) for lm in ekf.landmarks]
            H = ekf.dense_H(preds)
            r = np.concatenate([z[owner[pr.lm.uid]] - pr.uv for pr in preds])
            ekf.update(r, H, np.eye(r.size) * SIGMA_PX ** 2)
            ekf.switch_linear_landmarks()
        free = np.setdiff1d(np.flatnonzero(inside), list(owner.values()))
        for j in rng.permutation(free)[:max(0, N_LM - len(ekf.landmarks))]:
            r_c = ekf.x.p + ekf.x.R @ cam.t_bc
            ray = ekf.x.R @ cam.R_bc @ np.array([(z[j, 0] - cam.cx) / cam.fx, (z[j, 1] - cam.cy) / cam.fy, 1.0])
            rho, s_rho = inverse_depth_prior(r_c, ray / np.linalg.norm(ray), 5.0, rel_sigma=0.3)
            lm = ekf.add_landmark("visible", z[j], rho, s_rho)
            owner[lm.uid] = j
        e = np.concatenate([ekf.x.p - p, log_so3(ekf.x.R.T @ R)])
        nees.append(float(e @ np.linalg.solve(ekf.P[:6, :6], e)))
    return np.array(nees), ekf


@pytest.mark.slow
def test_pose_nees_within_chi2_bounds():
    runs = 10
    nees = np.array([_run(seed)[0] for seed in range(runs)])  # (runs, frames)
    anees = nees.mean(axis=0)
    lo, hi = stats.chi2.ppf([0.025, 0.975], 6 * runs) / runs
    inside = (anees >= lo) & (anees <= hi)
    # a consistent filter keeps the average NEES inside its 95 % band at (nearly) every time step
    assert inside.mean() >= 0.8, (anees.round(2), lo, hi)
    lo99, hi99 = stats.chi2.ppf([0.005, 0.995], 6 * runs * nees.shape[1]) / (runs * nees.shape[1])
    assert lo99 * 0.8 <= anees.mean() <= hi99 * 1.2, (anees.mean(), lo99, hi99)


def test_covariance_stays_symmetric_positive_definite():
    nees, ekf = _run(3, n_frames=8)
    P = ekf.P
    np.testing.assert_array_equal(P, P.T)
    ev = np.linalg.eigvalsh(P)
    # positive semi-definite: a new landmark's anchor r_i is a function of the pose (exactly singular directions)
    assert ev.min() > -1e-12 * ev.max()
    assert np.all(np.linalg.eigvalsh(P[:15, :15]) > 0)
    assert np.isfinite(nees).all() and len(ekf.landmarks) == N_LM


def test_switch_to_xyz_keeps_the_point_its_covariance_and_its_prediction():
    _, ekf = _run(4, n_frames=4)
    lm = ekf.landmarks[5]
    blk = ekf.state_index(lm)
    X, J = id_to_xyz(ekf.params(lm))
    T = np.delete(np.eye(ekf.n), blk[3:], axis=0)  # drop 3 rows ...
    T[blk[0]:blk[0] + 3, :] = 0.0
    T[blk[0]:blk[0] + 3, blk] = J  # ... and map the 6 parameters to the point: P' = T P T^T
    P_expect = T @ ekf.P @ T.T
    uv_before = ekf.predict(lm).uv
    S_before = ekf.predict(lm).S
    ekf.to_xyz(lm)
    assert lm.kind == "xyz" and ekf.n == P_expect.shape[0]
    np.testing.assert_allclose(ekf.params(lm), X, atol=1e-9)
    np.testing.assert_allclose(ekf.P, P_expect, atol=1e-9)
    np.testing.assert_allclose(ekf.predict(lm).uv, uv_before, atol=1e-9)
    np.testing.assert_allclose(ekf.predict(lm).S, S_before, rtol=1e-6)


def test_negative_inverse_depth_is_clamped():
    _, ekf = _run(5, n_frames=2)
    lm = next(lm for lm in ekf.landmarks if lm.kind == "id")
    dx = np.zeros(ekf.n)
    dx[ekf.state_index(lm)[5]] = -1.0  # drives rho far below zero
    _, m = ekf.apply_correction(dx)
    assert m[lm.offset + 5] == ekf.cfg.rho_min
