"""Run the descent filter over a descent sequence in one mode: visible, thermal, dual or visible-64.

Modes (the memorandum's sec. 3.1, plus a control):

* ``visible`` / ``thermal``: one camera, at most 32 landmarks;
* ``dual``: both cameras' landmarks in one map, 32 each (64), after Sola et al. 2008;
* ``visible-64``: the visible camera alone with 64 landmarks -- the control that separates
  "two modalities" from "more landmarks".

Per frame: IMU propagation to each altimeter sample and to the frame time (altimeter facet updates
on the way), SIFT on each camera of the mode, active search of the mapped landmarks, 1-point RANSAC
update over all cameras' matches, deletion of landmarks that leave the image or fail too often, the
inverse-depth -> XYZ switch, and replacement of lost landmarks by spatial diversity.

The filter starts from the ground truth of the first frame perturbed by a draw from its initial
covariance (``seed``: the same draw for every mode of a trial -- common random numbers); the
initial velocity is the derivative of a quadratic through the first three ground-truth positions.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from board.descent.altimeter import beam_ground_height, inverse_depth_prior
from board.descent.ekf import DescentEKF, FilterCamera, FilterConfig
from board.descent.features import SiftDetector, active_search
from board.descent.imu_propagation import ImuNoise, VehicleState
from board.descent.landmarks import sample_new
from board.descent.quaternion import log_so3, quat_from_rot, quat_from_xyzw, quat_to_xyzw, rot_from_quat
from board.descent.ransac import Match, one_point_ransac
from board.errors import InvalidInputError

log = logging.getLogger(__name__)

#: mode -> (cameras used, landmarks per camera)
MODES: dict[str, tuple[tuple[str, ...], int]] = {
    "visible": (("visible",), 32),
    "thermal": (("thermal",), 32),
    "dual": (("visible", "thermal"), 32),
    "visible-64": (("visible",), 64),
}


@dataclass
class RunConfig:
    """Tuning of a run (units in the names)."""

    sigma_px: dict = field(default_factory=lambda: {"visible": 1.0, "thermal": 1.5})
    n_sift: int = 400
    sigma0_p_m: float = 0.5
    sigma0_theta_rad: float = 0.005
    sigma0_v_mps: float = 0.1
    sigma0_bg: float = 1e-4
    sigma0_ba: float = 1e-3
    rho_rel_sigma: float = 0.3
    image_margin_px: float = 8.0
    min_predictions: int = 4
    min_match_ratio: float = 0.5
    weighting: str = "diversity"
    use_altimeter: bool = True
    imu_glitch_mps2: float = 100.0  # specific force beyond this (~8 g on Europa's lander) is a glitch
    filter: FilterConfig = field(default_factory=FilterConfig)


@dataclass
class RunResult:
    """Per-frame output of a run: estimate (TUM rows), pose covariance, diagnostics."""

    mode: str
    tum: np.ndarray  # (n, 8) t x y z qx qy qz qw
    pose_cov: np.ndarray  # (n, 6, 6) [dp, dtheta]
    landmarks: np.ndarray  # (n,) landmarks in the map after the frame
    matched: np.ndarray  # (n,) inlier matches used in the frame
    step_ms: np.ndarray  # (n,) CPU time of the frame's filter step (ms)
    altimeter_ok: int = 0
    altimeter_gated: int = 0


def write_tum(path, rows: np.ndarray) -> None:
    """Write TUM rows ``t x y z qx qy qz qw``."""
    with open(path, "w") as f:
        for r in rows:
            f.write(" ".join(f"{v:.9f}" if i == 0 else f"{v:.6f}" for i, v in enumerate(r)) + "\n")


def filter_camera(name: str, cam, sigma_px: float) -> FilterCamera:
    m = cam.model
    return FilterCamera(name, m.width, m.height, m.fx, m.fy, m.cx, m.cy, np.asarray(cam.R_body_cam, float),
                        np.asarray(cam.t_body_cam, float), sigma_px)


def _imu_noise(meta: dict) -> ImuNoise:
    imu = meta.get("imu", {})
    try:
        return ImuNoise(float(imu["gyro_noise_rad_s_sqrt_hz"]), float(imu["accel_noise_m_s2_sqrt_hz"]),
                        float(imu["gyro_bias_rw"]), float(imu["accel_bias_rw"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidInputError(f"sequence.json imu block lacks a noise figure ({exc}); the filter needs "
                                "gyro_noise_rad_s_sqrt_hz, accel_noise_m_s2_sqrt_hz, gyro_bias_rw, accel_bias_rw") \
            from exc


def initial_state(gt: np.ndarray, cfg: RunConfig, rng: np.random.Generator) -> tuple[VehicleState, np.ndarray]:
    """Initial state (truth of frame 0 + a draw from P0) and P0 (15, 15)."""
    p = gt[0, 1:4]
    R = rot_from_quat(quat_from_xyzw(gt[0, 4:8]))
    k = min(3, gt.shape[0])
    if k >= 2:
        t = gt[:k, 0] - gt[0, 0]
        deg = min(2, k - 1)
        v = np.array([np.polyfit(t, gt[:k, 1 + a], deg)[-2] for a in range(3)])
    else:
        v = np.zeros(3)
    sig = np.concatenate([np.full(3, cfg.sigma0_p_m), np.full(3, cfg.sigma0_theta_rad), np.full(3, cfg.sigma0_v_mps),
                          np.full(3, cfg.sigma0_bg), np.full(3, cfg.sigma0_ba)])
    P0 = np.diag(sig ** 2)
    x = VehicleState(p.copy(), R.copy(), v)
    return x.boxplus(rng.normal(0.0, sig)), P0


def pose_error(tum_est_row: np.ndarray, tum_true_row: np.ndarray) -> np.ndarray:
    """[p_est - p_true, log(R_est^T R_true)] (6,): the filter's error convention (m, rad)."""
    Re = rot_from_quat(quat_from_xyzw(tum_est_row[4:8]))
    Rt = rot_from_quat(quat_from_xyzw(tum_true_row[4:8]))
    return np.concatenate([tum_est_row[1:4] - tum_true_row[1:4], log_so3(Re.T @ Rt)])


