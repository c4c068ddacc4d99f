"""Lander-scale Europa terrain: heights and albedo on a regular grid in the world frame.

World frame: x east, y north, z up, metres.  ``DescentTerrain.height[iy, ix]`` is the height of the
node at ``(x0 + ix * res_m, y0 + iy * res_m)`` (row 0 is the *south* edge, unlike a GeoTIFF), and
the surface between nodes is bilinear.  A procedural terrain (``procedural:europa:SEED``) is centred
on (0, 0) like ``skyloc dem synth``; a DEM file keeps its own metric coordinates.

The procedural terrain reproduces the memorandum's section 4.1 with the feature generators of
``blender_addon.terrain.procedural`` (the ``europa`` preset's relief spectrum, craters, blocks,
broken plates, penitentes, crevasses) at lander scale: 400 x 400 m, features sampled from
size-frequency laws (hills and craters: cumulative power laws; blocks: N(>h) ~ h^-2.5) and uniform
or clustered spatial distributions, scaled to the memorandum's 31.7 m of elevation range.  The albedo
map (section 4.2) is centred on Europa's albedo with "splotches" (a band-limited random field) and
darker linear "striae" that have no geometry.
"""
from __future__ import annotations

import hashlib
import logging
import math
from dataclasses import dataclass

import numpy as np

from board.errors import InvalidInputError

from .constants import EUROPA_ALBEDO

log = logging.getLogger(__name__)

#: Bumped whenever the procedural descent terrain changes for a given seed.
DESCENT_TERRAIN_VERSION = 1
DEFAULT_SIZE_M = 400.0
DEFAULT_RES_M = 0.25
#: Memorandum section 4.1: elevation range of the simulated terrain, metres.
DEFAULT_RELIEF_RANGE_M = 31.7


@dataclass(frozen=True)
class DescentTerrain:
    """Height and albedo grids (world frame, see the module docstring).

    height : (ny, nx) float32 m; albedo : (ny, nx) float32 normal albedo in [0, 1];
    x0, y0 : world position of node (0, 0), m; res_m : node spacing, m; spec : "procedural:europa:SEED"
    or the DEM path.
    """

    height: np.ndarray
    albedo: np.ndarray
    x0: float
    y0: float
    res_m: float
    spec: str

    def __post_init__(self) -> None:
        h = np.ascontiguousarray(self.height, dtype=np.float32)
        a = np.ascontiguousarray(self.albedo, dtype=np.float32)
        if h.ndim != 2 or min(h.shape) < 4 or h.shape != a.shape:
            raise InvalidInputError(f"terrain height {h.shape} and albedo {a.shape} must be equal 2-D grids >= 4x4")
        if not np.all(np.isfinite(h)):
            raise InvalidInputError("terrain heights contain NaN (nodata): fill or crop the DEM first")
        if not self.res_m > 0:
            raise InvalidInputError(f"terrain resolution {self.res_m} m must be positive")
        object.__setattr__(self, "height", h)
        object.__setattr__(self, "albedo", a)

    @property
    def shape(self) -> tuple[int, int]:
        return self.height.shape  # type: ignore[return-value]

    @property
    def size_m(self) -> float:
        """Side (m) spanned by the nodes along x."""
        return (self.shape[1] - 1) * self.res_m

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the node grid, m."""
        ny, nx = self.shape
        return self.x0, self.y0, self.x0 + (nx - 1) * self.res_m, self.y0 + (ny - 1) * self.res_m

    @property
    def sha256(self) -> str:
        """Hash of the height grid (float32, little-endian, row-major) and its geometry."""
        h = hashlib.sha256(np.ascontiguousarray(self.height, dtype="<f4").tobytes())
        h.update(f"{self.x0:.6f},{self.y0:.6f},{self.res_m:.6f},{self.shape}".encode())
        return h.hexdigest()

    def height_at(self, x, y) -> np.ndarray:
        """Bilinear height (m) at world points (x, y); NaN outside the grid."""
        fx = (np.asarray(x, dtype=np.float64) - self.x0) / self.res_m
        fy = (np.asarray(y, dtype=np.float64) - self.y0) / self.res_m
        ny, nx = self.shape
        ok = (fx >= 0) & (fx <= nx - 1) & (fy >= 0) & (fy <= ny - 1)
        ix = np.clip(np.floor(fx).astype(np.int64), 0, nx - 2)
        iy = np.clip(np.floor(fy).astype(np.int64), 0, ny - 2)
        tx, ty = fx - ix, fy - iy
        h = self.height
        z = ((1 - tx) * (1 - ty) * h[iy, ix] + tx * (1 - ty) * h[iy, ix + 1]
             + (1 - tx) * ty * h[iy + 1, ix] + tx * ty * h[iy + 1, ix + 1])
        return np.where(ok, z, np.nan)

    def normals(self) -> np.ndarray:
        """(ny, nx, 3) unit upward surface normals at the nodes (central differences of the heights)."""
        gy, gx = np.gradient(self.height.astype(np.float64), self.res_m)
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        return (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)


# -- procedural terrain ------------------------------------------------------------------------------
def _segment_distance(px, py, a, b):
    """Distance (m) of points (px, py) to the segment a-b (world metres)."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    t = np.clip(((px - a[0]) * dx + (py - a[1]) * dy) / max(dx * dx + dy * dy, 1e-12), 0.0, 1.0)
    return np.hypot(px - a[0] - t * dx, py - a[1] - t * dy)


