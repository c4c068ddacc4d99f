"""Improved skyline detector: sky-region consistency, L1-smooth path, sub-pixel line, per-column confidence.

Where the report's graph looks only at gradients near the line (and so follows strong edges
inside the terrain, or misses peaks next to them), this detector asks that the region above
the line look like sky and the region below like ground:

1. Features per pixel: blurred intensity, roughness (RMS of the vertical second difference
   over the smaller of the windows just above and just below the pixel: a smooth haze gradient
   or sun halo is not texture, and the measure does not bleed across the line) and, for colour
   images, log(blue / red).  Robust Gaussian classes (sky, ground) per feature and azimuth
   sector (the sunlit side of a hill can be brighter than the sky, the shaded side darker),
   spread to every column by linear interpolation between sector centres, give a per-pixel sky
   probability ``p`` (naive Bayes; smoothness gives at most ``smooth_evidence_cap`` of sky
   evidence: hazy distant terrain is smooth too; intensity and colour are clipped to the interval
   between the two class centres first, so that a value beyond the sky's centre, such as a sun halo brighter
   than a smooth sky, counts as sky and not as the wider ground class).  First split: Otsu on grey per sector, the
   sky class being the one that fills the top of the picture, replaced by the top and bottom
   bands of the view in the sectors where it contradicts them; then the classes are re-fitted
   on the two sides of the detected line and the line detected again.
2. Node cost of a boundary just above row ``r`` in column ``c``: the number of pixels it
   misclassifies in that column (sky-like pixels below, ground-like above; scaled, capped)
   plus the lack of a sky-to-ground step on the Fisher discriminant of intensity and colour
   (scaled per column so that sky is 0 and ground 1).
3. Path: one row per column, any jump between neighbouring columns at a cost per row (cliffs
   allowed), solved exactly by dynamic programming with L1 distance transforms
   (:func:`board.detect.graph_dp.shortest_path_l1`), with 360-degree wrap.
4. Sub-pixel position from a parabola through the vertical intensity step (the discriminant's
   where intensity does not separate the classes).
5. Confidence per column in [0, 1]: step contrast against the noise and the class contrast,
   sky/ground consistency of the two sides, saturation (glare), enough seen pixels on both
   sides, and no sky-to-ground step above the line (a hazy distant ridge the line passed under);
   columns below ``min_confidence`` (and short isolated runs) are masked, never guessed.  A column
   masked for a step above gets the path solved again at or above that step (a far ridge behind a near
   slope's edge, :func:`_reseat_on_step_above`) and takes it where every check passes there.

Positions are continuous row coordinates with the centre of the top pixel at 0: a line at
``y`` means rows ``< y`` are sky (the boundary between rows ``b - 1`` and ``b`` is ``b - 0.5``).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np

from board.detect.clipped_edge import clipped_run_above, edge_width_px
from board.detect.graph_dp import shortest_path_l1
from board.detect.preprocess import fill_unseen_rows, seen_or_all, to_grey01
from board.detect.subpixel_phase import table_for_width, undo_phase
from board.errors import InvalidInputError
from board.transfer import check_transfer, to_linear

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DetectorParams:
    """Tuning of :func:`detect_skyline` (dimensionless unless stated)."""

    blur_sigma_px: float = 1.0          # vertical Gaussian blur before features and steps, pixels
    texture_window_px: int = 7          # texture window height (one-sided, one column wide), pixels
    region_scale_px: float = 6.0        # misclassified pixels worth one unit of cost
    region_cap: float = 4.0             # cap of the region cost (keeps far rows from dominating)
    edge_weight: float = 1.0
    jump_cost_per_px: float = 0.03      # cost of a one-row jump between neighbouring columns
    iterations: int = 2                 # class re-fits on the detected line
    n_sectors: int = 24                 # class models fitted per azimuth sector (sunlit vs shaded sides)
    min_sector_pixels: int = 400        # fewer pixels of a class in a sector: use the global model there
    refit_margin_px: int = 4            # rows next to the line left out of the re-fit
    contrast_window_px: int = 5         # rows each side for the step contrast
    region_window_px: int = 30          # rows each side for the region consistency check
    min_confidence: float = 0.5
    min_run_columns: int = 5            # valid runs shorter than this are masked
    mask_margin_columns: int = 6        # columns next to a masked run (>= min_run_columns) are masked too:
                                        # the smooth path needs a few columns to leave a wrong row
    saturation_level: float = 0.98      # fraction of full scale counted as saturated
    clipped_gap_rows: int = 1           # unsaturated (mixed) rows directly above the line stepped over when the
                                        # clipped band of sky above it is counted (board.detect.clipped_edge)
    min_seen_rows: int = 3              # seen rows needed on each side of the line
    wrap_margin_columns: int = 200
    use_colour: bool = True             # add log(blue / red) to the features of a colour image
    intensity_subpixel_separation: float = 1.5   # intensity separation above which the line is placed on the grey step
    transfer: str = "srgb"              # the image's transfer function (board.transfer): the grey step is placed
                                        # on the linearised image, where blur and pixel area average the light
    ground_broadening: float = 0.0      # ground spread at least this fraction of the sky-ground distance (re-fits)
    sky_band_px: int = 0               # the sky is re-fitted on this many rows above the line (haze gradients)
    smooth_evidence_cap: float = 0.5    # most sky evidence (log-likelihood ratio) smoothness alone may give
    above_step_window_px: int = 3       # rows each side of a step looked for above the line
    above_step_range: tuple[float, float] = (0.15, 0.3)   # a step above the line this large (class contrasts)
                                        # lowers the confidence from 1 to 0: the line may be a lower ridge
    colour_step_above: bool = True      # the step-above check also on the colour feature alone
    above_step_sector_noise: bool = True  # under a black sky (black_sky_grey), the step-above check's noise (6 sigmas
                                        # of the sky's steps) measured per azimuth sector too, the larger one
                                        # counting: the discriminant is scaled per column, so a dim sector's sky is
                                        # noisier in it (the view's one figure let sensor noise pass for a ridge in
                                        # 10-30 % of the columns, session 34).  Not under a bright sky: there a
                                        # low-contrast sector is where a hazy ridge stands, and a noisy view's
                                        # sector figure let lines under such ridges through (rendered noise scene)
    initial_bands: float = 0.2          # > 0: where the grey split contradicts the view, first class fits
                                        # on this fraction of the seen rows at the top / bottom
    local_grey_step: float = 0.5        # the line is placed on the grey step where it is this share of the class
                                        # contrast at least (else on the discriminant's)
    quantisation_texture_levels: float = 1.5  # roughness below this many grey levels of an integer image is
                                              # quantisation of a smooth gradient, not texture
    min_noise: float = 0.03             # floor of the sky spread on the discriminant (units of the class contrast)
    sky_colour_min_contrast: float = 0.08   # the view's sky and ground differ by this much in log(blue / red) at
                                            # least for the "sky coloured like the ground" check to run
    sky_colour_ramp: tuple[float, float] = (0.25, 0.5)  # a column's sky window this share of the way from the
                                            # ground's colour to the view's sky colour: confidence 0 -> 1
    colour_min_grey: float = 0.05       # in a black-sky view (black_sky_grey), a sky window darker than this (grey,
                                        # 0-1) has no colour (log(blue / red) of sensor noise): the colour check
                                        # leaves its column alone and it does not set the sky's colour
    black_sky_grey: float = 0.05        # a view whose sky (seen rows well above the line) is darker than this (grey,
                                        # 0-1) has a black, airless sky: no gradient, haze or glow of its own
    faint_ground_rows: tuple[int, int] = (3, 13)   # under a black sky, the rows [3, 13) above the line ...
    faint_ground_columns: int = 3       # ... averaged over this many columns each side ...
    faint_ground_z: tuple[float, float] = (6.0, 10.0)  # ... brighter than the sky by this many noise sigmas of that
                                        # mean: confidence 1 -> 0 (a shaded far ridge above a lit near edge)
    colour_second_pass_fraction: float = 0.03   # this share of the columns with a ground-coloured "sky": detect
                                                # again from classes that start from the pixels' colour
    colour_second_pass_masked: float = 0.05     # ... also when the first pass masks this share of the seen columns
                                                # (a bright haze low in the sky taken for ground with a sunlit floor
                                                # below it: the path crosses the sky's gradient and is masked there)
    colour_second_pass_unrefitted: bool = True  # the second pass also tried on its colour classes as they are (no
                                                # re-fit on its line: fitted over every row above the line, the
                                                # clear upper sky makes a whitish haze low in the sky ground again),
                                                # when the better detection still masks colour_second_pass_masked
    max_direct_pixels: int = 1_200_000  # larger images: detected on a reduced copy of about this many pixels, the
                                        # line then refined at full resolution in a band around it (0: never)
    monotone_classes: bool = True       # intensity or colour beyond a class's centre (away from the other class) counts
                                        # as that class, never as the other: a sun halo brighter than the sky is sky
    linear_colour_step: bool = True     # colour images: the sub-pixel line on the linear colour projected on each
                                        # column's local ground - sky colour difference (session 18), not on grey
    colour_step_min: float = 0.01       # that difference's length (linear fraction of full scale) below which the
                                        # column keeps the grey / discriminant step
    colour_step_min_share: float = 0.25 # ... and its share of the whole ground - sky difference below which it does:
                                        # a grey scene's colour difference is the channels' noise
    coarse_contrast_cap: bool = False   # True: the reduced copy's step-contrast check also caps the full-resolution
                                        # confidence (before session 15; now only its wide-window checks do)
    subpixel_gaussian: bool = True      # the step's peak refined by a parabola through the logarithms of its three
                                        # samples (exact for a Gaussian-blurred edge) rather than through the samples
                                        # (which pulls it towards the sampled row by up to 0.05-0.07 px, "pixel
                                        # locking"; session 34), where the three are positive
    subpixel_phase: bool = True         # ... and that peak read through the phase curve of a box pixel under the
                                        # view's lens blur (measured edge width) and this detector's blur: the
                                        # Gaussian's residual lock (up to 0.037 px without lens blur) undone on the
                                        # linear intensity and colour steps (board.detect.subpixel_phase)
    reseat_on_step_above: bool = True   # columns masked for a sky-to-ground step above the line: the path solved
                                        # again kept at or above that step (a far ridge behind a near slope's
                                        # edge); a column takes the new line only where it passes every check

    def clipped_above(self, grey: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Per column, the clipped rows of sky directly above row ``b`` (pixels), at this tuning's saturation
        level and over up to ``clipped_gap_rows`` mixed rows (:func:`board.detect.clipped_edge.clipped_run_above`)."""
        return clipped_run_above(grey, b, self.saturation_level, self.clipped_gap_rows)


