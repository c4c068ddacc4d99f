"""Coordinate reference systems and bodies for DEM import (GDAL/OSR, no bpy).

Decides which body a CRS lives on (from its ellipsoid, or an explicit ``body=``),
and builds the local metric working CRS a geographic DEM is reprojected into:
an azimuthal equidistant projection centred on the DEM (see docs/terrain.md).
"""
from __future__ import annotations

import logging
import math

from osgeo import osr

from board.conventions import BODIES, Body, body_from_name
from board.errors import CrsError, InvalidInputError

log = logging.getLogger(__name__)
osr.UseExceptions()

#: Ranges of ellipsoid semi-major axes (metres) that identify a body.
#: Earth: every terrestrial ellipsoid (Clarke 1866 6378206.4, GRS80, WGS84, ...);
#: Mars: IAU 2000 3396190 and the mean sphere 3389500; Moon 1737400; Europa ~1560800.
_SEMI_MAJOR_RANGES: tuple[tuple[str, float, float], ...] = (
    ("earth", 6_350_000.0, 6_400_000.0),
    ("mars", 3_370_000.0, 3_400_000.0),
    ("moon", 1_730_000.0, 1_745_000.0),
    ("europa", 1_555_000.0, 1_566_000.0),
)

BODY_HINT = "pass --body NAME|RADIUS (Python: body=...), NAME one of earth, mars, moon, europa, or a radius in metres"


def srs_from_wkt(wkt: str) -> osr.SpatialReference:
    """SpatialReference from WKT (or any user input GDAL accepts), axis order x=east/lon, y=north/lat."""
    srs = osr.SpatialReference()
    try:
        srs.SetFromUserInput(wkt)
    except RuntimeError as exc:
        raise CrsError(f"cannot parse the CRS {wkt[:80]!r}: {exc}; give an EPSG code, a WKT or a PROJ string") from None
    srs.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
    return srs


def body_from_semi_major(semi_major_m: float) -> Body | None:
    """Body whose reference ellipsoid has this semi-major axis (metres), or None when unknown."""
    for name, lo, hi in _SEMI_MAJOR_RANGES:
        if lo <= semi_major_m <= hi:
            return BODIES[name]
    return None


def resolve_body(srs: osr.SpatialReference | None, body: str | float | Body | None) -> tuple[Body, bool]:
    """Body of a DEM: the explicit ``body`` if given, else the one the CRS's ellipsoid names.

    Returns ``(body, overrides_crs)``; ``overrides_crs`` is True when an explicit body
    disagrees with (or cannot be checked against) the CRS's ellipsoid, in which case
    geographic coordinates are taken on a sphere of the explicit body's radius.
    Raises CrsError when neither gives a known body.
    """
    from_crs = body_from_semi_major(srs.GetSemiMajor()) if srs is not None else None
    if body is not None:
        try:
            explicit = body if isinstance(body, Body) else body_from_name(body)
        except InvalidInputError as exc:
            raise CrsError(str(exc)) from None
        if from_crs is None:
            return explicit, True
        if from_crs.name != explicit.name and not math.isclose(from_crs.radius_m, explicit.radius_m, rel_tol=0.01):
            log.warning(
                "the CRS's ellipsoid (semi-major %.0f m) looks like %s but body=%s was given: using %s",
                srs.GetSemiMajor(), from_crs.name, explicit.name, explicit.name,
            )
            return explicit, True
        return explicit, False
    if from_crs is None:
        a = srs.GetSemiMajor() if srs is not None else float("nan")
        raise CrsError(f"cannot tell which body this DEM is on (ellipsoid semi-major axis {a:.0f} m): {BODY_HINT}")
    return from_crs, False


def is_geographic(srs: osr.SpatialReference) -> bool:
    """True when the CRS's coordinates are angles (degrees) rather than lengths."""
    return bool(srs.IsGeographic())