def _hills(rng, xs, ys, size_m):
    """Broad hills (positive) and valleys (negative): Gaussian bumps, radii 10-80 m from N(>r) ~ r^-2."""
    z = np.zeros((ys.size, xs.size), np.float64)
    n = int(rng.poisson(40 * (size_m / 400.0) ** 2))
    u = rng.random(n)
    r_lo, r_hi = 10.0, 80.0
    radii = (r_lo ** -2 - u * (r_lo ** -2 - r_hi ** -2)) ** -0.5
    cx = rng.uniform(xs[0], xs[-1], n)
    cy = rng.uniform(ys[0], ys[-1], n)
    amp = rng.normal(0.0, 1.0, n) * 0.12 * radii           # height ~ 12 % of the radius, either sign
    stretch = rng.uniform(1.0, 3.0, n)                        # valleys and ridges are elongated
    ang = rng.uniform(0, math.pi, n)
    for i in range(n):
        reach = 3 * radii[i] * stretch[i]
        c0, c1 = np.searchsorted(xs, [cx[i] - reach, cx[i] + reach])
        r0, r1 = np.searchsorted(ys, [cy[i] - reach, cy[i] + reach])
        if c1 <= c0 or r1 <= r0:
            continue
        X, Y = np.meshgrid(xs[c0:c1] - cx[i], ys[r0:r1] - cy[i])
        u_ = X * math.cos(ang[i]) + Y * math.sin(ang[i])
        v_ = -X * math.sin(ang[i]) + Y * math.cos(ang[i])
        z[r0:r1, c0:c1] += amp[i] * np.exp(-0.5 * ((u_ / (radii[i] * stretch[i])) ** 2 + (v_ / radii[i]) ** 2))
    return z


def _albedo_map(rng, xs, ys, size_m, res_m):
    """Normal albedo: Europa's mean with splotches (+-10 %) and darker linear striae (no geometry)."""
    from blender_addon.terrain.procedural.fields import spectral_field

    shape = (ys.size, xs.size)
    splotch = spectral_field(shape, rng, cell_m=res_m, wavelength_min_m=max(2 * res_m, 2.0),
                             wavelength_max_m=size_m / 2, beta=2.2)
    alb = EUROPA_ALBEDO * (1.0 + 0.10 * splotch)
    X, Y = np.meshgrid(xs, ys)
    n_striae = int(rng.poisson(12 * (size_m / 400.0) ** 2))
    for _ in range(n_striae):
        length = rng.uniform(0.3, 1.2) * size_m
        width = rng.uniform(0.5, 4.0)
        depth = rng.uniform(0.15, 0.45)
        a0 = rng.uniform(0, 2 * math.pi)
        p = np.array([rng.uniform(xs[0], xs[-1]), rng.uniform(ys[0], ys[-1])])
        n_seg = 4
        pts = [p]
        for _ in range(n_seg):
            a0 += rng.normal(0, 0.15)
            pts.append(pts[-1] + length / n_seg * np.array([math.cos(a0), math.sin(a0)]))
        for a, b in zip(pts[:-1], pts[1:]):
            reach = 4.0 * width
            c0, c1 = np.searchsorted(xs, [min(a[0], b[0]) - reach, max(a[0], b[0]) + reach])
            r0, r1 = np.searchsorted(ys, [min(a[1], b[1]) - reach, max(a[1], b[1]) + reach])
            if c1 <= c0 or r1 <= r0:
                continue
            d = _segment_distance(X[r0:r1, c0:c1], Y[r0:r1, c0:c1], a, b)
            alb[r0:r1, c0:c1] *= 1.0 - depth * np.exp(-0.5 * (d / width) ** 2)
    return np.clip(alb, 0.05, 1.0)


