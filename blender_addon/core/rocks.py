"""Rocks and pebbles: size-frequency sampling, placement around the rover, and rock meshes.

Sizes follow a truncated power law on the cumulative number of rocks per unit area,
``N(>D) = density * (D / d_min) ** -b`` for ``d_min <= D <= d_max`` (the form fitted to
Mars landing-site rock counts), sampled by inverting its CDF.  Positions are uniform over a
disc around the rover with a small keep-out around the wheels/mast; optional large rocks
are put close to the mast to occlude parts of the skyline.

Meshes are built here in numpy (an irregular, flattened icosphere per rock, all rocks in
one vertex/face array) so the Blender layer only copies arrays with ``foreach_set``.
Coordinates: the DEM's metric CRS (x east, y north, z up), metres.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from board.errors import InvalidInputError

log = logging.getLogger(__name__)

#: Hard cap on the number of rocks in one scene (memory and Blender build time).
MAX_ROCKS = 20_000


@dataclass(frozen=True)
class RockField:
    """Rocks around a site (all arrays (n,)).

    x, y : centre, metres (metric CRS); diameter : metres; height_ratio : height / diameter;
    yaw_deg : rotation about the vertical, degrees; shape : index of the mesh prototype
    near : True for the rocks placed near the mast
    """

    x: np.ndarray
    y: np.ndarray
    diameter: np.ndarray
    height_ratio: np.ndarray
    yaw_deg: np.ndarray
    shape: np.ndarray
    near: np.ndarray

    def __len__(self) -> int:
        return int(self.x.size)


def sample_power_law(n: int, d_min: float, d_max: float, exponent: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` diameters (metres) with ``P(D > d) = ((d / d_min)**-b - r) / (1 - r)``, ``r = (d_max/d_min)**-b``.

    The cumulative law N(>D) proportional to D**-b truncated to [d_min, d_max].
    """
    if not (0 < d_min < d_max) or exponent <= 0:
        raise InvalidInputError(f"power law needs 0 < d_min < d_max and b > 0, got {d_min}, {d_max}, {exponent}")
    u = rng.random(int(n))
    lo = d_min ** -exponent
    hi = d_max ** -exponent
    return (lo - u * (lo - hi)) ** (-1.0 / exponent)


def fit_power_law_exponent(d: np.ndarray, d_min: float, d_max: float) -> float:
    """Maximum-likelihood exponent b of the truncated cumulative power law on [d_min, d_max].

    Solves the likelihood equation ``1/b + ln(d_min) - mean(ln d) - r ln(d_max/d_min) / (1 - r) = 0``
    (``r = (d_max/d_min)**-b``) by bisection.
    """
    d = np.asarray(d, dtype=float)
    mean_log = float(np.mean(np.log(d / d_min)))
    L = math.log(d_max / d_min)

    def score(b: float) -> float:
        r = math.exp(-b * L)
        return 1.0 / b - mean_log - r * L / (1.0 - r)

    lo, hi = 1e-3, 50.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if score(mid) > 0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def expected_count(density_per_m2: float, radius_m: float, keep_out_m: float = 0.0) -> float:
    """Expected number of rocks >= d_min on the disc of ``radius_m`` minus the keep-out disc."""
    return density_per_m2 * math.pi * max(radius_m ** 2 - keep_out_m ** 2, 0.0)