@dataclass
class Detection:
    """Per-column result of a detector on an (H, W) image.

    line_row : (W,) float, continuous row of the line (rows above are sky), NaN where masked
    raw_row : (W,) float, the line before masking (for debugging pictures)
    confidence : (W,) float in [0, 1]
    valid : (W,) bool, columns kept
    diagnostics : scene-level numbers (class separation, fraction of columns at top/bottom, the unclipped
        steps' width ``edge_width_px``, ...)
    clipped_rows : (W,) rows of saturated sky directly above the line (0 where the sky there is not clipped;
        :mod:`board.detect.clipped_edge`), None when not measured
    context_confidence : (W,) the confidence's wide-window checks alone (region, glare and saturation, a step
        above the line, the sky's colour; not the step contrast): what a reduced copy passes on to the band
        of a coarse-to-fine detection; None when not measured
    """

    line_row: np.ndarray
    raw_row: np.ndarray
    confidence: np.ndarray
    valid: np.ndarray
    diagnostics: dict = field(default_factory=dict)
    clipped_rows: np.ndarray | None = None
    context_confidence: np.ndarray | None = None


# -- features -------------------------------------------------------------------------------------
def _texture(grey: np.ndarray, win: int) -> np.ndarray:
    """Local roughness over ``win`` rows of one column: RMS of the vertical second difference
    ``g[r-1] - 2 g[r] + g[r+1]``, the smaller of the windows ending and starting at each pixel.

    A second difference ignores smooth vertical gradients (a haze or dust gradient brightening to the
    horizon, a sun halo), which a plain standard deviation takes for texture; one column wide so that
    a steep line does not leak into the window from the neighbouring columns.
    """
    import cv2

    f = grey.astype(np.float32, copy=False)
    d2 = np.zeros_like(f)
    d2[1:-1] = f[:-2] + f[2:]
    d2[1:-1] -= 2.0 * f[1:-1]
    np.multiply(d2, d2, out=d2)
    out = None
    for anchor_y in (win - 1, 0):
        m = cv2.boxFilter(d2, -1, (1, win), anchor=(0, anchor_y), borderType=cv2.BORDER_REFLECT)
        if out is None:
            out = m
        else:
            np.minimum(out, m, out=out)
            del m
    del d2
    np.maximum(out, 0.0, out=out)
    return np.sqrt(out, out=out)


def _chroma(image: np.ndarray) -> np.ndarray | None:
    """log(blue / red) of a BGR image (float32, (H, W)), None for a grey one.

    Sky and regolith differ in colour even where their grey levels meet (a clear sky brightening to
    the horizon next to sunlit ground; a butterscotch dusty sky is still less red than the regolith).
    """
    img = np.asarray(image)
    if img.ndim != 3:
        return None
    full = 255.0 if img.dtype == np.uint8 else (65535.0 if img.dtype == np.uint16 else 1.0)
    eps = np.float32(2.0 / 255.0 * full)
    b = img[..., 0].astype(np.float32) + eps
    r = img[..., 2].astype(np.float32) + eps
    np.divide(b, r, out=b)
    del r
    return np.log(b, out=b)


