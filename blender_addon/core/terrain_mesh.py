"""Terrain meshes from a multi-resolution DEM, as plain numpy arrays (no bpy).

Each level of a :class:`~blender_addon.terrain.model.MultiResTerrain` becomes a grid of quads
whose vertices are the level's cell centres (so the surface is the same piecewise-bilinear-ish
surface the ray-marcher samples).  A level leaves a hole where the next finer level has data
(every quad with a corner strictly inside the finer level's vertex extent is dropped), and every
border of the quad set (level borders, holes, nodata) gets a vertical *skirt* hanging down, so
no line of sight passes through the seam between two levels: no cracks.

Coordinates
    Scene coordinates are world coordinates (the DEM's projected CRS, metres) minus a
    :class:`SceneOffset` (as BlenderGIS does), so Blender's float32 vertices stay near the origin.
Curvature
    With ``radius_m`` given, every vertex drops by ``r**2 (1 - k) / (2 R)``, ``r`` being its
    horizontal distance from the offset origin (the tangent point).  A camera at the origin then
    sees exactly the ray-marcher's ``d**2 (1 - k) / 2R`` drop; a camera elsewhere must be tilted
    to the local normal of that paraboloid, see :func:`local_up_enu`.
Memory
    A level is emitted in chunks of at most ``chunk_cells x chunk_cells`` quads, so the temporary
    arrays stay bounded whatever the DEM size.
"""
from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass
from typing import Iterator

import numpy as np

from blender_addon.terrain.model import MultiResTerrain, TerrainLevel
from board.conventions import curvature_coefficient, curvature_drop_m
from board.errors import InvalidInputError, NoDataError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SceneOffset:
    """World position (projected CRS, metres) of the Blender scene origin.

    x_m, y_m : easting/northing of the origin (also the curvature tangent point), metres
    z_m : height subtracted from every vertex, metres
    """

    x_m: float
    y_m: float
    z_m: float = 0.0

    def to_scene(self, x, y, z):
        """World (x, y, z) metres -> scene coordinates (no curvature), metres."""
        return np.asarray(x) - self.x_m, np.asarray(y) - self.y_m, np.asarray(z) - self.z_m

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "SceneOffset":
        return cls(float(d["x_m"]), float(d["y_m"]), float(d.get("z_m", 0.0)))


@dataclass
class MeshChunk:
    """One mesh object's arrays.

    name : object name ("L0_0_0": level, chunk row, chunk column)
    level : index of the terrain level (0 = finest)
    vertices : (n, 3) float32, scene coordinates, metres
    quads : (m, 4) int32 vertex indices (terrain quads, then skirt quads)
    n_skirt : how many of the quads (at the end) are skirt walls
    """

    name: str
    level: int
    vertices: np.ndarray
    quads: np.ndarray
    n_skirt: int = 0


def sample_height(terrain: MultiResTerrain, x: float, y: float) -> float:
    """Ground height (metres) at world point (x, y): bilinear on the finest level that has it.

    Raises NoDataError when no level has a finite height there.
    """
    for lev in terrain.levels:
        z = _bilinear(lev, x, y)
        if z is not None and math.isfinite(z):
            return z
    raise NoDataError(
        f"no terrain height at ({x:.1f}, {y:.1f}) m: the point is outside the terrain or on nodata; "
        "choose a position inside the DEM")


def _bilinear(lev: TerrainLevel, x: float, y: float) -> float | None:
    rows, cols = lev.array.shape
    u = (x - lev.x0) / lev.cell_m - 0.5
    v = (lev.y0 - y) / lev.cell_m - 0.5
    if not (0.0 <= u <= cols - 1 and 0.0 <= v <= rows - 1):
        return None
    c0 = min(int(math.floor(u)), cols - 2)
    r0 = min(int(math.floor(v)), rows - 2)
    fu, fv = u - c0, v - r0
    a = lev.array[r0:r0 + 2, c0:c0 + 2].astype(float)
    return float((a[0, 0] * (1 - fu) + a[0, 1] * fu) * (1 - fv) + (a[1, 0] * (1 - fu) + a[1, 1] * fu) * fv)


def default_offset(terrain: MultiResTerrain) -> SceneOffset:
    """Scene origin at the site, at the site's ground height (rounded to the metre)."""
    sx, sy = (float(v) for v in terrain.site_xy)
    try:
        z = round(sample_height(terrain, sx, sy))
    except NoDataError:
        finite = terrain.finest.array[np.isfinite(terrain.finest.array)]
        z = round(float(np.median(finite))) if finite.size else 0.0
    return SceneOffset(sx, sy, float(z))