def _deglitch(imu: np.ndarray, limit_mps2: float) -> np.ndarray:
    """IMU rows with physically impossible specific forces replaced by the nearest good sample (logged)."""
    bad = np.linalg.norm(imu[:, 4:7], axis=1) > limit_mps2
    if not bad.any():
        return imu
    if bad.all():
        raise InvalidInputError(f"every IMU sample exceeds {limit_mps2} m/s2: check the accelerometer units (m/s2)")
    good = np.flatnonzero(~bad)
    out = imu.copy()
    for i in np.flatnonzero(bad):
        k = good[np.argmin(np.abs(good - i))]
        out[i, 1:7] = imu[k, 1:7]
    log.warning("%d IMU sample(s) above %.0f m/s2 replaced by their nearest good neighbour (first at t=%.3f s)",
                int(bad.sum()), limit_mps2, float(imu[np.flatnonzero(bad)[0], 0]))
    return out


class DescentNavigator:
    """The filter with its feature tracking, frame by frame."""

    def __init__(self, seq, mode: str, *, seed: int = 0, config: RunConfig | None = None) -> None:
        if mode not in MODES:
            raise InvalidInputError(f"mode {mode!r}: use one of {', '.join(MODES)}")
        self.cfg = config or RunConfig()
        self.seq = seq
        self.mode = mode
        self.cam_names, self.n_per_cam = MODES[mode]
        missing = [c for c in self.cam_names if c not in seq.cameras]
        if missing:
            raise InvalidInputError(f"mode {mode} needs the {', '.join(missing)} camera, which this sequence lacks")
        self.rng = np.random.default_rng(seed)
        self.imu = _deglitch(seq.imu, self.cfg.imu_glitch_mps2)
        x0, P0 = initial_state(seq.groundtruth, self.cfg, np.random.default_rng([seed, 7]))
        cams = {c: filter_camera(c, seq.cameras[c], self.cfg.sigma_px.get(c, 1.0)) for c in self.cam_names}
        self.ekf = DescentEKF(x0, P0, seq.gravity_w, _imu_noise(seq.meta), cams, self.cfg.filter)
        self.detectors = {c: SiftDetector(seq.cameras[c].model, n_features=self.cfg.n_sift) for c in self.cam_names}
        self.alt_sigma = float(seq.meta.get("altimeter", {}).get("sigma_m", 1.0))
        self.ground_z: float | None = None
        self.t = float(seq.frame_times[0])
        self.alt_i = 0
        self.alt_ok = 0
        self.alt_gated = 0

    # -- altimeter and propagation --------------------------------------------------------------------
    def _advance(self, t1: float) -> None:
        alt = self.seq.altimeter
        imu = self.imu
        while self.alt_i < alt.shape[0] and alt[self.alt_i, 0] <= t1 + 1e-9:
            ta, rng_m, valid = alt[self.alt_i]
            self.alt_i += 1
            if ta < self.t - 1e-9:
                continue
            self.ekf.propagate(imu, self.t, ta)
            self.t = max(self.t, ta)
            if valid and np.isfinite(rng_m) and rng_m > 0:
                self.ground_z = beam_ground_height(self.ekf.x.p, self.ekf.x.R, rng_m)
                if self.cfg.use_altimeter:
                    status, _ = self.ekf.altimeter_update(rng_m, self.alt_sigma)
                    self.alt_ok += status == "ok"
                    self.alt_gated += status == "gated"
        self.ekf.propagate(imu, self.t, t1)
        self.t = t1

    def _ground_z(self) -> float:
        if self.ground_z is not None:
            return self.ground_z
        return 0.0  # no altimeter yet: the terrain datum

    # -- one frame --------------------------------------------------------------------------------------
    def step(self, i: int) -> int:
        """Process frame ``i``; returns the number of inlier matches used."""
        t = float(self.seq.frame_times[i])
        if i > 0:
            self._advance(t)
        ekf = self.ekf
        feats = {c: self.detectors[c].detect(self.seq.load_frame(c, i)) for c in self.cam_names}
        matches: list[Match] = []
        used_kp: dict[str, set[int]] = {c: set() for c in self.cam_names}
        doomed = []
        for c in self.cam_names:
            cam = ekf.cameras[c]
            preds = []
            for lm in [lm for lm in ekf.landmarks if lm.camera == c]:
                pr = ekf.predict(lm)
                if pr is None or not (self.cfg.image_margin_px <= pr.uv[0] <= cam.width - 1 - self.cfg.image_margin_px
                                      and self.cfg.image_margin_px <= pr.uv[1]
                                      <= cam.height - 1 - self.cfg.image_margin_px):
                    doomed.append(lm)
                    continue
                preds.append(pr)
            if preds:
                pairs = active_search(np.array([p.uv for p in preds]), np.array([p.S for p in preds]),
                                      np.array([p.lm.descriptor for p in preds]), feats[c])
                for row, kp in pairs:
                    matches.append(Match(preds[row], feats[c].uv[kp]))
                    preds[row].lm.descriptor = feats[c].desc[kp]
                    used_kp[c].add(kp)
            for p in preds:
                p.lm.n_predicted += 1
        ekf.delete_landmarks(doomed)
        matches = [m for m in matches if any(m.pred.lm is lm for lm in ekf.landmarks)]
        _, inliers = one_point_ransac(ekf, matches, self.rng)
        bad = []
        for lm in ekf.landmarks:
            if lm.uid in inliers:
                lm.n_matched += 1
            if lm.n_predicted >= self.cfg.min_predictions and lm.n_matched < self.cfg.min_match_ratio * lm.n_predicted:
                bad.append(lm)
        ekf.delete_landmarks(bad)
        ekf.switch_linear_landmarks()
        self._replenish(feats, used_kp, t)
        return len(inliers)

    def _replenish(self, feats, used_kp, t: float) -> None:
        ekf = self.ekf
        for c in self.cam_names:
            mine = [lm for lm in ekf.landmarks if lm.camera == c]
            need = self.n_per_cam - len(mine)
            if need <= 0 or len(feats[c]) == 0:
                continue
            free = np.array([k for k in range(len(feats[c])) if k not in used_kp[c]], int)
            if free.size == 0:
                continue
            tracked_uv = ekf.project_all(mine) if mine else np.zeros((0, 2))
            tracked_uv = tracked_uv[np.isfinite(tracked_uv).all(axis=1)]
            cam = ekf.cameras[c]
            uv = feats[c].uv[free]
            m = self.cfg.image_margin_px * 2
            inside = (uv[:, 0] > m) & (uv[:, 0] < cam.width - 1 - m) & (uv[:, 1] > m) & (uv[:, 1] < cam.height - 1 - m)
            free, uv = free[inside], uv[inside]
            pick = sample_new(uv, tracked_uv, need, self.rng, weighting=self.cfg.weighting)
            gz = self._ground_z()
            r_cam = ekf.x.p + ekf.x.R @ cam.t_bc
            for j in pick:
                d_c = np.array([(uv[j, 0] - cam.cx) / cam.fx, (uv[j, 1] - cam.cy) / cam.fy, 1.0])
                ray = ekf.x.R @ cam.R_bc @ d_c
                ray /= np.linalg.norm(ray)
                rho, s_rho = inverse_depth_prior(r_cam, ray, gz, rel_sigma=self.cfg.rho_rel_sigma,
                                                 rho_min=ekf.cfg.rho_min)
                ekf.add_landmark(c, uv[j], rho, s_rho, descriptor=feats[c].desc[free[j]].copy(), t=t)

    def pose_row(self) -> np.ndarray:
        x = self.ekf.x
        return np.concatenate([[self.t], x.p, quat_to_xyzw(quat_from_rot(x.R))])


def run_sequence(seq, mode: str, *, seed: int = 0, config: RunConfig | None = None,
                 max_frames: int | None = None) -> RunResult:
    """Run the filter over ``seq`` (a DescentSequence or a duck-typed in-memory one) in ``mode``."""
    cv2.setNumThreads(1)
    nav = DescentNavigator(seq, mode, seed=seed, config=config)
    n = seq.frame_times.size if max_frames is None else min(int(max_frames), seq.frame_times.size)
    rows, covs, nlm, nmatch, ms = [], [], [], [], []
    for i in range(n):
        c0 = time.process_time()
        nmatch.append(nav.step(i))
        ms.append(1e3 * (time.process_time() - c0))
        rows.append(nav.pose_row())
        covs.append(nav.ekf.P[0:6, 0:6].copy())
        nlm.append(len(nav.ekf.landmarks))
    return RunResult(mode, np.array(rows), np.array(covs), np.array(nlm), np.array(nmatch), np.array(ms),
                     nav.alt_ok, nav.alt_gated)


__all__ = ["MODES", "RunConfig", "RunResult", "DescentNavigator", "run_sequence", "write_tum", "pose_error"]
