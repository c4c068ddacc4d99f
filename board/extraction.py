"""From an acquisition or a panorama to a skyline (elevation by azimuth), with failure detection.

``extract_from_acquisition(dir)`` builds the panorama (:mod:`board.panorama`) and runs
``extract_from_panorama``, which

1. refuses pictures with nothing to find, with the reason: nothing seen, black,
   over-exposed, all sky, all ground, too few confident columns (status "failed", no skyline:
   a made-up skyline is worse than none);
2. detects the line (:func:`board.detect.detect_skyline`), masking doubtful columns;
3. converts rows to elevations and samples them as the database does: point samples at
   ``azimuth_start_deg + j * step`` (a line fitted to the kept columns within half a step,
   :data:`SAMPLE_FIT_HALF_STEPS`; NaN when either of the two nearest panorama columns is masked
   or unseen).  Azimuths are relative to the heading (0 = optical axis at pan 0)
   for panoramas built from acquisitions; a panorama whose ``azimuth_reference`` is "north"
   gives a skyline relative to north (``meta["azimuth_reference"]``).

Status: "ok" (>= ``min_ok_fraction`` of the seen columns kept), "degraded" (fewer, still at
least ``min_coverage_deg`` of azimuth) or "failed" (``skyline`` is None, ``reason`` says why).
"""
from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from board.acquisition import Acquisition, Panorama, PanoramaGeometry, load_acquisition, load_panorama
from board.clipped_sky import CLIPPED_SHIFT_GAIN, clipped_line_offset_px
from board.conventions import DEFAULT_N_AZIMUTH, azimuth_grid_deg
from board.detect import Detection, DetectorParams, detect_skyline
from board.detect.preprocess import to_grey01
from board.errors import InvalidInputError
from board.panorama import build_panorama
from board.skyline import Skyline

log = logging.getLogger(__name__)

STATUS_OK = "ok"
STATUS_DEGRADED = "degraded"
STATUS_FAILED = "failed"


@dataclass(frozen=True)
class ExtractionOptions:
    """Options of the extraction (angles in degrees)."""

    n_azimuth: int = DEFAULT_N_AZIMUTH
    azimuth_start_deg: float = 0.0
    detector: DetectorParams = DetectorParams()
    black_level: float = 0.03            # fraction of full scale
    saturation_level: float = 0.98
    bad_pixel_fraction: float = 0.9      # fraction of seen pixels black/saturated that fails the picture
    min_separation: float = 2.0          # sky/ground contrast over their spread (90th percentile of the columns)
                                         # below which there is one class
    min_coverage_deg: float = 20.0
    min_ok_fraction: float = 0.9
    clipped_sky_gain: float = CLIPPED_SHIFT_GAIN   # a clipped sky's line is moved up to its edge by this model
                                                   # gain (board.clipped_sky); 0 leaves it where it was found
    sample_fit_degree: int = 1           # each sample is the intercept of a line (1) or a parabola (2) fitted over
                                         # its azimuth window (SAMPLE_FIT_HALF_STEPS)
    fine_samples: bool = True            # the skyline also carries the line at about the panorama's own step
                                         # (Skyline.fine_elevation_deg), which the matcher aligns with the database


@dataclass
class ExtractionResult:
    """Outcome of an extraction.

    skyline : Skyline (relative to the heading) or None when status is "failed"
    status, reason : "ok" / "degraded" / "failed" and why
    column_confidence : (W,) confidence of every panorama column (empty when detection did not run)
    panorama, detection : the intermediate products (for debug pictures)
    """

    skyline: Skyline | None
    status: str
    reason: str
    column_confidence: np.ndarray = field(default_factory=lambda: np.zeros(0))
    panorama: Panorama | None = None
    detection: Detection | None = None
    elapsed_s: float = 0.0
    diagnostics: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status != STATUS_FAILED

    def to_json_dict(self) -> dict:
        return {"status": self.status, "reason": self.reason, "elapsed_s": round(self.elapsed_s, 4),
                "coverage_deg": None if self.skyline is None else self.skyline.coverage_deg,
                "skyline": None if self.skyline is None else self.skyline.to_dict(),
                "diagnostics": _jsonable(self.diagnostics)}


def _jsonable(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, (np.floating, np.integer, np.bool_)):
            v = v.item()
        out[k] = v
    return out


