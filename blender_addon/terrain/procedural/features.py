"""Small and icy landforms: blocks and boulders, and Europa's penitentes, crevasses, double ridges, broken plates.

All functions modify a height grid ``z`` (rows, cols; metres; row 0 north) in place and
draw from a ``numpy.random.Generator`` in a fixed order (same seed, same terrain).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .fields import smooth_mask, spectral_field


def add_blocks(
    z: np.ndarray, rng: np.random.Generator, *, cell_m: float, count: int, h_min_m: float, h_max_m: float,
    slope: float = 2.5, centres_rc: np.ndarray | None = None, spread_cells: np.ndarray | None = None,
) -> None:
    """Add ``count`` blocks/boulders: flat-topped prisms of 1-3 cells, heights power-law in [h_min_m, h_max_m].

    Heights follow a cumulative power law N(>h) ~ h^-slope (many small, few large).  Blocks sit
    at uniformly random cells, or scattered (Gaussian, ``spread_cells``) around ``centres_rc``
    (e.g. crater rims).  A block's top is the local ground plus its height (max with what is there).
    """
    if count <= 0:
        return
    rows, cols = z.shape
    u = rng.random(count)
    a, b = h_min_m ** -slope, h_max_m ** -slope
    heights = ((a - u * (a - b)) ** (-1.0 / slope)).astype(np.float32)
    if centres_rc is None:
        r = rng.integers(0, rows, count)
        c = rng.integers(0, cols, count)
    else:
        k = rng.integers(0, len(centres_rc), count)
        ang = rng.uniform(0, 2 * math.pi, count)
        rad = np.abs(rng.normal(0.0, 1.0, count)) * spread_cells[k]
        r = np.clip((centres_rc[k, 0] + rad * np.sin(ang)).astype(np.int64), 0, rows - 1)
        c = np.clip((centres_rc[k, 1] + rad * np.cos(ang)).astype(np.int64), 0, cols - 1)
    # footprint in cells grows with height (a block about as wide as it is high)
    w = np.clip(np.round(heights / cell_m), 1, 3).astype(np.int64)
    ground_all = z[r, c].copy()  # blocks rest on the ground, not on each other
    for size in (1, 2, 3):
        sel = w == size
        if not sel.any():
            continue
        for dr in range(size):
            for dc in range(size):
                rr = np.clip(r[sel] + dr, 0, rows - 1)
                cc = np.clip(c[sel] + dc, 0, cols - 1)
                np.maximum.at(z, (rr, cc), ground_all[sel] + heights[sel])


def _line_distance(cell_m, p0, p1, r0, r1, c0, c1):
    """Distance (m) from cell centres in the window to the segment p0-p1 (x east, y south, metres)."""
    ys = (np.arange(r0, r1, dtype=np.float32) + 0.5)[:, None] * cell_m
    xs = (np.arange(c0, c1, dtype=np.float32) + 0.5)[None, :] * cell_m
    dx, dy = p1[0] - p0[0], p1[1] - p0[1]
    L2 = dx * dx + dy * dy
    t = np.clip(((xs - p0[0]) * dx + (ys - p0[1]) * dy) / L2, 0.0, 1.0)
    px = p0[0] + t * dx
    py = p0[1] + t * dy
    return np.sqrt((xs - px) ** 2 + (ys - py) ** 2), t


def _polyline(rng, width_m, height_m, length_m, n_seg, wiggle):
    """A gently curving polyline (metres, x east, y south) of about ``length_m`` starting inside the area."""
    x, y = rng.uniform(0, width_m), rng.uniform(0, height_m)
    ang = rng.uniform(0, 2 * math.pi)
    pts = [(x, y)]
    seg = length_m / n_seg
    for _ in range(n_seg):
        ang += rng.normal(0.0, wiggle)
        x, y = x + seg * math.cos(ang), y + seg * math.sin(ang)
        pts.append((x, y))
    return pts


def _stamp_polyline(z, cell_m, pts, half_width_m, profile):
    """Apply ``profile(distance_m, t)`` -> height delta along a polyline, windowed per segment (max-combined)."""
    rows, cols = z.shape
    pieces = []
    for p0, p1 in zip(pts[:-1], pts[1:]):
        c0 = max(int((min(p0[0], p1[0]) - half_width_m) / cell_m), 0)
        c1 = min(int((max(p0[0], p1[0]) + half_width_m) / cell_m) + 2, cols)
        r0 = max(int((min(p0[1], p1[1]) - half_width_m) / cell_m), 0)
        r1 = min(int((max(p0[1], p1[1]) + half_width_m) / cell_m) + 2, rows)
        if c1 <= c0 or r1 <= r0:
            continue
        d, t = _line_distance(cell_m, p0, p1, r0, r1, c0, c1)
        pieces.append(((r0, r1, c0, c1), profile(d, t)))
    # combine overlapping segment windows without double counting: keep the largest |delta| per cell
    acc = np.zeros_like(z)
    for (r0, r1, c0, c1), h in pieces:
        cur = acc[r0:r1, c0:c1]
        np.copyto(cur, h, where=np.abs(h) > np.abs(cur))
    z += acc


def add_crevasses(z, rng, *, cell_m, count, length_m=(300.0, 4000.0), depth_m=(8.0, 40.0), width_m=None) -> None:
    """Narrow V-shaped cracks (Europa): ``count`` gently curving lines, 1-3 cells wide, ``depth_m`` deep."""
    rows, cols = z.shape
    for _ in range(count):
        L = rng.uniform(*length_m)
        depth = rng.uniform(*depth_m)
        half_w = (width_m or rng.uniform(1.0, 3.0) * cell_m) / 2.0 + 0.5 * cell_m
        pts = _polyline(rng, cols * cell_m, rows * cell_m, L, max(2, int(L / 250.0)), 0.15)

        def prof(d, t, depth=depth, half_w=half_w):
            taper = np.sin(np.pi * np.clip(t, 0.02, 0.98)) ** 0.5  # shallower at the tips
            return -depth * taper * np.clip(1.0 - d / half_w, 0.0, 1.0)

        _stamp_polyline(z, cell_m, pts, half_w, prof)


def add_double_ridges(z, rng, *, cell_m, count, height_m=(60.0, 200.0), width_m=(600.0, 1500.0)) -> None:
    """Europa's double ridges: two parallel crests with a central trough along long gentle curves."""
    rows, cols = z.shape
    span = math.hypot(rows, cols) * cell_m
    for _ in range(count):
        h = rng.uniform(*height_m)
        w = rng.uniform(*width_m)
        pts = _polyline(rng, cols * cell_m, rows * cell_m, span * rng.uniform(0.6, 1.2), 12, 0.05)
        # start the polyline before the raster edge so it crosses the whole area
        dx, dy = pts[-1][0] - pts[0][0], pts[-1][1] - pts[0][1]
        pts = [(x - 0.4 * dx, y - 0.4 * dy) for x, y in pts]

        def prof(d, t, h=h, w=w):
            s = d / (w / 2.0)
            crest = np.exp(-0.5 * ((s - 0.45) / 0.22) ** 2)  # two crests at +-0.45 half-widths
            return (h * crest * (s < 1.6)).astype(np.float32)

        _stamp_polyline(z, cell_m, pts, w * 0.8, prof)


