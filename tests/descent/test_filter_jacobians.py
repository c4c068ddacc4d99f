"""Finite-difference checks of every Jacobian of the descent filter (Civera's F_Test_* habit as pytest)."""
import numpy as np
import pytest

from board.descent.altimeter import facet_range
from board.descent.imu_propagation import IBA, IBG, ITH, IV, VehicleState, imu_step
from board.descent.inverse_depth import (
    angles_of_direction,
    camera_point_id,
    camera_point_xyz,
    id_to_xyz,
    init_inverse_depth,
    pinhole,
    ray_direction,
)
from board.descent.quaternion import exp_so3, log_so3, quat_from_rot, rot_from_quat

EPS = 1e-6


def _num_jac(f, x0, eps=EPS):
    """Central differences of f (array-valued) at x0."""
    x0 = np.asarray(x0, float)
    f0 = np.atleast_1d(f(x0))
    J = np.zeros((f0.size, x0.size))
    for i in range(x0.size):
        d = np.zeros_like(x0)
        d[i] = eps
        J[:, i] = (np.atleast_1d(f(x0 + d)) - np.atleast_1d(f(x0 - d))) / (2 * eps)
    return J


def _rig(rng):
    R_wb = exp_so3(rng.normal(0, 0.3, 3))
    p = np.array([10.0, -5.0, 120.0]) + rng.normal(0, 3, 3)
    R_bc = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]) @ exp_so3(rng.normal(0, 0.05, 3))
    t_bc = rng.normal(0, 0.3, 3)
    return p, R_wb, R_bc, t_bc


def _landmark(rng, p):
    X = np.array([p[0] + rng.normal(0, 20), p[1] + rng.normal(0, 20), rng.normal(0, 5)])
    r0 = p + rng.normal(0, 5, 3)
    th, ph, _ = angles_of_direction(X - r0)
    return np.array([*r0, th, ph, 1.0 / np.linalg.norm(X - r0)]), X


@pytest.mark.parametrize("seed", range(5))
def test_quaternion_round_trips(seed):
    rng = np.random.default_rng(seed)
    phi = rng.normal(0, 1.0, 3)
    R = exp_so3(phi)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rot_from_quat(quat_from_rot(R)), R, atol=1e-12)
    np.testing.assert_allclose(exp_so3(log_so3(R)), R, atol=1e-10)


def test_ray_direction_and_angles():
    rng = np.random.default_rng(1)
    for _ in range(10):
        th, ph = rng.uniform(-3, 3), rng.uniform(-1.4, 1.4)
        m, dmt, dmp = ray_direction(th, ph)
        assert abs(np.linalg.norm(m) - 1) < 1e-12
        J = _num_jac(lambda a: ray_direction(a[0], a[1])[0], [th, ph])
        np.testing.assert_allclose(np.column_stack([dmt, dmp]), J, atol=1e-8)
        th2, ph2, Ja = angles_of_direction(m * 3.0)
        assert abs(np.angle(np.exp(1j * (th2 - th)))) < 1e-12 and abs(ph2 - ph) < 1e-12
        np.testing.assert_allclose(Ja, _num_jac(lambda v: np.array(angles_of_direction(v)[:2]), m * 3.0), atol=1e-7)


@pytest.mark.parametrize("seed", range(5))
def test_inverse_depth_to_xyz_jacobian(seed):
    rng = np.random.default_rng(seed)
    p, *_ = _rig(rng)
    y, X = _landmark(rng, p)
    X2, J = id_to_xyz(y)
    np.testing.assert_allclose(X2, X, atol=1e-9)
    np.testing.assert_allclose(J, _num_jac(lambda q: id_to_xyz(q)[0], y), rtol=1e-6, atol=1e-6)


def _perturbed(p, R, d):
    """Pose perturbed by the error [dp, dtheta] (body-frame, right-multiplied)."""
    return p + d[0:3], R @ exp_so3(d[3:6])


@pytest.mark.parametrize("seed", range(5))
def test_camera_point_jacobians(seed):
    rng = np.random.default_rng(seed)
    p, R, R_bc, t_bc = _rig(rng)
    y, X = _landmark(rng, p)
    h, Jx, Jy = camera_point_id(y, p, R, R_bc, t_bc)
    # the scaled inverse-depth point is rho times the Euclidean one
    hx, Jxx, JX = camera_point_xyz(X, p, R, R_bc, t_bc)
    np.testing.assert_allclose(h, y[5] * hx, rtol=1e-9)
    np.testing.assert_allclose(Jx, _num_jac(lambda d: camera_point_id(y, *_perturbed(p, R, d), R_bc, t_bc)[0],
                                            np.zeros(6)), atol=1e-7)
    np.testing.assert_allclose(Jy, _num_jac(lambda q: camera_point_id(q, p, R, R_bc, t_bc)[0], y), atol=1e-6)
    np.testing.assert_allclose(Jxx, _num_jac(lambda d: camera_point_xyz(X, *_perturbed(p, R, d), R_bc, t_bc)[0],
                                             np.zeros(6)), atol=1e-6)
    np.testing.assert_allclose(JX, _num_jac(lambda q: camera_point_xyz(q, p, R, R_bc, t_bc)[0], X), atol=1e-7)