def local_up_enu(x: float, y: float, offset: SceneOffset, radius_m: float | None,
                 refraction_k: float = 0.0) -> np.ndarray:
    """Unit normal (ENU) of the curved scene at world (x, y): the "up" a camera there must use.

    The scene surface is ``z - c r^2`` with ``c = (1 - k) / 2R``; its normal at horizontal offset
    ``(dx, dy)`` from the origin is ``(2 c dx, 2 c dy, 1)`` normalised.  With that up vector, a point
    at distance ``d`` from the camera drops by exactly ``c d^2`` below the camera's horizontal.
    """
    if not radius_m:
        return np.array([0.0, 0.0, 1.0])
    c = curvature_coefficient(radius_m, refraction_k)
    v = np.array([2 * c * (x - offset.x_m), 2 * c * (y - offset.y_m), 1.0])
    return v / np.linalg.norm(v)


def scene_z(terrain_z, x, y, offset: SceneOffset, radius_m: float | None, refraction_k: float = 0.0):
    """Scene z (metres) of world height ``terrain_z`` at world (x, y), curvature drop included."""
    z = np.asarray(terrain_z, dtype=float) - offset.z_m
    if radius_m:
        r2 = (np.asarray(x, dtype=float) - offset.x_m) ** 2 + (np.asarray(y, dtype=float) - offset.y_m) ** 2
        z = z - curvature_drop_m(np.sqrt(r2), radius_m, refraction_k)
    return z


def _vertex_extent(lev: TerrainLevel) -> tuple[float, float, float, float]:
    """(xmin, ymin, xmax, ymax) of the level's cell centres, metres."""
    rows, cols = lev.array.shape
    h = lev.cell_m
    return lev.x0 + 0.5 * h, lev.y0 - (rows - 0.5) * h, lev.x0 + (cols - 0.5) * h, lev.y0 - 0.5 * h


def quad_mask(terrain: MultiResTerrain, k: int) -> np.ndarray:
    """(rows-1, cols-1) bool: which quads of level ``k`` are meshed.

    A quad is kept when its four corners are finite and (for k > 0) none of its corners lies
    strictly inside the vertex extent of level ``k - 1`` (which meshes that area finer).
    """
    lev = terrain.levels[k]
    a = lev.array
    fin = np.isfinite(a)
    keep = fin[:-1, :-1] & fin[1:, :-1] & fin[:-1, 1:] & fin[1:, 1:]
    if k > 0:
        xmin, ymin, xmax, ymax = _vertex_extent(terrain.levels[k - 1])
        rows, cols = a.shape
        xs = lev.x0 + (np.arange(cols) + 0.5) * lev.cell_m
        ys = lev.y0 - (np.arange(rows) + 0.5) * lev.cell_m
        inx = (xs > xmin) & (xs < xmax)
        iny = (ys > ymin) & (ys < ymax)
        inside = iny[:, None] & inx[None, :]          # vertex strictly inside the finer extent
        any_in = inside[:-1, :-1] | inside[1:, :-1] | inside[:-1, 1:] | inside[1:, 1:]
        keep &= ~any_in
    return keep


def level_chunks(terrain: MultiResTerrain, k: int, *, offset: SceneOffset, radius_m: float | None = None,
                 refraction_k: float = 0.0, chunk_cells: int = 256,
                 skirt_depth_m: float | None = None) -> Iterator[MeshChunk]:
    """Mesh chunks of level ``k`` (see the module docstring).

    skirt_depth_m : how far skirts hang below their edge, metres (default: 20 cells, at least 50 m)
    """
    if chunk_cells < 1:
        raise InvalidInputError(f"chunk_cells must be >= 1, got {chunk_cells}")
    lev = terrain.levels[k]
    a = lev.array
    rows, cols = a.shape
    if rows < 2 or cols < 2:
        return
    depth = float(skirt_depth_m) if skirt_depth_m is not None else max(50.0, 20.0 * lev.cell_m)
    q = quad_mask(terrain, k)
    # Boundary edges of the quad set.  Horizontal edge (r, c) joins vertices (r, c)-(r, c+1),
    # between quads (r-1, c) above and (r, c) below; vertical edge (r, c) joins (r, c)-(r+1, c),
    # between quads (r, c-1) left and (r, c) right.
    qp = np.zeros((rows + 1, cols + 1), dtype=bool)
    qp[1:-1, 1:-1] = q
    above, below = qp[:-1, 1:-1], qp[1:, 1:-1]            # (rows, cols-1)
    left, right = qp[1:-1, :-1], qp[1:-1, 1:]              # (rows-1, cols)
    h_edge = above ^ below
    v_edge = left ^ right
    # the quad that owns each boundary edge (its chunk emits the skirt)
    h_qr = np.where(below, np.arange(rows)[:, None], np.arange(rows)[:, None] - 1)
    v_qc = np.where(right, np.arange(cols)[None, :], np.arange(cols)[None, :] - 1)

    for qr0 in range(0, rows - 1, chunk_cells):
        for qc0 in range(0, cols - 1, chunk_cells):
            qr1, qc1 = min(qr0 + chunk_cells, rows - 1), min(qc0 + chunk_cells, cols - 1)
            sub = q[qr0:qr1, qc0:qc1]
            if not sub.any():
                continue
            chunk = _chunk(lev, k, sub, qr0, qc0, qr1, qc1, h_edge, h_qr, v_edge, v_qc,
                           offset, radius_m, refraction_k, depth)
            yield chunk