def _with_sampling(options: ExtractionOptions, azimuth_step_deg: float | None,
                   azimuth_start_deg: float | None) -> ExtractionOptions:
    """Options with the skyline's azimuth sampling replaced (a step must divide 360 degrees)."""
    from dataclasses import replace

    if azimuth_step_deg is not None:
        n = 360.0 / float(azimuth_step_deg) if azimuth_step_deg > 0 else float("nan")
        if not (np.isfinite(n) and abs(n - round(n)) < 1e-6):
            raise InvalidInputError(f"azimuth step {azimuth_step_deg} deg does not divide 360 degrees: "
                                    "use the database's step (e.g. 1, 0.5, 0.25)")
        options = replace(options, n_azimuth=int(round(n)))
    if azimuth_start_deg is not None:
        options = replace(options, azimuth_start_deg=float(azimuth_start_deg))
    return options


def extract_from_acquisition(acq: Acquisition | str | os.PathLike, *, refine_yaw: bool = False,
                             azimuth_step_deg: float | None = None, azimuth_start_deg: float | None = None,
                             panorama_step_deg: float | None = None,
                             options: ExtractionOptions = ExtractionOptions()) -> ExtractionResult:
    """Build the panorama of an acquisition (folder or object) and extract its skyline.

    azimuth_step_deg / azimuth_start_deg : sampling of the returned skyline (the database's, degrees;
    default ``options``: 1 degree from 0 = the heading); panorama_step_deg : panorama resolution,
    degrees per pixel (default: the camera's native resolution); refine_yaw : correct the pan angles
    by matching overlapping frames.
    """
    t0 = time.perf_counter()
    options = _with_sampling(options, azimuth_step_deg, azimuth_start_deg)
    if not isinstance(acq, Acquisition):
        acq = load_acquisition(Path(acq))
    pano = build_panorama(acq, refine_yaw=refine_yaw, azimuth_step_deg=panorama_step_deg)
    res = extract_from_panorama(pano, options=options)
    res.elapsed_s = time.perf_counter() - t0
    return res


def extract_from_panorama(pano: Panorama | str | os.PathLike, *, azimuth_step_deg: float | None = None,
                          azimuth_start_deg: float | None = None,
                          options: ExtractionOptions = ExtractionOptions()) -> ExtractionResult:
    """Detect the skyline of a panorama (folder or object) and sample it on the skyline azimuth grid
    (``azimuth_step_deg`` / ``azimuth_start_deg`` override ``options``, degrees)."""
    t0 = time.perf_counter()
    options = _with_sampling(options, azimuth_step_deg, azimuth_start_deg)
    if not isinstance(pano, Panorama):
        pano = load_panorama(Path(pano))
    res = _extract(pano, options)
    res.elapsed_s = time.perf_counter() - t0
    log.info("extraction %s in %.2f s: %s", res.status, res.elapsed_s, res.reason)
    return res


def _failed(reason: str, pano: Panorama, det: Detection | None = None, diag: dict | None = None) -> ExtractionResult:
    conf = det.confidence if det is not None else np.zeros(0)
    return ExtractionResult(None, STATUS_FAILED, reason, conf, pano, det, diagnostics=diag or {})


