"""The skyline-database ray-marcher: horizon elevation by azimuth over a multi-resolution DEM.

For an eye at ground height (bilinear on level 0) plus the camera height, the horizon at azimuth
``az`` (degrees clockwise from grid north) is the maximum over horizontal distances ``d`` of
``atan2(z(d) - z_eye - d^2 (1 - k) / 2R, d)``.  In the near field (the first
``near_field_cells`` cells of level 0, 25 by default) the maximum is exact: the ray is walked
cell by cell over level 0 and the bilinear surface, a quadratic in ``d`` inside each cell, is
maximised analytically.  Beyond, samples are taken on the finest level that contains them
(bilinear), every ``clip(step_per_m * d, min_step_cells * cell_0, cell_L)`` metres, so the step
grows with distance but never exceeds one cell of the level sampled.
Negative elevations are kept.  Blocks of terrain whose maximum cannot beat the best tangent so
far are skipped whole (exactly: the skip is conservative), and the ray stops when no remaining
level can beat it.  Coordinates are in the terrain's projected metric CRS (metres).
"""
from __future__ import annotations

import logging
import math
import threading
import weakref
from dataclasses import dataclass

import numpy as np

from blender_addon.terrain.model import MultiResTerrain
from board.conventions import curvature_coefficient
from board.errors import InvalidInputError
from board.skydb import GridSpec, Tile
from render_service.renderers import _kernels
from render_service.renderers.base import RenderSpec, TileResult

log = logging.getLogger(__name__)

#: Recorded in the database metadata; bump when results change.
__version__ = "3"   # 2: exact near field; 3: a block skip stops at its level's edge
RENDERER_NAME = "raymarch"


#: Cap of the automatic near-field radius, in level-0 cells (when step_per_m is tiny or 0).
NEAR_FIELD_MAX_CELLS = 64.0


@dataclass(frozen=True)
class MarchOptions:
    """Sampling of the march (defaults meet the accuracy targets in docs/renderer.md).

    near_field_cells : radius (level-0 cells) searched exactly around the eye, cell by cell
        (see :func:`._kernels.near_field`); 0 turns it off.  None (default): out to where the
        march's step starts to grow, ``min_step_cells / step_per_m`` cells (25 with the defaults;
        at most NEAR_FIELD_MAX_CELLS), so that nowhere is the march's step more than
        ``step_per_m`` of the distance (a fixed step near the eye would miss nearby crests by
        up to ``slope change x step / 2d`` radians: degrees within a few cells)
    min_step_cells : smallest step (and first sample distance beyond the near field), in level-0 cells
    step_per_m : step growth with distance (metres of step per metre of distance; 0.01 ~ 0.57 deg)
    block_cells : sizes (small, big) of the blocks used for empty-space skipping, in cells
    seed_growth : ratio of the sparse geometric pre-pass that seeds the best tangent (0: none)
    chunk_positions : consecutive positions a thread marches together, azimuth by azimuth
    """

    near_field_cells: float | None = None
    min_step_cells: float = 0.25
    step_per_m: float = 0.01
    block_cells: tuple[int, int] = (8, 64)
    seed_growth: float = 1.2
    chunk_positions: int = 32


DEFAULT_OPTIONS = MarchOptions()


@dataclass
class PackedTerrain:
    """A MultiResTerrain flattened for the kernels (see :mod:`._kernels`)."""

    heights: np.ndarray
    offsets: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    x0: np.ndarray
    y0: np.ndarray
    cell: np.ndarray
    suffix_max: np.ndarray
    blk1: np.ndarray
    blk1_off: np.ndarray
    blk1_cols: np.ndarray
    blk1_size: int
    blk2: np.ndarray
    blk2_off: np.ndarray
    blk2_cols: np.ndarray
    blk2_size: int

    def level_args(self) -> tuple:
        return (self.heights, self.offsets, self.rows, self.cols, self.x0, self.y0, self.cell)

    def kernel_args(self) -> tuple:
        return (*self.level_args(), self.suffix_max, self.blk1, self.blk1_off, self.blk1_cols, self.blk1_size,
                self.blk2, self.blk2_off, self.blk2_cols, self.blk2_size)