def _chunk(lev, k, sub, qr0, qc0, qr1, qc1, h_edge, h_qr, v_edge, v_qc, offset, radius_m, refraction_k, depth):
    nr, nc = qr1 - qr0 + 1, qc1 - qc0 + 1                 # vertex rows/cols of the block
    a = lev.array[qr0:qr1 + 1, qc0:qc1 + 1].astype(np.float64)
    xs = lev.x0 + (np.arange(qc0, qc1 + 1) + 0.5) * lev.cell_m
    ys = lev.y0 - (np.arange(qr0, qr1 + 1) + 0.5) * lev.cell_m
    X, Y = np.meshgrid(xs, ys)
    Z = scene_z(np.where(np.isfinite(a), a, 0.0), X, Y, offset, radius_m, refraction_k)
    vid = np.arange(nr * nc, dtype=np.int64).reshape(nr, nc)
    rr, cc = np.nonzero(sub)
    quads = np.stack([vid[rr, cc], vid[rr + 1, cc], vid[rr + 1, cc + 1], vid[rr, cc + 1]], axis=1)

    # skirts: boundary edges owned by quads of this block
    he = h_edge[qr0:qr1 + 1, qc0:qc1] & (h_qr[qr0:qr1 + 1, qc0:qc1] >= qr0) & (h_qr[qr0:qr1 + 1, qc0:qc1] < qr1)
    ve = v_edge[qr0:qr1, qc0:qc1 + 1] & (v_qc[qr0:qr1, qc0:qc1 + 1] >= qc0) & (v_qc[qr0:qr1, qc0:qc1 + 1] < qc1)
    er, ec = np.nonzero(he)
    vr, vc = np.nonzero(ve)
    e1 = np.concatenate([vid[er, ec], vid[vr, vc]])
    e2 = np.concatenate([vid[er, ec + 1], vid[vr + 1, vc]])

    flat = np.stack([X.ravel() - offset.x_m, Y.ravel() - offset.y_m, Z.ravel()], axis=1)
    # keep only used vertices (a coarse level's hole would otherwise carry loose vertices)
    used = np.zeros(nr * nc, dtype=bool)
    used[quads.ravel()] = True
    remap = np.cumsum(used) - 1
    verts = flat[used]
    quads = remap[quads]
    n_skirt = e1.size
    if n_skirt:
        ends = np.unique(np.concatenate([e1, e2]))
        low = flat[ends].copy()
        low[:, 2] -= depth
        low_id = np.full(nr * nc, -1, dtype=np.int64)
        low_id[ends] = verts.shape[0] + np.arange(ends.size)
        verts = np.concatenate([verts, low])
        skirt = np.stack([remap[e1], remap[e2], low_id[e2], low_id[e1]], axis=1)
        quads = np.concatenate([quads, skirt])
    return MeshChunk(name=f"L{k}_{qr0}_{qc0}", level=k,
                     vertices=verts.astype(np.float32), quads=quads.astype(np.int32), n_skirt=int(n_skirt))


#: (factor, margin in level-0 cells) of the refinement rings, finest first: cells within the grid
#: plus 4 cells are split 8 x 8, out to 16 cells 4 x 4, out to 64 cells 2 x 2.
DEFAULT_RINGS: tuple[tuple[int, int], ...] = ((8, 4), (4, 16), (2, 64))
DEFAULT_REFINE_BUDGET = 6_000_000


def _cell_rect(lev: TerrainLevel, site_xy, reach_m: float) -> tuple[int, int, int, int]:
    """(c0, c1, r0, r1): level-0 cell-centre indices spanning the square of half-side ``reach_m``, clipped."""
    rows, cols = lev.array.shape
    h = lev.cell_m
    sx, sy = site_xy
    c0 = max(0, int(math.floor((sx - reach_m - lev.x0) / h - 0.5)))
    c1 = min(cols - 1, int(math.ceil((sx + reach_m - lev.x0) / h - 0.5)))
    r0 = max(0, int(math.floor((lev.y0 - (sy + reach_m)) / h - 0.5)))
    r1 = min(rows - 1, int(math.ceil((lev.y0 - (sy - reach_m)) / h - 0.5)))
    return c0, c1, r0, r1