def _extract(pano: Panorama, opt: ExtractionOptions) -> ExtractionResult:
    geom = pano.geometry
    seen = pano.seen if pano.seen is not None else np.ones(pano.image.shape[:2], dtype=bool)
    if not seen.any():
        return _failed("nothing seen: no frame covers the panorama (check the frames and the pan/tilt angles)", pano)
    frac_black, frac_sat = _exposure_fractions(pano.image, seen, opt.black_level, opt.saturation_level)
    diag = {"black_fraction": frac_black, "saturated_fraction": frac_sat}
    if geom.kind != "binary":
        if frac_black >= opt.bad_pixel_fraction:
            return _failed(f"black picture: {100 * frac_black:.0f}% of the seen pixels are below "
                           f"{100 * opt.black_level:.0f}% of full scale (lens cap, night or exposure far too short)",
                           pano, diag=diag)
        if frac_sat >= opt.bad_pixel_fraction:
            return _failed(f"over-exposed picture: {100 * frac_sat:.0f}% of the seen pixels are saturated "
                           "(shorten the exposure)", pano, diag=diag)
    det = detect_skyline(pano.image, seen=seen, wrap=geom.is_full_circle, params=opt.detector, transfer=pano.transfer)
    diag.update(det.diagnostics)
    # the contrast where the view has the most of it (the best tenth of the columns): a NavCam view whose
    # other half is a near slope filling the frames has its sky in half the columns only
    sep = det.diagnostics.get("separation_p90", 0.0)
    seen_cols = seen.any(axis=0)
    if sep < opt.min_separation or det.diagnostics.get("reason") == "one class only":
        kind = _uniform_kind(to_grey01(pano.image)[0], seen)
        return _failed(f"{kind}: the picture has no sky/ground contrast (separation {sep:.2f} < "
                       f"{opt.min_separation} in the best tenth of the columns)", pano, det, diag)
    top = det.diagnostics["line_at_top_fraction"]
    bottom = det.diagnostics["line_at_bottom_fraction"]
    if top >= 0.9:
        return _failed(f"all ground: the line sits at the top of the view in {100 * top:.0f}% of the columns "
                       "(tilt the camera up)", pano, det, diag)
    if bottom >= 0.9:
        return _failed(f"all sky: the line sits at the bottom of the view in {100 * bottom:.0f}% of the columns "
                       "(tilt the camera down)", pano, det, diag)
    line = det.line_row
    if opt.clipped_sky_gain > 0 and det.clipped_rows is not None and geom.kind != "binary":
        # a clipped sky's line lies below its edge (board.clipped_sky)
        line = line - clipped_line_offset_px(det.clipped_rows, geom.elevation_step_deg,
                                             det.diagnostics.get("edge_width_px"), gain=opt.clipped_sky_gain)
    skyline = panorama_line_to_skyline(line, geom, n_azimuth=opt.n_azimuth,
                                       azimuth_start_deg=opt.azimuth_start_deg, fit_degree=opt.sample_fit_degree)
    kept = float(det.valid[seen_cols].mean()) if seen_cols.any() else 0.0
    if skyline.coverage_deg < opt.min_coverage_deg:
        return _failed(f"too few confident columns: {skyline.coverage_deg:.0f} deg of azimuth kept, "
                       f"{opt.min_coverage_deg:.0f} needed ({100 * kept:.0f}% of the seen columns confident)",
                       pano, det, diag)
    meta = {"source": "skyloc extract", "azimuth_reference": geom.azimuth_reference,
            "panorama_step_deg": geom.azimuth_step_deg, "kept_column_fraction": round(kept, 4)}
    if pano.mast_height_m is not None:
        meta["mast_height_m"] = pano.mast_height_m
    fine_el, fine_step = None, None
    if opt.fine_samples:
        fine = fine_skyline(line, geom, n_azimuth=opt.n_azimuth, azimuth_start_deg=opt.azimuth_start_deg,
                            fit_degree=opt.sample_fit_degree)
        if fine is not None:
            fine_el, fine_step = fine.elevation_deg, fine.azimuth_step_deg
    skyline = Skyline(skyline.elevation_deg, skyline.azimuth_start_deg, skyline.azimuth_step_deg, meta,
                      fine_el, fine_step)
    if kept >= opt.min_ok_fraction:
        status, reason = STATUS_OK, f"{100 * kept:.0f}% of the seen columns kept"
    else:
        status, reason = STATUS_DEGRADED, (f"only {100 * kept:.0f}% of the seen columns are confident "
                                           "(low contrast, glare or saturation); the rest are masked")
    meta["status"] = status
    return ExtractionResult(skyline, status, reason, det.confidence, pano, det, diagnostics=diag)


def _exposure_fractions(image: np.ndarray, seen: np.ndarray, black: float, saturated: float) -> tuple[float, float]:
    """Fractions of the seen pixels whose grey level (fraction of full scale, as :func:`to_grey01` gives it) is
    <= ``black`` and >= ``saturated``.  8/16-bit images: from the histogram of the integer grey image (no
    full-size float copy), the levels compared in float32 as the float image would be."""
    import cv2

    img = np.asarray(image)
    if img.dtype in (np.uint8, np.uint16) and (img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3)):
        g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else np.ascontiguousarray(img)
        full = 255 if img.dtype == np.uint8 else 65535
        mask = np.ascontiguousarray(seen, dtype=bool).view(np.uint8)
        hist = cv2.calcHist([g], [0], mask, [full + 1], [0, full + 1]).ravel().astype(np.float64)
        levels = np.arange(full + 1, dtype=np.float32) * np.float32(1.0 / full)
        n = max(hist.sum(), 1.0)
        return float(hist[levels <= black].sum() / n), float(hist[levels >= saturated].sum() / n)
    vals = to_grey01(img)[0][seen]
    return float(np.mean(vals <= black)), float(np.mean(vals >= saturated))