def _footprint_block_max(a: np.ndarray, b: int) -> np.ndarray:
    """Max of cells ``[i*b, i*b+b] x [j*b, j*b+b]`` (inclusive: the bilinear footprint of the block).

    NaN cells are ignored; an all-NaN block gives -inf (nothing there can be seen).
    """
    a = np.where(np.isfinite(a), a, -np.inf).astype(np.float32)
    rows, cols = a.shape
    # m[r, c] = max of a[r:r+2, c:c+2] (edges padded with -inf)
    p = np.full((rows + 1, cols + 1), -np.inf, dtype=np.float32)
    p[:rows, :cols] = a
    m = np.maximum(np.maximum(p[:-1, :-1], p[1:, :-1]), np.maximum(p[:-1, 1:], p[1:, 1:]))
    nby, nbx = -(-rows // b), -(-cols // b)
    q = np.full((nby * b, nbx * b), -np.inf, dtype=np.float32)
    q[:rows, :cols] = m
    return q.reshape(nby, b, nbx, b).max(axis=(1, 3))


def pack_terrain(terrain: MultiResTerrain, *, block_cells: tuple[int, int] = DEFAULT_OPTIONS.block_cells) -> PackedTerrain:
    """Flatten the levels (finest first) and their block maxima into contiguous arrays."""
    if not terrain.levels:
        raise InvalidInputError("the terrain has no levels: build it with `skyloc dem prepare`")
    b1, b2 = int(block_cells[0]), int(block_cells[1])
    if b1 < 1 or b2 < 1:
        raise InvalidInputError(f"block sizes must be >= 1 cell, got {block_cells}")
    arrays, blk1, blk2 = [], [], []
    lmax = []
    for lev in terrain.levels:
        a = np.ascontiguousarray(lev.array, dtype=np.float32)
        if a.ndim != 2 or min(a.shape) < 2:
            raise InvalidInputError(f"terrain level of shape {a.shape} is too small (needs >= 2 x 2 cells)")
        if not (lev.cell_m > 0):
            raise InvalidInputError(f"terrain level cell size must be positive, got {lev.cell_m}")
        arrays.append(a)
        blk1.append(_footprint_block_max(a, b1))
        blk2.append(_footprint_block_max(a, b2))
        finite = a[np.isfinite(a)]
        lmax.append(float(finite.max()) if finite.size else -np.inf)
    suffix = np.maximum.accumulate(np.array(lmax[::-1], dtype=np.float64))[::-1].copy()

    def offs(parts):
        return np.concatenate([[0], np.cumsum([p.size for p in parts])[:-1]]).astype(np.int64)

    return PackedTerrain(
        heights=np.concatenate([a.ravel() for a in arrays]),
        offsets=offs(arrays),
        rows=np.array([a.shape[0] for a in arrays], dtype=np.int64),
        cols=np.array([a.shape[1] for a in arrays], dtype=np.int64),
        x0=np.array([lv.x0 for lv in terrain.levels], dtype=np.float64),
        y0=np.array([lv.y0 for lv in terrain.levels], dtype=np.float64),
        cell=np.array([lv.cell_m for lv in terrain.levels], dtype=np.float64),
        suffix_max=suffix,
        blk1=np.concatenate([b.ravel() for b in blk1]), blk1_off=offs(blk1),
        blk1_cols=np.array([b.shape[1] for b in blk1], dtype=np.int64), blk1_size=b1,
        blk2=np.concatenate([b.ravel() for b in blk2]), blk2_off=offs(blk2),
        blk2_cols=np.array([b.shape[1] for b in blk2], dtype=np.int64), blk2_size=b2,
    )


# One packed copy per live terrain object (a Dask worker renders many tiles of one terrain).
_CACHE: dict[int, tuple[weakref.ref, tuple[int, int], PackedTerrain]] = {}
_CACHE_LOCK = threading.Lock()


def _packed(terrain: MultiResTerrain, options: MarchOptions) -> PackedTerrain:
    key = id(terrain)
    with _CACHE_LOCK:
        hit = _CACHE.get(key)
        if hit is not None and hit[0]() is terrain and hit[1] == tuple(options.block_cells):
            return hit[2]
        packed = pack_terrain(terrain, block_cells=options.block_cells)
        for k in [k for k, v in _CACHE.items() if v[0]() is None]:
            del _CACHE[k]
        _CACHE[key] = (weakref.ref(terrain), tuple(options.block_cells), packed)
        return packed


def _direction_tables(spec: RenderSpec) -> tuple[np.ndarray, np.ndarray]:
    az = np.radians(spec.azimuths_deg())
    return np.sin(az), np.cos(az)   # (east, north) components: azimuth clockwise from grid north


def near_field_cells(options: MarchOptions) -> float:
    """Radius (level-0 cells) of the exact near field for these options (see MarchOptions)."""
    if options.near_field_cells is not None:
        return float(options.near_field_cells)
    if options.step_per_m <= 0:
        return NEAR_FIELD_MAX_CELLS
    return min(options.min_step_cells / options.step_per_m, NEAR_FIELD_MAX_CELLS)


def render_positions(terrain: MultiResTerrain, x_m, y_m, spec: RenderSpec, *,
                     options: MarchOptions = DEFAULT_OPTIONS) -> tuple[np.ndarray, np.ndarray]:
    """Horizons at arbitrary positions (metres, terrain CRS).

    Returns
    -------
    elevation_deg, distance_m : (n_pos, n_azimuth) float32
        Horizon elevation (degrees above the eye's horizontal) and horizontal distance (metres)
        of the point forming it; NaN for positions outside level 0.
    """
    px = np.ascontiguousarray(np.ravel(x_m), dtype=np.float64)
    py = np.ascontiguousarray(np.ravel(y_m), dtype=np.float64)
    if px.shape != py.shape:
        raise InvalidInputError("x and y must have the same number of positions")
    if not (options.min_step_cells > 0 and options.step_per_m >= 0 and options.chunk_positions >= 1
            and (options.near_field_cells is None or options.near_field_cells >= 0)):
        raise InvalidInputError("min_step_cells must be > 0, step_per_m >= 0, chunk_positions >= 1 and "
                                "near_field_cells >= 0")
    pk = _packed(terrain, options)
    sin_az, cos_az = _direction_tables(spec)
    c_per_m = curvature_coefficient(spec.body_radius_m, spec.refraction_k)
    min_step = options.min_step_cells * float(pk.cell[0])
    max_dist = math.inf if spec.max_distance_m is None else float(spec.max_distance_m)
    return _kernels.render_positions(px, py, float(spec.camera_height_m), sin_az, cos_az, *pk.kernel_args(),
                                     c_per_m, min_step, min_step, float(options.step_per_m), max_dist,
                                     float(options.seed_growth), int(options.chunk_positions),
                                     near_field_cells(options) * float(pk.cell[0]))


def check_positions_inside(terrain: MultiResTerrain, x_m, y_m) -> None:
    """Raise InvalidInputError unless every position lies where level 0 gives a ground height."""
    lv = terrain.levels[0]
    rows, cols = lv.array.shape
    u = (np.asarray(x_m, dtype=float) - lv.x0) / lv.cell_m - 0.5
    v = (lv.y0 - np.asarray(y_m, dtype=float)) / lv.cell_m - 0.5
    bad = ~((u >= 0) & (v >= 0) & (u <= cols - 1) & (v <= rows - 1))
    if np.any(bad):
        xb, yb = np.ravel(x_m)[np.ravel(bad)][0], np.ravel(y_m)[np.ravel(bad)][0]
        xmin, ymin, xmax, ymax = lv.bounds()
        raise InvalidInputError(
            f"{int(bad.sum())} position(s), e.g. ({xb:.1f}, {yb:.1f}) m, are outside the terrain's finest level "
            f"(x {xmin:.1f}..{xmax:.1f}, y {ymin:.1f}..{ymax:.1f} m, less half a cell): move the site or grid "
            "inside the DEM, or prepare the terrain with a larger grid_half_m")


def render_tile(terrain: MultiResTerrain, grid: GridSpec, tile: Tile, spec: RenderSpec, *,
                options: MarchOptions = DEFAULT_OPTIONS) -> TileResult:
    """Render one tile of a skyline-database grid (the renderer contract of :mod:`.base`).

    Returns a TileResult with elevation_deg and distance_m of shape (nrows, ncols, n_azimuth).
    """
    ii, jj = np.meshgrid(np.arange(tile.row0, tile.row0 + tile.nrows),
                         np.arange(tile.col0, tile.col0 + tile.ncols), indexing="ij")
    x, y = grid.xy(ii, jj)
    check_positions_inside(terrain, x, y)
    el, dist = render_positions(terrain, x, y, spec, options=options)
    shape = (tile.nrows, tile.ncols, spec.n_azimuth)
    return TileResult(elevation_deg=el.reshape(shape), distance_m=dist.reshape(shape))


def horizon_at(terrain: MultiResTerrain, x: float, y: float, spec: RenderSpec, *,
               options: MarchOptions = DEFAULT_OPTIONS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Horizon at one position (metres, terrain CRS).

    Returns (azimuth_deg, elevation_deg, distance_m), each (n_azimuth,): azimuth clockwise from
    grid north, elevation in degrees above the eye's horizontal, distance in metres.
    """
    check_positions_inside(terrain, [x], [y])
    el, dist = render_positions(terrain, [x], [y], spec, options=options)
    return spec.azimuths_deg(), el[0].astype(np.float64), dist[0].astype(np.float64)
