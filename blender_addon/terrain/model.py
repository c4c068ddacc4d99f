"""In-memory terrain types shared by the importer, the multi-resolution builder and renderers.

All coordinates are in the DEM's projected metric CRS (x east, y north, metres);
heights are metres above the body's reference sphere/datum.  Arrays are row-major with
row 0 at the north edge (GDAL north-up convention).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from board.conventions import Body


@dataclass
class DemRaster:
    """A DEM in a projected metric CRS.

    array : (rows, cols) ndarray float32, metres, NaN where nodata
    geotransform : GDAL geotransform (north-up: gt[2] == gt[4] == 0)
    crs_wkt : WKT of the projected metric CRS
    body : the body the heights live on (radius used for curvature)
    sha256 : content hash of the source file (the database records it)
    """

    array: np.ndarray
    geotransform: tuple[float, float, float, float, float, float]
    crs_wkt: str
    body: Body
    sha256: str = ""
    source: str = ""

    @property
    def cell_m(self) -> float:
        return abs(self.geotransform[1])

    @property
    def shape(self) -> tuple[int, int]:
        return self.array.shape  # type: ignore[return-value]

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the raster's outer edges, metres."""
        gt = self.geotransform
        rows, cols = self.array.shape
        x0, x1 = gt[0], gt[0] + cols * gt[1]
        y0, y1 = gt[3], gt[3] + rows * gt[5]
        return min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)


@dataclass
class TerrainLevel:
    """One level of a multi-resolution terrain: a north-up grid of heights.

    array : (rows, cols) ndarray float32, metres (max-downsampled from the source), NaN = no data
    x0, y0 : x of the west edge of column 0 and y of the north edge of row 0, metres
    cell_m : cell size, metres (square cells)
    Cell (r, c) has its centre at (x0 + (c + 0.5) cell_m, y0 - (r + 0.5) cell_m).
    """

    array: np.ndarray
    x0: float
    y0: float
    cell_m: float
    path: str = ""

    @property
    def geotransform(self) -> tuple[float, float, float, float, float, float]:
        return (self.x0, self.cell_m, 0.0, self.y0, 0.0, -self.cell_m)

    def bounds(self) -> tuple[float, float, float, float]:
        rows, cols = self.array.shape
        return self.x0, self.y0 - rows * self.cell_m, self.x0 + cols * self.cell_m, self.y0


@dataclass
class MultiResTerrain:
    """Nested terrain levels around a site, finest first.

    Level 0 is the native DEM around the site; each following level covers a larger
    area with coarser cells.  A renderer samples, at any point, the finest level whose
    extent contains it.
    """

    levels: list[TerrainLevel]
    crs_wkt: str
    body: Body
    site_xy: tuple[float, float]
    dem_sha256: str = ""
    meta: dict = field(default_factory=dict)

    @property
    def finest(self) -> TerrainLevel:
        return self.levels[0]
