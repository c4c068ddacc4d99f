"""The conventions every skyloc package shares, defined once.

World frame
    The DEM's projected, metric CRS: x east, y north (grid north), z up, metres.
    For local geometry we use ENU (east, north, up) aligned with the grid.
Azimuth
    Degrees clockwise from grid north (+y), in [0, 360).  ``az = atan2(east, north)``.
Elevation
    Degrees above the camera's local horizontal, positive up.
Heading
    Azimuth of the optical axis at pan 0.  Pitch and roll: tilt of the mast from
    the local vertical (pitch: nose up positive; roll: right side down positive).
Skyline
    Elevations sampled on a regular azimuth grid; sample ``j`` is the point sample
    at azimuth ``start + j * step`` exactly (not a bin average).  NaN = not seen.
Curvature
    A point at horizontal distance ``d`` on a sphere of radius ``R`` drops by
    ``d**2 / (2 R)`` (times ``1 - k`` with a refraction coefficient ``k``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from board.errors import InvalidInputError

DEG_PER_RAD: float = 180.0 / math.pi
RAD_PER_DEG: float = math.pi / 180.0

#: Default azimuth sampling of a skyline: 360 samples, 1 degree apart, from north.
DEFAULT_N_AZIMUTH: int = 360
DEFAULT_AZIMUTH_START_DEG: float = 0.0


@dataclass(frozen=True)
class Body:
    """A planetary body modelled as a sphere.

    name : lower-case name ("mars", "moon", ...), or "custom"
    radius_m : mean radius in metres
    """

    name: str
    radius_m: float


#: Mean radii (IAU / IAG values), metres.
BODIES: dict[str, Body] = {
    "earth": Body("earth", 6_371_008.8),
    "mars": Body("mars", 3_389_500.0),
    "moon": Body("moon", 1_737_400.0),
    "europa": Body("europa", 1_560_800.0),
}


def body_from_name(name_or_radius: str | float) -> Body:
    """Resolve a body name ("mars", ...) or a radius in metres ("3389500") to a Body."""
    if isinstance(name_or_radius, (int, float)):
        radius = float(name_or_radius)
    else:
        key = str(name_or_radius).strip().lower()
        if key in BODIES:
            return BODIES[key]
        try:
            radius = float(key)
        except ValueError:
            raise InvalidInputError(
                f"unknown body {name_or_radius!r}: use one of {', '.join(BODIES)} "
                "or a radius in metres (e.g. 3389500)"
            ) from None
    if not (1e3 <= radius <= 1e8):
        raise InvalidInputError(
            f"body radius {radius} m is implausible: give a radius in metres between 1 km and 100,000 km"
        )
    return Body("custom", radius)


def wrap_az_deg(az_deg):
    """Wrap azimuths (degrees) into [0, 360)."""
    out = np.mod(az_deg, 360.0)
    # np.mod(-1e-17, 360) == 360.0 in floating point: fold it back.
    return np.where(out >= 360.0, 0.0, out) if isinstance(out, np.ndarray) else (0.0 if out >= 360.0 else float(out))


def wrap_deg180(angle_deg):
    """Wrap an angle difference (degrees) into [-180, 180)."""
    return np.mod(np.asarray(angle_deg) + 180.0, 360.0) - 180.0


def az_from_en_deg(east, north):
    """Azimuth in degrees clockwise from grid north of a horizontal vector (east, north)."""
    return wrap_az_deg(np.degrees(np.arctan2(east, north)))


def en_from_az_deg(az_deg):
    """Unit horizontal vector (east, north) pointing at azimuth ``az_deg`` (degrees)."""
    a = np.radians(az_deg)
    return np.sin(a), np.cos(a)


def enu_from_az_el_deg(az_deg, el_deg) -> np.ndarray:
    """Unit ENU direction(s) for azimuth/elevation in degrees; shape (..., 3)."""
    a = np.radians(az_deg)
    e = np.radians(el_deg)
    ce = np.cos(e)
    return np.stack(np.broadcast_arrays(ce * np.sin(a), ce * np.cos(a), np.sin(e)), axis=-1)


def az_el_from_enu_deg(v) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (degrees) of ENU vector(s) ``v`` of shape (..., 3)."""
    v = np.asarray(v, dtype=float)
    az = az_from_en_deg(v[..., 0], v[..., 1])
    el = np.degrees(np.arctan2(v[..., 2], np.hypot(v[..., 0], v[..., 1])))
    return az, el


def azimuth_grid_deg(n: int = DEFAULT_N_AZIMUTH, start_deg: float = DEFAULT_AZIMUTH_START_DEG) -> np.ndarray:
    """Azimuths (degrees) of the ``n`` point samples of a skyline: start + j * 360/n."""
    if n <= 0:
        raise InvalidInputError(f"number of azimuths must be positive, got {n}")
    return start_deg + np.arange(n) * (360.0 / n)


def curvature_coefficient(radius_m: float, refraction_k: float = 0.0) -> float:
    """``c = (1 - k) / 2R`` (1/m): the apparent drop of a point at horizontal distance d is ``c d**2``."""
    return (1.0 - float(refraction_k)) / (2.0 * float(radius_m))


def curvature_drop_m(distance_m, radius_m: float, refraction_k: float = 0.0):
    """Apparent drop (metres) of a point at horizontal distance ``distance_m`` on a sphere.

    ``d**2 / (2 R) * (1 - k)``; ``k`` is the refraction coefficient (0 on airless bodies,
    about 0.13 on Earth).
    """
    return np.asarray(distance_m, dtype=float) ** 2 * curvature_coefficient(radius_m, refraction_k)


def horizon_dip_deg(height_m: float, radius_m: float) -> float:
    """Dip (degrees, positive) of the geometric horizon of a smooth sphere seen from ``height_m``."""
    return math.degrees(math.acos(radius_m / (radius_m + height_m)))


def rotation_enu_from_camera(heading_deg: float, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """Rotation matrix taking body-frame vectors to ENU.

    Body frame: x forward (heading direction), y left, z up.  Applied as
    ENU = Rz(heading) @ Ry(pitch) @ Rx(roll) @ body, with heading measured clockwise
    from north, pitch positive nose-up, roll positive right-side-down.
    Returns (3, 3) ndarray.
    """
    h = math.radians(heading_deg)
    p = math.radians(pitch_deg)
    r = math.radians(roll_deg)
    # forward axis in ENU at heading h, level: (sin h, cos h, 0); left axis: (-cos h, sin h, 0)
    R_heading = np.array(
        [[math.sin(h), -math.cos(h), 0.0], [math.cos(h), math.sin(h), 0.0], [0.0, 0.0, 1.0]]
    )
    # pitch about the left (y) axis: nose-up positive
    R_pitch = np.array([[math.cos(p), 0.0, -math.sin(p)], [0.0, 1.0, 0.0], [math.sin(p), 0.0, math.cos(p)]])
    # roll about the forward (x) axis: right side down positive (left side up)
    R_roll = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(r), -math.sin(r)], [0.0, math.sin(r), math.cos(r)]])
    return R_heading @ R_pitch @ R_roll
