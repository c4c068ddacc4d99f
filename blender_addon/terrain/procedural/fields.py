"""Seeded random height fields: spectral (Fourier) fractal synthesis and its ridged variants.

Every function takes a ``numpy.random.Generator`` and draws from it in a fixed order,
so a seed gives the same field on every run.  Shapes are (rows, cols), cells square of
``cell_m`` metres; fields are periodic (the spectral method wraps around).
"""
from __future__ import annotations

import math

import numpy as np
import scipy.fft
from scipy import ndimage


def spectral_field(
    shape: tuple[int, int],
    rng: np.random.Generator,
    *,
    cell_m: float,
    wavelength_min_m: float,
    wavelength_max_m: float,
    beta: float = 3.0,
) -> np.ndarray:
    """Band-limited fractal noise with power spectrum ~ |k|^-beta, zero mean and unit standard deviation.

    shape : (rows, cols); cell_m : cell size (m)
    wavelength_min_m, wavelength_max_m : shortest/longest wavelengths kept (m)
    beta : spectral exponent (3 = Brownian-like surface; larger = smoother)
    Fields without short wavelengths are synthesised on a coarser grid and upsampled
    (bilinear), which keeps big DEMs fast.  Returns (rows, cols) float32.
    """
    rows, cols = shape
    coarse = max(1.0, wavelength_min_m / (4.0 * cell_m))
    crow = max(8, int(math.ceil(rows / coarse)))
    ccol = max(8, int(math.ceil(cols / coarse)))
    ccell_y = rows * cell_m / crow
    ccell_x = cols * cell_m / ccol
    white = rng.standard_normal((crow, ccol), dtype=np.float32)
    spec = scipy.fft.rfft2(white, workers=2)
    ky = scipy.fft.fftfreq(crow, d=ccell_y).astype(np.float32)[:, None]
    kx = scipy.fft.rfftfreq(ccol, d=ccell_x).astype(np.float32)[None, :]
    k = np.sqrt(kx * kx + ky * ky)
    kmin, kmax = 1.0 / wavelength_max_m, 1.0 / wavelength_min_m
    with np.errstate(divide="ignore"):
        amp = np.where((k >= kmin) & (k <= kmax), k ** (-beta / 2.0), 0.0).astype(np.float32)
    # soft band edges avoid ringing
    amp *= np.exp(-((k / kmax) ** 4)).astype(np.float32)
    field = scipy.fft.irfft2(spec * amp, s=(crow, ccol), workers=2).astype(np.float32)
    std = float(field.std())
    if std > 0:
        field /= std
    field -= field.mean()
    if (crow, ccol) != (rows, cols):
        # periodic upsampling: pad one wrap-around row/col so the edges stay continuous
        padded = np.pad(field, ((0, 1), (0, 1)), mode="wrap")
        ry = np.linspace(0, crow, rows, endpoint=False, dtype=np.float32) + 0.5 * crow / rows - 0.5
        rx = np.linspace(0, ccol, cols, endpoint=False, dtype=np.float32) + 0.5 * ccol / cols - 0.5
        ry = np.clip(ry, 0, crow)
        rx = np.clip(rx, 0, ccol)
        field = _bilinear_grid(padded, ry, rx)
        std = float(field.std())
        if std > 0:
            field /= std
    return field.astype(np.float32, copy=False)


def _bilinear_grid(a: np.ndarray, ry: np.ndarray, rx: np.ndarray) -> np.ndarray:
    """Sample ``a`` bilinearly on the outer product of fractional row/col coordinates (separable: columns, then rows)."""
    c0 = np.floor(rx).astype(np.int64)
    c1 = np.minimum(c0 + 1, a.shape[1] - 1)
    fx = (rx - c0).astype(np.float32)[None, :]
    cols_done = a[:, c0] * (1 - fx) + a[:, c1] * fx  # (coarse rows, fine cols): small
    r0 = np.floor(ry).astype(np.int64)
    r1 = np.minimum(r0 + 1, a.shape[0] - 1)
    fy = (ry - r0).astype(np.float32)[:, None]
    out = cols_done[r0]
    out *= 1 - fy
    out += cols_done[r1] * fy
    return out


def ridged(field: np.ndarray, *, sharpness: float = 2.0) -> np.ndarray:
    """Ridged transform 1 - |f| (clipped at 0) raised to ``sharpness``: sharp crests along f's zero lines.

    Returns values in [0, 1]; with f a unit-std field, crests (value 1) form a network of
    narrow ridges and the rest falls off smoothly.
    """
    return np.clip(1.0 - np.abs(field), 0.0, 1.0) ** sharpness


def smooth_mask(field: np.ndarray, *, threshold: float, width: float = 0.5) -> np.ndarray:
    """Smooth 0..1 mask where a unit-std ``field`` exceeds ``threshold`` (transition over ``width``)."""
    t = np.clip((field - threshold) / width + 0.5, 0.0, 1.0)
    return (t * t * (3.0 - 2.0 * t)).astype(np.float32)


def blur(field: np.ndarray, sigma_cells: float) -> np.ndarray:
    """Gaussian blur (wrap-around), sigma in cells."""
    return ndimage.gaussian_filter(field, sigma_cells, mode="wrap")