def procedural_europa(seed: int, *, size_m: float = DEFAULT_SIZE_M, res_m: float = DEFAULT_RES_M,
                      relief_range_m: float = DEFAULT_RELIEF_RANGE_M) -> DescentTerrain:
    """The memorandum's procedural Europa terrain, same seed same grid (see the module docstring).

    seed : integer; size_m : side (m); res_m : node spacing (m); relief_range_m : max - min height (m).
    """
    from blender_addon.terrain.procedural import craters as _craters
    from blender_addon.terrain.procedural import features as _features
    from blender_addon.terrain.procedural.fields import spectral_field

    if not (20.0 <= size_m <= 4000.0 and 0.05 <= res_m <= size_m / 16):
        raise InvalidInputError(f"descent terrain {size_m} m at {res_m} m: use 20-4000 m and a cell of 0.05 m to "
                                "size/16")
    if not relief_range_m > 0:
        raise InvalidInputError(f"relief range {relief_range_m} m must be positive")
    n = int(round(size_m / res_m)) + 1
    rng = np.random.Generator(np.random.PCG64([int(seed), DESCENT_TERRAIN_VERSION, 14]))
    half = (n - 1) * res_m / 2.0
    xs = -half + np.arange(n) * res_m
    ys = xs.copy()
    shape = (n, n)
    # z_geo is in GeoTIFF orientation (row 0 north) for the procedural feature stamps, flipped at the end
    z = 0.6 * spectral_field(shape, rng, cell_m=res_m, wavelength_min_m=2 * res_m, wavelength_max_m=size_m,
                             beta=3.0).astype(np.float64)
    z += _hills(rng, xs, ys, size_m)[::-1]
    diam = _craters.draw_diameters(rng, area_m2=size_m ** 2, density_per_km2_above_1km=0.05, slope=2.0,
                                   d_min_m=max(8 * res_m, 4.0), d_max_m=0.2 * size_m)
    craters = _craters.place_craters(rng, diam, width_m=size_m, height_m=size_m)
    z32 = z.astype(np.float32)
    _craters.stamp_craters(z32, craters, cell_m=res_m, transition_m=5000.0)
    centre = (rng.uniform(0.25, 0.75) * size_m, rng.uniform(0.25, 0.75) * size_m)
    _features.add_broken_plates(z32, rng, cell_m=res_m, centre_xy_m=centre, radius_m=rng.uniform(0.12, 0.22) * size_m,
                                plate_size_m=(0.04 * size_m, 0.1 * size_m), matrix_drop_m=3.0, tilt_deg=6.0)
    _features.add_crevasses(z32, rng, cell_m=res_m, count=int(rng.integers(2, 5)),
                            length_m=(0.2 * size_m, 0.6 * size_m), depth_m=(1.5, 5.0))
    cover = spectral_field(shape, rng, cell_m=res_m, wavelength_min_m=max(4 * res_m, size_m / 8),
                           wavelength_max_m=size_m, beta=3.0)
    _features.add_penitentes(z32, rng, cell_m=res_m, coverage_field=cover, height_m=(0.5, 2.0),
                             spacing_m=max(2.5 * res_m, 1.5), threshold=1.0)
    _features.add_blocks(z32, rng, cell_m=res_m, count=int(3000 * (size_m / 400.0) ** 2), h_min_m=0.3, h_max_m=2.5)
    height = z32[::-1].astype(np.float64)
    log.debug("procedural europa %d: %.1f m of relief before scaling to %.1f m", seed, np.ptp(height), relief_range_m)
    height = (height - height.min()) * (relief_range_m / max(float(np.ptp(height)), 1e-9))
    albedo = _albedo_map(rng, xs, ys, size_m, res_m)
    return DescentTerrain(height.astype(np.float32), albedo.astype(np.float32), float(xs[0]), float(ys[0]), res_m,
                          f"procedural:europa:{int(seed)}")


def load_terrain(spec: str, *, res_m: float = DEFAULT_RES_M, size_m: float = DEFAULT_SIZE_M,
                 albedo_seed: int = 0) -> DescentTerrain:
    """``procedural:europa:SEED`` or a DEM file (read with the project's DEM reader, GDAL) as a DescentTerrain.

    A DEM keeps its metric coordinates and cell size; its albedo map is procedural (``albedo_seed``).
    """
    spec = str(spec)
    if spec.startswith("procedural:"):
        parts = spec.split(":")
        if len(parts) != 3 or parts[1].lower() != "europa":
            raise InvalidInputError(f"terrain {spec!r}: the descent simulator's procedural terrain is "
                                    "procedural:europa:SEED")
        try:
            seed = int(parts[2])
        except ValueError:
            raise InvalidInputError(f"terrain {spec!r}: SEED must be an integer") from None
        return procedural_europa(seed, size_m=size_m, res_m=res_m)
    from blender_addon.terrain.dem import read_dem

    dem = read_dem(spec)
    gt = dem.geotransform
    res = abs(gt[1])
    rows, cols = dem.shape
    height = np.ascontiguousarray(dem.array[::-1], dtype=np.float32)
    if not np.all(np.isfinite(height)):
        raise InvalidInputError(f"{spec}: the DEM has nodata cells; the descent renderer needs a complete grid "
                                "(crop it to its valid part)")
    x0 = gt[0] + 0.5 * res
    y0 = gt[3] + gt[5] * (rows - 0.5)
    rng = np.random.Generator(np.random.PCG64([int(albedo_seed), DESCENT_TERRAIN_VERSION, 15]))
    xs = x0 + np.arange(cols) * res
    ys = y0 + np.arange(rows) * res
    albedo = _albedo_map(rng, xs, ys, max(cols, rows) * res, res)
    return DescentTerrain(height, albedo.astype(np.float32), float(x0), float(y0), res, spec)
