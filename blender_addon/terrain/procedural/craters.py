"""Impact craters: power-law size-frequency draws and morphometric crater profiles.

Profiles follow the usual morphometry of fresh craters on the Moon and Mars
(Pike 1977; Garvin et al. 2003): simple bowls with depth ~0.2 D and rim height
~0.04 D; above the simple-to-complex transition diameter the depth grows slower
than D, the floor flattens and a central peak appears.  Ejecta thin as (r/R)^-3
out to ~3 R.  Degraded (older) craters are shallower: every crater gets a freshness
factor in [0.3, 1] that scales its depth, rim and ejecta.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Crater:
    """One crater: centre (x, y) in metres from the raster's north-west corner (x east, y south), diameter (m)."""

    x: float
    y: float
    diameter_m: float
    freshness: float = 1.0


def draw_diameters(
    rng: np.random.Generator, *, area_m2: float, density_per_km2_above_1km: float, slope: float,
    d_min_m: float, d_max_m: float, max_count: int = 60000,
) -> np.ndarray:
    """Crater diameters (m) from a cumulative power law N(>D) = n1 * area * (D / 1 km)^-slope.

    n1 = ``density_per_km2_above_1km`` (craters per km^2 larger than 1 km), slope ~2 for
    small craters on the Moon and Mars.  Diameters outside [d_min_m, d_max_m] are not drawn;
    at most ``max_count`` are (the smallest are dropped first).  Sorted largest first.
    """
    n_expected = density_per_km2_above_1km * area_m2 / 1e6 * ((d_min_m / 1000.0) ** -slope - (d_max_m / 1000.0) ** -slope)
    n = int(rng.poisson(max(n_expected, 0.0)))
    u = rng.random(n)
    # inverse CDF of the truncated Pareto distribution between d_min and d_max
    a, b = d_min_m ** -slope, d_max_m ** -slope
    d = (a - u * (a - b)) ** (-1.0 / slope)
    d = np.sort(d)[::-1]
    return d[:max_count]


def crater_profile(r_norm: np.ndarray, diameter_m: float, *, transition_m: float, freshness: float = 1.0) -> np.ndarray:
    """Height (m) relative to the pre-impact surface at normalised distance r/R from the centre.

    Simple (D < transition): parabolic bowl, depth (rim crest to floor) 0.2 D, rim crest
    0.04 D above the surroundings.
    Complex: depth 0.2 D (transition/D)^0.5, flat floor out to 0.4 R, central peak
    (height ~ 0.4 depth, radius 0.15 R), rim 0.04 D (transition/D)^0.3.
    Outside: ejecta blanket rim * (r/R)^-3, tapered to 0 at 3 R.
    """
    D = float(diameter_m)
    f = float(freshness)
    if D < transition_m:
        depth = 0.2 * D  # rim crest to floor
        rim = 0.04 * D
        floor_r = 0.0
        peak_h, peak_r = 0.0, 0.0
    else:
        depth = 0.2 * D * math.sqrt(transition_m / D)
        rim = 0.04 * D * (transition_m / D) ** 0.3
        floor_r = 0.4
        peak_h = 0.4 * depth * min(1.0, 0.5 + 0.5 * (D / transition_m - 1.0))
        peak_r = 0.15
    depth *= f
    rim *= f
    peak_h *= f
    r = np.asarray(r_norm, dtype=np.float32)
    h = np.zeros_like(r)
    inside = r < 1.0
    # bowl: floor at rim - depth, rising as a parabola from floor_r to the rim crest at r = 1
    t = np.clip((r - floor_r) / (1.0 - floor_r), 0.0, 1.0)
    h_in = (rim - depth) + depth * t * t
    if peak_h > 0:
        h_in = h_in + peak_h * np.exp(-0.5 * (r / (peak_r / 2.0)) ** 2)
    h = np.where(inside, h_in, h)
    out = (r >= 1.0) & (r < 3.0)
    ej = rim * (np.maximum(r, 1.0) ** -3 - 3.0**-3) / (1.0 - 3.0**-3)
    h = np.where(out, ej, h)
    return h.astype(np.float32)


def stamp_craters(
    z: np.ndarray, craters: list[Crater], *, cell_m: float, transition_m: float, inherit: float = 0.7
) -> None:
    """Add crater profiles to the height grid ``z`` (rows, cols; metres) in place.

    Inside each crater the pre-existing relief is damped (by ``inherit`` at the centre,
    fading to none at the rim) so that younger craters overprint older terrain.
    Craters are clipped at the raster's edges (no wrap-around).
    """
    rows, cols = z.shape
    for c in craters:
        R = c.diameter_m / 2.0
        reach = 3.0 * R
        c0 = max(int((c.x - reach) / cell_m), 0)
        c1 = min(int((c.x + reach) / cell_m) + 2, cols)
        r0 = max(int((c.y - reach) / cell_m), 0)
        r1 = min(int((c.y + reach) / cell_m) + 2, rows)
        if c1 <= c0 or r1 <= r0:
            continue
        xs = ((np.arange(c0, c1, dtype=np.float32) + 0.5) * cell_m - c.x) / R
        ys = ((np.arange(r0, r1, dtype=np.float32) + 0.5) * cell_m - c.y) / R
        rn = np.sqrt(xs[None, :] ** 2 + ys[:, None] ** 2)
        prof = crater_profile(rn, c.diameter_m, transition_m=transition_m, freshness=c.freshness)
        win = z[r0:r1, c0:c1]
        inside = rn < 1.0
        if inside.any() and inherit > 0:
            base = float(np.mean(win[inside]))
            damp = inherit * c.freshness * np.clip(1.0 - rn, 0.0, 1.0)
            win -= (win - base) * damp * inside
        win += prof


def place_craters(
    rng: np.random.Generator, diameters: np.ndarray, *, width_m: float, height_m: float, fresh_min: float = 0.3
) -> list[Crater]:
    """Uniformly random centres (allowed up to one radius outside the raster) and freshness in [fresh_min, 1].

    Returned oldest first (the largest craters tend to be old), so later stamps overprint them.
    """
    n = len(diameters)
    xs = rng.uniform(0, width_m, n)
    ys = rng.uniform(0, height_m, n)
    fr = rng.uniform(fresh_min, 1.0, n)
    # a loose age order: large craters first (mostly older), with random interleaving
    key = np.argsort(-(np.log(diameters) + rng.normal(0, 1.0, n)))
    craters = [Crater(float(xs[i]), float(ys[i]), float(diameters[i]), float(fr[i])) for i in key]
    return craters