def _fit(values: np.ndarray, floor: float, max_size: int = 20_000) -> tuple[float, float]:
    """Robust centre and spread (median, 1.4826 MAD) of a class, the spread floored; subsampled to about
    ``max_size`` values."""
    if values.size < 10:
        return float("nan"), floor
    if values.size > max_size:
        values = values[:: values.size // max_size]
    med = _median(values)
    mad = 1.4826 * _median(np.abs(values - med))
    return med, max(mad, floor)


def _median(v: np.ndarray) -> float:
    """``float(np.median(v))`` of a finite 1-D array, bit for bit, with one partition and without np.median's
    per-call overhead (the class fits take a few hundred medians per image)."""
    n = v.size
    k = n // 2
    p = np.partition(v, k)
    if n % 2:
        return float(p[k])
    # the mean of the two middle values as np.median takes it: their sum in the array's type, halved
    return float((p[:k].max() + p[k]) * v.dtype.type(0.5))


def _sector_edges(W: int, n_sectors: int) -> np.ndarray:
    return np.linspace(0, W, max(1, min(n_sectors, W // 8)) + 1).round().astype(int)


def _per_column(values: np.ndarray, edges: np.ndarray, W: int, wrap: bool) -> np.ndarray:
    """Spread per-sector values to every column, linearly between sector centres (circularly if ``wrap``)."""
    centres = 0.5 * (edges[:-1] + edges[1:]) - 0.5
    cols = np.arange(W, dtype=np.float64)
    if values.size == 1:
        return np.full(W, values[0])
    if wrap:
        xp = np.concatenate([centres[-1:] - W, centres, centres[:1] + W])
        fp = np.concatenate([values[-1:], values, values[:1]])
        return np.interp(cols, xp, fp)
    return np.interp(cols, centres, values)


#: pixels per sector (both classes) a class fit subsamples to: the robust centre and spread of a class from a few
#: thousand pixels are within a percent of its spread of the full sector's (20 000 before session 29: the medians were
#: a third of the detector's time)
_SECTOR_FIT_PIXELS = 5_000


def _fit_sectors(f: np.ndarray, mask: np.ndarray, edges: np.ndarray, floor: float, min_pixels: int,
                 wrap: bool) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """Per-column (median, spread) of ``f`` over ``mask``, fitted per sector, global fit where a sector is thin."""
    g_mu, g_sd = _fit(f[mask], floor)
    mus, sds = [], []
    H = f.shape[0]
    for c0, c1 in zip(edges[:-1], edges[1:]):
        # a regular subsample of about _SECTOR_FIT_PIXELS pixels
        k = max(1, int(math.sqrt(H * (c1 - c0) / _SECTOR_FIT_PIXELS)))
        m = mask[::k, c0:c1:k]
        if m.sum() * k * k < min_pixels:
            mus.append(g_mu), sds.append(g_sd)
            continue
        mu, sd = _fit(f[::k, c0:c1:k][m], floor)
        mus.append(mu), sds.append(sd)
    W = f.shape[1]
    return (_per_column(np.array(mus), edges, W, wrap), _per_column(np.array(sds), edges, W, wrap), (g_mu, g_sd))


def _class_llr(feats: list[np.ndarray], sky: np.ndarray, ground: np.ndarray, floors: list[float],
               edges: np.ndarray, min_pixels: int, wrap: bool, caps: list[float | None] | None = None,
               broaden: float = 0.0, monotone: list[bool] | None = None) -> tuple[np.ndarray, list]:
    """Log-likelihood ratio sky vs ground (float32, (H, W)), naive Bayes with one Gaussian per class,
    feature and azimuth sector.  Returns the LLR and, per feature, (mu_sky, sd_sky, mu_ground, sd_ground)
    as per-column arrays plus the global fits.

    caps : per feature, the largest sky evidence it may give (None: no cap).  Smoothness is capped:
    a smooth patch may be sky or hazy distant terrain, while a rough one is ground.
    monotone : per feature, True to clip it to the interval between the two class centres first, so that
    the ratio is monotone in it (two Gaussians of unequal spreads would otherwise give a value far beyond
    the narrow class, such as a sun halo brighter than a smooth sky, to the wide one).
    """
    llr = np.zeros(feats[0].shape, dtype=np.float32)
    tmp = np.empty_like(llr)
    monotone = monotone or [False] * len(feats)
    fc = np.empty_like(llr) if any(monotone) else None
    stats = []
    caps = caps or [None] * len(feats)
    for f, floor, cap, mono in zip(feats, floors, caps, monotone):
        ms, ss, gs = _fit_sectors(f, sky, edges, floor, min_pixels, wrap)
        mg, sg, gg = _fit_sectors(f, ground, edges, floor, min_pixels, wrap)
        stats.append((ms, ss, mg, sg, gs, gg))
        if broaden:
            # the ground is everything that is not sky (near and far, hazy, shaded, sunlit): a value
            # between the two classes is not sky (the likelihood only; the fits are returned as they are)
            sg = np.maximum(sg, broaden * np.abs(mg - ms))
        if not (np.isfinite(gs[0]) and np.isfinite(gg[0])):
            continue
        # term = -0.5 ((f - ms) / ss)^2 + 0.5 ((f - mg) / sg)^2 + log(sg / ss), in place (float32)
        term = np.zeros_like(llr) if cap is not None else llr
        if mono:
            np.clip(f, np.minimum(ms, mg).astype(np.float32)[None, :], np.maximum(ms, mg).astype(np.float32)[None, :],
                    out=fc)
        fx = fc if mono else f
        for mu, sd, sign in ((ms, ss, -0.5), (mg, sg, 0.5)):
            np.subtract(fx, mu.astype(np.float32)[None, :], out=tmp)
            tmp *= (1.0 / sd).astype(np.float32)[None, :]
            np.multiply(tmp, tmp, out=tmp)
            tmp *= np.float32(sign)
            term += tmp
        term += np.log(sg / ss).astype(np.float32)[None, :]
        if cap is not None:
            np.minimum(term, np.float32(cap), out=term)
            llr += term
            del term
    return llr, stats


def _otsu_split(blur: np.ndarray, seen: np.ndarray, top: np.ndarray, bottom: np.ndarray) -> tuple[float, bool]:
    """Otsu threshold (fraction of full scale) of the seen pixels, and whether the sky is the bright
    class: the top of the seen area (sky) is brighter than its bottom (ground).  Comparing the two
    bands, not the band with the threshold, keeps a sky with a brightness gradient on the right side."""
    import cv2

    vals8 = np.clip(blur[seen] * 255.0 + 0.5, 0, 255).astype(np.uint8)
    thr, _ = cv2.threshold(vals8.reshape(-1, 1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    thr = float(thr) / 255.0
    t, b = blur[top], blur[bottom]
    if t.size == 0 or b.size == 0:
        return thr, True
    return thr, bool(np.median(t) >= np.median(b))


def _bands_from_line(line: np.ndarray, H: int, margin: int, sky_band: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Sky rows above ``line - margin`` (only the ``sky_band`` nearest when > 0) and ground rows below
    ``line + margin``: the sky just above the horizon, where a haze gradient makes it brightest."""
    rows = np.arange(H)[:, None]
    sky = rows < (line[None, :] - margin)
    if sky_band > 0:
        sky &= rows >= (line[None, :] - margin - sky_band)
    return sky, rows >= (line[None, :] + margin)


# -- the detector ---------------------------------------------------------------------------------
def detect_skyline(image: np.ndarray, *, seen: np.ndarray | None = None, wrap: bool = False,
                   params: DetectorParams = DetectorParams(), transfer: str | None = None) -> Detection:
    """Detect the skyline in an (H, W) or (H, W, 3) image whose columns are azimuths and rows elevations.

    seen : (H, W) bool, False where nothing was observed (never used as evidence); wrap : True for
    a 360-degree panorama; transfer : the image's transfer function (``"srgb"`` or ``"linear"``,
    :mod:`board.transfer`; default ``params.transfer``, sRGB): the sub-pixel line is placed on the
    light, not on the stored values.  Returns a :class:`Detection` (rows in pixels, see the module docstring).

    Images of more than ``params.max_direct_pixels`` pixels are detected coarse to fine
    (:func:`_detect_coarse_to_fine`): the whole detector on a copy reduced by an integer factor,
    then the line and its confidence again at full resolution in a band of rows around it.
    """
    img = np.asarray(image)
    if img.ndim not in (2, 3):
        raise InvalidInputError(f"an image is (H, W) or (H, W, 3), got shape {img.shape}")
    if transfer is not None:
        params = replace(params, transfer=check_transfer(transfer))
    H, W = img.shape[:2]
    if seen is not None:
        # the features look a few rows across: the seen border must not see the black beyond it
        img = fill_unseen_rows(img, seen_or_all(seen, (H, W)))
    n = params.max_direct_pixels
    if n > 0 and H * W > n and min(H, W) >= 128:
        return _detect_coarse_to_fine(img, seen, wrap, params)
    return _detect_direct(img, seen, wrap, params)


def _detect_direct(image: np.ndarray, seen: np.ndarray | None, wrap: bool, params: DetectorParams, *,
                   init_classes: tuple[np.ndarray, np.ndarray] | None = None) -> Detection:
    """The detector on the image as it is (see the module docstring).

    init_classes : (sky, ground) (H, W) bool masks of the first class fit instead of the brightness split
    (the second pass of a view whose sky the colour check found in only some columns)."""
    import cv2

    P = params
    grey, blur, tex, chroma = _vertical_features(image, P)
    H, W = grey.shape
    seen = seen_or_all(seen, (H, W))
    diag: dict = {"height": H, "width": W, "seen_fraction": float(seen.mean())}

    if not seen.any():
        return _empty(W, diag | {"reason": "nothing seen"})
    edges = _sector_edges(W, P.n_sectors)
    n_seen_col = seen.sum(axis=0, dtype=np.int32)
    if init_classes is None:
        sky0, ground0, diag["sky_is_bright_initial_fraction"] = _initial_classes(blur, seen, n_seen_col, edges, P)
    else:
        sky0, ground0 = init_classes[0] & seen, init_classes[1] & seen

    seen_pair = seen[1:] & seen[:-1]
    feats, floors, step_features = _feature_stack(blur, tex, chroma)
    line = None
    sky_cls, ground_cls = sky0, ground0
    for it in range(max(1, P.iterations)):
        p, stats = _class_llr(feats, sky_cls, ground_cls, floors, edges, P.min_sector_pixels, wrap,
                              broaden=P.ground_broadening if it > 0 else 0.0, **_feature_likelihoods(len(feats), P))
        _sky_probability(p)
        mu_s, sd_s, mu_g, sd_g, glob_s, glob_g = stats[0]
        if not (np.isfinite(glob_s[0]) and np.isfinite(glob_g[0])):
            diag.update(reason="one class only", intensity_sky=glob_s[0], intensity_ground=glob_g[0])
            return _empty(W, diag)
        polarity = np.where(mu_g >= mu_s, 1.0, -1.0).astype(np.float32)   # sky -> ground step sign, per column
        contrast = np.abs(mu_g - mu_s)
        # the smooth features (intensity, colour) projected on their discriminant, scaled so that sky
        # is 0 and ground 1 in every column; its vertical step (r-1 -> r, stored at r) is the edge evidence
        proj, sd_proj_sky = _discriminant(feats, stats, step_features)
        node, diff = _node_cost(p, proj, seen, seen_pair, P)
        last = it + 1 >= max(1, P.iterations)
        if last or min(H, W) < 64:
            line = shortest_path_l1(node, jump_cost=P.jump_cost_per_px, wrap=wrap,
                                    margin=P.wrap_margin_columns).rows_top
        else:
            # the class re-fit only needs the line roughly: solve it on a 2x coarser grid
            small = cv2.resize(node, (W // 2, H // 2), interpolation=cv2.INTER_AREA)
            coarse = shortest_path_l1(small, jump_cost=P.jump_cost_per_px, wrap=wrap,
                                      margin=P.wrap_margin_columns // 2).rows_top
            line = np.repeat(2 * coarse + 1, 2)[:W]
            if line.size < W:
                line = np.concatenate([line, np.full(W - line.size, line[-1])])
        if it + 1 < max(1, P.iterations):
            sky_cls, ground_cls = _bands_from_line(line.astype(np.float64), H, P.refit_margin_px, P.sky_band_px)
            sky_cls &= seen
            ground_cls &= seen
            if sky_cls.sum() < 50 or ground_cls.sum() < 50:
                break
    sep_col = contrast / np.hypot(sd_s, sd_g)
    # separation of the two classes over all features (Mahalanobis-like, independent features)
    sep_all = np.sqrt(sum((np.abs(st[2] - st[0]) / np.hypot(st[1], st[3])) ** 2 for st in stats))
    diag.update(intensity_sky=float(np.median(mu_s)), intensity_ground=float(np.median(mu_g)),
                texture_sky=float(np.median(stats[1][0])), texture_ground=float(np.median(stats[1][2])),
                intensity_sigma_sky=float(np.median(sd_s)), intensity_sigma_ground=float(np.median(sd_g)),
                polarity_flipped_fraction=float(np.mean(polarity < 0)),
                intensity_separation=float(np.median(sep_col)), separation=float(np.median(sep_all)),
                separation_p90=float(np.percentile(sep_all, 90)))
    b = line.astype(np.int64)
    # sub-pixel position from the intensity step where intensity separates the classes (colour edges
    # shift with lens dispersion), from the discriminant elsewhere
    lin_raw, lin_rgb = _linear_light(image, P)
    lin = _vertical_blur(lin_raw, P)
    colour_proj = _colour_projection(feats, stats, chroma, P)

    def line_and_confidence(b: np.ndarray, on_step: np.ndarray | None = None, checks: dict | None = None
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple | None]:
        """Sub-pixel line, confidence and wide-window confidence of the path ``b``, and for colour images
        :func:`_sky_colour_unlike_ground`'s factor, sky-ground colour offset and ground colour."""
        y = _subpixel_line(blur, lin, diff, b, seen_pair, polarity, sep_col, contrast, P, lin_rgb=lin_rgb,
                           phase=phase)
        black = _black_sky(grey, seen, b, P)      # once for both checks that act only under a black sky
        conf, context = _confidence(grey, proj, p, seen, b, sd_proj_sky, P, colour_proj, on_step, checks, wrap,
                                    black=black)
        colour = None
        if chroma is not None:
            colour = _sky_colour_unlike_ground(chroma, seen, b, P, grey, black=black)
            np.minimum(conf, colour[0], out=conf)
            np.minimum(context, colour[0], out=context)
        return y, conf, context, colour

    clipped = P.clipped_above(grey, b)
    diag["edge_width_px"] = edge_width_px(lin_raw, b, clipped)
    phase = _phase_curve(diag["edge_width_px"], P)
    del lin_raw
    checks: dict = {}
    y, conf, context, colour = line_and_confidence(b, checks=checks)
    first_seen = np.argmax(seen, axis=0)
    seen_cols = n_seen_col > 0
    no_sky = 0.0
    if colour is not None:
        c_colour, offset, g_ref = colour
        diag["sky_ground_colour_contrast"] = offset
        no_sky = float(np.mean(c_colour[seen_cols] < 0.5)) if seen_cols.any() else 0.0
        diag["sky_coloured_like_ground_fraction"] = no_sky
    if P.reseat_on_step_above:
        scored: dict = {}

        def score(b2: np.ndarray, on_step: np.ndarray | None = None) -> np.ndarray:
            scored["y"], scored["conf"], scored["context"], _ = line_and_confidence(b2, on_step)
            return scored["conf"]

        b2, take = _reseat_on_step_above(node, b, conf, checks, score, first_seen, P, wrap)
        diag["reseated_columns"] = int(take.sum())
        first_conf, first_b = conf, b
        if take.any():
            y, conf, context, b = (np.where(take, scored["y"], y), np.where(take, scored["conf"], conf),
                                   np.where(take, scored["context"], context), np.where(take, b2, b))
            clipped = np.where(take, P.clipped_above(grey, b2), clipped)
    lin = lin_rgb = node = None          # freed (the closures above are done with them)
    valid = _valid_columns(conf, n_seen_col, wrap, P)
    if P.reseat_on_step_above and take.any():
        valid = _masks_after_reseat(valid, take, first_conf, first_b, b, n_seen_col, wrap, P)
    masked_share = float(np.mean(~valid[seen_cols])) if seen_cols.any() else 0.0
    # (only for a view whose sky and ground differ in colour: the classes of the second pass start from it)
    if (init_classes is None and colour is not None and abs(offset) >= P.sky_colour_min_contrast
            and (no_sky >= P.colour_second_pass_fraction or masked_share >= P.colour_second_pass_masked)):
        # where a slope was taken for the sky, the sector's classes were fitted on it and the line followed
        # its foot; the real horizon above it (often there, near the top of the view) is found again from
        # classes that start from the pixels' colour: the sky's colour as sky, the ground's as ground.  The
        # same where the first pass masked many columns: a haze brightening low in the sky, fitted into the
        # bright class with a sunlit floor below it, sends the path across the sky's gradient (masked there)
        share = (chroma - np.float32(g_ref)) / np.float32(offset)
        lo, hi = P.sky_colour_ramp
        init = (share >= hi, share <= lo)
        # the first pass's images are not needed any more (the second one makes its own: 256 MB on board)
        del share, grey, blur, tex, chroma, feats, p, proj, diff, sky_cls, ground_cls, sky0, ground0
        again = _detect_direct(image, seen, wrap, P, init_classes=init)
        # ... and on those classes without their re-fit: fitted on every row above the second pass's line, the
        # clear upper sky (a narrow spread) makes the 20-40 rows of whitish haze above a far floor's horizon a
        # ground value in grey and colour alike, and the path climbs back into the gradient.  Tried only while
        # the better detection so far still masks P.colour_second_pass_masked of the seen columns; of the
        # detections, the one that keeps the most columns (every one under the same checks) is kept
        best, label, best_valid = valid.sum(), None, valid
        if again.valid.sum() > best:
            best, label, best_valid = again.valid.sum(), "kept", again.valid
        # (every masked column counts: restricted to those with the sky's colour above the first line, the third
        # detection missed held-out labels whose masked columns it does recover, Ötztal distorted 91 -> 100 %)
        still_masked = float(np.mean(~best_valid[seen_cols])) if seen_cols.any() else 0.0
        n_detections = 2
        if (P.colour_second_pass_unrefitted and P.iterations > 1
                and still_masked >= P.colour_second_pass_masked):
            plain = _detect_direct(image, seen, wrap, replace(P, iterations=1), init_classes=init)
            n_detections = 3
            if plain.valid.sum() > best:
                again, label = plain, "kept, classes of the colour"
        del init
        if label is not None:
            again.diagnostics.update(colour_second_pass=label, detections_run=n_detections)
            return again
        diag.update(colour_second_pass="ran, first pass kept", detections_run=n_detections)
    last_seen = H - 1 - np.argmax(seen[::-1], axis=0)
    diag["line_at_top_fraction"] = float(np.mean(b <= first_seen + 1))
    diag["line_at_bottom_fraction"] = float(np.mean(b >= last_seen))
    diag["valid_fraction"] = float(valid.mean())
    return Detection(np.where(valid, y, np.nan), y, conf, valid, diag, clipped, context)


def _initial_classes(blur: np.ndarray, seen: np.ndarray, n_seen_col: np.ndarray, edges: np.ndarray,
                     P: DetectorParams) -> tuple[np.ndarray, np.ndarray, float]:
    """(sky, ground) masks of the first class fit and the share of sectors whose sky is the brighter class.

    First split, per azimuth sector: Otsu on the seen pixels; the sky class is the one filling the top of
    the seen area (sunlit ground can be brighter than the sky on one side only)."""
    seen_rank = np.cumsum(seen, axis=0, dtype=np.int32)
    band = np.maximum(2, 0.1 * n_seen_col)[None, :]
    top = seen & (seen_rank <= band)
    bottom = seen & (seen_rank > n_seen_col[None, :] - band)
    del seen_rank
    g_thr, g_bright = _otsu_split(blur, seen, top, bottom)
    thr_s, bright_s = [], []
    for c0, c1 in zip(edges[:-1], edges[1:]):
        if seen[:, c0:c1].sum() < P.min_sector_pixels:
            thr_s.append(g_thr), bright_s.append(g_bright)
            continue
        t, b_ = _otsu_split(blur[:, c0:c1], seen[:, c0:c1], top[:, c0:c1], bottom[:, c0:c1])
        thr_s.append(t), bright_s.append(b_)
    del top, bottom
    thr_col = np.repeat(np.array(thr_s, dtype=np.float32), np.diff(edges))
    bright_col = np.repeat(np.array(bright_s), np.diff(edges))
    sky0 = seen & ((blur > thr_col[None, :]) == bright_col[None, :])
    ground0 = seen & ~sky0
    if P.initial_bands > 0:
        # the brightness split can put sunlit ground with a sky of the same grey.  Where it contradicts
        # the view (its "sky" fills the bottom of the seen rows, or its "ground" the top), take the top
        # and the bottom of the view as sky and ground instead: true of any view with a horizon in it
        seen_rank = np.cumsum(seen, axis=0, dtype=np.int32)
        band = np.maximum(2, P.initial_bands * n_seen_col)[None, :]
        top_b = seen & (seen_rank <= band)
        bot_b = seen & (seen_rank > n_seen_col[None, :] - band)
        del seen_rank
        for c0, c1 in zip(edges[:-1], edges[1:]):
            t, bo = top_b[:, c0:c1], bot_b[:, c0:c1]
            sky_at_bottom = (sky0[:, c0:c1] & bo).sum() > 0.5 * max(bo.sum(), 1)
            ground_at_top = (ground0[:, c0:c1] & t).sum() > 0.5 * max(t.sum(), 1)
            if sky_at_bottom or ground_at_top:
                sky0[:, c0:c1] = t
                ground0[:, c0:c1] = bo
    return sky0, ground0, float(np.mean(bright_s))


def _feature_stack(blur: np.ndarray, tex: np.ndarray, chroma: np.ndarray | None
                   ) -> tuple[list[np.ndarray], list[float], list[int]]:
    """(features, their spread floors, the indices of the smooth ones the edge is measured on): blurred
    intensity and log texture, plus chroma for colour images."""
    if chroma is None:
        return [blur, tex], [0.01, 0.05], [0]
    return [blur, tex, chroma], [0.01, 0.05, 0.01], [0, 2]


def _feature_likelihoods(n_features: int, P: DetectorParams) -> dict:
    """:func:`_class_llr`'s per-feature options for :func:`_feature_stack`'s features (intensity, roughness,
    colour): ``caps``, only smoothness's sky evidence capped; ``monotone``, intensity and colour when
    ``P.monotone_classes``, never the roughness (one-sided, its sky class at the floor: made monotone it
    moved the line of dark lunar skies by 0.003 deg and nothing else)."""
    return {"caps": [None, P.smooth_evidence_cap, None][:n_features],
            "monotone": [P.monotone_classes, False, P.monotone_classes][:n_features]}


def _sky_probability(llr: np.ndarray) -> np.ndarray:
    """``1 / (1 + exp(-llr))`` in place (``llr`` clipped to +-20 first); returns the same array."""
    np.clip(llr, -20.0, 20.0, out=llr)
    np.negative(llr, out=llr)
    np.exp(llr, out=llr)
    llr += 1.0
    np.reciprocal(llr, out=llr)
    return llr


def _subpixel_line(blur: np.ndarray, lin: np.ndarray, diff: np.ndarray, b: np.ndarray, seen_pair: np.ndarray,
                   polarity: np.ndarray, sep_col: np.ndarray, contrast: np.ndarray, P: DetectorParams, *,
                   lin_rgb: np.ndarray | None = None,
                   phase: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Sub-pixel line per column (rows) from the intensity step where intensity separates the classes and
    the grey level steps at the line by at least ``P.local_grey_step`` of the class ``contrast`` (colour
    edges shift with lens dispersion), from the discriminant's step ``diff`` elsewhere.  The step's sign is
    the local one (``polarity``, the classes' sky -> ground sign, where the grey level is flat).  ``blur`` is
    the stored grey (the classes' units), ``lin`` the same blurred grey as linear light, where the step is
    placed (an sRGB-encoded blurred step peaks up to half a pixel towards its dark side).

    A sky clipped above the line hides its half of the step and the line stays below the edge; the
    extraction moves it back (:mod:`board.clipped_sky`, from the clipped band this detector counts).

    ``lin_rgb`` (colour images, (H, W, 3) linear light blurred like ``lin``): where a column's ground and sky
    colours just below and above the line differ by ``P.colour_step_min`` at least, the step is placed on
    the linear colour projected on that difference instead (:func:`_colour_step`): a mixed pixel is linear
    in its sky share in every channel, so the projection's half-way point is the edge as the grey's is, and
    it carries the colour contrast where the grey has little (a sunlit crest as bright as the sky), which
    the log-chroma discriminant has too but not linearly.

    ``phase``: the view's phase curve (:func:`board.detect.subpixel_phase.table_for_width`), applied where the
    step is linear light (the intensity and the colour step; the discriminant's is not linear in the pixel's
    ground share)."""
    # the step's sign and size where the line is, not the classes' (a haze band can make the sky just above
    # the horizon brighter than the ground while the sky as a whole is darker)
    w = P.contrast_window_px
    sf = seen_pair.astype(np.float32)
    above, _ = _window_mean(blur[:-1], sf, b - 1, -w + 1, 1)
    below, _ = _window_mean(blur[1:], sf, b - 1, 1, w + 1)
    local = np.nan_to_num(below - above)
    polarity = np.where(local != 0, np.sign(local), polarity).astype(np.float32)
    istep = np.zeros(lin.shape, dtype=np.float32)
    np.subtract(lin[1:], lin[:-1], out=istep[1:])
    istep[1:] *= seen_pair
    istep *= polarity[None, :]
    on_grey = (sep_col >= P.intensity_subpixel_separation) & (np.abs(local) >= P.local_grey_step * contrast)
    g = P.subpixel_gaussian
    y = np.where(on_grey, _subpixel(istep, b, g, phase), _subpixel(diff, b, g))
    if lin_rgb is None or not P.linear_colour_step:
        return y
    clip = float(to_linear(np.array([P.saturation_level], np.float32), P.transfer)[0]) - 1e-4
    cstep, length, whole = _colour_step(lin_rgb, sf, b, w, clip)
    use = (length >= P.colour_step_min) & (length >= P.colour_step_min_share * whole)
    return np.where(use, _subpixel(cstep, b, g, phase), y)


def _colour_step(lin_rgb: np.ndarray, sf: np.ndarray, b: np.ndarray, w: int, clip: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertical step (r-1 -> r, stored at r, ground side positive) of the linear colour projected on each column's
    unit ground - sky difference across the ground's colour (the means of ``w`` rows below and above the line
    ``b``), that difference's length and the whole difference's (linear fractions of full scale); ``sf``
    (H-1, W) weights the seen row pairs.  A channel clipped (at ``clip`` or above, linear light: the detector's
    saturation level through the image's transfer) in any of the ``w`` rows on either side is left out of that
    column's difference: clipped, it is not linear in the mix."""
    clip = np.float32(clip)
    d, g = [], []
    for c in range(lin_rgb.shape[2]):
        ch = lin_rgb[..., c]
        above, _ = _window_mean(ch[:-1], sf, b - 1, -w + 1, 1)
        below, _ = _window_mean(ch[1:], sf, b - 1, 1, w + 1)
        sat = ch >= clip
        sat_a, _ = _window_mean(sat[:-1].astype(np.float32), sf, b - 1, -w + 1, 1)
        sat_b, _ = _window_mean(sat[1:].astype(np.float32), sf, b - 1, 1, w + 1)
        keep = ~((np.nan_to_num(sat_a) > 0) | (np.nan_to_num(sat_b) > 0))
        d.append(np.where(keep, np.nan_to_num(below - above), 0.0))
        g.append(np.where(keep, np.nan_to_num(below), 0.0))
    d = np.stack(d, axis=-1).astype(np.float32)                 # (W, 3): ground - sky
    g = np.stack(g, axis=-1).astype(np.float32)                 # (W, 3): the ground's colour
    # only the part of the difference across the ground's own colour: the ground's shading (texture, a
    # sunlit crest) scales its colour and moves nothing along that part, where a mixed pixel is linear
    # in its sky share
    whole = np.sqrt((d * d).sum(axis=-1))
    gn = g / np.maximum(np.sqrt((g * g).sum(axis=-1)), np.float32(1e-9))[:, None]
    d -= (d * gn).sum(axis=-1)[:, None] * gn
    length = np.sqrt((d * d).sum(axis=-1))
    u = d / np.maximum(length, np.float32(1e-9))[:, None]
    proj = np.einsum("hwc,wc->hw", lin_rgb, u, dtype=np.float32)
    step = np.zeros(proj.shape, dtype=np.float32)
    np.subtract(proj[1:], proj[:-1], out=step[1:])
    step[1:] *= sf
    return step, length, whole


def _colour_projection(feats: list[np.ndarray], stats: list, chroma: np.ndarray | None,
                       P: DetectorParams) -> np.ndarray | None:
    """The colour feature alone scaled sky 0 / ground 1 (for the colour step-above check), or None."""
    if chroma is None or not P.colour_step_above:
        return None
    return _discriminant(feats, stats, [2])[0]


def _valid_columns(conf: np.ndarray, n_seen_col: np.ndarray, wrap: bool, P: DetectorParams) -> np.ndarray:
    """Columns kept: confident and seen; masked runs long enough to have dragged the smooth path off the
    line grown by ``P.mask_margin_columns``; kept runs shorter than ``P.min_run_columns`` dropped."""
    valid = conf >= P.min_confidence
    valid &= n_seen_col > 0
    long_bad = ~_drop_short_runs(~valid, P.min_run_columns, wrap)
    valid &= _grow_mask(long_bad, P.mask_margin_columns, wrap)
    return _drop_short_runs(valid, P.min_run_columns, wrap)


def _node_cost(p: np.ndarray, proj: np.ndarray, seen: np.ndarray, seen_pair: np.ndarray, P: DetectorParams
               ) -> tuple[np.ndarray, np.ndarray]:
    """Node cost of a boundary just above each row (region + edge terms, see the module docstring) and the
    vertical step of the discriminant (r-1 -> r, stored at r), both (H, W) float32."""
    H, W = p.shape
    diff = np.zeros((H, W), dtype=np.float32)
    np.subtract(proj[1:], proj[:-1], out=diff[1:])
    diff[1:] *= seen_pair
    # region cost of a boundary just above row b: sky-like pixels below + ground-like above
    qcum = np.zeros((H + 1, W), dtype=np.float32)
    np.cumsum(np.where(seen, p - np.float32(0.5), np.float32(0.0)), axis=0, out=qcum[1:])
    node = qcum[:-1] * np.float32(-2.0)                # (H, W), boundary above row b
    node += qcum[-1][None, :]
    del qcum
    node -= node.min(axis=0, keepdims=True)
    node *= np.float32(1.0 / P.region_scale_px)
    np.minimum(node, np.float32(P.region_cap), out=node)
    # + edge term: 1 - (sky -> ground step, scaled to the scene contrast)
    edge = diff * np.float32(2.0)
    np.clip(edge, 0.0, 1.0, out=edge)
    edge *= np.float32(-P.edge_weight)
    edge += np.float32(P.edge_weight)
    node += edge
    return node, diff


def _reflect_rows(rows: np.ndarray, H: int) -> np.ndarray:
    """Row indices mapped into [0, H) as ``cv2.BORDER_REFLECT`` extends an image (fedcba|abcdef|fedcba)."""
    r = np.where(rows < 0, -rows - 1, rows)
    r = np.where(r >= H, 2 * H - 1 - r, r)
    return np.clip(r, 0, H - 1)


def _vertical_features(image: np.ndarray, P: DetectorParams
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """grey, vertically blurred grey, log texture and (blurred) chroma of an image, as the detector makes them
    (vertical-only blur: a horizontal one would smear steep slopes into ramps and bias the line)."""

    grey, full = to_grey01(image)
    blur = _vertical_blur(grey, P)
    tex = _texture(grey, P.texture_window_px)
    # an integer image's smooth gradient (a haze band brightening to the horizon) steps one level every
    # few rows: its second differences of +-1 level are quantisation, not texture.  Below the floor all
    # roughness is alike (a clean sky rendered to 8 bits is not rougher where its gradient is steeper)
    np.maximum(tex, np.float32(texture_floor(full, P)), out=tex)
    tex += 1e-3
    np.log(tex, out=tex)
    chroma = _chroma(image) if P.use_colour else None
    if chroma is not None:
        chroma = _vertical_blur(chroma, P)
    return grey, blur, tex, chroma


def _vertical_blur(a: np.ndarray, P: DetectorParams) -> np.ndarray:
    """``a`` blurred along the rows (columns untouched) by a Gaussian of ``P.blur_sigma_px``; ``a`` itself when 0."""
    import cv2

    if P.blur_sigma_px <= 0:
        return a
    k = cv2.getGaussianKernel(2 * int(math.ceil(3 * P.blur_sigma_px)) + 1, P.blur_sigma_px, cv2.CV_32F)
    return cv2.sepFilter2D(a, -1, np.ones((1, 1), np.float32), k, borderType=cv2.BORDER_REFLECT)


def _linear_light(image: np.ndarray, P: DetectorParams) -> tuple[np.ndarray, np.ndarray | None]:
    """The image as linear light (``P.transfer`` undone per channel, once): its grey, where the sub-pixel step is
    placed once blurred vertically like :func:`_vertical_features`'s grey, and for a colour image with
    ``P.linear_colour_step`` its channels already blurred so (H, W, 3), else None."""
    import cv2

    lin = to_linear(image, P.transfer)
    if lin.ndim != 3:
        return lin, None
    grey = cv2.cvtColor(lin, cv2.COLOR_BGR2GRAY)
    return grey, (_vertical_blur(lin, P) if P.linear_colour_step and lin.shape[2] == 3 else None)


def texture_floor(full_scale: float, P: DetectorParams) -> float:
    """Roughness (fraction of full scale) below which a texture is quantisation: ``P.quantisation_texture_levels``
    grey levels of an integer image (``full_scale`` 255 or 65535), 0 for a float image (``full_scale`` 1)."""
    return P.quantisation_texture_levels / full_scale if full_scale > 1.0 else 0.0


def _detect_coarse_to_fine(img: np.ndarray, seen: np.ndarray | None, wrap: bool, P: DetectorParams) -> Detection:
    """Detection of a large image: the whole detector on a copy reduced ``f`` times (an integer, ``f^2`` of
    about ``P.max_direct_pixels``), then at full resolution in a band of rows around that line: the
    features, the classes re-fitted on the two sides of the coarse line (per sector, as in the re-fit of
    the direct detector), the node costs, the smooth path (its jumps counted in image rows, exactly), the
    sub-pixel position and the column confidence, which is also capped by the coarse one's wide-window
    checks (region consistency, glare and saturation, a step above the line, the sky's colour: their
    windows see ``f`` times further, a hazy ridge far above the line, a glare patch), but not by its step
    contrast unless ``P.coarse_contrast_cap``: the reduced copy's classes are fitted over whole sectors,
    where a sunlit face brighter than the sky and the shaded ground below it mix, and the step at the
    skyline can run against their polarity where the band's classes, fitted next to the line, measure
    it right.  Only the reduced copy and the band are ever held as float images."""
    import cv2

    H, W = img.shape[:2]
    f = int(math.ceil(math.sqrt(H * W / P.max_direct_pixels)))
    Hc, Wc = max(64, int(round(H / f))), max(64, int(round(W / f)))
    src = img.astype(np.uint8) * np.uint8(255) if img.dtype == bool else img
    small = cv2.resize(src, (Wc, Hc), interpolation=cv2.INTER_AREA)
    del src
    seen_c = None
    if seen is not None:
        seen = seen_or_all(seen, (H, W))
        if seen.all():
            seen = None
        else:
            # a reduced pixel is seen when all the pixels it averages are (unseen pixels are black)
            seen_c = cv2.resize(seen.view(np.uint8) * np.uint8(255), (Wc, Hc), interpolation=cv2.INTER_AREA) >= 255
    coarse = _detect_direct(small, seen_c, wrap, P)
    del small, seen_c
    diag = dict(coarse.diagnostics)
    diag.update(height=H, width=W, pyramid_factor=f)
    if not np.isfinite(coarse.raw_row).any():
        return _empty(W, diag)
    sy, sx = H / Hc, W / Wc
    cols = np.arange(W)
    centres = (np.arange(Wc) + 0.5) * sx - 0.5
    guide_c = (coarse.raw_row + 0.5) * sy - 0.5
    guide = np.interp(cols, centres, guide_c, period=W) if wrap else np.interp(cols, centres, guide_c)
    col_c = np.minimum(((cols + 0.5) / sx).astype(np.int64), Wc - 1)
    conf_c = (coarse.confidence if P.coarse_contrast_cap else coarse.context_confidence)[col_c]
    clipped_c = coarse.clipped_rows[col_c] * sy if coarse.clipped_rows is not None else np.zeros(W)
    n_seen_col = np.full(W, H) if seen is None else seen.sum(axis=0)
    del coarse

    R = P.region_window_px + P.contrast_window_px + 4 * f       # band rows each side of the coarse line
    M = P.texture_window_px + 2 + int(math.ceil(3 * P.blur_sigma_px))   # filter margin, cropped after
    Hb = 2 * R
    off = np.rint(guide).astype(np.int64) - R                   # image row of band row 0, per column
    rows = off[None, :] + np.arange(-M, Hb + M)[:, None]
    band = img[_reflect_rows(rows, H), cols[None, :]]
    rows = rows[M:-M]
    bseen = (rows >= 0) & (rows < H)
    if seen is not None:
        bseen &= seen[np.clip(rows, 0, H - 1), cols[None, :]]
    del rows
    grey, blur, tex, chroma = (None if a is None else a[M:-M] for a in _vertical_features(band, P))
    lin_raw, lin_rgb = _linear_light(band, P)
    lin = _vertical_blur(lin_raw, P)[M:-M]
    lin_raw = lin_raw[M:-M]
    lin_rgb = None if lin_rgb is None else lin_rgb[M:-M]
    del band
    feats, floors, step_features = _feature_stack(blur, tex, chroma)
    sky_cls, ground_cls = _bands_from_line(guide - off, Hb, P.refit_margin_px + f, P.sky_band_px)
    sky_cls &= bseen
    ground_cls &= bseen
    if sky_cls.sum() < 50 or ground_cls.sum() < 50:
        return _empty(W, diag | {"reason": "one class only"})
    edges = _sector_edges(W, P.n_sectors)
    p, stats = _class_llr(feats, sky_cls, ground_cls, floors, edges, P.min_sector_pixels, wrap,
                          broaden=P.ground_broadening, **_feature_likelihoods(len(feats), P))
    del sky_cls, ground_cls
    _sky_probability(p)
    mu_s, sd_s, mu_g, sd_g, glob_s, glob_g = stats[0]
    if not (np.isfinite(glob_s[0]) and np.isfinite(glob_g[0])):
        return _empty(W, diag | {"reason": "one class only"})
    polarity = np.where(mu_g >= mu_s, 1.0, -1.0).astype(np.float32)
    proj, sd_proj_sky = _discriminant(feats, stats, step_features)
    seen_pair = bseen[1:] & bseen[:-1]
    node, diff = _node_cost(p, proj, bseen, seen_pair, P)
    b = shortest_path_l1(node, jump_cost=P.jump_cost_per_px, wrap=wrap, margin=P.wrap_margin_columns,
                         offsets=off).rows_top.astype(np.int64)
    contrast = np.abs(mu_g - mu_s)
    sep_col = contrast / np.hypot(sd_s, sd_g)
    colour_proj = _colour_projection(feats, stats, chroma, P)

    def clipped_rows(b: np.ndarray) -> np.ndarray:
        # the clipped band above the line: counted in the band, and on the reduced copy where it fills the band
        clipped = P.clipped_above(grey, b).astype(np.float64)
        # (a run stepped over a mixed row above the line reaches the band's top a row or two sooner)
        return np.where(b - clipped <= P.clipped_gap_rows, np.maximum(clipped, clipped_c), clipped)

    def line_and_confidence(b: np.ndarray, on_step: np.ndarray | None = None,
                            checks: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
        y = _subpixel_line(blur, lin, diff, b, seen_pair, polarity, sep_col, contrast, P, lin_rgb=lin_rgb,
                           phase=phase)
        conf, _ = _confidence(grey, proj, p, bseen, b, sd_proj_sky, P, colour_proj, on_step, checks, wrap,
                              black=_black_sky(grey, bseen, b, P))
        np.minimum(conf, conf_c, out=conf)
        return y, conf

    clipped = clipped_rows(b)
    diag["edge_width_px"] = edge_width_px(lin_raw, b, clipped)
    phase = _phase_curve(diag["edge_width_px"], P)
    del lin_raw
    checks: dict = {}
    y, conf = line_and_confidence(b, checks=checks)
    if P.reseat_on_step_above:
        scored: dict = {}

        def score(b2: np.ndarray, on_step: np.ndarray) -> np.ndarray:
            scored["y"], scored["conf"] = line_and_confidence(b2, on_step)
            return scored["conf"]

        top = np.zeros(W, dtype=np.int64) if seen is None else np.argmax(seen, axis=0)   # the view's first seen row
        b2, take = _reseat_on_step_above(node, b, conf, checks, score, top - off, P, wrap, offsets=off)
        diag["refined_reseated_columns"] = int(take.sum())
        first_conf = conf
        if take.any():
            y, conf = np.where(take, scored["y"], y), np.where(take, scored["conf"], conf)
            b_taken = np.where(take, b2, b)
            clipped = np.where(take, clipped_rows(b2), clipped)
    node = diff = lin = lin_rgb = None   # freed (the closures above are done with them)
    valid = _valid_columns(conf, n_seen_col, wrap, P)
    if P.reseat_on_step_above and take.any():
        valid = _masks_after_reseat(valid, take, first_conf, b + off, b_taken + off, n_seen_col, wrap, P)
    y = y + off
    diag["valid_fraction"] = float(valid.mean())
    diag["refined_shift_px_median"] = float(np.median(np.abs(y - guide)))
    return Detection(np.where(valid, y, np.nan), y, conf, valid, diag, clipped)


def _empty(W: int, diag: dict) -> Detection:
    nan = np.full(W, np.nan)
    return Detection(nan, nan.copy(), np.zeros(W), np.zeros(W, dtype=bool), diag)


def _phase_curve(edge_width_px: float, P: DetectorParams) -> tuple[np.ndarray, np.ndarray] | None:
    """The box pixel's phase curve for the lens a view's measured edge width implies
    (:func:`board.detect.subpixel_phase.table_for_width`), None when ``P`` does not read the peak through it."""
    if not (P.subpixel_gaussian and P.subpixel_phase):
        return None
    return table_for_width(edge_width_px, P.blur_sigma_px)


def _subpixel(step: np.ndarray, b: np.ndarray, gaussian: bool = False,
              phase: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Line position: the strongest step within +-1 row of ``b``, refined by a parabola (rows) through the three
    samples around it or, ``gaussian``, through their logarithms where all three are positive (a Gaussian's peak
    exactly: a blurred edge's step is nearly one, and the samples' parabola pulls its peak towards the sampled row
    by up to 0.05 px at a blur of 1 px, 0.07 px at 0.8 px); ``phase`` (with ``gaussian``): that Gaussian's
    offset read through a box pixel's phase curve (:func:`board.detect.subpixel_phase.undo_phase`)."""
    H, W = step.shape
    cols = np.arange(W)
    offs = np.arange(-1, 2)
    cand = np.clip(b[None, :] + offs[:, None], 1, H - 1)
    s = step[cand, cols[None, :]]
    k = np.argmax(s, axis=0)
    bb = cand[k, cols]
    g0 = step[np.clip(bb - 1, 0, H - 1), cols]
    g1 = step[bb, cols]
    g2 = step[np.clip(bb + 1, 0, H - 1), cols]
    den = g0 - 2.0 * g1 + g2
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(den < -1e-9, 0.5 * (g0 - g2) / den, 0.0)
        if gaussian:
            pos = (g0 > 0) & (g1 > 0) & (g2 > 0)
            l0, l1, l2 = (np.log(np.where(pos, g, 1.0)) for g in (g0, g1, g2))
            den = l0 - 2.0 * l1 + l2
            gauss = pos & (den < -1e-9)
            d = np.where(gauss, 0.5 * (l0 - l2) / den, d)
    d = np.clip(d, -0.5, 0.5)
    if gaussian and phase is not None:
        d = np.where(gauss, undo_phase(d, phase), d)
    # step[r] sits between rows r-1 and r, i.e. at r - 0.5
    return bb - 0.5 + d


def _window_mean(a: np.ndarray, w: np.ndarray, b: np.ndarray, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean of ``a`` over rows [b+lo, b+hi) of every column (weights ``w``), and the weight sum."""
    H, W = a.shape
    rows = b[None, :] + np.arange(lo, hi)[:, None]
    inside = (rows >= 0) & (rows < H)
    rows = np.clip(rows, 0, H - 1)
    cols = np.arange(W)[None, :]
    ww = w[rows, cols] * inside
    sw = ww.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = (a[rows, cols] * ww).sum(axis=0) / sw
    return m, sw


def _discriminant(feats: list[np.ndarray], stats: list, which: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Fisher projection of the features ``which`` per column, scaled so sky maps to 0 and ground to 1.

    Independent features: weight ``(mu_g - mu_s) / var`` each (var: mean of the two class variances),
    normalised by the total; returns the projected (H, W) float32 image and the sky spread on it (W,).
    """
    W = feats[0].shape[1]
    coef, den = [], np.zeros(W)
    for i in which:
        ms, ss, mg, sg = stats[i][:4]
        a = (mg - ms) / (0.5 * (ss * ss + sg * sg))
        coef.append(a)
        den += (mg - ms) * a
    den = np.maximum(den, 1e-12)
    proj = np.zeros(feats[0].shape, dtype=np.float32)
    offset, var_s = np.zeros(W), np.zeros(W)
    for i, a in zip(which, coef):
        a = a / den
        proj += feats[i] * a.astype(np.float32)[None, :]
        offset += a * stats[i][0]
        var_s += (a * stats[i][1]) ** 2
    proj -= offset.astype(np.float32)[None, :]
    return proj, np.sqrt(var_s)


def _step_above(proj: np.ndarray, seen: np.ndarray, b: np.ndarray, P: DetectorParams, wrap: bool = False,
                black: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per column, 1 where ``proj`` (sky 0, ground 1 per column) has no sky-to-ground step above the line, 0
    where it has one of ``P.above_step_range`` or more (and 6 noise sigmas of such steps in the sky: the view's,
    or in a ``black``-sky view its azimuth sector's where larger, ``P.above_step_sector_noise``), and the row just
    below the largest such step (-1: none)."""
    edges = _sector_edges(proj.shape[1], P.n_sectors) if (black and P.above_step_sector_noise) else None
    s_above, s_noise, row = _largest_step_above(proj, seen, b, P.above_step_window_px, edges, wrap)
    lo, hi = P.above_step_range
    lo = np.maximum(lo, 6.0 * s_noise)
    hi = np.maximum(hi, lo + 0.05)
    return 1.0 - np.clip((s_above - lo) / (hi - lo), 0, 1), row


def _black_sky(grey: np.ndarray, seen: np.ndarray, b: np.ndarray, P: DetectorParams) -> tuple[float, float] | None:
    """The sky's level and noise (grey, 0-1: :func:`_fit`'s median and 1.4826 MAD, floored at half a level of
    8 bits) when the view's sky is black (airless: no gradient, haze or glow of its own), else None.

    The one definition of "a black-sky view" for the checks that act only there: the seen pixels more than 20
    rows above the line (every 4th row and column: a few thousand pixels, not millions), at least 500 of them,
    whose median is darker than ``P.black_sky_grey`` (0 turns those checks off)."""
    if P.black_sky_grey <= 0:
        return None
    H = grey.shape[0]
    far = seen[::4, ::4] & (np.arange(0, H, 4)[:, None] < (b[None, ::4] - 20))
    vals = grey[::4, ::4][far]
    if vals.size < 500:
        return None
    sky, sd = _fit(vals, 0.5 / 255.0)
    return (sky, sd) if sky < P.black_sky_grey else None


def _faint_ground_above(grey: np.ndarray, seen: np.ndarray, b: np.ndarray, P: DetectorParams, wrap: bool,
                        black: tuple[float, float] | None) -> np.ndarray:
    """Per column 1, or down to 0 where, under a black (airless) sky, the rows just above the line are brighter
    than the sky by more than its noise: a shaded far ridge, lit only by the ground around it (a few grey
    levels over the sky's black), rising behind a sunlit near edge that the line follows.  Its step is far
    below the classes' contrast (the step-above check's 0.15) but, averaged over ``P.faint_ground_rows`` and
    ``P.faint_ground_columns`` each side, many noise sigmas of a sky that has no gradient, haze or glow.

    ``black``: the view's sky level and noise (:func:`_black_sky`); views whose sky is not black (None) are not
    checked.
    """
    W = grey.shape[1]
    ones = np.ones(W)
    m, k = P.faint_ground_rows
    if k <= m:
        return ones
    if black is None:
        return ones
    sky, sd = black
    band, nb = _window_mean(grey, seen.astype(np.float32), b, -k, -m)
    weight = nb * (nb >= 0.5 * (k - m))                  # seen rows of a column's band (none: too few seen)
    h = max(int(P.faint_ground_columns), 0)
    box = np.ones(2 * h + 1)
    if wrap and W > 2 * h:
        ext = lambda a: np.concatenate([a[-h:], a, a[:h]]) if h else a  # noqa: E731
        num = np.convolve(ext(np.nan_to_num(band - sky) * weight), box, "valid")
        den = np.convolve(ext(weight), box, "valid")
    else:
        num = np.convolve(np.nan_to_num(band - sky) * weight, box, "same")
        den = np.convolve(weight, box, "same")
    with np.errstate(invalid="ignore", divide="ignore"):
        z = (num / den) / (sd / np.sqrt(den))
    z = np.where(den > 0, z, 0.0)
    z0, z1 = P.faint_ground_z
    return 1.0 - np.clip((z - z0) / (z1 - z0), 0.0, 1.0)


def _confidence(grey: np.ndarray, proj: np.ndarray, p: np.ndarray, seen: np.ndarray, b: np.ndarray,
                sigma_sky: np.ndarray, P: DetectorParams, colour_proj: np.ndarray | None = None,
                on_step: np.ndarray | None = None, checks: dict | None = None, wrap: bool = False,
                black: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-column confidence in [0, 1] (min of the individual checks, see the module docstring) and the
    same without the step-contrast and seen-rows checks: the checks whose windows look beyond the step
    (region consistency, saturation and glare, a step above the line).

    proj : the discriminant image (sky 0, ground 1 per column); sigma_sky : its sky spread;
    colour_proj : the same scaling of the colour feature alone (None for grey images); on_step : (W,) bool,
    the columns of a path re-seated on a step above the first line (:func:`_step_above_limits`): there a
    pixel below the line also counts as ground where the discriminant is past the middle of the line's own
    step (a far ridge as bright as the sky, that the classes ``p``, fitted on the whole sector's ground, call
    sky); checks : a dict that receives
    the individual checks' factors (``"region"``, ``"above"``) and the step-above check's factor and step
    row per column on the discriminant and the colour (``"above_steps"``, :func:`_step_above`); black : the
    view's :func:`_black_sky` for this line (None: the sky is not black)."""
    w = P.contrast_window_px
    sf = seen.astype(np.float32)
    above, n_above = _window_mean(proj, sf, b, -w, 0)
    below, n_below = _window_mean(proj, sf, b, 0, w)
    local = below - above
    # noise of a w-pixel mean of the projection: generous bound from the sky spread
    noise = np.maximum(sigma_sky, P.min_noise) / np.sqrt(w)
    c_contrast = np.minimum(np.clip((local / noise - 3.0) / 3.0, 0, 1), np.clip((local - 0.1) / 0.2, 0, 1))
    R = P.region_window_px
    sky_like = (p > 0.5).astype(np.float32)
    fs, ns = _window_mean(sky_like, sf, b, -R, 0)
    ground_like = 1.0 - sky_like
    if on_step is not None and on_step.any():
        # below a re-seated line, ground is what stays past the middle of the line's own step (a far ridge
        # between the sky and a dark slope in grey is nearer the sky's level than the slope's)
        mid = np.nan_to_num(above + 0.5 * local, nan=0.5).astype(np.float32)
        ground_like = np.where(on_step[None, :], np.maximum(ground_like, (proj > mid[None, :]).astype(np.float32)),
                               ground_like)
    fg, ng = _window_mean(ground_like, sf, b, 0, R)
    c_region = np.minimum(np.clip((fs - 0.6) / 0.3, 0, 1), np.clip((fg - 0.45) / 0.3, 0, 1))
    # clipped on both sides of the line (glare, over-exposure, crushed blacks): the step is not measurable.
    # One clipped side is fine (a black lunar sky, a saturated sky over lit ground).
    # Below the line the window is deep: glare that saturates the ground a few rows down also makes
    # saturated ground pass for sky, which would pull the line down with full confidence.
    c_sat = np.ones(b.shape)
    for clipped in (grey >= P.saturation_level, grey <= 1.0 - P.saturation_level):
        c = clipped.astype(np.float32)
        f_above, _ = _window_mean(c, sf, b, -w, 0)
        f_below, _ = _window_mean(c, sf, b, 0, R)
        c_sat = np.minimum(c_sat, 1.0 - np.clip(np.minimum(f_above, f_below) / 0.5, 0, 1))
    # a saturated "sky" over ground touched by saturation is glare, no evidence of sky: mask when most
    # of the sky window is clipped and some of the ground window too.  A saturated sky over unclipped
    # ground (over-exposure) is a measurable boundary and is kept.
    sat = (grey >= P.saturation_level).astype(np.float32)
    f_sky_sat, _ = _window_mean(sat, sf, b, -R, 0)
    f_ground_sat, _ = _window_mean(sat, sf, b, 0, R)
    glare = np.clip((f_ground_sat - 0.02) / 0.03, 0, 1)
    c_sat = np.minimum(c_sat, 1.0 - glare * np.clip((f_sky_sat - 0.3) / 0.3, 0, 1))
    c_seen = ((n_above >= P.min_seen_rows) & (n_below >= P.min_seen_rows)).astype(np.float64)
    # a sky-to-ground step above the line: a hazy distant ridge the line passed under
    steps = [_step_above(proj, seen, b, P, wrap, black is not None)]
    if colour_proj is not None:
        # ... in colour alone too: sunlit ground brighter than the sky (and a shaded slope below it) can
        # make the intensity-and-colour discriminant of the ground strip between them look like sky,
        # while its colour is plainly the ground's
        steps.append(_step_above(colour_proj, seen, b, P, wrap, black is not None))
    c_above = np.minimum.reduce([c for c, _ in steps])
    c_faint = _faint_ground_above(grey, seen, b, P, wrap, black)
    if checks is not None:
        checks.update(region=np.nan_to_num(c_region, nan=0.0), above=np.nan_to_num(c_above, nan=0.0),
                      above_steps=steps)
    context = np.nan_to_num(np.minimum.reduce([c_region, c_sat, c_above, c_faint]), nan=0.0)
    conf = np.minimum.reduce([c_contrast, c_region, c_sat, c_seen, c_above, c_faint])
    log.debug("confidence checks (fraction of columns passing): contrast %.3f region %.3f saturation %.3f seen %.3f "
              "above %.3f faint ground %.3f", np.mean(c_contrast >= 0.5), np.mean(c_region >= 0.5),
              np.mean(c_sat >= 0.5), np.mean(c_seen >= 0.5), np.mean(c_above >= 0.5), np.mean(c_faint >= 0.5))
    return np.nan_to_num(conf, nan=0.0), context


#: node cost added below the limit row of a re-seated path (far more than any path's cost per node)
_FORBIDDEN = 1.0e4
#: rows below a step's row that a re-seated path may still take (the step's row is the largest of 3-row
#: window differences on a blurred image: within a row of the edge)
_LIMIT_SLACK_ROWS = 1


def _solve_above(node: np.ndarray, lim: np.ndarray, b: np.ndarray, P: DetectorParams, wrap: bool,
                 offsets: np.ndarray | None = None) -> np.ndarray:
    """The smooth path (rows, int64) through ``node`` kept at or above row ``lim + _LIMIT_SLACK_ROWS``
    in every column (``lim`` from :func:`_step_above_limits`; ``H``: free); ``offsets``: the image row of
    ``node``'s row 0 per column (a band), as for :func:`shortest_path_l1`.

    Only the columns near the limited ones can change: the path is solved in windows of
    ``2 * P.mask_margin_columns + 2`` columns around each run of limited columns, pinned to the first path
    ``b`` at both ends of the window (the whole width at once when the windows cover half of it)."""
    H, W = node.shape
    limited = lim < H
    if not limited.any():
        return b.copy()
    m = 2 * P.mask_margin_columns + 2
    window = ~_grow_mask(~limited, m, wrap)
    if window.mean() > 0.5:
        kept = np.where(np.arange(H)[:, None] > lim[None, :] + _LIMIT_SLACK_ROWS, np.float32(_FORBIDDEN), node)
        return shortest_path_l1(kept, jump_cost=P.jump_cost_per_px, wrap=wrap, margin=P.wrap_margin_columns,
                                offsets=offsets).rows_top.astype(np.int64)
    shift = int(np.flatnonzero(~window)[0]) if wrap else 0     # a window never straddles column 0 then
    cols = (np.arange(W) + shift) % W
    win = window[cols]
    b2 = b.copy()
    edges = np.flatnonzero(np.diff(np.concatenate([[0], win.astype(np.int8), [0]])))
    for a, c in zip(edges[::2], edges[1::2]):
        cc = cols[max(a - 1, 0):min(c + 1, W)]                  # the window and one pinned column each side
        sub = np.where(np.arange(H)[:, None] > lim[cc][None, :] + _LIMIT_SLACK_ROWS,
                       np.float32(_FORBIDDEN), node[:, cc])
        for j in ((0,) if a > 0 else ()) + ((cc.size - 1,) if c < W else ()):
            pin = np.full(H, np.float32(_FORBIDDEN))
            pin[b[cc[j]]] = 0.0
            sub[:, j] = pin
        path = shortest_path_l1(sub, jump_cost=P.jump_cost_per_px, wrap=False,
                                offsets=None if offsets is None else offsets[cc]).rows_top
        b2[cc] = path
    return b2


def _reseat_on_step_above(node: np.ndarray, b: np.ndarray, conf: np.ndarray, checks: dict, score,
                          first_seen: np.ndarray, P: DetectorParams, wrap: bool, offsets: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The path solved again above the sky-to-ground steps that mask columns of the line ``b``, and the
    columns that take it.

    At the junction where a near slope's edge runs down in front of a far ridge (as bright as the sky in
    grey, plain in colour), the smooth path keeps to the slope's strong edge and the columns are masked for
    the step above them (``checks["above"]`` from :func:`_confidence`).  The skyline lies at or above every
    real sky-to-ground step of its column, so the path is solved again kept at or above those steps
    (:func:`_step_above_limits`, :func:`_solve_above`).  A masked column takes the new path only where it is
    higher and passes every check there: ``score(b2, on_step)`` is the confidence of the path ``b2``, whose
    region check in the ``on_step`` columns also counts as ground the pixels past the middle of the line's
    own step on the discriminant (the classes, fitted on the whole sector's ground, call a far ridge nearly
    as bright as the sky sky).  A column without sky (a near
    slope filling the top of the view) has ground steps above its line too; its new path fails the sky's
    colour or region there and it stays masked.  Two guards keep the new line off what is not a far ridge:
    it must have half a region window of seen rows above it (``first_seen``: the first seen row per column;
    the top rows of a vignetted or distorted view step too), and the columns that take it must form runs of
    ``P.min_run_columns`` at least on their own, across gaps of up to 2 columns (a junction's ridge spans
    many columns; single columns took a step in a noisy sky, in a tuning-split Mars label).  ``offsets``:
    see :func:`_solve_above` (the band of the full-resolution pass).  Returns ``(b2, take)``; ``take`` all
    False when fewer than ``P.min_run_columns`` columns are masked by a step above."""
    H, W = node.shape
    masked = (conf < P.min_confidence) & (checks["above"] < 0.5)
    if not masked.any():
        return b, np.zeros(W, dtype=bool)
    lim = _fill_short_gaps(_step_above_limits(checks["above_steps"], masked, H), H, P.mask_margin_columns)
    on_step = lim < H
    if int(on_step.sum()) < P.min_run_columns:
        return b, np.zeros(W, dtype=bool)
    b2 = _solve_above(node, lim, b, P, wrap, offsets)
    on_step &= (b2 < b) & (b2 - first_seen >= P.region_window_px // 2)
    if not on_step.any():
        return b2, on_step
    take = on_step & (score(b2, on_step) >= P.min_confidence)
    # runs of taking columns, across gaps of up to 2 columns (near the crossing point every other column
    # can fail a check), at least P.min_run_columns long
    closed = ~_drop_short_runs(~take, 3, wrap)
    return b2, take & _drop_short_runs(closed, P.min_run_columns, wrap)


def _masks_after_reseat(valid: np.ndarray, take: np.ndarray, first_conf: np.ndarray, first_row: np.ndarray,
                        new_row: np.ndarray, n_seen_col: np.ndarray, wrap: bool, P: DetectorParams) -> np.ndarray:
    """``valid`` (from the merged confidence) after a re-seat that ``take`` columns took, with two masks kept:

    * a column that did not take the new line is kept only if the first line's confidence ``first_conf`` kept
      it too.  A column next to a long masked run is masked with it (:func:`_valid_columns`' margin: the smooth
      path needs a few columns to leave a wrong row); when the run is re-seated and kept, that margin must not
      go with it: in a held-out Mars label the line dove 20 deg into the foreground beside such a run, and
      three more of its columns were kept;
    * the ``P.mask_margin_columns`` columns beyond each end of a re-seated run are masked where the first line
      next to that end (``first_row``) lies more than ``P.region_window_px`` rows below the re-seated one
      (``new_row``): the first line there is still under the ridge the run was re-seated onto, or dives into
      the foreground beside it (in that Mars label the sample fitted across that cliff was 5 deg off).

    Kept runs shorter than ``P.min_run_columns`` are dropped after both."""
    W = take.size
    out = valid & (take | _valid_columns(first_conf, n_seen_col, wrap, P))
    starts = take & ~np.roll(take, 1) if wrap else take & ~np.concatenate([[False], take[:-1]])
    ends = take & ~np.roll(take, -1) if wrap else take & ~np.concatenate([take[1:], [False]])
    for edge, step in ((starts, -1), (ends, 1)):
        for j in np.flatnonzero(edge):
            nb = j + step
            if not wrap and not 0 <= nb < W:
                continue
            nb %= W
            if first_row[nb] - new_row[j] > P.region_window_px:
                cols = (j + step * np.arange(1, P.mask_margin_columns + 1))
                cols = cols % W if wrap else cols[(cols >= 0) & (cols < W)]
                out[cols[~take[cols]]] = False
    return _drop_short_runs(out, P.min_run_columns, wrap)


def _fill_short_gaps(lim: np.ndarray, H: int, gap: int) -> np.ndarray:
    """``lim`` (W,) with every run of at most ``gap`` free columns (value ``H``) between two limited ones
    given the limit interpolated linearly between them (no wrap): a path limited in every other column of a
    junction zig-zags between the slope's edge and the ridge above it."""
    out = lim.copy()
    idx = np.flatnonzero(lim < H)
    if idx.size < 2:
        return out
    for a, c in zip(idx[:-1], idx[1:]):
        if 1 < c - a <= gap + 1:
            t = (np.arange(a + 1, c) - a) / (c - a)
            out[a + 1:c] = np.rint(lim[a] + t * (lim[c] - lim[a])).astype(out.dtype)
    return out


def _step_above_limits(steps: list[tuple[np.ndarray, np.ndarray]], masked: np.ndarray, H: int) -> np.ndarray:
    """Per column, the row just below the highest sky-to-ground step above the line that masks it, in the
    ``masked`` columns where there is one; ``H`` elsewhere.  ``steps``: the step-above check's factor and
    step row per column, on the discriminant and on the colour alone (:func:`_step_above`, kept by
    :func:`_confidence` as ``checks["above_steps"]``).

    Such a step is a boundary the line passed under: at the junction where a near slope's edge runs down
    in front of a far ridge (as bright as the sky in grey, plain in colour), the smooth path keeps to the
    slope's strong edge and the columns are masked.  The skyline lies at or above every real sky-to-ground
    step of its column, so the path may be solved again above these rows."""
    lim = np.full(masked.size, H, dtype=np.int64)
    for c, row in steps:
        hit = masked & (c < 0.5) & (row >= 0)
        lim = np.where(hit, np.minimum(lim, row), lim)
    return lim


def _sky_colour_unlike_ground(chroma: np.ndarray, seen: np.ndarray, b: np.ndarray, P: DetectorParams,
                              grey: np.ndarray | None = None, black: tuple[float, float] | None = None
                              ) -> tuple[np.ndarray, float, float]:
    """Per column, 1 where the window above the line has the sky's colour, 0 where it has the ground's.

    Where near slopes fill the top of a view, there is no sky in those columns: the per-sector classes
    then take the slope for "sky" and the line falls on an edge inside the ground, with full contrast.
    Colour (log blue / red) hardly depends on the light, and the ground's colour is known from the rows
    below the line everywhere.  The view's sky colour is the far tail of the columns' "sky" colours
    (10th or 90th percentile of their offsets from the ground's, the larger): a real sky in a tenth of
    the view sets it.  A column whose "sky" window is less than ``P.sky_colour_ramp[0]`` of the way from
    the ground's colour to the sky's gets 0, more than ``[1]`` of the way 1.  Views whose sky and ground
    differ by less than ``P.sky_colour_min_contrast`` (grey images, a dusty sky the regolith's colour)
    are not checked (all 1).  With ``grey`` (the image's grey, 0-1), in a view whose sky is black
    (:func:`_black_sky`), a "sky" window darker than ``P.colour_min_grey`` has no
    colour to measure (the log ratio of sensor noise) and is left alone (1), nor does it set the view's sky
    colour; under a bright sky every window is checked as before.  Returns the per-column factor, that sky-ground
    colour offset and the ground's colour (log blue / red).  ``black``: the view's :func:`_black_sky` for this
    line (None: the sky is not black).
    """
    W = b.size
    R, m = P.region_window_px, P.contrast_window_px
    sf = seen.astype(np.float32)
    sky_c, n_s = _window_mean(chroma, sf, b, -R, -m)
    gr_c, n_g = _window_mean(chroma, sf, b, m, R)
    ok_g = n_g >= P.min_seen_rows
    ok_s = n_s >= P.min_seen_rows
    # only in a view whose sky is black (:func:`_black_sky`): under a bright sky a dark "sky" window is a shaded
    # slope, and its colour (even the ratio of noise) is all the check has to go on there, as before
    if grey is not None and P.colour_min_grey > 0 and ok_s.any() and black is not None:
        sky_grey, _ = _window_mean(grey, sf, b, -R, -m)
        ok_s &= sky_grey >= P.colour_min_grey
    if ok_g.sum() < 10 or ok_s.sum() < 10:
        return np.ones(W), 0.0, 0.0
    g_ref = float(np.median(gr_c[ok_g]))
    d = sky_c - g_ref
    lo, hi = np.percentile(d[ok_s], [10.0, 90.0])
    offset = float(hi if abs(hi) >= abs(lo) else lo)
    if abs(offset) < P.sky_colour_min_contrast:
        return np.ones(W), offset, g_ref
    t0, t1 = P.sky_colour_ramp
    share = np.where(ok_s, d / offset, 1.0)
    return np.clip((share - t0) / (t1 - t0), 0.0, 1.0), offset, g_ref


def _largest_step_above(proj: np.ndarray, seen: np.ndarray, b: np.ndarray, k: int,
                        edges: np.ndarray | None = None, wrap: bool = False
                        ) -> tuple[np.ndarray, float | np.ndarray, np.ndarray]:
    """Per column, the largest sky-to-ground step of ``proj`` (mean of ``k`` rows below minus ``k`` rows
    above a row boundary) among the boundaries whose windows lie in seen rows strictly above row ``b - 1``
    (0 where there is no such boundary), the noise of such a step: 1.4826 MAD of the steps in the
    sky more than 10 rows above the line (the features are blurred: the pixel noise would not tell), and
    the row just below that step's boundary (-1 where there is no boundary).

    With sector ``edges`` (:func:`_sector_edges`) the noise is per column: the larger of the view's and its
    sector's (the same MAD over about ``_SECTOR_NOISE_COLUMNS`` evenly spaced columns of the sector, at least 100
    steps, at most 1 000 of them, spread between sector centres as the classes are; circularly when ``wrap``).
    ``proj`` is scaled per column by the sector's class contrast, so a sector of dim ground has a noisier sky in it
    than the view's figure says.

    float32 running sums in place: about four (H, W) float32 arrays at the peak.
    """
    H, W = proj.shape
    if H < 2 * k + 2:
        return np.zeros(W), 0.0, np.full(W, -1, dtype=np.int64)
    cs = np.zeros((H + 1, W), dtype=np.float32)
    np.cumsum(np.where(seen, proj, np.float32(0.0)), axis=0, out=cs[1:])
    n = H - 2 * k + 1                                     # boundaries r = k .. H - k (between rows r-1 and r)
    step = cs[2 * k:] - cs[k:H - k + 1]                   # k * mean of rows [r, r + k)
    step -= cs[k:H - k + 1]
    step += cs[:n]                                        # ... minus k * mean of rows [r - k, r)
    step *= np.float32(1.0 / k)
    del cs
    cn = np.zeros((H + 1, W), dtype=np.int32)
    np.cumsum(seen, axis=0, out=cn[1:])
    ok = (cn[2 * k:] - cn[:n]) == 2 * k
    del cn
    r = np.arange(k, H - k + 1)[:, None]
    ok &= r + k <= b[None, :] - 1
    far = ok & (r + k <= b[None, :] - 10)
    noise = _mad_sigma(step[far], max_size=50_000)
    if edges is not None and len(edges) > 2:
        cols = [slice(c0, c1, max(1, (c1 - c0) // _SECTOR_NOISE_COLUMNS)) for c0, c1 in zip(edges[:-1], edges[1:])]
        per_sector = np.array([_mad_sigma(step[:, c][far[:, c]], max_size=1_000) for c in cols])
        noise = np.maximum(noise, _per_column(per_sector, edges, W, wrap))
    del far
    step[~ok] = 0.0
    at = np.argmax(step, axis=0)
    best = step[at, np.arange(W)]
    row = np.where(ok.any(axis=0), at + k, -1).astype(np.int64)
    return np.maximum(best, 0.0).astype(np.float64), noise, row


#: columns of a sector whose sky steps give its noise (:func:`_largest_step_above`): evenly spaced, a few hundred
#: steps, a millisecond for the 24 sectors where all the sector's columns took 8 ms per call (a detection makes 4-8)
_SECTOR_NOISE_COLUMNS = 16


def _mad_sigma(v: np.ndarray, max_size: int, min_size: int = 100) -> float:
    """:func:`_fit`'s spread (1.4826 MAD, unfloored) of ``v`` from an even subsample of about ``max_size`` values;
    0 for fewer than ``min_size`` values (too few to tell the noise)."""
    return _fit(v, 0.0, max_size)[1] if v.size >= min_size else 0.0


def _grow_mask(valid: np.ndarray, margin: int, wrap: bool) -> np.ndarray:
    """Invalidate the ``margin`` columns on each side of every invalid column (circularly when ``wrap``)."""
    if margin <= 0 or valid.all() or not valid.any():
        return valid
    bad = ~valid
    W = bad.size
    grown = bad.copy()
    for k in range(1, margin + 1):
        if wrap:
            grown |= np.roll(bad, k) | np.roll(bad, -k)
        else:
            grown[k:] |= bad[:-k] if k < W else False
            grown[:-k] |= bad[k:] if k < W else False
    return ~grown


def _drop_short_runs(valid: np.ndarray, min_run: int, wrap: bool) -> np.ndarray:
    """Mask runs of valid columns shorter than ``min_run`` (runs may cross the seam when ``wrap``)."""
    if min_run <= 1 or valid.all() or not valid.any():
        return valid
    v = valid.copy()
    W = v.size
    if wrap:
        shift = int(np.argmin(v))          # start at an invalid column so no run crosses the seam
        v = np.roll(v, -shift)
    d = np.diff(np.concatenate([[0], v.astype(np.int8), [0]]))
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1)
    for s, e in zip(starts, ends):
        if e - s < min_run:
            v[s:e] = False
    if wrap:
        v = np.roll(v, shift)
    assert v.size == W
    return v