def place_rocks(center_xy: tuple[float, float], rng: np.random.Generator, *, density_per_m2: float,
                d_min_m: float, d_max_m: float, exponent: float, radius_m: float, near_count: int = 0,
                near_distance_m: tuple[float, float] = (2.0, 6.0),
                near_diameter_m: tuple[float, float] = (0.5, 1.5), keep_out_m: float = 1.2,
                n_shapes: int = 8) -> RockField:
    """Scatter rocks around ``center_xy`` (metres); the count is Poisson with the expected mean.

    Rocks keep ``keep_out_m + D/2`` away from the centre (the rover).  ``near_count`` extra rocks
    get uniform azimuths, distances in ``near_distance_m`` and diameters in ``near_diameter_m``.
    Raises InvalidInputError when the expected count exceeds MAX_ROCKS (lower the density or radius).
    """
    mean = expected_count(density_per_m2, radius_m, keep_out_m)
    if mean + near_count > MAX_ROCKS:
        raise InvalidInputError(f"{mean:.0f} rocks expected (density {density_per_m2}/m2 over {radius_m} m): more "
                                f"than {MAX_ROCKS}; lower rocks.density_per_m2 or rocks.radius_m")
    n = int(rng.poisson(mean)) if mean > 0 else 0
    d = sample_power_law(n, d_min_m, d_max_m, exponent, rng) if n else np.zeros(0)
    # uniform over the annulus [keep_out, radius]
    r = np.sqrt(rng.uniform(keep_out_m ** 2, radius_m ** 2, n)) if n else np.zeros(0)
    r = np.maximum(r, keep_out_m + d / 2.0)
    a = rng.uniform(0.0, 2.0 * math.pi, n)
    nd = rng.uniform(near_diameter_m[0], near_diameter_m[1], near_count)
    nr = rng.uniform(near_distance_m[0], near_distance_m[1], near_count)
    nr = np.maximum(nr, keep_out_m + nd / 2.0)
    na = rng.uniform(0.0, 2.0 * math.pi, near_count)
    diam = np.concatenate([d, nd])
    rad = np.concatenate([r, nr])
    ang = np.concatenate([a, na])
    total = diam.size
    return RockField(
        x=center_xy[0] + rad * np.sin(ang),
        y=center_xy[1] + rad * np.cos(ang),
        diameter=diam,
        height_ratio=rng.uniform(0.35, 0.8, total),
        yaw_deg=rng.uniform(0.0, 360.0, total),
        shape=rng.integers(0, n_shapes, total),
        near=np.concatenate([np.zeros(n, bool), np.ones(near_count, bool)]),
    )


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere: vertices (V, 3) float64 and triangles (F, 3) int32 (outward winding)."""
    t = (1.0 + math.sqrt(5.0)) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=float)
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6],
         [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
         [8, 6, 7], [9, 8, 1]]
    verts = list(v / np.linalg.norm(v, axis=1, keepdims=True))
    faces = f
    for _ in range(subdivisions):
        cache: dict[tuple[int, int], int] = {}

        def mid(i: int, j: int) -> int:
            key = (min(i, j), max(i, j))
            if key not in cache:
                m = verts[i] + verts[j]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        new = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        faces = new
    return np.array(verts), np.array(faces, dtype=np.int32)


def rock_prototypes(n_shapes: int, rng: np.random.Generator, *, subdivisions: int = 2) -> list[np.ndarray]:
    """``n_shapes`` irregular unit rocks (vertices of a shared icosphere topology, radius ~0.5).

    Each vertex is pushed radially by a few random low-order bumps, so rocks are lumpy and
    angular; the bottom is flattened (they sit on the ground).
    """
    base, _ = icosphere(subdivisions)
    out = []
    for _ in range(n_shapes):
        dirs = rng.normal(size=(6, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        amps = rng.uniform(0.05, 0.25, 6)
        bump = (amps[None, :] * np.clip(base @ dirs.T, 0.0, None) ** 2).sum(axis=1)
        # a few planar cuts make the rocks angular rather than pebble-round
        facet = rng.normal(size=(4, 3))
        facet /= np.linalg.norm(facet, axis=1, keepdims=True)
        flat = 1.0 - 0.6 * np.clip(base @ facet.T - 0.45, 0.0, None).max(axis=1)
        v = base * (0.5 * (1.0 + bump) * flat)[:, None]
        v[:, 2] = np.maximum(v[:, 2], -0.15)
        out.append(v)
    return out


def rock_mesh(field: RockField, ground_z: np.ndarray, rng: np.random.Generator, *, subdivisions: int = 2,
              pebble_subdivisions: int = 1, pebble_diameter_m: float = 0.15,
              origin: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """All rocks as one mesh: vertices (V, 3) float32 and triangles (F, 3) int32.

    ground_z : (n,) terrain height under every rock, metres; rocks are sunk by 10 % of their height.
    origin : subtracted from vertex coordinates (the scene offset that keeps Blender near 0).
    Rocks smaller than ``pebble_diameter_m`` use the coarser ``pebble_subdivisions`` sphere.
    """
    n = len(field)
    if n == 0:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
    n_shapes = int(field.shape.max()) + 1
    protos = {sub: rock_prototypes(n_shapes, np.random.default_rng(rng.integers(1 << 62)), subdivisions=sub)
              for sub in {subdivisions, pebble_subdivisions}}
    faces_of = {sub: icosphere(sub)[1] for sub in protos}
    verts_out, faces_out = [], []
    offset = 0
    for i in range(n):
        sub = pebble_subdivisions if field.diameter[i] < pebble_diameter_m else subdivisions
        v = protos[sub][int(field.shape[i])]
        d = field.diameter[i]
        h = d * field.height_ratio[i]
        yaw = math.radians(field.yaw_deg[i])
        c, s = math.cos(yaw), math.sin(yaw)
        xy = v[:, :2] @ np.array([[c, s], [-s, c]]) * d
        # prototype z spans about [-0.15, 0.55]: scale to a height h, bottom 10 % of h below ground
        z = (v[:, 2] + 0.15) * (h / 0.7) - 0.1 * h + ground_z[i]
        verts_out.append(np.column_stack([xy[:, 0] + field.x[i] - origin[0], xy[:, 1] + field.y[i] - origin[1],
                                          z - origin[2]]))
        faces_out.append(faces_of[sub] + offset)
        offset += v.shape[0]
    return np.concatenate(verts_out).astype(np.float32), np.concatenate(faces_out).astype(np.int32)


def bilinear_height(array: np.ndarray, x0: float, y0: float, cell_m: float, x, y) -> np.ndarray:
    """Terrain height at points (x, y) (metres) of a north-up grid (cell centres at x0 + (c + 0.5) cell)."""
    rows, cols = array.shape
    c = (np.asarray(x, float) - x0) / cell_m - 0.5
    r = (y0 - np.asarray(y, float)) / cell_m - 0.5
    c = np.clip(c, 0, cols - 1.000001)
    r = np.clip(r, 0, rows - 1.000001)
    c0 = np.floor(c).astype(int)
    r0 = np.floor(r).astype(int)
    fc = c - c0
    fr = r - r0
    a = np.nan_to_num(array.astype(np.float64), nan=float(np.nanmean(array)))
    return (a[r0, c0] * (1 - fc) * (1 - fr) + a[r0, c0 + 1] * fc * (1 - fr)
            + a[r0 + 1, c0] * (1 - fc) * fr + a[r0 + 1, c0 + 1] * fc * fr)