def add_broken_plates(
    z, rng, *, cell_m, centre_xy_m, radius_m, plate_size_m=(300.0, 1500.0), matrix_drop_m=60.0, tilt_deg=8.0,
) -> None:
    """Chaos terrain: within a disc, the crust breaks into polygonal plates (Voronoi cells), each tilted and
    shifted, separated by a lower hummocky matrix."""
    rows, cols = z.shape
    cx, cy = centre_xy_m
    c0, c1 = max(int((cx - radius_m) / cell_m), 0), min(int((cx + radius_m) / cell_m) + 1, cols)
    r0, r1 = max(int((cy - radius_m) / cell_m), 0), min(int((cy + radius_m) / cell_m) + 1, rows)
    if c1 <= c0 or r1 <= r0:
        return
    area = math.pi * radius_m**2
    mean_plate = float(np.mean(plate_size_m))
    n = max(4, int(area / mean_plate**2))
    ang = rng.uniform(0, 2 * math.pi, n)
    rad = radius_m * np.sqrt(rng.random(n))
    seeds = np.stack([cy + rad * np.sin(ang), cx + rad * np.cos(ang)], axis=1)
    ys = (np.arange(r0, r1) + 0.5) * cell_m
    xs = (np.arange(c0, c1) + 0.5) * cell_m
    Y, X = np.meshgrid(ys, xs, indexing="ij")
    pts = np.stack([Y.ravel(), X.ravel()], axis=1)
    dist, idx = cKDTree(seeds).query(pts, k=2)
    gap = (dist[:, 1] - dist[:, 0]).reshape(Y.shape)  # ~2x distance to the plate boundary
    owner = idx[:, 0].reshape(Y.shape)
    tilt = np.tan(np.radians(rng.uniform(0, tilt_deg, n)))
    tdir = rng.uniform(0, 2 * math.pi, n)
    lift = rng.normal(0.0, matrix_drop_m * 0.3, n)
    rdisc = np.hypot(Y - cy, X - cx) / radius_m
    inside = smooth_mask(-rdisc * 4.0, threshold=-3.6, width=0.6)  # 1 inside, fading at the disc edge
    plate_h = lift[owner] + tilt[owner] * ((X - seeds[owner, 1]) * np.cos(tdir[owner]) + (Y - seeds[owner, 0]) * np.sin(tdir[owner]))
    margin = rng.uniform(0.08, 0.2) * mean_plate
    on_plate = np.clip(gap / margin, 0.0, 1.0) ** 0.5  # 0 at boundaries (matrix), 1 on plates
    hummocks = spectral_field(Y.shape, rng, cell_m=cell_m, wavelength_min_m=2 * cell_m, wavelength_max_m=200.0, beta=2.5)
    matrix_h = -matrix_drop_m + 6.0 * hummocks
    delta = inside * (on_plate * plate_h + (1.0 - on_plate) * matrix_h)
    z[r0:r1, c0:c1] += delta.astype(np.float32)


