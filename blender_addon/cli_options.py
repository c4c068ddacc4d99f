"""The options every DEM-facing `skyloc` subcommand shares (--dem, --body, --crs, --assume-metric), declared once,
and the one conversion of a command-line position to the DEM's metric working CRS, with messages that say what
was assumed and how to fix a mistake.

Positions given on the command line are in the DEM's own CRS (lon,lat for a DEM in degrees) unless ``--crs``
names another; everything computed and written is in the DEM's metric working CRS (metres), which the outputs
name.  ``render_service``'s commands use these too (the service may import the add-on's bpy-free parts).
"""
from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import click

from board.cliargs import parse_xy
from board.errors import CrsError

log = logging.getLogger(__name__)

DEM_HELP = "DEM file, or procedural:PRESET:SEED[:SIZE_M[:RES_M]] (synthesised and cached)."
BODY_HELP = ("Body (earth, mars, moon, europa) or radius in metres; default: from the DEM's CRS "
             "(needed when the DEM has no CRS).")
CRS_HELP = ("CRS of the coordinates given here (e.g. EPSG:4326 for lon,lat, EPSG:32610, a WKT or PROJ string); "
            "default: the DEM's own CRS (lon,lat for a DEM in degrees).")
ASSUME_METRIC_HELP = "The DEM has no CRS but its coordinates are metres (give --body too)."
AT_HELP = "Position X,Y in the DEM's CRS (lon,lat for a DEM in degrees) unless --crs names another."


def dem_option(*, required: bool = True, default: str | None = None, note: str = "") -> Callable:
    """``--dem``: a DEM file or procedural spec (``note``: what this command adds, appended to the shared help)."""
    return click.option("--dem", "dem", required=required and default is None, default=default,
                        show_default=default is not None, help=f"{DEM_HELP} {note}".strip())


def at_option() -> Callable:
    """``--at``: one position on the command line, in the DEM's CRS unless ``--crs``."""
    return click.option("--at", "at", required=True, help=AT_HELP)


def body_option() -> Callable:
    """``--body``: the body when the DEM's CRS does not say (or to override it)."""
    return click.option("--body", default=None, help=BODY_HELP)


def crs_option() -> Callable:
    """``--crs``: the CRS of the positions given on the command line."""
    return click.option("--crs", default=None, help=CRS_HELP)


def assume_metric_option() -> Callable:
    """``--assume-metric``: a DEM without CRS whose coordinates are metres."""
    return click.option("--assume-metric", is_flag=True, help=ASSUME_METRIC_HELP)


def dem_options(*, crs: bool = True) -> Callable:
    """--dem, --body, --assume-metric (and --crs unless ``crs=False``) on one command."""
    opts = [dem_option(), body_option(), assume_metric_option()] + ([crs_option()] if crs else [])

    def deco(f):
        for opt in reversed(opts):
            f = opt(f)
        return f

    return deco


@dataclass(frozen=True)
class Site:
    """A command-line position: as given (``given``, in ``given_crs``) and in the DEM's working CRS (metres)."""

    dem_path: Path
    given: tuple[float, float]
    given_crs: str
    xy_m: tuple[float, float]
    working_crs_name: str

    def describe(self) -> str:
        """'(x, y) in <given CRS> -> (x, y) m in <working CRS>' for the command's output."""
        g = f"({self.given[0]:g}, {self.given[1]:g}) in {self.given_crs}"
        return f"{g} -> ({self.xy_m[0]:.2f}, {self.xy_m[1]:.2f}) m in the working CRS {self.working_crs_name!r}"


def _looks_projected(x: float, y: float) -> bool:
    return abs(x) > 360.0 or abs(y) > 90.0


def site(dem: str, value: str, name: str, *, crs: str | None, body: str | None,
         assume_metric: bool = False) -> Site:
    """Parse ``value`` ("X,Y" given to option ``name``) and convert it to the DEM's metric working CRS.

    Raises CrsError saying which CRS the numbers were taken in and what to change: projected metres
    given as lon,lat (with ``--crs EPSG:4326`` or for a DEM in degrees), lon,lat outside the valid range.
    """
    from blender_addon.terrain.crs import crs_name, srs_from_wkt  # noqa: PLC0415
    from blender_addon.terrain.dem import open_metric_source, resolve_dem, to_metric_xy  # noqa: PLC0415

    path = resolve_dem(dem)
    x, y = parse_xy(value, name)
    src = open_metric_source(path, body=body, assume_metric=assume_metric)
    if crs is not None:
        srs = srs_from_wkt(crs)
        geographic = bool(srs.IsGeographic())
        given_crs = f"{crs} ({srs.GetName()}{', lon,lat' if geographic else ''})"
    else:
        geographic = src.is_geographic
        given_crs = (f"the DEM's own CRS ({src.source_srs.GetName()}"
                     f"{', lon,lat in degrees' if geographic else ', metres'})")
    if geographic and _looks_projected(x, y):
        raise CrsError(
            f"{name} {value} was taken as lon,lat in {given_crs}, but {x:g}, {y:g} are not valid degrees: they "
            "look like projected metres (UTM or the DEM's working CRS). Give the CRS they are in "
            "(e.g. --crs EPSG:32610), or give lon,lat")
    try:
        xm, ym = to_metric_xy(x, y, dem_path=path, crs=crs, body=body, assume_metric=assume_metric)
    except CrsError as exc:
        raise CrsError(f"{name} {value} (taken in {given_crs}): {exc}. Check the numbers and --crs; "
                       "`skyloc dem info DEM` prints the DEM's bounds in the CRS --at/--center expect") from None
    if not (math.isfinite(xm) and math.isfinite(ym)):
        raise CrsError(f"{name} {value} (taken in {given_crs}) has no position in the DEM's CRS: check --crs")
    s = Site(path, (x, y), given_crs, (float(xm), float(ym)), crs_name(src.crs_wkt))
    log.info("%s %s", name, s.describe())
    return s
