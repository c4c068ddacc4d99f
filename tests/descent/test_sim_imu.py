"""The IMU integrated back along the truth trajectory: exact without noise, within its noise model with it."""
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from blender_addon.descent.constants import EUROPA_GRAVITY_MPS2
from blender_addon.descent.imu import ImuParams, simulate_imu
from blender_addon.descent.trajectories import TRAJECTORIES, make_motion, rotations_enu_from_body
from board.conventions import rotation_enu_from_camera

G_W = np.array([0.0, 0.0, -EUROPA_GRAVITY_MPS2])


def _strapdown(imu, p0, v0, R0):
    """Integrate gyro (body rates) and accelerometer (specific force) from an initial state (trapezoid)."""
    t = imu[:, 0]
    steps = Rotation.from_rotvec(0.5 * (imu[1:, 1:4] + imu[:-1, 1:4]) * np.diff(t)[:, None]).as_matrix()
    R = [R0]
    for dR in steps:
        R.append(R[-1] @ dR)
    R = np.stack(R)
    a = np.einsum("nij,nj->ni", R, imu[:, 4:7]) + G_W
    dt = np.diff(t)[:, None]
    v = np.vstack([v0, v0 + np.cumsum(0.5 * (a[1:] + a[:-1]) * dt, axis=0)])
    p = np.vstack([p0, p0 + np.cumsum(v[:-1] * dt + (2 * a[:-1] + a[1:]) / 6 * dt ** 2, axis=0)])
    return R, v, p


@pytest.mark.parametrize("traj", [3, 9, 10])
def test_noise_free_imu_integrates_back_to_the_truth(traj):
    m = make_motion(traj, 4, z_top=31.7, duration_s=200.0)
    imu, truth = simulate_imu(m, ImuParams(), EUROPA_GRAVITY_MPS2, np.random.default_rng(0), duration_s=60.0,
                              noise=False)
    assert imu.shape == truth.shape[:1] + (7,) and imu[1, 0] - imu[0, 0] == pytest.approx(1 / 200)
    R_true = Rotation.from_quat(truth[:, 4:8]).as_matrix()
    R, v, p = _strapdown(imu, truth[0, 1:4], m.velocity([0.0])[0], R_true[0])
    att_err = np.linalg.norm(Rotation.from_matrix(np.einsum("nji,njk->nik", R_true, R)).as_rotvec(), axis=1)
    assert att_err.max() < 1e-6
    assert np.abs(p - truth[:, 1:4]).max() < 0.01          # 1 cm after 60 s of dead reckoning


def test_a_level_hover_reads_plus_g_on_the_body_z_axis():
    m = make_motion(6, 0, z_top=0.0, noise_pos_m=0.0, noise_att_deg=0.0)
    imu, _ = simulate_imu(m, ImuParams(), EUROPA_GRAVITY_MPS2, np.random.default_rng(0), duration_s=1.0, noise=False)
    # trajectory 6 descends at a nearly constant rate, level, with a slow sway: f = R^T (a - g) ~ (0, 0, g)
    np.testing.assert_allclose(imu[:, 6], EUROPA_GRAVITY_MPS2, atol=5e-3)
    np.testing.assert_allclose(imu[:, 1:4], 0.0, atol=1e-3)


def test_imu_errors_follow_the_stated_noise_model():
    p = ImuParams()
    T = 40.0
    att, vel = [], []
    for seed in range(8):
        m = make_motion(4, seed, z_top=31.7)
        clean, truth = simulate_imu(m, p, EUROPA_GRAVITY_MPS2, None, duration_s=T, noise=False)
        noisy, _ = simulate_imu(m, p, EUROPA_GRAVITY_MPS2, np.random.default_rng(seed), duration_s=T)
        R_true = Rotation.from_quat(truth[:, 4:8]).as_matrix()
        R, _, _ = _strapdown(noisy, truth[0, 1:4], np.zeros(3), R_true[0])
        att.append(Rotation.from_matrix(R_true[-1].T @ R[-1]).as_rotvec())
        # velocity error of the accelerometer alone: its noise integrated in the true attitude
        dv = np.einsum("nij,nj->ni", R_true, noisy[:, 4:7] - clean[:, 4:7])
        vel.append(np.sum(0.5 * (dv[1:] + dv[:-1]) * np.diff(noisy[:, 0])[:, None], axis=0))
    var_att = p.gyro_noise_rad_s_sqrt_hz ** 2 * T + p.gyro_bias_rw ** 2 * T ** 3 / 3
    var_vel = p.accel_noise_m_s2_sqrt_hz ** 2 * T + p.accel_bias_rw ** 2 * T ** 3 / 3
    for err, var in ((np.array(att), var_att), (np.array(vel), var_vel)):
        stat = np.sum(err ** 2) / var
        dof = err.size
        assert chi2.ppf(0.001, dof) < stat < chi2.ppf(0.999, dof), (stat, dof)
    assert math.sqrt(var_att) > 1e-4       # the bound is not vacuous: errors of a few 1e-4 rad are seen


def test_every_trajectory_is_defined_and_clears_the_terrain():
    assert sorted(TRAJECTORIES) == list(range(1, 11))
    for tid in TRAJECTORIES:
        m = make_motion(tid, 29, z_top=31.7)
        z = m.position(np.linspace(0, m.duration_s, 50))[:, 2]
        assert z.min() > 31.7 + 15.0


def test_vectorised_attitudes_equal_the_conventions_rotation():
    rng = np.random.default_rng(2)
    a = rng.uniform([-360, -30, -30], [720, 30, 30], (50, 3))
    R = rotations_enu_from_body(a[:, 0], a[:, 1], a[:, 2])
    for k in range(50):
        np.testing.assert_allclose(R[k], rotation_enu_from_camera(*a[k]), atol=1e-14)
