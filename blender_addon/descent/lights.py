"""Light sources of Europa's sky: the Sun and Jupiter (direction, irradiance, apparent size).

Directions follow board.conventions: azimuth clockwise from grid north, elevation above the local
horizontal (degrees); ``Light.direction`` is the unit world (ENU) vector towards the source.
The default sky is equatorial Europa in the morning, 30 degrees of longitude from the sub-Jovian
point: the Sun in the east at 30 degrees, Jupiter in the west at 60 degrees (memorandum section 4.3
irradiances and sizes).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from board.conventions import enu_from_az_el_deg
from board.errors import InvalidInputError

from .constants import (JUPITER_DIAMETER_ARCMIN, JUPITER_REFLECTED_IRRADIANCE_W_M2, JUPITER_REFLECTED_SUN_W_M2,
                        JUPITER_THERMAL_IRRADIANCE_W_M2, SUN_DIAMETER_ARCMIN, SUN_IRRADIANCE_W_M2)


@dataclass(frozen=True)
class Light:
    """A distant source: name, direction (degrees), irradiance at normal incidence (W/m2), size (arcmin).

    kind : "sun" (sunlight), "reflected" (sunlight reflected by Jupiter: lights the visible and the
    thermal balance) or "thermal" (Jupiter's own infrared emission: absorbed with the emissivity,
    invisible to the visible camera).
    """

    name: str
    azimuth_deg: float
    elevation_deg: float
    irradiance_w_m2: float
    apparent_diameter_arcmin: float
    kind: str = "sun"

    def __post_init__(self) -> None:
        if self.kind not in ("sun", "reflected", "thermal"):
            raise InvalidInputError(f"light kind {self.kind!r}: use sun, reflected or thermal")
        if not (-90.0 <= self.elevation_deg <= 90.0) or self.irradiance_w_m2 < 0:
            raise InvalidInputError(f"light {self.name}: elevation {self.elevation_deg} deg must be in [-90, 90] and "
                                    f"irradiance {self.irradiance_w_m2} W/m2 >= 0")

    @property
    def direction(self) -> np.ndarray:
        """(3,) unit world vector towards the source."""
        return enu_from_az_el_deg(self.azimuth_deg, self.elevation_deg).astype(np.float64)

    def to_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, (int, float)) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> "Light":
        return cls(str(d["name"]), float(d["azimuth_deg"]), float(d["elevation_deg"]), float(d["irradiance_w_m2"]),
                   float(d.get("apparent_diameter_arcmin", 0.0)), str(d.get("kind", "sun")))


def default_lights(*, sun_azimuth_deg: float = 90.0, sun_elevation_deg: float = 30.0,
                   jupiter_azimuth_deg: float = 270.0, jupiter_elevation_deg: float = 60.0) -> list[Light]:
    """The memorandum's sources: Sun (50 W/m2, 6.14'), Jupiter's reflected light (0.0897 W/m2, 717.55') and the
    Sun's reflection in Jupiter (0.0001 W/m2), plus Jupiter's thermal emission (used by the thermal models)."""
    return [
        Light("sun", sun_azimuth_deg, sun_elevation_deg, SUN_IRRADIANCE_W_M2, SUN_DIAMETER_ARCMIN, "sun"),
        Light("jupiter", jupiter_azimuth_deg, jupiter_elevation_deg, JUPITER_REFLECTED_IRRADIANCE_W_M2,
              JUPITER_DIAMETER_ARCMIN, "reflected"),
        Light("jupiter_sun_glint", jupiter_azimuth_deg, jupiter_elevation_deg, JUPITER_REFLECTED_SUN_W_M2,
              0.0, "reflected"),
        Light("jupiter_thermal", jupiter_azimuth_deg, jupiter_elevation_deg, JUPITER_THERMAL_IRRADIANCE_W_M2,
              JUPITER_DIAMETER_ARCMIN, "thermal"),
    ]