def _uniform_kind(grey: np.ndarray, seen: np.ndarray, *, texture_threshold: float = 0.01) -> str:
    """'all sky' for a smooth picture, 'all ground' for a textured one (no sky/ground split either way).

    Texture: spread of a band-pass (difference of Gaussians, 1 and 4 px) in fractions of full scale;
    white sensor noise is attenuated about fourfold by it (noise of 3% of full scale stays below the
    threshold), terrain texture much less.
    """
    import cv2

    band = cv2.GaussianBlur(grey, (0, 0), 1.0) - cv2.GaussianBlur(grey, (0, 0), 4.0)
    texture = float(np.std(band[seen]))
    return "all ground" if texture > texture_threshold else "all sky"


#: Each skyline sample is a straight line fitted to the kept panorama columns within this many azimuth
#: steps of it (docs/extraction.md, "Pipeline", step 6).  The detector's per-column errors are nearly
#: independent (lag-1 autocorrelation 0.07 at 1440 px), so using the ~4 columns of a 1-degree step instead
#: of the 2 around the sample brought the kept samples from 0.049 to 0.037 deg RMS against the ray-marched
#: truth (60 Aristoteles panoramas, session 7; held-out campaigns: docs/benchmarks.md, "Session 8").
SAMPLE_FIT_HALF_STEPS = 0.5


def panorama_line_to_skyline(line_row: np.ndarray, geom: PanoramaGeometry, *, n_azimuth: int = DEFAULT_N_AZIMUTH,
                             azimuth_start_deg: float = 0.0,
                             fit_half_steps: float = SAMPLE_FIT_HALF_STEPS,
                             fit_degree: int = 1) -> Skyline:
    """Sample a per-column line (continuous rows, NaN = masked) as a Skyline.

    Sample ``j`` is the elevation at azimuth ``a_j = azimuth_start_deg + j * 360 / n_azimuth`` exactly:
    the intercept at ``a_j`` of the least-squares line through the kept columns within
    ``fit_half_steps`` skyline steps of it (the two columns around ``a_j`` always count, so a panorama
    coarser than the skyline, or ``fit_half_steps = 0``, gives linear interpolation between them).  NaN
    when either of those two columns is masked (only the one when ``a_j`` falls on a column) or the
    azimuth is outside a partial panorama.  A line through ~4 independent column errors halves their
    noise (interpolation between two: 1/sqrt 2); its bias on a curved skyline is below
    ``|el''| * w**2 / 6`` for a half-width ``w``.
    """
    if not (np.isfinite(fit_half_steps) and fit_half_steps >= 0):
        raise InvalidInputError(f"fit_half_steps must be a finite number >= 0 (got {fit_half_steps})")
    el_col = geom.el_of_row(np.asarray(line_row, dtype=np.float64))
    az = azimuth_grid_deg(n_azimuth, azimuth_start_deg)
    x = geom.col_of_az(az)
    W = geom.width
    c0 = np.floor(x).astype(np.int64)
    t = x - c0
    if geom.is_full_circle:
        e0 = el_col[np.mod(c0, W)]
        e1 = el_col[np.mod(c0 + 1, W)]
        inside = np.ones(x.shape, dtype=bool)
    else:
        inside = (c0 >= 0) & (c0 + 1 <= W - 1) | ((c0 == W - 1) & (t == 0))
        e0 = np.where(inside, el_col[np.clip(c0, 0, W - 1)], np.nan)
        e1 = np.where(inside, el_col[np.clip(c0 + 1, 0, W - 1)], np.nan)
    el = np.where(t == 0, e0, (1.0 - t) * e0 + t * e1)
    half_cols = fit_half_steps * (360.0 / n_azimuth) / geom.azimuth_step_deg
    if half_cols > 1.0:
        el = _fit_samples(el_col, x, c0, el, half_cols, full_circle=geom.is_full_circle, degree=fit_degree)
    return Skyline(el, float(azimuth_start_deg), 360.0 / n_azimuth, {"azimuth_reference": geom.azimuth_reference})


