"""Error-state EKF-SLAM with inverse-depth landmarks (the memorandum's sec. 3.1, made consistent).

State: the vehicle (:mod:`board.descent.imu_propagation`, 15 error states) followed by the map, a
flat vector of landmarks, each either inverse depth (6) or Euclidean (3)
(:mod:`board.descent.inverse_depth`), tagged with the camera that observes it (``dual`` mode keeps
both cameras' landmarks in one map, after Sola et al. 2008).

Updates use the Joseph form ``P = (I - K H) P (I - K H)^T + K R K^T`` followed by symmetrisation;
a new landmark keeps its cross-covariance with the whole state (undelayed initialisation); negative
or too small inverse depths are clamped to ``rho_min``; a landmark whose linearity index falls below
``xyz_switch`` is converted to XYZ.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from board.descent.altimeter import facet_range
from board.descent.imu_propagation import N_VEHICLE, ImuNoise, VehicleState, propagate
from board.descent.inverse_depth import (
    ID_SIZE,
    XYZ_SIZE,
    camera_point_id,
    camera_point_xyz,
    id_to_xyz,
    init_inverse_depth,
    linearity_index,
    pinhole,
    ray_direction,
)
from board.errors import InvalidInputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FilterCamera:
    """One camera as the filter sees it: undistorted pinhole intrinsics (px), extrinsics, pixel noise.

    R_bc : (3, 3) rotates camera-frame (OpenCV) vectors into the body frame; t_bc : (3,) m, body frame.
    sigma_px : measurement noise of a matched feature, pixels (per axis).
    """

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    R_bc: np.ndarray
    t_bc: np.ndarray
    sigma_px: float = 1.0


@dataclass
class Landmark:
    """A mapped landmark: its place in the map vector and its track record."""

    uid: int
    camera: str
    kind: str  # "id" or "xyz"
    offset: int  # index of its first parameter in the map vector
    descriptor: np.ndarray | None = None
    n_predicted: int = 0
    n_matched: int = 0
    born_t: float = 0.0

    @property
    def size(self) -> int:
        return ID_SIZE if self.kind == "id" else XYZ_SIZE


@dataclass
class Prediction:
    """A predicted observation of one landmark: pixel (2,), compact Jacobians, innovation covariance."""

    lm: Landmark
    uv: np.ndarray
    Hx: np.ndarray  # (2, 6) wrt [dp, dtheta]
    Hy: np.ndarray  # (2, size) wrt the landmark
    S: np.ndarray  # (2, 2)
    depth_m: float


@dataclass
class FilterConfig:
    """Tuning of the filter (units in the names)."""

    rho_min: float = 1e-4  # 1/m: 10 km
    xyz_switch: float = 0.1  # linearity index below which an inverse-depth landmark becomes XYZ
    altimeter_gate_chi2: float = 6.63  # 1 dof, 99 %
    altimeter_facet_rel_sigma: float = 0.01  # facet model error, fraction of the range ...
    altimeter_facet_edge_sigma: float = 0.05  # ... plus this fraction of the facet's mean edge (terrain relief)
    facet_max_rel_depth_sigma: float = 0.1  # landmarks used for a facet: depth sigma / depth below this
    extra: dict = field(default_factory=dict)


class DescentEKF:
    """The filter: vehicle + landmark map, covariance, propagation and updates."""

    def __init__(self, x0: VehicleState, P0: np.ndarray, g_w: np.ndarray, imu_noise: ImuNoise,
                 cameras: dict[str, FilterCamera], config: FilterConfig | None = None) -> None:
        P0 = np.asarray(P0, dtype=np.float64)
        if P0.shape != (N_VEHICLE, N_VEHICLE):
            raise InvalidInputError(f"the initial covariance must be ({N_VEHICLE}, {N_VEHICLE}), got {P0.shape}")
        self.x = x0.copy()
        self.P = 0.5 * (P0 + P0.T)
        self.m = np.zeros(0)
        self.landmarks: list[Landmark] = []
        self.g_w = np.asarray(g_w, dtype=np.float64)
        self.imu_noise = imu_noise
        self.cameras = dict(cameras)
        self.cfg = config or FilterConfig()
        self._next_uid = 0

    # -- bookkeeping -------------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return N_VEHICLE + self.m.size

    def state_index(self, lm: Landmark) -> np.ndarray:
        return np.arange(N_VEHICLE + lm.offset, N_VEHICLE + lm.offset + lm.size)

    def params(self, lm: Landmark) -> np.ndarray:
        return self.m[lm.offset:lm.offset + lm.size]

    def landmark_xyz(self, lm: Landmark) -> tuple[np.ndarray, np.ndarray]:
        """World point of a landmark (m) and its Jacobian wrt its parameters."""
        y = self.params(lm)
        if lm.kind == "id":
            return id_to_xyz(y)
        return y.copy(), np.eye(3)

    def _reindex(self) -> None:
        off = 0
        for lm in self.landmarks:
            lm.offset = off
            off += lm.size

    # -- propagation -------------------------------------------------------------------------------
    def propagate(self, imu: np.ndarray, t0: float, t1: float) -> None:
        """Propagate the vehicle from ``t0`` to ``t1`` (s) with the IMU rows (t, gyro, accel)."""
        self.x, Phi, Qd = propagate(self.x, imu, t0, t1, self.g_w, self.imu_noise)
        v = slice(0, N_VEHICLE)
        P = self.P
        P[v, v] = Phi @ P[v, v] @ Phi.T + Qd
        if self.m.size:
            P[v, N_VEHICLE:] = Phi @ P[v, N_VEHICLE:]
            P[N_VEHICLE:, v] = P[v, N_VEHICLE:].T
        self.P = 0.5 * (P + P.T)

    # -- measurement model --------------------------------------------------------------------------
    def camera_point(self, lm: Landmark, x: VehicleState | None = None, y: np.ndarray | None = None):
        """``h_c`` of ``lm`` in its camera and the compact Jacobians (see inverse_depth)."""
        cam = self.cameras[lm.camera]
        x = self.x if x is None else x
        y = self.params(lm) if y is None else y
        if lm.kind == "id":
            return camera_point_id(y, x.p, x.R, cam.R_bc, cam.t_bc)
        return camera_point_xyz(y, x.p, x.R, cam.R_bc, cam.t_bc)

    def predict(self, lm: Landmark) -> Prediction | None:
        """Predicted pixel, Jacobians and innovation covariance of ``lm``; None if behind the camera."""
        cam = self.cameras[lm.camera]
        h, Jx, Jy = self.camera_point(lm)
        if h[2] <= 1e-6:
            return None
        uv, Jp = pinhole(h, cam.fx, cam.fy, cam.cx, cam.cy)
        Hx, Hy = Jp @ Jx, Jp @ Jy
        idx = np.concatenate([np.arange(6), self.state_index(lm)])
        Hc = np.hstack([Hx, Hy])
        S = Hc @ self.P[np.ix_(idx, idx)] @ Hc.T + np.eye(2) * cam.sigma_px ** 2
        depth = float(h[2] / self.params(lm)[5]) if lm.kind == "id" else float(h[2])
        return Prediction(lm, uv, Hx, Hy, 0.5 * (S + S.T), depth)

    def dense_H(self, preds: list[Prediction]) -> np.ndarray:
        """Stacked dense Jacobian (2k, n) of the predictions."""
        H = np.zeros((2 * len(preds), self.n))
        for j, pr in enumerate(preds):
            H[2 * j:2 * j + 2, 0:6] = pr.Hx
            H[2 * j:2 * j + 2, self.state_index(pr.lm)] = pr.Hy
        return H

    def project_all(self, lms: list[Landmark], x: VehicleState | None = None, m: np.ndarray | None = None
                    ) -> np.ndarray:
        """Predicted pixels (k, 2) of ``lms`` for a (possibly hypothetical) state; NaN behind the camera."""
        x = self.x if x is None else x
        m = self.m if m is None else m
        out = np.full((len(lms), 2), np.nan)
        for j, lm in enumerate(lms):
            cam = self.cameras[lm.camera]
            y = m[lm.offset:lm.offset + lm.size]
            if lm.kind == "id":
                mdir, _, _ = ray_direction(y[3], y[4])
                h = cam.R_bc.T @ (x.R.T @ (y[5] * (y[0:3] - x.p) + mdir) - y[5] * cam.t_bc)
            else:
                h = cam.R_bc.T @ (x.R.T @ (y - x.p) - cam.t_bc)
            if h[2] > 1e-6:
                out[j] = (cam.fx * h[0] / h[2] + cam.cx, cam.fy * h[1] / h[2] + cam.cy)
        return out

    # -- update ---------------------------------------------------------------------------------------
    def correction(self, r: np.ndarray, H: np.ndarray, R: np.ndarray) -> np.ndarray:
        """The state correction ``K r`` of an update, without touching the covariance (for RANSAC)."""
        PHt = self.P @ H.T
        S = H @ PHt + R
        return PHt @ np.linalg.solve(S, r)

    def apply_correction(self, dx: np.ndarray, x: VehicleState | None = None, m: np.ndarray | None = None
                         ) -> tuple[VehicleState, np.ndarray]:
        """``(x, m)`` corrected by ``dx`` (inverse depths clamped to ``rho_min``); the filter is unchanged."""
        x = self.x if x is None else x
        m = (self.m if m is None else m) + dx[N_VEHICLE:]
        for lm in self.landmarks:
            if lm.kind == "id" and m[lm.offset + 5] < self.cfg.rho_min:
                m[lm.offset + 5] = self.cfg.rho_min
        return x.boxplus(dx[:N_VEHICLE]), m

    def update(self, r: np.ndarray, H: np.ndarray, R: np.ndarray) -> float:
        """EKF update with the residual ``r`` (k,), Jacobian ``H`` (k, n) and noise ``R`` (k, k), Joseph form.

        Returns the normalised innovation squared ``r^T S^-1 r``.
        """
        P = self.P
        PHt = P @ H.T
        S = H @ PHt + R
        S = 0.5 * (S + S.T)
        K = np.linalg.solve(S, PHt.T).T
        nis = float(r @ np.linalg.solve(S, r))
        dx = K @ r
        IKH = -K @ H
        IKH[np.diag_indices_from(IKH)] += 1.0
        P = IKH @ P @ IKH.T + K @ R @ K.T
        self.P = 0.5 * (P + P.T)
        self.x, self.m = self.apply_correction(dx)
        return nis

    # -- map management -------------------------------------------------------------------------------
    def add_landmark(self, camera: str, uv: np.ndarray, rho0: float, sigma_rho: float, *,
                     descriptor: np.ndarray | None = None, t: float = 0.0) -> Landmark:
        """Undelayed inverse-depth initialisation of a landmark seen at undistorted pixel ``uv``."""
        cam = self.cameras[camera]
        y, Jx, Jz, Jrho = init_inverse_depth(np.asarray(uv, float), rho0, self.x.p, self.x.R, cam.R_bc, cam.t_bc,
                                             cam.fx, cam.fy, cam.cx, cam.cy)
        n = self.n
        Pxa = self.P[0:6, :]  # rows of [dp, dtheta] against the whole state
        P_yx = Jx @ Pxa  # (6, n)
        P_yy = Jx @ self.P[0:6, 0:6] @ Jx.T + (cam.sigma_px ** 2) * Jz @ Jz.T + sigma_rho ** 2 * np.outer(Jrho, Jrho)
        P = np.zeros((n + ID_SIZE, n + ID_SIZE))
        P[:n, :n] = self.P
        P[n:, :n] = P_yx
        P[:n, n:] = P_yx.T
        P[n:, n:] = 0.5 * (P_yy + P_yy.T)
        self.P = P
        lm = Landmark(self._next_uid, camera, "id", self.m.size, descriptor, born_t=t)
        self._next_uid += 1
        self.m = np.concatenate([self.m, y])
        self.landmarks.append(lm)
        return lm

    def delete_landmarks(self, doomed: list[Landmark]) -> None:
        """Remove landmarks (and their rows and columns of P)."""
        if not doomed:
            return
        ids = {lm.uid for lm in doomed}
        drop = np.concatenate([self.state_index(lm) for lm in self.landmarks if lm.uid in ids])
        keep = np.setdiff1d(np.arange(self.n), drop)
        self.P = self.P[np.ix_(keep, keep)]
        self.m = np.delete(self.m, drop - N_VEHICLE)
        self.landmarks = [lm for lm in self.landmarks if lm.uid not in ids]
        self._reindex()

    def to_xyz(self, lm: Landmark) -> None:
        """Replace an inverse-depth landmark by its XYZ form (covariance transformed by the Jacobian)."""
        if lm.kind != "id":
            return
        blk = self.state_index(lm)
        X, J = id_to_xyz(self.params(lm))
        A = J @ self.P[blk, :]  # (3, n)
        Pbb = A[:, blk] @ J.T
        P = self.P
        P[blk[:3], :] = A
        P[:, blk[:3]] = A.T
        P[np.ix_(blk[:3], blk[:3])] = Pbb
        keep = np.setdiff1d(np.arange(self.n), blk[3:])
        self.P = P[np.ix_(keep, keep)]
        self.m = np.delete(self.m, blk[3:] - N_VEHICLE)
        self.m[lm.offset:lm.offset + 3] = X
        lm.kind = "xyz"
        self._reindex()

    def switch_linear_landmarks(self) -> int:
        """Convert every inverse-depth landmark whose linearity index is below the threshold; returns how many."""
        n = 0
        for lm in list(self.landmarks):
            if lm.kind != "id":
                continue
            cam = self.cameras[lm.camera]
            i = N_VEHICLE + lm.offset + 5
            r_cam = self.x.p + self.x.R @ cam.t_bc
            if linearity_index(self.params(lm), float(np.sqrt(max(self.P[i, i], 0.0))), r_cam) < self.cfg.xyz_switch:
                self.to_xyz(lm)
                n += 1
        return n

    def depth_rel_sigma(self, lm: Landmark) -> float:
        """Relative sigma of the landmark's depth (sigma_rho / rho for inverse depth; sigma_d / d for XYZ)."""
        blk = self.state_index(lm)
        if lm.kind == "id":
            rho = self.params(lm)[5]
            return float(np.sqrt(max(self.P[blk[5], blk[5]], 0.0)) / rho)
        X = self.params(lm)
        d = X - self.x.p
        dist = float(np.linalg.norm(d))
        u = d / max(dist, 1e-9)
        return float(np.sqrt(max(u @ self.P[np.ix_(blk, blk)] @ u, 0.0)) / max(dist, 1e-9))

    # -- altimeter --------------------------------------------------------------------------------------
    def altimeter_update(self, range_m: float, sigma_m: float) -> tuple[str, float]:
        """Facet altimeter update (:mod:`board.descent.altimeter`), chi-square gated.

        Returns ``(status, nis)`` with status ``"ok"``, ``"gated"`` or ``"no_facet"``.
        """
        cand = [lm for lm in self.landmarks if self.depth_rel_sigma(lm) < self.cfg.facet_max_rel_depth_sigma]
        if len(cand) < 3:
            return "no_facet", float("nan")
        b = self.x.R @ np.array([0.0, 0.0, -1.0])
        pts = []
        for lm in cand:
            X, J = self.landmark_xyz(lm)
            d = X - self.x.p
            off = float(np.linalg.norm(d - (d @ b) * b))  # distance from the beam line
            pts.append((off, lm, X, J))
        pts.sort(key=lambda t: t[0])
        chosen = self._facet_triangle(pts, b)
        if chosen is None:
            return "no_facet", float("nan")
        (_, l1, X1, J1), (_, l2, X2, J2), (_, l3, X3, J3) = chosen
        h, Jx, Jk = facet_range(self.x.p, self.x.R, X1, X2, X3)
        if not np.isfinite(h) or h <= 0:
            return "no_facet", float("nan")
        H = np.zeros((1, self.n))
        H[0, 0:6] = Jx
        for lm, Jxyz, Jpt in ((l1, J1, Jk[0]), (l2, J2, Jk[1]), (l3, J3, Jk[2])):
            H[0, self.state_index(lm)] += Jpt @ Jxyz
        edge = (np.linalg.norm(X2 - X1) + np.linalg.norm(X3 - X2) + np.linalg.norm(X1 - X3)) / 3.0
        var = sigma_m ** 2 + (self.cfg.altimeter_facet_rel_sigma * h) ** 2 + (self.cfg.altimeter_facet_edge_sigma
                                                                             * edge) ** 2
        R = np.array([[var]])
        r = np.array([range_m - h])
        S = float(H @ self.P @ H.T + var)
        nis = float(r[0] ** 2 / S)
        if nis > self.cfg.altimeter_gate_chi2:
            return "gated", nis
        self.update(r, H, R)
        return "ok", nis

    def _facet_triangle(self, pts: list, b: np.ndarray):
        """The first triangle (of the landmarks nearest the beam) whose plane the beam meets inside it."""
        near = pts[:8]
        for i in range(len(near)):
            for j in range(i + 1, len(near)):
                for k in range(j + 1, len(near)):
                    X1, X2, X3 = near[i][2], near[j][2], near[k][2]
                    n = np.cross(X2 - X1, X3 - X1)
                    D = float(n @ b)
                    area = 0.5 * float(np.linalg.norm(n))
                    if area < 1.0 or abs(D) < 0.3 * 2 * area:
                        continue
                    s = float(n @ (X1 - self.x.p)) / D
                    q = self.x.p + s * b
                    # barycentric inside test
                    c1 = np.cross(X2 - X1, q - X1) @ n
                    c2 = np.cross(X3 - X2, q - X2) @ n
                    c3 = np.cross(X1 - X3, q - X3) @ n
                    if (c1 >= 0 and c2 >= 0 and c3 >= 0) or (c1 <= 0 and c2 <= 0 and c3 <= 0):
                        return near[i], near[j], near[k]
        return None
