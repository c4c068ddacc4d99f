"""Missing-data handling for DEM windows: fill small holes, refuse areas with too much missing.

A *hole* is a connected (8-neighbour) group of nodata cells that does not touch the
window's border; nodata that touches the border is the edge of the DEM's footprint
(e.g. a reprojected or quadrangle-shaped DEM) and stays NaN.  Holes of at most
``max_hole_cells`` cells are filled by GDAL's inverse-distance interpolation
(``gdal.FillNodata``); larger ones stay NaN.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from osgeo import gdal
from scipy import ndimage

from board.errors import NoDataError

log = logging.getLogger(__name__)
gdal.UseExceptions()

#: Default largest hole filled (cells): 64 x 64.
DEFAULT_MAX_HOLE_CELLS = 4096
#: Default largest fraction of a read window left missing after filling.
DEFAULT_MAX_MISSING_FRACTION = 0.25


@dataclass
class FillReport:
    """What :func:`fill_small_holes` did.

    n_missing : nodata cells before filling
    n_filled : cells filled (in holes of at most max_hole_cells)
    n_holes_filled, n_holes_left : interior holes filled / left (too large)
    missing_fraction : fraction of the window still NaN afterwards
    missing_bbox_rc : (row0, col0, row1, col1) bounding box (inclusive) of what is still NaN, or None
    """

    n_missing: int = 0
    n_filled: int = 0
    n_holes_filled: int = 0
    n_holes_left: int = 0
    missing_fraction: float = 0.0
    missing_bbox_rc: tuple[int, int, int, int] | None = None


def _bbox(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    return int(rows[0]), int(cols[0]), int(rows[-1]), int(cols[-1])


def fill_small_holes(array: np.ndarray, *, max_hole_cells: int = DEFAULT_MAX_HOLE_CELLS) -> FillReport:
    """Fill, in place, the interior nodata holes (NaN) of ``array`` with at most ``max_hole_cells`` cells.

    array : (rows, cols) float32/float64 ndarray, NaN = nodata; modified in place.
    Returns a :class:`FillReport`.
    """
    missing = np.isnan(array)
    report = FillReport(n_missing=int(missing.sum()))
    if report.n_missing == 0:
        return report
    labels, n = ndimage.label(missing, structure=np.ones((3, 3), dtype=bool))
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    border = np.zeros(n + 1, dtype=bool)
    for edge in (labels[0, :], labels[-1, :], labels[:, 0], labels[:, -1]):
        border[edge] = True
    border[0] = False
    fillable = (~border) & (sizes <= max_hole_cells)
    fillable[0] = False
    report.n_holes_filled = int(fillable.sum())
    report.n_holes_left = int(((~border) & ~fillable).sum()) - 1  # minus label 0 (valid cells)
    if report.n_holes_filled:
        target = fillable[labels]
        _idw_fill(array, missing, target, max_hole_cells)
        report.n_filled = int(target.sum())
        still = np.isnan(array)
    else:
        still = missing
    report.missing_fraction = float(still.mean())
    report.missing_bbox_rc = _bbox(still)
    if report.n_holes_left:
        log.warning("%d nodata hole(s) larger than %d cells left unfilled", report.n_holes_left, max_hole_cells)
    return report


def _idw_fill(array: np.ndarray, missing: np.ndarray, target: np.ndarray, max_hole_cells: int) -> None:
    """Inverse-distance fill of ``target`` cells (a subset of ``missing``) with gdal.FillNodata."""
    r0, c0, r1, c1 = _bbox(target)  # type: ignore[misc]
    pad = int(math.ceil(math.sqrt(max_hole_cells))) + 2
    r0, c0 = max(r0 - pad, 0), max(c0 - pad, 0)
    r1, c1 = min(r1 + pad, array.shape[0] - 1), min(c1 + pad, array.shape[1] - 1)
    sub = array[r0 : r1 + 1, c0 : c1 + 1]
    sub_missing = missing[r0 : r1 + 1, c0 : c1 + 1]
    sub_target = target[r0 : r1 + 1, c0 : c1 + 1]
    rows, cols = sub.shape
    mem = gdal.GetDriverByName("MEM")
    ds = mem.Create("", cols, rows, 1, gdal.GDT_Float64)
    band = ds.GetRasterBand(1)
    band.WriteArray(np.where(sub_missing, 0.0, sub).astype(np.float64))
    mds = mem.Create("", cols, rows, 1, gdal.GDT_Byte)
    mband = mds.GetRasterBand(1)
    mband.WriteArray(np.where(sub_missing, 0, 255).astype(np.uint8))
    gdal.FillNodata(band, mband, maxSearchDist=float(pad * 2), smoothingIterations=0)
    filled = band.ReadAsArray()
    sub[sub_target] = filled[sub_target].astype(sub.dtype)


def check_missing(
    report: FillReport,
    *,
    max_fraction: float,
    geotransform: tuple[float, ...],
    what: str = "the area read",
    fix: str = "",
) -> None:
    """Raise NoDataError when more than ``max_fraction`` of a window is still missing.

    The message gives the fraction and the bounding box of the missing cells in the
    window's metric CRS (from ``geotransform``).
    """
    if report.missing_fraction <= max_fraction or report.missing_bbox_rc is None:
        return
    r0, c0, r1, c1 = report.missing_bbox_rc
    gt = geotransform
    xa, xb = gt[0] + c0 * gt[1], gt[0] + (c1 + 1) * gt[1]
    ya, yb = gt[3] + r0 * gt[5], gt[3] + (r1 + 1) * gt[5]
    raise NoDataError(
        f"{report.missing_fraction:.1%} of {what} has no data (allowed {max_fraction:.1%}), "
        f"missing cells within x {min(xa, xb):.1f}..{max(xa, xb):.1f}, y {min(ya, yb):.1f}..{max(ya, yb):.1f} m "
        f"(rows {r0}..{r1}, cols {c0}..{c1}); "
        + (fix or "choose an area inside the DEM's data, fill the gap (gdal_fillnodata) or use a complete DEM")
    )
