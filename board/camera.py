"""Calibrated camera model (Brown-Conrady distortion) and pan-tilt geometry.

Frames
------
Camera frame (OpenCV): x right, y down, z forward (optical axis).
Pixel coordinates ``(u, v)``: column and row, the centre of the top-left pixel is
``(0, 0)`` (OpenCV convention), so an ideal centred camera has ``cx = (width - 1) / 2``.
Body frame (:mod:`board.conventions`): x forward, y left, z up.

Pan-tilt composition (defined here, once)
-----------------------------------------
At pan 0, tilt 0 the optical axis is the body's x axis (forward), image right is the
body's -y axis and image down is the body's -z axis.  The pan axis is fixed to the body
(its z axis); the tilt axis rides on the pan stage::

    R_body_from_cam(pan, tilt) = Rz_cw(pan) @ R_up(tilt) @ R0

with ``R0`` the fixed camera-to-body axis swap, ``Rz_cw(pan)`` a rotation of ``pan``
degrees clockwise seen from above (pan 90 looks right of forward) and ``R_up(tilt)`` a
rotation about the body's left axis that lifts the optical axis by ``tilt`` degrees.
ENU directions follow with :func:`board.conventions.rotation_enu_from_camera`
(heading, pitch, roll of the body)::

    R_enu_from_cam = rotation_enu_from_camera(heading, pitch, roll) @ R_body_from_cam(pan, tilt)

so with heading 0 and level body, pan 90 looks east and tilt 10 looks 10 degrees up.
"""
from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass

import numpy as np

from board.conventions import az_el_from_enu_deg, enu_from_az_el_deg, rotation_enu_from_camera
from board.errors import FormatError, InvalidInputError

log = logging.getLogger(__name__)

#: Fixed axis swap: columns are the camera x (right), y (down), z (forward) axes in the body frame.
R_BODY_FROM_CAM0 = np.array([[0.0, 0.0, 1.0],
                             [-1.0, 0.0, 0.0],
                             [0.0, -1.0, 0.0]])

