"""Panorama building: frames projected through the camera model and the pan-tilt angles.

Every panorama pixel is a direction (azimuth relative to the heading, elevation above the
horizontal of the levelled body, degrees); each frame that sees it contributes its
bilinearly-sampled value, weighted by the distance to the frame's border (feathered seams).
Frame order and absolute azimuth come from the pan-tilt unit, never from feature matching, so
the panorama cannot be assembled out of order.  Pixels no frame sees are marked unseen
(``Panorama.seen``), never filled.  The grid is always the full circle (column 0 at azimuth
``step / 2``), so the 360-degree wrap needs no special case.

Optional refinement (``refine_yaw=True``) for pan-tilt units with about a degree of error:
neighbouring frames are warped onto the grid, their overlap is phase-correlated for the
azimuth shift, and per-frame pan corrections are solved by least squares with the unit's
angles as prior (``pan_sigma_deg``), so a featureless overlap changes nothing.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from board.acquisition import Acquisition, Panorama, PanoramaGeometry, load_acquisition
from board.camera import CameraModel, az_el_to_pixel, pixel_to_az_el
from board.errors import InvalidInputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FrameFootprint:
    """Azimuth interval (start, width; degrees, wrapped start) and elevation range a frame covers."""

    az_start_deg: float
    az_width_deg: float
    el_min_deg: float
    el_max_deg: float


def frame_footprint(camera: CameraModel, pan_deg: float, tilt_deg: float, *, pitch_deg: float = 0.0,
                    roll_deg: float = 0.0, samples: int = 64) -> FrameFootprint:
    """Directions covered by a frame, from rays through its border (degrees).

    A frame containing the zenith or nadir covers every azimuth (width 360).
    """
    t = np.linspace(0.0, 1.0, samples)
    w, h = camera.width - 1.0, camera.height - 1.0
    u = np.concatenate([t * w, np.full(samples, w), t * w, np.zeros(samples)]) + 0.0
    v = np.concatenate([np.zeros(samples), t * h, np.full(samples, h), t * h])
    az, el = pixel_to_az_el(camera, u, v, pan_deg, tilt_deg, pitch_deg=pitch_deg, roll_deg=roll_deg)
    ok = np.isfinite(az)
    if not ok.any():
        raise InvalidInputError("the camera model maps no border pixel to a direction: check its distortion")
    az, el = az[ok], el[ok]
    # does the frame contain a pole?  then it covers every azimuth
    for pole in (90.0, -90.0):
        uu, vv = az_el_to_pixel(camera, 0.0, pole, pan_deg, tilt_deg, pitch_deg=pitch_deg, roll_deg=roll_deg)
        if np.isfinite(uu) and camera.in_image(uu, vv):
            return FrameFootprint(0.0, 360.0, float(min(el.min(), pole)), float(max(el.max(), pole)))
    # smallest arc containing all border azimuths: the complement of the largest gap
    a = np.sort(np.mod(az, 360.0))
    gaps = np.diff(np.concatenate([a, [a[0] + 360.0]]))
    k = int(np.argmax(gaps))
    start = a[(k + 1) % a.size]
    width = 360.0 - gaps[k]
    return FrameFootprint(float(start), float(width), float(el.min()), float(el.max()))


def panorama_geometry_for(acq: Acquisition, *, azimuth_step_deg: float | None = None,
                          elevation_range_deg: tuple[float, float] | None = None,
                          max_height_px: int = 4000) -> PanoramaGeometry:
    """Full-circle grid for an acquisition: native resolution of the camera unless ``azimuth_step_deg``
    is given (degrees per pixel, both axes), elevation range spanning every frame unless given."""
    step = azimuth_step_deg if azimuth_step_deg else math.degrees(1.0 / max(acq.camera.fx, acq.camera.fy))
    width = int(math.ceil(360.0 / step))
    step = 360.0 / width
    if elevation_range_deg is None:
        pitch, roll = acq.attitude or (0.0, 0.0)
        fps = [frame_footprint(acq.camera, f.pan_deg, f.tilt_deg, pitch_deg=pitch, roll_deg=roll)
               for f in acq.frames]
        lo = max(-89.9, min(fp.el_min_deg for fp in fps))
        hi = min(89.9, max(fp.el_max_deg for fp in fps))
    else:
        lo, hi = sorted(elevation_range_deg)
    height = int(math.ceil((hi - lo) / step))
    if height > max_height_px:
        raise InvalidInputError(f"the panorama would be {height} px tall: pass a coarser azimuth_step_deg or a "
                                "narrower elevation_range_deg")
    top = lo + height * step
    return PanoramaGeometry(width, height, step / 2.0, step, top - step / 2.0, step, "heading", "intensity")


def _columns_of(fp: FrameFootprint, geom: PanoramaGeometry, pad_deg: float) -> np.ndarray:
    if fp.az_width_deg + 2 * pad_deg >= 360.0:
        return np.arange(geom.width)
    az = geom.azimuths_deg()
    rel = np.mod(az - (fp.az_start_deg - pad_deg), 360.0)
    return np.flatnonzero(rel <= fp.az_width_deg + 2 * pad_deg)


def warp_frame(image: np.ndarray, camera: CameraModel, pan_deg: float, tilt_deg: float, geom: PanoramaGeometry,
               *, pitch_deg: float = 0.0, roll_deg: float = 0.0, columns: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample one frame onto the panorama grid.

    Returns (columns, values (H, n[, C]) float32, weights (H, n) float32); weight 0 outside the frame,
    growing linearly (per pixel) from the frame's border so overlapping frames blend without seams.
    """
    import cv2

    if columns is None:
        fp = frame_footprint(camera, pan_deg, tilt_deg, pitch_deg=pitch_deg, roll_deg=roll_deg)
        columns = _columns_of(fp, geom, 2.0 * geom.azimuth_step_deg)
    az = geom.azimuths_deg()[columns][None, :]
    el = geom.elevations_deg()[:, None]
    u, v = az_el_to_pixel(camera, az, el, pan_deg, tilt_deg, pitch_deg=pitch_deg, roll_deg=roll_deg)
    inside = np.isfinite(u) & camera.in_image(np.nan_to_num(u, nan=-10), np.nan_to_num(v, nan=-10))
    mx = np.where(inside, u, -10.0).astype(np.float32)
    my = np.where(inside, v, -10.0).astype(np.float32)
    src = image.astype(np.float32)
    vals = cv2.remap(src, mx, my, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    edge = np.minimum.reduce([mx + 0.5, camera.width - 0.5 - mx, my + 0.5, camera.height - 0.5 - my])
    wgt = np.where(inside, np.clip(edge, 0.0, None) + 1e-3, 0.0).astype(np.float32)
    return columns, vals, wgt


def build_panorama(acq: Acquisition | str, *, azimuth_step_deg: float | None = None,
                   elevation_range_deg: tuple[float, float] | None = None, refine_yaw: bool = False,
                   pan_sigma_deg: float = 1.0, max_yaw_correction_deg: float = 3.0,
                   progress=None) -> Panorama:
    """Project every frame of an acquisition onto a full-circle azimuth/elevation grid.

    acq : an Acquisition or its folder.  Azimuths are relative to the heading (pan 0); the body is
    levelled with the acquisition's measured attitude when it has one.  ``refine_yaw`` corrects the
    pan angles by feature matching (see the module docstring); the corrections are stored in
    ``Panorama.meta["pan_corrections_deg"]``.  ``progress`` : optional callable(i, n).
    """
    if not isinstance(acq, Acquisition):
        acq = load_acquisition(acq)
    geom = panorama_geometry_for(acq, azimuth_step_deg=azimuth_step_deg, elevation_range_deg=elevation_range_deg)
    pitch, roll = acq.attitude or (0.0, 0.0)
    images = [acq.read_frame(i) for i in range(len(acq.frames))]
    pans = np.array([f.pan_deg for f in acq.frames], dtype=np.float64)
    tilts = np.array([f.tilt_deg for f in acq.frames], dtype=np.float64)
    meta: dict = {"n_frames": len(images), "attitude_used": [pitch, roll]}
    if refine_yaw and len(images) > 1:
        corr = refine_pan_angles(images, acq.camera, pans, tilts, geom, pitch_deg=pitch, roll_deg=roll,
                                 pan_sigma_deg=pan_sigma_deg, max_correction_deg=max_yaw_correction_deg)
        pans = pans + corr
        meta["pan_corrections_deg"] = [round(float(c), 4) for c in corr]
    first = images[0]
    chans = () if first.ndim == 2 else (first.shape[2],)
    acc = np.zeros((geom.height, geom.width, *chans), dtype=np.float32)
    wsum = np.zeros((geom.height, geom.width), dtype=np.float32)
    for i, img in enumerate(images):
        cols, vals, wgt = warp_frame(img, acq.camera, pans[i], tilts[i], geom, pitch_deg=pitch, roll_deg=roll)
        acc[:, cols] += vals * (wgt[..., None] if chans else wgt)
        wsum[:, cols] += wgt
        if progress is not None:
            progress(i + 1, len(images))
    seen = wsum > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        out = acc / (wsum[..., None] if chans else wsum)
    out[~seen] = 0
    if first.dtype in (np.uint8, np.uint16):
        out = np.clip(np.rint(out), 0, np.iinfo(first.dtype).max).astype(first.dtype)
    log.info("panorama %dx%d px, %.3f deg/px, elevation %.1f..%.1f deg, %.0f%% seen", geom.width, geom.height,
             geom.azimuth_step_deg, geom.el_of_row(geom.height - 1), geom.elevation_row0_deg, 100 * seen.mean())
    return Panorama(out, geom, seen, acq.mast_height_m, acq.truth, meta, None, acq.transfer)


def refine_pan_angles(images: list[np.ndarray], camera: CameraModel, pans: np.ndarray, tilts: np.ndarray,
                      geom: PanoramaGeometry, *, pitch_deg: float = 0.0, roll_deg: float = 0.0,
                      pan_sigma_deg: float = 1.0, max_correction_deg: float = 3.0,
                      min_response: float = 0.5, min_overlap_columns: int = 16) -> np.ndarray:
    """Per-frame pan corrections (degrees) from the azimuth shifts between overlapping frames.

    Each overlapping pair gives ``corr_j - corr_i = shift``; the corrections minimise
    ``sum (corr_j - corr_i - shift)^2 / s_m^2 + sum corr_i^2 / pan_sigma_deg^2`` (s_m = a quarter
    pixel), i.e. the unit's angles are the prior.  The shift of a pair minimises the mean squared
    difference of the overlap (integer search within ``max_correction_deg``, parabola to sub-pixel);
    pairs whose minimum is not distinct (``min_response``: relative rise of the error one pixel
    away) or lies on the search border are ignored.
    """
    n = len(images)
    warps = []
    for i in range(n):
        cols, vals, wgt = warp_frame(images[i], camera, pans[i], tilts[i], geom, pitch_deg=pitch_deg,
                                     roll_deg=roll_deg)
        grey = vals if vals.ndim == 2 else vals.mean(axis=2)
        warps.append((cols, grey, wgt))
    rows_eq, rhs = [], []
    for i in range(n):
        for j in range(i + 1, n):
            ci, gi, wi = warps[i]
            cj, gj, wj = warps[j]
            common, ii, jj = np.intersect1d(ci, cj, return_indices=True)
            if common.size < min_overlap_columns:
                continue
            both = (wi[:, ii] > 0) & (wj[:, jj] > 0)
            rws = np.flatnonzero(both.any(axis=1))
            if rws.size < min_overlap_columns:
                continue
            # contiguous run of columns across the seam: order by position relative to the first column
            order = np.argsort(np.mod(common - common[0] + geom.width // 2, geom.width))
            a = gi[rws][:, ii[order]]
            b = gj[rws][:, jj[order]]
            m = both[rws][:, order]
            max_shift = int(math.ceil(max_correction_deg / geom.azimuth_step_deg))
            shift_px, contrast = _masked_shift(a, b, m, max_shift)
            shift_deg = -shift_px * geom.azimuth_step_deg     # b shows a frame at -e_j: corr_j - corr_i = -shift
            if not np.isfinite(shift_px) or contrast < min_response:
                log.debug("frames %d-%d: no reliable shift (contrast %.2f): ignored", i, j, contrast)
                continue
            row = np.zeros(n)
            row[i], row[j] = -1.0, 1.0
            rows_eq.append(row)
            rhs.append(shift_deg)
            log.debug("frames %d-%d: relative yaw %.3f deg (contrast %.2f)", i, j, shift_deg, contrast)
    if not rows_eq:
        log.info("yaw refinement: no overlap could be matched; the pan-tilt angles are kept")
        return np.zeros(n)
    s_m = 0.25 * geom.azimuth_step_deg
    A = np.vstack([np.array(rows_eq) / s_m, np.eye(n) / pan_sigma_deg])
    y = np.concatenate([np.array(rhs) / s_m, np.zeros(n)])
    corr, *_ = np.linalg.lstsq(A, y, rcond=None)
    log.info("yaw refinement: %d pairs, corrections %s deg", len(rhs), np.round(corr, 3).tolist())
    return corr


def _masked_shift(a: np.ndarray, b: np.ndarray, mask: np.ndarray, max_shift: int) -> tuple[float, float]:
    """Column shift ``s`` (pixels, sub-pixel) such that ``b[:, c + s] ~ a[:, c]`` on ``mask``, and the
    relative rise of the error one pixel away from the minimum (distinctiveness).  NaN when unreliable."""
    n = a.shape[1]
    shifts = np.arange(-max_shift, max_shift + 1)
    err = np.full(shifts.size, np.inf)
    for k, s in enumerate(shifts):
        lo, hi = max(0, -s), min(n, n - s)
        if hi - lo < 8:
            continue
        m = mask[:, lo:hi] & mask[:, lo + s:hi + s]
        cnt = m.sum()
        if cnt < 50:
            continue
        d = (a[:, lo:hi] - b[:, lo + s:hi + s])[m]
        err[k] = float(np.mean(d * d))
    k = int(np.argmin(err))
    if not np.isfinite(err[k]) or k == 0 or k == shifts.size - 1 or not np.isfinite(err[k - 1] + err[k + 1]):
        return float("nan"), 0.0
    e0, e1, e2 = err[k - 1], err[k], err[k + 1]
    den = e0 - 2.0 * e1 + e2
    frac = 0.5 * (e0 - e2) / den if den > 0 else 0.0
    contrast = float(min(e0, e2) / max(e1, 1e-12) - 1.0)
    return float(shifts[k] + np.clip(frac, -0.5, 0.5)), contrast
