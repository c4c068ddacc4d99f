"""Rotations for the descent filter: skew matrices, the SO(3) exponential/logarithm, quaternions.

Quaternions are Hamilton quaternions stored as ``(w, x, y, z)`` (scalar first) in this package and
written ``qx qy qz qw`` in TUM files (:func:`quat_to_xyzw`).  A quaternion ``q_wb`` represents the
rotation matrix ``R_world_body`` (it rotates body-frame vectors into the world frame).

The filter's attitude error is multiplicative and expressed in the body frame:
``R_true = R_est @ exp_so3(dtheta)`` (``dtheta`` in rad, body axes).
"""
from __future__ import annotations

import numpy as np

from board.errors import InvalidInputError


def skew(v: np.ndarray) -> np.ndarray:
    """(3, 3) cross-product matrix: ``skew(a) @ b == np.cross(a, b)``."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``phi`` (rad, axis * angle) by Rodrigues' formula."""
    phi = np.asarray(phi, dtype=np.float64)
    a = float(np.linalg.norm(phi))
    K = skew(phi)
    if a < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + (np.sin(a) / a) * K + ((1.0 - np.cos(a)) / (a * a)) * K @ K


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of the rotation matrix ``R`` (inverse of :func:`exp_so3`, angle in [0, pi])."""
    q = quat_from_rot(R)
    w, v = q[0], q[1:]
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        return 2.0 * v
    angle = 2.0 * np.arctan2(s, w)
    return angle * v / s


def quat_from_rot(R: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` with ``w >= 0`` of the rotation matrix ``R`` (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3):
        raise InvalidInputError(f"a rotation matrix is (3, 3), got {R.shape}")
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def rot_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of the quaternion ``(w, x, y, z)`` (normalised first)."""
    q = np.asarray(q, dtype=np.float64)
    n = float(np.linalg.norm(q))
    if not np.isfinite(n) or n < 1e-9:
        raise InvalidInputError(f"quaternion {q} has no direction (norm {n}); it must be a non-zero (w, x, y, z)")
    w, x, y, z = q / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def quat_to_xyzw(q: np.ndarray) -> np.ndarray:
    """``(w, x, y, z)`` -> ``(x, y, z, w)`` (the TUM order)."""
    q = np.asarray(q, dtype=np.float64)
    return np.array([q[1], q[2], q[3], q[0]])


def quat_from_xyzw(q: np.ndarray) -> np.ndarray:
    """``(x, y, z, w)`` (the TUM order) -> ``(w, x, y, z)``."""
    q = np.asarray(q, dtype=np.float64)
    return np.array([q[3], q[0], q[1], q[2]])


def orthonormalise(R: np.ndarray) -> np.ndarray:
    """The rotation matrix nearest to ``R`` (SVD), to undo round-off after many products."""
    U, _, Vt = np.linalg.svd(R)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt
