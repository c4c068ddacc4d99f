"""The sub-pixel line's residual pixel locking, undone (bpy-free: numpy and OpenCV).

The detector places the line on the peak of the vertically blurred intensity step, refined by a Gaussian
through the step's three samples around its strongest one (:func:`board.detect.sky_regions._subpixel`).  A
pixel integrates the edge over its height (a box), so the step is a Gaussian convolved with that box, not a
Gaussian, and the refined peak still leans towards the sampled row by a function of the edge's sub-pixel
phase: up to 0.037 px (std 0.026 px) when the optics add no blur of their own, 0.016 px std at a lens blur of
0.3 px, nothing to speak of past 0.6 px (the detector's own 1 px blur added in every case).  Along a horizon
that drifts slowly across the rows that is a smooth error, which the matcher cannot average away.

For a model edge (a box pixel, a Gaussian lens of sigma ``s``, the detector's blur as it applies it) the phase
curve (estimated offset -> true offset) is exact; :func:`phase_table` computes it once per (``s``, blur) and
:func:`undo_phase` reads a measured offset through it.  The lens sigma of a view is read off its measured
edge width (:func:`board.detect.clipped_edge.edge_width_px`, whose definition :func:`model_width_px`
reproduces on the model): :func:`lens_sigma_from_width`.

Units: rows (pixels) throughout; offsets ``d`` are :func:`~board.detect.sky_regions._subpixel`'s, in
[-0.5, 0.5] rows about the step's sample row.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

#: sub-pixel phases sampled by the model curves (one pixel, ends included)
_N_PHASES = 201
#: model rows (the edge sits at row _ROW0 + phase)
_N_ROWS = 41
_ROW0 = 20.0
#: lens sigmas of the width curve, pixels (past 1 px there is nothing to undo: :func:`table_for_width`)
_SIGMA_GRID = np.round(np.arange(0.0, 1.2001, 0.02), 4)


def _ndtr(z: np.ndarray) -> np.ndarray:
    """The standard normal CDF, to 1.5e-7 (Abramowitz & Stegun 7.1.26 for erf; numpy has none and the board
    does not load scipy for it)."""
    x = np.abs(z) / math.sqrt(2.0)
    t = 1.0 / (1.0 + 0.3275911 * x)
    poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))))
    erf = 1.0 - poly * np.exp(-x * x)
    return 0.5 * (1.0 + np.sign(z) * erf)


def _phi_integral(x: np.ndarray, s: float) -> np.ndarray:
    """Antiderivative of the unit edge blurred by a Gaussian of sigma ``s`` (``s`` > 0): int Phi(x / s) dx."""
    z = x / s
    return x * _ndtr(z) + s * np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)


def model_edge(phase: np.ndarray, lens_sigma: float) -> np.ndarray:
    """(``_N_ROWS``, n) pixel values (0 above the edge, 1 below) of a horizontal edge at row ``_ROW0 + phase``
    (row ``k`` covers [k - 0.5, k + 0.5]), blurred by a Gaussian lens of ``lens_sigma`` pixels, each pixel the
    mean of the blurred edge over its height."""
    k = np.arange(_N_ROWS, dtype=np.float64)[:, None]
    y0 = _ROW0 + np.asarray(phase, dtype=np.float64)[None, :]
    if lens_sigma <= 1e-6:
        return np.clip(k + 0.5 - y0, 0.0, 1.0)
    return _phi_integral(k + 0.5 - y0, lens_sigma) - _phi_integral(k - 0.5 - y0, lens_sigma)


def model_width_px(lens_sigma: float) -> float:
    """The width :func:`board.detect.clipped_edge.edge_width_px` measures on the model edge of ``lens_sigma``:
    the median over phases of ``A / (sqrt(2 pi) g)`` (``A`` = 1 the step, ``g`` its steepest one-row
    difference).  0.532 px for a sharp edge, 0.585 at 0.3 px, 0.775 at 0.6 px, then about sqrt(s^2 + 1/12)."""
    phases = np.linspace(-0.5, 0.5, _N_PHASES)
    g = np.diff(model_edge(phases, lens_sigma), axis=0).max(axis=0)
    return float(np.median(1.0 / g) / math.sqrt(2.0 * math.pi))


@lru_cache(maxsize=1)
def _width_curve() -> tuple[np.ndarray, np.ndarray]:
    w = np.array([model_width_px(float(s)) for s in _SIGMA_GRID])
    return np.maximum.accumulate(w), _SIGMA_GRID


def lens_sigma_from_width(width_px: float) -> float | None:
    """The lens sigma (pixels) whose model edge measures ``width_px``; 0 at or below a sharp edge's width,
    None when the width is unknown (NaN: too few clean steps in the view)."""
    if not np.isfinite(width_px):
        return None
    w, s = _width_curve()
    if width_px <= w[0]:
        return 0.0
    # the curve is flat below ~0.15 px (a sharp edge's width barely changes): take the smallest sigma there
    i = int(np.searchsorted(w, width_px, side="left"))
    if i >= w.size:
        return float(s[-1])
    lo = max(i - 1, 0)
    if w[i] == w[lo]:
        return float(s[lo])
    return float(s[lo] + (s[i] - s[lo]) * (width_px - w[lo]) / (w[i] - w[lo]))


@lru_cache(maxsize=16)
def _phase_table_cached(lens_sigma: float, blur_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    from board.detect.sky_regions import _subpixel  # the detector's own estimator (it imports this module)

    phases = np.linspace(-0.75, 0.75, int(1.5 * (_N_PHASES - 1)) + 1)
    img = model_edge(phases, lens_sigma).astype(np.float32)
    if blur_sigma > 0:
        k = cv2.getGaussianKernel(2 * int(math.ceil(3 * blur_sigma)) + 1, blur_sigma, cv2.CV_32F)
        img = cv2.sepFilter2D(img, -1, np.ones((1, 1), np.float32), k, borderType=cv2.BORDER_REFLECT)
    step = np.zeros(img.shape, dtype=np.float64)
    step[1:] = img[1:] - img[:-1]                     # step[r] sits between rows r - 1 and r
    bb = np.argmax(step, axis=0)                      # the strongest sample: _subpixel keeps it, offset d
    d_est = _subpixel(step, bb, gaussian=True) - (bb - 0.5)
    # the true line in _subpixel's rows (``bb - 0.5 + d``) is the edge's own row (row k covering [k-0.5, k+0.5])
    d_true = (_ROW0 + phases) - (bb - 0.5)
    keep = np.abs(d_est) < 0.5
    order = np.argsort(d_est[keep])
    est, true = d_est[keep][order], d_true[keep][order]
    # the two ends (|d| = 0.5, where a neighbouring sample takes over) are fixed points of the estimator
    return np.concatenate([[-0.5], est, [0.5]]), np.concatenate([[-0.5], true, [0.5]])


def phase_table(lens_sigma: float, blur_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """(estimated offsets, true offsets), both increasing, of the model edge with a lens of ``lens_sigma`` and
    the detector's blur of ``blur_sigma`` pixels (both rounded to 0.02 px, cached)."""
    return _phase_table_cached(round(float(lens_sigma) / 0.02) * 0.02, round(float(blur_sigma), 4))


def table_for_width(width_px: float, blur_sigma: float) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`phase_table` of the lens a view's measured edge width ``width_px`` implies; None when the width
    is unknown or the lens blur is wide enough for the step to be a Gaussian already (nothing to undo)."""
    s = lens_sigma_from_width(width_px)
    if s is None or s >= 1.0:
        return None
    return phase_table(s, blur_sigma)


def undo_phase(d: np.ndarray, table: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The true sub-pixel offsets of measured ones ``d`` (rows, in [-0.5, 0.5]) through ``table``."""
    est, true = table
    return np.interp(d, est, true)


__all__ = ["lens_sigma_from_width", "model_edge", "model_width_px", "phase_table", "table_for_width", "undo_phase"]