def add_penitentes(z, rng, *, cell_m, coverage_field: np.ndarray, height_m=(3.0, 12.0), spacing_m=None,
                   threshold: float = 0.6) -> None:
    """Penitente fields: closely spaced east-west blades (sun-aligned) in patches where ``coverage_field`` is high.

    Blades are a rectified sine across north-south with a noisy phase, spacing ~3 cells (or
    ``spacing_m``), height varying in ``height_m`` with a slow random field.
    """
    rows, cols = z.shape
    mask = smooth_mask(coverage_field, threshold=threshold, width=0.4)
    if not mask.any():
        return
    spacing = spacing_m or 3.0 * cell_m
    phase = spectral_field((rows, cols), rng, cell_m=cell_m, wavelength_min_m=4 * spacing, wavelength_max_m=40 * spacing, beta=3.0)
    amp = spectral_field((rows, cols), rng, cell_m=cell_m, wavelength_min_m=50 * spacing, wavelength_max_m=400 * spacing, beta=3.0)
    y = (np.arange(rows, dtype=np.float32) + 0.5)[:, None] * cell_m
    blades = np.abs(np.sin(np.pi * y / spacing + 1.5 * phase)) ** 3
    h = height_m[0] + (height_m[1] - height_m[0]) * np.clip(0.5 + 0.35 * amp, 0.0, 1.0)
    z += (mask * h * blades).astype(np.float32)


def smooth(z: np.ndarray, sigma_cells: float) -> np.ndarray:
    """Gaussian smoothing (nearest at the edges)."""
    return ndimage.gaussian_filter(z, sigma_cells, mode="nearest")