def test_pinhole_jacobian():
    h = np.array([3.0, -2.0, 40.0])
    uv, J = pinhole(h, 500.0, 510.0, 320.0, 240.0)
    np.testing.assert_allclose(uv, [320 + 500 * 3 / 40, 240 - 510 * 2 / 40])
    np.testing.assert_allclose(J, _num_jac(lambda q: pinhole(q, 500.0, 510.0, 320.0, 240.0)[0], h), atol=1e-7)


@pytest.mark.parametrize("seed", range(5))
def test_landmark_initialisation_jacobians(seed):
    rng = np.random.default_rng(seed)
    p, R, R_bc, t_bc = _rig(rng)
    K = (500.0, 500.0, 320.0, 240.0)
    uv = np.array([rng.uniform(0, 640), rng.uniform(0, 480)])
    rho0 = 1 / 100.0
    y, Jx, Jz, Jr = init_inverse_depth(uv, rho0, p, R, R_bc, t_bc, *K)
    # the landmark reprojects onto the pixel it came from, whatever its depth
    h, _, _ = camera_point_id(y, p, R, R_bc, t_bc)
    np.testing.assert_allclose(pinhole(h, *K)[0], uv, atol=1e-8)
    np.testing.assert_allclose(Jx, _num_jac(lambda d: init_inverse_depth(uv, rho0, *_perturbed(p, R, d), R_bc, t_bc,
                                                                         *K)[0], np.zeros(6)), atol=1e-6)
    np.testing.assert_allclose(Jz, _num_jac(lambda q: init_inverse_depth(q, rho0, p, R, R_bc, t_bc, *K)[0], uv,
                                            eps=1e-4), atol=1e-8)
    np.testing.assert_allclose(Jr, _num_jac(lambda q: init_inverse_depth(uv, q[0], p, R, R_bc, t_bc, *K)[0],
                                            [rho0]).ravel(), atol=1e-8)


@pytest.mark.parametrize("seed", range(5))
def test_imu_error_state_jacobian(seed):
    """F of the error dynamics against differences of the nominal mechanisation over a short step."""
    rng = np.random.default_rng(seed)
    g = np.array([0.0, 0.0, -1.315])
    x = VehicleState(rng.normal(0, 10, 3), exp_so3(rng.normal(0, 0.5, 3)), rng.normal(0, 3, 3),
                     rng.normal(0, 0.01, 3), rng.normal(0, 0.05, 3))
    gyro, acc = rng.normal(0, 0.2, 3), rng.normal(0, 1.0, 3) + [0, 0, 1.315]
    dt = 1e-3

    def err(xa, xb):  # error state xb - xa (body-frame attitude)
        return np.concatenate([xb.p - xa.p, log_so3(xa.R.T @ xb.R), xb.v - xa.v, xb.bg - xa.bg, xb.ba - xa.ba])

    x1, F, _ = imu_step(x, gyro, acc, dt, g)
    Phi_num = _num_jac(lambda d: err(x1, imu_step(x.boxplus(d), gyro, acc, dt, g)[0]), np.zeros(15), eps=1e-6)
    Phi = np.eye(15) + F * dt
    # first order in dt: the O(dt^2) terms are below 1e-5 here
    np.testing.assert_allclose(Phi, Phi_num, atol=2e-5)
    assert np.abs(F[IV, ITH]).max() > 0.1 and np.abs(F[ITH, IBG]).max() == 1.0 and np.abs(F[IV, IBA]).max() > 0.1


@pytest.mark.parametrize("seed", range(5))
def test_altimeter_facet_jacobians(seed):
    rng = np.random.default_rng(seed)
    p, R, _, _ = _rig(rng)
    b = R @ np.array([0, 0, -1.0])
    ground = p + b * (p[2] / -b[2])
    X = [ground + np.array([*rng.normal(0, 15, 2), rng.normal(0, 3)]) for _ in range(3)]
    h, Jx, Jk = facet_range(p, R, *X)
    # independent truth: solve the ray-plane intersection as a linear system p + s b = X1 + a e2 + c e3
    A = np.column_stack([b, -(X[1] - X[0]), -(X[2] - X[0])])
    s = np.linalg.solve(A, X[0] - p)[0]
    assert abs(h - s) < 1e-9
    np.testing.assert_allclose(Jx, _num_jac(lambda d: facet_range(*_perturbed(p, R, d), *X)[0],
                                            np.zeros(6)).ravel(), atol=1e-6)
    for k in range(3):
        def f(q, k=k):
            Y = list(X)
            Y[k] = q
            return facet_range(p, R, *Y)[0]
        np.testing.assert_allclose(Jk[k], _num_jac(f, X[k]).ravel(), atol=1e-6)