def _upsample(lev: TerrainLevel, rect: tuple[int, int, int, int], f: int) -> TerrainLevel:
    """Level-0 cells ``rect`` split ``f x f``, vertices on the bilinear surface (cell centres aligned)."""
    c0, c1, r0, r1 = rect
    rows, cols = lev.array.shape
    h = lev.cell_m
    u = c0 + np.arange((c1 - c0) * f + 1) / f
    v = r0 + np.arange((r1 - r0) * f + 1) / f
    ci = np.minimum(np.floor(u).astype(int), cols - 2)
    ri = np.minimum(np.floor(v).astype(int), rows - 2)
    fu = (u - ci)[None, :]
    fv = (v - ri)[:, None]
    a = lev.array
    z = ((a[np.ix_(ri, ci)] * (1 - fu) + a[np.ix_(ri, ci + 1)] * fu) * (1 - fv)
         + (a[np.ix_(ri + 1, ci)] * (1 - fu) + a[np.ix_(ri + 1, ci + 1)] * fu) * fv).astype(np.float32)
    fine_cell = h / f
    return TerrainLevel(array=z, x0=lev.x0 + (c0 + 0.5) * h - 0.5 * fine_cell,
                        y0=lev.y0 - (r0 + 0.5) * h + 0.5 * fine_cell, cell_m=fine_cell)


def refine_near_field(terrain: MultiResTerrain, *, half_m: float | None = None,
                      rings: tuple[tuple[int, int], ...] = DEFAULT_RINGS,
                      max_quads: int = DEFAULT_REFINE_BUDGET) -> MultiResTerrain:
    """A terrain with extra, finer levels: level 0 bilinearly upsampled in rings around the site.

    A quad split into two triangles departs from the bilinear surface the ray-marcher samples by up
    to a quarter of the cell's twist ``|z00 + z11 - z01 - z10| / 4``; seen from a camera ``d`` away
    that is an elevation error of up to ``twist / 4d`` radians (degrees on rough 30 m DEMs a cell or
    two from the camera).  Splitting cells ``f x f`` with vertices on the bilinear surface divides it
    by ``f**2``.  Ring ``k`` (``rings[k] = (f, margin_cells)``) covers the square of half-side
    ``half_m + margin_cells`` level-0 cells around the site (``half_m`` default: the terrain's
    ``meta["grid_half_m"]``, else 0), aligned to level-0 cell centres so that each coarser ring's
    (and level 0's) hole meets it without a gap (see :func:`quad_mask`); along a shared edge the
    bilinear surface is linear, so the finer vertices lie on the coarser edge (no cracks).
    Factors are lowered (ring by ring, finest first) until all rings hold at most ``max_quads``
    quads; rings whose factor reaches 1 are dropped.
    """
    lev = terrain.levels[0]
    if half_m is None:
        half_m = float(terrain.meta.get("grid_half_m", 0.0) or 0.0)
    rects = [_cell_rect(lev, terrain.site_xy, half_m + m * lev.cell_m) for _, m in rings]
    factors = [int(f) for f, _ in rings]

    def n_quads(fs):
        total, inner = 0, 0
        for (c0, c1, r0, r1), f in zip(rects, fs):
            cells = max(0, c1 - c0) * max(0, r1 - r0)
            if f > 1:
                total += (cells - inner) * f * f
            inner = cells
        return total

    while n_quads(factors) > max_quads and any(f > 1 for f in factors):
        k = max(range(len(factors)), key=lambda i: (factors[i], -i))    # largest factor, innermost first
        factors[k] -= 1
    extra = [_upsample(lev, rect, f) for rect, f in zip(rects, factors) if f > 1 and rect[1] > rect[0]
             and rect[3] > rect[2]]
    if not extra:
        return terrain
    log.info("near field refined: factors %s, %d quads", [f for f in factors if f > 1], n_quads(factors))
    meta = dict(terrain.meta, refined_factors=[f for f in factors if f > 1])
    return MultiResTerrain(levels=[*extra, *terrain.levels], crs_wkt=terrain.crs_wkt, body=terrain.body,
                           site_xy=terrain.site_xy, dem_sha256=terrain.dem_sha256, meta=meta)


def terrain_chunks(terrain: MultiResTerrain, *, offset: SceneOffset | None = None, radius_m: float | None = None,
                   refraction_k: float = 0.0, chunk_cells: int = 256,
                   skirt_depth_m: float | None = None) -> Iterator[MeshChunk]:
    """All mesh chunks of all levels, finest first (see :func:`level_chunks`)."""
    if not terrain.levels:
        raise InvalidInputError("the terrain has no levels: build it with blender_addon.terrain.multires")
    off = offset if offset is not None else default_offset(terrain)
    for k in range(len(terrain.levels)):
        yield from level_chunks(terrain, k, offset=off, radius_m=radius_m, refraction_k=refraction_k,
                                chunk_cells=chunk_cells, skirt_depth_m=skirt_depth_m)