_DIST_KEYS = ("k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class CameraModel:
    """Pinhole camera with Brown-Conrady (OpenCV 5-parameter) distortion.

    width, height : image size, pixels
    fx, fy : focal lengths, pixels
    cx, cy : principal point, pixels (centre of the top-left pixel is (0, 0))
    k1, k2, k3 : radial distortion coefficients; p1, p2 : tangential coefficients
    (OpenCV's ``distCoeffs = (k1, k2, p1, p2, k3)`` on normalised coordinates).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    def __post_init__(self) -> None:
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise InvalidInputError(f"camera size {self.width}x{self.height} px: width and height must be positive")
        if not (self.fx > 0 and self.fy > 0):
            raise InvalidInputError(f"camera focal lengths fx={self.fx}, fy={self.fy} px must be positive")
        for name in ("cx", "cy", *_DIST_KEYS):
            if not math.isfinite(float(getattr(self, name))):
                raise InvalidInputError(f"camera parameter {name}={getattr(self, name)} must be a finite number")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # -- construction / serialisation -------------------------------------------------------
    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float, *, k1: float = 0.0, k2: float = 0.0,
                 p1: float = 0.0, p2: float = 0.0, k3: float = 0.0) -> "CameraModel":
        """Centred camera with square pixels and horizontal field of view ``hfov_deg`` (degrees, edge to edge)."""
        if not (0.0 < hfov_deg < 180.0):
            raise InvalidInputError(f"horizontal field of view {hfov_deg} deg must be in (0, 180)")
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, k1, k2, p1, p2, k3)

    def to_dict(self) -> dict:
        return {k: (int(v) if k in ("width", "height") else float(v)) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict, where: str = "camera") -> "CameraModel":
        try:
            return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]), float(d["cx"]),
                       float(d["cy"]), *(float(d.get(k, 0.0)) for k in _DIST_KEYS))
        except (KeyError, TypeError, ValueError) as exc:
            raise FormatError(f"{where}: malformed camera model ({exc!r}); it needs width, height, fx, fy, cx, cy "
                              "and optionally k1, k2, p1, p2, k3") from exc

    @property
    def dist_coeffs(self) -> np.ndarray:
        """OpenCV order (k1, k2, p1, p2, k3)."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    @property
    def matrix(self) -> np.ndarray:
        """3x3 intrinsic matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(getattr(self, k) != 0.0 for k in _DIST_KEYS)

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view of the undistorted pinhole, degrees (edge to edge)."""
        return 2.0 * math.degrees(math.atan((self.width / 2.0) / self.fx))

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view of the undistorted pinhole, degrees (edge to edge)."""
        return 2.0 * math.degrees(math.atan((self.height / 2.0) / self.fy))

    # -- distortion on normalised coordinates ----------------------------------------------
    def distort(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Apply distortion to ideal normalised coordinates ``(x, y) = (X/Z, Y/Z)``."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return xd, yd

    def _radially_monotonic(self, r2: np.ndarray) -> np.ndarray:
        """True where the radial model is still one-to-one (d(r * radial)/dr > 0)."""
        return 1.0 + r2 * (3.0 * self.k1 + r2 * (5.0 * self.k2 + r2 * 7.0 * self.k3)) > 0.0

    def undistort(self, xd, yd, *, iterations: int = 20, tol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
        """Invert :meth:`distort` by Newton iterations (vectorised); NaN where it does not converge."""
        xd = np.asarray(xd, dtype=np.float64)
        yd = np.asarray(yd, dtype=np.float64)
        if not self.has_distortion:
            return xd.copy(), yd.copy()
        k1, k2, k3, p1, p2 = self.k1, self.k2, self.k3, self.p1, self.p2
        x = xd.copy()
        y = yd.copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)      # d radial / d r2
            fx_ = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
            fy_ = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
            j11 = radial + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
            j12 = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
            j21 = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
            j22 = radial + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
            det = j11 * j22 - j12 * j21
            dx = (j22 * fx_ - j12 * fy_) / det
            dy = (-j21 * fx_ + j11 * fy_) / det
            x = x - dx
            y = y - dy
            if np.all(~np.isfinite(dx) | (np.abs(dx) + np.abs(dy) < tol)):
                break
        ex, ey = self.distort(x, y)
        bad = ~(np.abs(ex - xd) + np.abs(ey - yd) < 1e-9) | ~self._radially_monotonic(x * x + y * y)
        return np.where(bad, np.nan, x), np.where(bad, np.nan, y)

    # -- pixels <-> rays ----------------------------------------------------------------------
    def project(self, dirs_cam) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates ``(u, v)`` of camera-frame directions ``dirs_cam`` (..., 3).

        NaN for directions behind the camera (z <= 0) or beyond the range where the
        distortion model is one-to-one.  Points outside the image are returned as is;
        test them with :meth:`in_image`.
        """
        d = np.asarray(dirs_cam, dtype=np.float64)
        if d.shape[-1] != 3:
            raise InvalidInputError(f"directions must have shape (..., 3), got {d.shape}")
        z = d[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(z > 0, d[..., 0] / z, np.nan)
            y = np.where(z > 0, d[..., 1] / z, np.nan)
        xd, yd = self.distort(x, y)
        ok = self._radially_monotonic(x * x + y * y)
        u = np.where(ok, self.fx * xd + self.cx, np.nan)
        v = np.where(ok, self.fy * yd + self.cy, np.nan)
        return u, v

    def unproject(self, u, v) -> np.ndarray:
        """Unit camera-frame directions (..., 3) of pixel coordinates ``(u, v)``; NaN where not invertible."""
        xd = (np.asarray(u, dtype=np.float64) - self.cx) / self.fx
        yd = (np.asarray(v, dtype=np.float64) - self.cy) / self.fy
        x, y = self.undistort(xd, yd)
        d = np.stack(np.broadcast_arrays(x, y, np.ones_like(x)), axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def in_image(self, u, v, *, margin: float = 0.0) -> np.ndarray:
        """True where ``(u, v)`` lies inside the image (pixel centres from 0 to size - 1), less ``margin`` px."""
        u = np.asarray(u)
        v = np.asarray(v)
        return ((u >= -0.5 + margin) & (u <= self.width - 0.5 - margin)
                & (v >= -0.5 + margin) & (v <= self.height - 0.5 - margin))

    def pixel_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """``(u, v)`` of every pixel centre, each (height, width)."""
        return np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))


# -- pan-tilt geometry -----------------------------------------------------------------------
def rotation_pan_cw(pan_deg: float) -> np.ndarray:
    """Rotation about the body's z (up) axis by ``pan_deg`` clockwise seen from above."""
    p = math.radians(pan_deg)
    c, s = math.cos(p), math.sin(p)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_tilt_up(tilt_deg: float) -> np.ndarray:
    """Rotation about the body's y (left) axis lifting the x (forward) axis by ``tilt_deg``."""
    t = math.radians(tilt_deg)
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def rotation_body_from_camera(pan_deg: float, tilt_deg: float) -> np.ndarray:
    """(3, 3) rotation taking camera-frame vectors to the body frame for a pan-tilt setting (degrees)."""
    return rotation_pan_cw(pan_deg) @ rotation_tilt_up(tilt_deg) @ R_BODY_FROM_CAM0


def rotation_enu_from_frame(pan_deg: float, tilt_deg: float, *, heading_deg: float = 0.0,
                            pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """(3, 3) rotation camera frame -> ENU for a pan-tilt setting and a body attitude (degrees)."""
    return rotation_enu_from_camera(heading_deg, pitch_deg, roll_deg) @ rotation_body_from_camera(pan_deg, tilt_deg)


def camera_to_body(dirs_cam, pan_deg: float, tilt_deg: float) -> np.ndarray:
    """Camera-frame directions (..., 3) expressed in the body frame."""
    return np.asarray(dirs_cam, dtype=np.float64) @ rotation_body_from_camera(pan_deg, tilt_deg).T


def pixel_to_az_el(camera: CameraModel, u, v, pan_deg: float, tilt_deg: float, *, heading_deg: float = 0.0,
                   pitch_deg: float = 0.0, roll_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (degrees, ENU) seen by pixel ``(u, v)`` of a frame taken at ``pan``/``tilt``.

    With the default heading 0 the azimuth is relative to the heading (the rover's skyline frame).
    """
    R = rotation_enu_from_frame(pan_deg, tilt_deg, heading_deg=heading_deg, pitch_deg=pitch_deg, roll_deg=roll_deg)
    return az_el_from_enu_deg(camera.unproject(u, v) @ R.T)


def az_el_to_pixel(camera: CameraModel, az_deg, el_deg, pan_deg: float, tilt_deg: float, *,
                   heading_deg: float = 0.0, pitch_deg: float = 0.0,
                   roll_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Pixel ``(u, v)`` where the direction ``(az, el)`` (degrees, ENU) lands in a frame at ``pan``/``tilt``.

    NaN behind the camera; points outside the image are returned as is (see :meth:`CameraModel.in_image`).
    """
    R = rotation_enu_from_frame(pan_deg, tilt_deg, heading_deg=heading_deg, pitch_deg=pitch_deg, roll_deg=roll_deg)
    return camera.project(enu_from_az_el_deg(az_deg, el_deg) @ R)