#: most fine samples per skyline step (:func:`fine_skyline`)
MAX_FINE_PER_STEP = 20


def fine_skyline(line_row: np.ndarray, geom: PanoramaGeometry, *, n_azimuth: int, azimuth_start_deg: float = 0.0,
                 fit_degree: int = 1) -> Skyline | None:
    """The line sampled ``k`` times per skyline step (``k`` = skyline step / panorama step, rounded, 2 to
    ``MAX_FINE_PER_STEP``), each sample the same estimator as :func:`panorama_line_to_skyline`'s (a line
    fitted over the same azimuth window), so that every k-th fine sample is a skyline sample.  None when
    the panorama is not finer than half the skyline's step (nothing to gain)."""
    step = 360.0 / n_azimuth
    k = int(round(step / geom.azimuth_step_deg))
    if k < 2:
        return None
    k = min(k, MAX_FINE_PER_STEP)
    return panorama_line_to_skyline(line_row, geom, n_azimuth=n_azimuth * k, azimuth_start_deg=azimuth_start_deg,
                                    fit_half_steps=SAMPLE_FIT_HALF_STEPS * k, fit_degree=fit_degree)


def _fit_samples(el_col: np.ndarray, x: np.ndarray, c0: np.ndarray, el_interp: np.ndarray, half_cols: float,
                 *, full_circle: bool, degree: int = 1) -> np.ndarray:
    """Intercepts at columns ``x`` of the lines (``degree`` 2: parabolas, where at least 5 columns count;
    the line elsewhere) fitted to the finite ``el_col`` within ``half_cols`` columns.

    Samples where ``el_interp`` is NaN (a neighbouring column masked, outside the view) stay NaN; the two
    columns around ``x`` are in every fit, the others only if finite and inside a partial panorama.
    """
    W = el_col.size
    k = int(np.ceil(half_cols))
    offs = np.arange(-k, k + 2)                               # relative to c0: c0 - k .. c0 + k + 1
    cols = c0[:, None] + offs[None, :]
    d = cols - x[:, None]                                     # column distance to the sample (columns)
    if full_circle:
        vals = el_col[np.mod(cols, W)]
    else:
        vals = np.where((cols >= 0) & (cols < W), el_col[np.clip(cols, 0, W - 1)], np.nan)
    use = np.isfinite(vals) & ((np.abs(d) <= half_cols) | (offs[None, :] == 0) | (offs[None, :] == 1))
    v = np.where(use, vals, 0.0)
    dw = np.where(use, d, 0.0)
    s0 = use.sum(axis=1).astype(np.float64)
    s1 = dw.sum(axis=1)
    s2 = (dw * dw).sum(axis=1)
    sy = v.sum(axis=1)
    sxy = (dw * v).sum(axis=1)
    det = s0 * s2 - s1 * s1
    with np.errstate(invalid="ignore", divide="ignore"):
        line = (s2 * sy - s1 * sxy) / det
    ok = np.isfinite(el_interp) & (s0 >= 2) & (det > 1e-9 * np.maximum(s0 * s2, 1e-300))
    line = np.where(ok, line, el_interp)
    if degree < 2:
        return line
    # the parabola's intercept: the line's curvature bias (|el''| w^2 / 6) gone, its noise about 1.5 x
    A = np.empty((d.shape[0], 3, 3))
    p = [s0, s1, s2, (dw ** 3).sum(axis=1), (dw ** 4).sum(axis=1)]
    for i in range(3):
        for j in range(3):
            A[:, i, j] = p[i + j]
    b = np.stack([sy, sxy, (dw * dw * v).sum(axis=1)], axis=1)
    good = ok & (s0 >= 5)
    quad = np.full(line.shape, np.nan)
    if np.any(good):
        Ag = A[good]
        cond = np.linalg.cond(Ag)
        fine = cond < 1e8
        sol = np.full(Ag.shape[0], np.nan)
        if np.any(fine):
            sol[fine] = np.linalg.solve(Ag[fine], b[good][fine][..., None])[:, 0, 0]
        quad[good] = sol
    return np.where(np.isfinite(quad), quad, line)
