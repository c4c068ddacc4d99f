"""SIFT features and the filter-guided active search (the memorandum's sec. 3.2, with a careful matcher).

Images are converted to 8-bit grey only (a 16-bit radiometric frame is stretched linearly between its
0.5 and 99.5 percentiles: no other pre-processing, as in the memorandum).  Keypoints are returned as
undistorted pixel coordinates of the camera's pinhole (``K`` of :class:`board.camera.CameraModel`,
distortion removed), the frame the filter's measurement model works in.

Matching a landmark is an active search (Davison 2007): only keypoints inside the 3-sigma ellipse of
its predicted pixel (``d^2 = r^T S^-1 r <= 9``) are candidates; among them the nearest descriptor wins
if it passes Lowe's ratio test against the second nearest and an absolute distance bound.  No
matching across the two cameras.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from board.camera import CameraModel
from board.errors import InvalidInputError


def to_gray8(img: np.ndarray) -> np.ndarray:
    """8-bit grey version of a stored frame (uint8 as is; uint16 linearly stretched, 0.5-99.5 percentiles)."""
    img = np.asarray(img)
    if img.ndim != 2:
        raise InvalidInputError(f"a frame must be a 2-D grey image, got shape {img.shape}")
    if img.dtype == np.uint8:
        return img
    f = img.astype(np.float32)
    lo, hi = np.percentile(f, (0.5, 99.5))
    if hi <= lo:
        return np.zeros(img.shape, np.uint8)
    return np.clip((f - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


@dataclass
class Features:
    """Keypoints of one frame: undistorted pixels (k, 2) and SIFT descriptors (k, 128) float32."""

    uv: np.ndarray
    desc: np.ndarray

    def __len__(self) -> int:
        return int(self.uv.shape[0])


class SiftDetector:
    """OpenCV SIFT on the grey frame, keypoints undistorted with the camera model."""

    def __init__(self, camera: CameraModel, *, n_features: int = 500, contrast_threshold: float = 0.02) -> None:
        self.camera = camera
        self.sift = cv2.SIFT_create(nfeatures=int(n_features), contrastThreshold=float(contrast_threshold))

    def detect(self, img: np.ndarray) -> Features:
        g = to_gray8(img)
        if g.shape != (self.camera.height, self.camera.width):
            raise InvalidInputError(f"frame shape {g.shape} does not match the camera "
                                    f"({self.camera.width}x{self.camera.height})")
        kps, desc = self.sift.detectAndCompute(g, None)
        if not kps:
            return Features(np.zeros((0, 2)), np.zeros((0, 128), np.float32))
        uv = np.array([k.pt for k in kps], dtype=np.float64)
        if self.camera.has_distortion:
            c = self.camera
            x, y = c.undistort((uv[:, 0] - c.cx) / c.fx, (uv[:, 1] - c.cy) / c.fy)
            uv = np.column_stack([c.fx * x + c.cx, c.fy * y + c.cy])
            ok = np.isfinite(uv).all(axis=1)
            uv, desc = uv[ok], desc[ok]
        return Features(uv, desc.astype(np.float32))


def active_search(pred_uv: np.ndarray, pred_S: np.ndarray, lm_desc: np.ndarray, feats: Features, *,
                  chi2_gate: float = 9.0, ratio: float = 0.8, max_desc_dist: float = 300.0
                  ) -> list[tuple[int, int]]:
    """Match predicted landmarks to keypoints; returns ``(landmark_row, keypoint_index)`` pairs.

    pred_uv : (m, 2) predicted pixels; pred_S : (m, 2, 2) innovation covariances (px^2);
    lm_desc : (m, 128) the landmarks' descriptors.  A keypoint is given to one landmark only (the one
    with the smaller descriptor distance).
    """
    m = pred_uv.shape[0]
    if m == 0 or len(feats) == 0:
        return []
    Sinv = np.linalg.inv(pred_S)  # (m, 2, 2)
    r = feats.uv[None, :, :] - pred_uv[:, None, :]  # (m, k, 2)
    d2 = np.einsum("mki,mij,mkj->mk", r, Sinv, r)
    inside = d2 <= chi2_gate
    best: dict[int, tuple[int, float]] = {}
    for i in np.flatnonzero(inside.any(axis=1)):
        cand = np.flatnonzero(inside[i])
        dd = np.linalg.norm(feats.desc[cand] - lm_desc[i][None, :], axis=1)
        order = np.argsort(dd)
        d1 = dd[order[0]]
        if d1 > max_desc_dist:
            continue
        if cand.size > 1 and d1 > ratio * dd[order[1]]:
            continue
        kp = int(cand[order[0]])
        if kp not in best or d1 < best[kp][1]:
            best[kp] = (int(i), float(d1))
    return sorted((i, kp) for kp, (i, _) in best.items())