def linear_unit_m(srs: osr.SpatialReference) -> float:
    """Metres per unit of a projected CRS."""
    return float(srs.GetLinearUnits())


def local_aeqd_srs(
    center_lon: float, center_lat: float, *, base: osr.SpatialReference | None, body: Body
) -> osr.SpatialReference:
    """Azimuthal equidistant projection centred on (lon, lat), metres.

    With ``base`` (a geographic CRS) the projection keeps that datum and ellipsoid, so no
    datum shift happens on reprojection.  Without it the projection is on a sphere of the
    body's mean radius.  Distances from the centre are true; at 10 km from it scale errors
    are below 1e-5 (Earth) / 2e-5 (Moon).
    """
    lon = round(float(center_lon), 6)
    lat = round(float(center_lat), 6)
    srs = osr.SpatialReference()
    if base is not None:
        srs.CopyGeogCSFrom(base)
        srs.SetProjCS(f"skyloc local azimuthal equidistant ({body.name}) lat {lat} lon {lon}")
        srs.SetAE(lat, lon, 0.0, 0.0)
        srs.SetLinearUnits(osr.SRS_UL_METER, 1.0)
    else:
        srs.ImportFromProj4(f"+proj=aeqd +lat_0={lat} +lon_0={lon} +x_0=0 +y_0=0 +R={body.radius_m} +units=m +no_defs")
    srs.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
    return srs


def sphere_geographic_srs(body: Body) -> osr.SpatialReference:
    """Longitude/latitude on a sphere of the body's mean radius."""
    srs = osr.SpatialReference()
    srs.ImportFromProj4(f"+proj=longlat +R={body.radius_m} +no_defs")
    srs.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
    return srs


_BODY_TITLES = {"mars": "Mars", "moon": "Moon", "europa": "Europa", "earth": "Earth"}


def body_equirectangular_srs(body: Body) -> osr.SpatialReference:
    """Equirectangular (equidistant cylindrical, lat_ts 0, lon_0 0) projection on the body's sphere, metres.

    Used for procedural terrain and for rasters declared metric without a CRS: near
    (0, 0) it is a true-scale local metric frame.  The GEOGCS carries the body's name and
    radius so any reader (QGIS, skyloc) identifies the body.
    """
    title = _BODY_TITLES.get(body.name, "Custom body")
    srs = osr.SpatialReference()
    srs.SetProjCS(f"{title} (sphere R={body.radius_m:.0f} m) equirectangular")
    srs.SetGeogCS(f"{title} sphere", f"D_{title.replace(' ', '_')}", f"{title} sphere", body.radius_m, 0.0)
    srs.SetEquirectangular2(0.0, 0.0, 0.0, 0.0, 0.0)
    srs.SetLinearUnits(osr.SRS_UL_METER, 1.0)
    srs.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
    return srs


def geographic_cell_m(srs: osr.SpatialReference, lat_deg: float, dlon_deg: float, dlat_deg: float) -> tuple[float, float]:
    """East-west and north-south ground size (metres) of a (dlon, dlat) degree cell at latitude ``lat_deg``.

    Uses the CRS's ellipsoid (prime-vertical and meridian radii of curvature).
    """
    a = srs.GetSemiMajor()
    b = srs.GetSemiMinor()
    e2 = 1.0 - (b * b) / (a * a)
    phi = math.radians(lat_deg)
    w = math.sqrt(1.0 - e2 * math.sin(phi) ** 2)
    n = a / w
    m = a * (1.0 - e2) / w**3
    return n * math.cos(phi) * math.radians(abs(dlon_deg)), m * math.radians(abs(dlat_deg))


def crs_name(wkt: str) -> str:
    """Human-readable name of a CRS given as WKT ("unknown CRS" when empty)."""
    if not wkt:
        return "unknown CRS"
    srs = osr.SpatialReference()
    srs.ImportFromWkt(wkt)
    return srs.GetName() or "unnamed CRS"
