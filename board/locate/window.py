"""Windows of the database around a grid node, and the position limits a refinement stays within.

Rows and columns are grid indices (fractional for refined positions); the database's geotransform
turns them into metres of its CRS.
"""
from __future__ import annotations

import numpy as np

from board.match.search import Region, fill_missing
from board.pose.refine import LocalDB
from board.skydb import GridSpec, SkyDB, Tile


def local_db(db: SkyDB, row: int, col: int, half: int = 2, *, parallax: bool = False,
             stored_heights: bool = True) -> LocalDB:
    """Node skylines within ``half`` nodes of (row, col); with ``parallax`` and stored horizon distances,
    a window that interpolates with parallax (see :mod:`board.pose.parallax`), moving the eye by the stored
    ground heights when the store holds them and ``stored_heights`` is set (else estimated from the skylines)."""
    g = db.grid
    r0, c0 = max(row - half, 0), max(col - half, 0)
    r1, c1 = min(row + half + 1, g.ny), min(col + half + 1, g.nx)
    win = Tile(-1, -1, r0, c0, r1 - r0, c1 - c0)
    el = db.read_tile(win).astype(np.float64)
    flat = el.reshape(-1, el.shape[2])
    fill_missing(flat)
    if not np.isfinite(flat).all():
        # a neighbour without a skyline: replace by the candidate's own (keeps the window usable)
        own = flat[(row - r0) * (c1 - c0) + (col - c0)]
        bad = ~np.isfinite(flat).all(axis=1)
        flat[bad] = own
    dist = db.read_distance(win) if parallax and db.meta.has_distance else None
    if dist is None:
        return LocalDB(flat.reshape(el.shape), r0, c0, db.meta.azimuth_start_deg)
    ground = db.read_ground(win) if stored_heights else None
    return LocalDB(flat.reshape(el.shape), r0, c0, db.meta.azimuth_start_deg, dist=dist.astype(np.float64),
                   cell_m=(g.geotransform[1], g.geotransform[5]),
                   ground=None if ground is None else ground.astype(np.float64))


def position_limits(grid: GridSpec, region: Region) -> dict[str, tuple[float, float]]:
    """Fractional (row, col) limits of a refined position: the region's bounding box plus half a node,
    inside the grid."""
    return {"row": (max(region.row0 - 0.5, 0), min(region.row0 + region.nrows - 0.5, grid.ny - 1)),
            "col": (max(region.col0 - 0.5, 0), min(region.col0 + region.ncols - 0.5, grid.nx - 1))}


def box(row: int, col: int, half: float, limits: dict[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
    """Refinement bounds: +-``half`` nodes around (row, col), within ``limits``."""
    return {k: (max(c - half, limits[k][0]), min(c + half, limits[k][1])) for k, c in (("row", row), ("col", col))}


def on_limits(values: dict, limits: dict[str, tuple[float, float]], tol: float) -> bool:
    """True when the fractional position ``values["row"], values["col"]`` is within ``tol`` nodes of ``limits``."""
    return any(min(values[k] - lo, hi - values[k]) < tol for k, (lo, hi) in limits.items())


def near_grid_edge(grid: GridSpec, row: float, col: float, steps: float = 1.0) -> bool:
    """True when the fractional grid position (row, col) lies within ``steps`` grid steps of the grid's edge
    (the outermost nodes are the edge)."""
    return bool(min(row, col, grid.ny - 1 - row, grid.nx - 1 - col) < steps)
